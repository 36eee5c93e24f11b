"""Scenario-file builder of the ``switching`` policy (:mod:`hqp_tpm.policies.switching`)."""

from __future__ import annotations

from hqp_tpm.app.policy_builders.registry import register_policy
from hqp_tpm.errors import ScenarioError, shown
from hqp_tpm.policies.switching import Switching
from hqp_tpm.references.operator import Operator
from hqp_tpm.tasks import Force, FramePosition, JointLimit, Manipulability, QuaternionOrientation


def task_of(sec, tasks: dict, key: str, cls, default: str):
    """The task named by ``sec.key`` (default ``default``), checked to be a ``cls``."""
    name = sec.string(key, default)
    task = tasks.get(name)
    if not isinstance(task, cls):
        kinds = ", ".join(f"{n} ({type(t).__name__})" for n, t in tasks.items())
        raise ScenarioError(f"{sec.where}.{key}: {name!r} is not a {cls.__name__} task; tasks: {kinds}")
    return task


def operator_from(sec, robot, frame: str) -> Operator | None:
    """``operator = { markers = [[x, y, z], ...], stiffness, damping, f_max, noise, seed, reach, give_up,
    t_start }`` (:class:`~hqp_tpm.references.operator.Operator`); absent: no operator (zero force)."""
    tab = sec.table("operator", None)
    if tab is None:
        return None
    raw = tab.raw("markers")
    if not isinstance(raw, list) or not raw:
        raise ScenarioError(f"{tab.where}.markers: expected a list of [x, y, z] positions")
    markers = [_point(tab, m, i) for i, m in enumerate(raw)]
    try:
        op = Operator(robot, frame, markers, stiffness=tab.number("stiffness", 200.0),
                      damping=tab.number("damping", 20.0), f_max=tab.number("f_max", 20.0),
                      noise=tab.number("noise", 0.5), seed=int(tab.number("seed", 0)),
                      reach=tab.number("reach", 0.02), give_up=tab.number("give_up", 10.0),
                      t_start=tab.number("t_start", 0.5), lag=tab.number("lag", 0.1))
    except ValueError as exc:
        raise ScenarioError(f"{tab.where}: {exc}") from exc
    tab.check_unused()
    return op


def _point(tab, m, i) -> list[float]:
    if not isinstance(m, list) or len(m) != 3 or not all(isinstance(x, (int, float)) for x in m):
        raise ScenarioError(f"{tab.where}.markers[{i}]: expected 3 numbers, got {shown(m)}")
    return [float(x) for x in m]


@register_policy("switching")
def build_switching(sc, robot, tasks: dict, sec, obstacles) -> Switching:
    """``[policy] type = "switching"``: ``position_task``, ``orientation_task``, ``force_task``,
    ``manipulability_task``, ``joint_limit_task`` (task names; defaults: position, orientation, force,
    manipulability, joint_limit), ``sigma_m_bar``, ``sigma_l_bar``, ``force_threshold``, ``tau``, ``operator``."""
    pos = task_of(sec, tasks, "position_task", FramePosition, "position")
    ori = task_of(sec, tasks, "orientation_task", QuaternionOrientation, "orientation")
    force = task_of(sec, tasks, "force_task", Force, "force")
    man = task_of(sec, tasks, "manipulability_task", Manipulability, "manipulability")
    lim = task_of(sec, tasks, "joint_limit_task", JointLimit, "joint_limit")
    op = operator_from(sec, robot, force.frame)
    try:
        pol = Switching(pos, ori, force, man, lim, sigma_m_bar=sec.number("sigma_m_bar", 1.5),
                        sigma_l_bar=sec.number("sigma_l_bar", 2.0),
                        force_threshold=sec.number("force_threshold", 2.0), tau=sec.number("tau", 0.1), operator=op)
    except ValueError as exc:
        raise ScenarioError(f"{sec.where}: {exc}") from exc
    sec.check_unused()
    return pol
