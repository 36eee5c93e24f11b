"""A simulated human operator for the co-manipulation of papers/003 (Sec. 6, Fig. 4).

The operator's hand holds the force sensor on the flange and pulls the end effector through a list
of markers (the paper's square: four markers), one after the other:

* a spring-damper hand: ``f = K_h (m_k - p) - D_h pdot`` (world frame; ``p``, ``pdot``: flange
  position and velocity, ``m_k``: the current marker);
* force saturation: the norm of ``f`` is limited to ``f_max`` (a person pushes with bounded force);
* a first-order lag of time constant ``lag`` (s) between that spring-damper force and the force
  applied (a hand does not apply a force step: at a marker switch or at ``t_start`` the force rises
  over about ``lag``; ``lag = 0``: no lag);
* noise: independent Gaussian noise of standard deviation ``noise`` (N) per axis, from a generator
  seeded with ``seed`` (runs are reproducible);
* marker switch: marker ``k`` counts as reached when ``||m_k - p|| < reach``; the operator then pulls
  towards ``m_{k+1}``. After ``give_up`` seconds on one marker without reaching it (the robot
  refuses to go there) the operator moves on to the next one. After the last marker the hand lets
  go: the force is zero from then on, as it is before ``t_start``.

The sensor reads ``f^s = R_s^T f`` (the force applied on it, in the sensor = flange frame), which
is what :class:`~hqp_tpm.tasks.force.Force` takes from :meth:`Operator.sensor_force`. The force is
computed once per control step by :meth:`Operator.update` (called by the policy's ``update``), so every
reader in one step sees the same noisy sample; :meth:`snapshot`/:meth:`restore` undo a rejected step.
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.errors import ParameterError, ShapeError
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State


class Operator:
    """Spring-damper hand pulling the flange through ``markers`` (N x 3, world frame, m)."""

    def __init__(self, robot: Robot, frame: str, markers, *, stiffness: float = 200.0, damping: float = 20.0,
                 f_max: float = 20.0, noise: float = 0.5, seed: int = 0, reach: float = 0.02,
                 give_up: float = 10.0, t_start: float = 0.5, lag: float = 0.1):
        self.fid = robot.frame_id(frame)
        self.markers = np.asarray(markers, dtype=float)
        if self.markers.ndim != 2 or self.markers.shape[1] != 3 or not len(self.markers):
            raise ShapeError(f"operator markers must be an N x 3 array (N >= 1), got shape {self.markers.shape}")
        if not np.isfinite(self.markers).all():
            raise ShapeError("operator markers hold non-finite values")
        for name, v in (("stiffness", stiffness), ("damping", damping), ("f_max", f_max), ("noise", noise),
                        ("reach", reach), ("give_up", give_up), ("t_start", t_start), ("lag", lag)):
            if not (np.isfinite(v) and v >= 0):
                raise ParameterError(f"operator {name} = {v!r} must be finite and >= 0")
        self.stiffness, self.damping, self.f_max, self.noise = stiffness, damping, f_max, noise
        self.reach, self.give_up, self.t_start, self.lag = reach, give_up, t_start, lag
        self._hand = np.zeros(3)  # the lagged spring-damper force (before noise)
        self._t_last: float | None = None
        self.rng = np.random.default_rng(seed)
        self.marker = 0  # index of the marker pulled towards (len(markers): done, hand off)
        self.reached: list[tuple[int, float]] = []  # (marker, time) of every marker reached
        self.skipped: list[tuple[int, float]] = []  # (marker, time) of every marker given up
        self._since = t_start
        self.force = np.zeros(3)  # world frame
        self._sensor = np.zeros(3)

    @property
    def done(self) -> bool:
        return self.marker >= len(self.markers)

    @property
    def touching(self) -> bool:
        return bool(np.any(self.force))

    def update(self, state: State, t: float) -> None:
        """The hand force at this step (once per step; advances the marker and the noise generator)."""
        if t < self.t_start or self.done:
            self.force = np.zeros(3)
            self._sensor = np.zeros(3)
            return
        p = state.position(self.fid)
        if np.linalg.norm(self.markers[self.marker] - p) < self.reach:
            self.reached.append((self.marker, t))
            self.marker, self._since = self.marker + 1, t
        elif t - self._since > self.give_up:
            self.skipped.append((self.marker, t))
            self.marker, self._since = self.marker + 1, t
        if self.done:
            self.force, self._sensor, self._hand = np.zeros(3), np.zeros(3), np.zeros(3)
            return
        pdot = state.jacobian(self.fid)[:3] @ state.v
        f = self.stiffness * (self.markers[self.marker] - p) - self.damping * pdot
        norm = np.linalg.norm(f)
        if norm > self.f_max:
            f *= self.f_max / norm
        dt = 0.0 if self._t_last is None else t - self._t_last
        self._t_last = t
        a = 1.0 if self.lag == 0 else 1.0 - np.exp(-dt / self.lag)  # exact step of the first-order lag
        self._hand = self._hand + a * (f - self._hand)
        self.force = self._hand + self.noise * self.rng.standard_normal(3)
        self._sensor = state.rotation(self.fid).T @ self.force

    def snapshot(self) -> tuple:
        """Everything :meth:`update` changes: lag filter, noise generator, marker, force (a rejected step)."""
        return (self._hand, self._t_last, self.rng.bit_generator.state, self.marker, len(self.reached),
                len(self.skipped), self._since, self.force, self._sensor)

    def restore(self, snapshot: tuple) -> None:
        (self._hand, self._t_last, rng, self.marker, n_reached, n_skipped, self._since, self.force,
         self._sensor) = snapshot
        self.rng.bit_generator.state = rng
        del self.reached[n_reached:], self.skipped[n_skipped:]

    def sensor_force(self, state: State, t: float) -> np.ndarray:
        """``f^s`` of this step (the :class:`~hqp_tpm.tasks.force.Force` source)."""
        return self._sensor
