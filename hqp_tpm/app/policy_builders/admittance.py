"""Scenario-file builder of the ``admittance`` policy (:mod:`hqp_tpm.policies.admittance`)."""

from __future__ import annotations

from hqp_tpm.app.policy_builders.registry import register_policy
from hqp_tpm.app.policy_builders.switching import operator_from, task_of
from hqp_tpm.errors import ScenarioError
from hqp_tpm.policies.admittance import Admittance, AdmittancePosition
from hqp_tpm.tasks import JointLimit, Manipulability, QuaternionOrientation


@register_policy("admittance")
def build_admittance(sc, robot, tasks: dict, sec, obstacles) -> Admittance:
    """``[policy] type = "admittance"``: ``frame``, ``orientation_task`` (or ``""``: none), ``mass``,
    ``damping``, ``stiffness``, ``kp``, ``manipulability_task``, ``joint_limit_task`` (recorded only),
    ``sigma_m_bar`` (for the summary), ``operator``."""
    if sc.order != 1:
        raise ScenarioError(f"{sec.where}: the admittance baseline works at velocity level only")
    frame = sec.string("frame")
    robot.frame_id(frame)
    ori_name = sec.string("orientation_task", "orientation")
    ori = task_of(sec, tasks, "orientation_task", QuaternionOrientation, "orientation") if ori_name else None
    man = task_of(sec, tasks, "manipulability_task", Manipulability, "manipulability")
    lim = task_of(sec, tasks, "joint_limit_task", JointLimit, "joint_limit")
    op = operator_from(sec, robot, frame)
    try:
        adm = AdmittancePosition(robot, frame, op, dt=sc.period, mass=sec.number("mass", 1.0),
                                 damping=sec.number("damping", 100.0), stiffness=sec.number("stiffness", 0.001),
                                 kp=sec.number("kp", 5.5))
    except ValueError as exc:
        raise ScenarioError(f"{sec.where}: {exc}") from exc
    pol = Admittance(robot, adm, ori, man, lim, op, sigma_m_bar=sec.number("sigma_m_bar", 1.5))
    sec.check_unused()
    return pol
