"""The stack-switching policy of papers/003 (Sec. 5, Fig. 3) with the smooth transitions of eq. (8).

Four stacks, highest priority first (Fig. 7 numbers them 1-4):

1. force:          force > orientation > manipulability > joint limit
2. manipulability: position (held) > orientation > manipulability > joint limit
3. joint limit:    position (held) > orientation > joint limit > manipulability
4. pose:           position (held) > orientation

Selection at every step: no operator force (``||f|| <= force_threshold``) -> pose; else some
``|q_i - q_i^*| > sigma_bar_l`` -> joint limit; else ``sigma_m < sigma_bar_m`` -> manipulability; else
force. (When both conditions hold the joint-limit stack wins: a mechanical limit is the harder
constraint; the paper does not say.) "Held": the position target is set to the flange position at
the moment of the switch from a stack without the position task (force) into one with it; between
the holding stacks it is kept.

On the iiwa (a spherical wrist, flange offset d7 along the flange z axis) the held position and the
2-D orientation fix the wrist centre, and with it the elbow angle q_4 (it sets the shoulder-wrist
distance): the joint-limit stack stops a joint-4 excursion but cannot undo it, whatever the gain of
the joint-limit task; only the operator pulling back does (iiwa_comanipulation: joint 4 stays at
2.00 rad until the simulated operator gives up on its marker).

Transitions (eq. (8), after Caccavale et al. 2013): at a switch at ``t_s`` the offset
``d = qd_old(t_s) - qd_new(t_s)`` is taken between the old and the new stack's solutions *at the
same state*, and the command is ``qd(t) = qd_new(t) + exp(-(t - t_s)/tau) d``. Both solutions come
from the controller's own solver (the ``blend`` hook re-solves the old stack with it), so this
works with any solver (tpm, sns_tpm, qp...). ``qd_old(t_s)`` includes what is left of a transition
still under way, so a switch during a transition is continuous too (the paper waits ``t >> tau``;
an operator near a threshold does not). At the switch step the command equals the old one; from
then on it changes per step by at most ``(1 - exp(-T/tau)) ||d||`` more than the new stack's own
command does. At acceleration level the same blend acts on ``qdd``. With a box (sns_tpm, sns, qp
with ``[limits]``) the controller clips the blended command into the box (the offset was taken at
the switch, the box is the current one), so the hard limits hold during a transition. ``--crosscheck`` compares
the blended command with the other solver's unblended one (the difference includes the offset).

``tau = 0.1 s`` (default; the paper gives no value): with T = 1 ms a switch adds at most 1 % of
the jump per step; and the old motion goes on for about ``tau``, so a joint moving at
``qd`` passes its threshold by about ``qd tau`` -- 0.05 rad at 0.5 rad/s, less than the 0.094 rad
between ``sigma_bar_l = 2 rad`` and the +-120 deg limits of the iiwa joints 2, 4, 6. ``tau = 0``
switches without smoothing.

``probe`` records per step: ``stack_id`` (1-4 as above), ``sigma_m``, ``sigma_l``,
``joint_deviation_max`` (max ``|q_i - q_i^*|``), ``joint_limit_margin`` (smallest distance of a joint
to its limit, rad), ``operator_force`` (world, N) and ``operator_force_norm``, ``marker``,
``blend_weight`` and ``blend_offset`` (``||exp(-(t - t_s)/tau) d||``, rad/s).
"""

from __future__ import annotations

import math

import numpy as np

from hqp_tpm.control.policy import SceneItems, StackPolicy
from hqp_tpm.control.stack import Stack
from hqp_tpm.errors import ParameterError
from hqp_tpm.references.operator import Operator
from hqp_tpm.references.trajectories import Constant
from hqp_tpm.robot.state import State
from hqp_tpm.tasks import Force, FramePosition, JointLimit, Manipulability
from hqp_tpm.tasks.base import Task

