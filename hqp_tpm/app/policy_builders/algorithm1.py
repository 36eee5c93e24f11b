"""Scenario-file builder of the ``algorithm1`` policy (:mod:`hqp_tpm.policies.algorithm1`)."""

from __future__ import annotations

from hqp_tpm.app.policy_builders.registry import register_policy
from hqp_tpm.errors import ScenarioError
from hqp_tpm.geometry.obstacles import Obstacle
from hqp_tpm.geometry.repulsion import Repulsion
from hqp_tpm.policies.algorithm1 import BODY_REPULSION, EE_REPULSION, Algorithm1, Thresholds
from hqp_tpm.tasks import Pointing


def _repulsion(sec, key: str, default: Repulsion) -> Repulsion:
    tab = sec.table(key, None)
    if tab is None:
        return default
    rep = Repulsion(tab.number("v_max"), tab.number("rho"), tab.number("gamma"), tab.number("c", 2.0))
    tab.check_unused()
    return rep


@register_policy("algorithm1")
def build_algorithm1(sc, robot, tasks: dict, sec, obstacles: list[Obstacle]) -> Algorithm1:
    ee_name = sec.string("ee_task")
    if ee_name not in tasks:
        raise ScenarioError(f"{sec.where}.ee_task: unknown task {ee_name!r}; tasks: {', '.join(tasks)}")
    p_name = sec.string("pointing_task", None)
    if p_name is not None and not isinstance(tasks.get(p_name), Pointing):
        raise ScenarioError(f"{sec.where}.pointing_task: {p_name!r} is not a pointing task; tasks: {', '.join(tasks)}")
    eps1, eps2 = sec.number("eps1", 0.05), sec.number("eps2", 0.15)
    if not 0 < eps1 < eps2:
        raise ScenarioError(f"{sec.where}.eps1: need 0 < eps1 < eps2, got eps1 = {eps1:g}, eps2 = {eps2:g}")
    eps_ee = sec.number("eps_ee", 0.1)
    if eps_ee <= 0:
        raise ScenarioError(f"{sec.where}.eps_ee: must be > 0, got {eps_ee:g}")
    th = Thresholds(eps1, eps2, eps_ee, sec.number("d_ee_default", 0.11))
    dim = {"1d": 1, "3d": 3}
    av = sec.string("avoidance", "1d", choices=tuple(dim))
    frames = sec.raw("control_points")
    if not isinstance(frames, list) or not all(isinstance(x, str) for x in frames):
        raise ScenarioError(f"{sec.where}.control_points: expected a list of frame names")
    for fr in [*frames, sec.string("ee_frame")]:
        robot.frame_id(fr)
    pol = Algorithm1(robot, tasks[ee_name], tasks.get(p_name) if p_name else None, frames, sec.string("ee_frame"),
                     obstacles, thresholds=th, ee_repulsion=_repulsion(sec, "ee_repulsion", EE_REPULSION),
                     body_repulsion=_repulsion(sec, "body_repulsion", BODY_REPULSION),
                     avoidance_dim=dim[av], direction=sec.string("direction", "nearest", choices=("nearest", "mean")),
                     record_range=sec.number("record_range", 0.5))
    sec.check_unused()
    return pol
