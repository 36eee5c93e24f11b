"""Scenario-file builder of the ``petric`` policy (:mod:`hqp_tpm.policies.petric`)."""

from __future__ import annotations

from hqp_tpm.app.policy_builders.registry import register_policy
from hqp_tpm.errors import ScenarioError
from hqp_tpm.geometry.obstacles import Obstacle
from hqp_tpm.policies.petric import COMBINE, SCHEMES, SECONDARY, Petric


@register_policy("petric")
def build_petric(sc, robot, tasks: dict, sec, obstacles: list[Obstacle]) -> Petric:
    """``[policy] type = "petric"``: ``ee_task``, ``scheme`` (exact | approximate | primary | transition),
    ``d_m``, ``d_i``, ``v_o``, ``d_b``, ``secondary`` (projected | prioritized), ``combine`` (weighted | nearest),
    ``p_ee``, ``p_avoid``, ``pwdls_damping`` (scheme pwdls), ``record_range``."""
    if sc.order != 1:
        raise ScenarioError(f"{sec.where}.type: the petric policy works at velocity level (papers/004), "
                            f"the scenario says level = {sc.level!r}")
    name = sec.string("ee_task", "ee")
    if name not in tasks:
        raise ScenarioError(f"{sec.where}.ee_task: unknown task {name!r}; tasks: {', '.join(tasks)}")
    if not obstacles:
        raise ScenarioError(f"{sec.where}: the petric policy needs at least one [[obstacles]] entry")
    pol = Petric(robot, tasks[name], obstacles, scheme=sec.string("scheme", "exact", choices=SCHEMES),
                 d_m=sec.number("d_m", 0.2), d_i=sec.number("d_i", 0.3), v_o=sec.number("v_o", 0.5),
                 d_b=sec.number("d_b", 0.02),
                 secondary=sec.string("secondary", "projected", choices=SECONDARY),
                 combine=sec.string("combine", "weighted", choices=COMBINE), p_ee=sec.number("p_ee", 5.0),
                 p_avoid=sec.number("p_avoid", 1.0), pwdls_damping=sec.number("pwdls_damping", 0.01),
                 record_range=sec.number("record_range", 1.0))
    sec.check_unused()
    return pol