#: Stack names in the order of the paper's Fig. 7 (stack_id = index + 1).
STACKS = ("force", "manipulability", "joint_limit", "pose")


class ComanipulationIndices:
    """The quantities recorded by both co-manipulation policies (switching and admittance)."""

    channels = ("sigma_m", "sigma_l", "joint_deviation_max", "joint_limit_margin", "operator_force",
                "operator_force_norm", "marker")

    def __init__(self, manipulability: Manipulability, joint_limit: JointLimit, operator: Operator | None):
        self.manipulability, self.joint_limit, self.operator = manipulability, joint_limit, operator

    def probe(self, ctrl, res) -> dict:
        st = ctrl.state
        f = self.operator.force if self.operator is not None else np.zeros(3)
        return {"sigma_m": float(self.manipulability.value(st)[0]), "sigma_l": float(self.joint_limit.value(st)[0]),
                "joint_deviation_max": float(self.joint_limit.deviation(st).max()),
                "joint_limit_margin": float(self.joint_limit.margin(st).min()),
                "operator_force": f.copy(), "operator_force_norm": float(np.linalg.norm(f)),
                "marker": float(self.operator.marker if self.operator is not None else -1)}

    def summary(self, arrays: dict, sigma_m_bar: float) -> dict:
        """Run summary: extreme values, time below the manipulability threshold, markers reached."""
        dt = float(arrays["t"][1] - arrays["t"][0]) if arrays["t"].size > 1 else 0.0
        out = {"sigma_m_min": float(arrays["sigma_m"].min()), "sigma_m_mean": float(arrays["sigma_m"].mean()),
               "sigma_m_below_threshold_s": float((arrays["sigma_m"] < sigma_m_bar).sum() * dt),
               "sigma_l_max": float(arrays["sigma_l"].max()),
               "joint_deviation_max": float(arrays["joint_deviation_max"].max()),
               "joint_limit_margin_min": float(arrays["joint_limit_margin"].min()),
               "operator_force_max": float(arrays["operator_force_norm"].max())}
        if self.operator is not None:
            out["markers_reached"] = [int(k) for k, _ in self.operator.reached]
            out["markers_reached_t"] = [float(t) for _, t in self.operator.reached]
            out["markers_skipped"] = [int(k) for k, _ in self.operator.skipped]
        return out


class Switching(StackPolicy):
    """Fig. 3 of papers/003: pose / force / manipulability / joint-limit stacks, eq. (8) transitions."""

    blends = True
    channels = (*ComanipulationIndices.channels, "stack_id", "blend_weight", "blend_offset")

    def __init__(self, position: FramePosition, orientation: Task, force: Force, manipulability: Manipulability,
                 joint_limit: JointLimit, *, sigma_m_bar: float = 1.5, sigma_l_bar: float = 2.0,
                 force_threshold: float = 2.0, tau: float = 0.1, operator: Operator | None = None):
        for name, v in (("sigma_m_bar", sigma_m_bar), ("sigma_l_bar", sigma_l_bar),
                        ("force_threshold", force_threshold), ("tau", tau)):
            if not (np.isfinite(v) and v >= 0):
                raise ParameterError(f"switching policy: {name} = {v!r} must be finite and >= 0")
        self.position, self.orientation, self.force = position, orientation, force
        self.manipulability, self.joint_limit = manipulability, joint_limit
        self.sigma_m_bar, self.sigma_l_bar = float(sigma_m_bar), float(sigma_l_bar)
        self.force_threshold, self.tau = float(force_threshold), float(tau)
        self.operator = operator
        if operator is not None:
            force.source = operator.sensor_force
        self.stacks = {
            "force": Stack.of(force, orientation, manipulability, joint_limit),
            "manipulability": Stack.of(position, orientation, manipulability, joint_limit),
            "joint_limit": Stack.of(position, orientation, joint_limit, manipulability),
            "pose": Stack.of(position, orientation),
        }
        self.indices = ComanipulationIndices(manipulability, joint_limit, operator)
        self.thresholds = {"sigma_m": {"sigma_bar_m": sigma_m_bar},
                           "joint_deviation_max": {"sigma_bar_l": sigma_l_bar}}
        self.active: str | None = None
        self.switches: list[tuple[float, str, str]] = []  # (t, from, to)
        self._switched = False
        self._old: Stack | None = None
        self._offset: np.ndarray | None = None
        self._t_switch = 0.0

    # hooks -------------------------------------------------------------------------------------
    def tasks(self) -> list[Task]:
        return [self.position, self.orientation, self.force, self.manipulability, self.joint_limit]

    def scene(self) -> SceneItems:
        return SceneItems(operator=self.operator)

    def update(self, state: State, t: float) -> None:
        if self.operator is not None:
            self.operator.update(state, t)

    def snapshot(self):
        """Active stack, switches, eq. (8) offset and switch time, the held position target, the operator."""
        return (self.active, len(self.switches), self._switched, self._old, self._offset, self._t_switch,
                self.position.trajectory, self.operator.snapshot() if self.operator is not None else None)

    def restore(self, snapshot) -> None:
        (self.active, n, self._switched, self._old, self._offset, self._t_switch, self.position.trajectory,
         op) = snapshot
        del self.switches[n:]
        if self.operator is not None:
            self.operator.restore(op)

    # the policy --------------------------------------------------------------------------------
    def select(self, state: State) -> str:
        """The stack the switching conditions of Fig. 3 ask for at ``state``."""
        if np.linalg.norm(self.force.value(state)) <= self.force_threshold:
            return "pose"
        if self.joint_limit.deviation(state).max() > self.sigma_l_bar:
            return "joint_limit"
        if self.manipulability.value(state)[0] < self.sigma_m_bar:
            return "manipulability"
        return "force"

    def __call__(self, state: State, t: float) -> Stack:
        name = self.select(state)
        if name != self.active:
            if self.active is None or self.active == "force":  # the position is held from the switch on
                p = self.position.value(state).copy()
                self.position.trajectory = Constant(value=p)
                self.position.trajectory.start(p)
            if self.active is not None:
                self.switches.append((t, self.active, name))
                self._old = self.stacks[self.active]
                self._switched = True
            self.active = name
        return self.stacks[name]

    def weight(self, t: float) -> float:
        """``exp(-(t - t_s)/tau)`` of eq. (8) (0 without a transition)."""
        if self._offset is None or self.tau == 0:
            return 0.0
        return math.exp(-(t - self._t_switch) / self.tau)

    def blend(self, state: State, t: float, stack: Stack, x: np.ndarray, resolve) -> np.ndarray:
        """Eq. (8): ``qd_new(t) + exp(-(t - t_s)/tau) (qd_old(t_s) - qd_new(t_s))``."""
        if self._switched:
            self._switched = False
            if self.tau > 0:
                old = resolve(self._old)
                if self._offset is not None:
                    old = old + self.weight(t) * self._offset  # a transition still under way
                self._offset, self._t_switch = old - x, t
        w = self.weight(t)
        if w < 1e-12:
            self._offset = None
            return x
        return x + w * self._offset

    def probe(self, ctrl, res) -> dict:
        w = self.weight(res.t)
        return {**self.indices.probe(ctrl, res), "stack_id": float(STACKS.index(self.active) + 1),
                "blend_weight": w,
                "blend_offset": float(w * np.linalg.norm(self._offset)) if self._offset is not None else 0.0}

    def summary(self, arrays: dict) -> dict:
        out = self.indices.summary(arrays, self.sigma_m_bar)
        dt = float(arrays["t"][1] - arrays["t"][0]) if arrays["t"].size > 1 else 0.0
        out["time_in_named_stack_s"] = {s: float((arrays["stack_id"] == i + 1).sum() * dt)
                                        for i, s in enumerate(STACKS)}
        return out
