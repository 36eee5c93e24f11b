"""Scenario-file builder of the ``whole_body`` policy (:mod:`hqp_tpm.policies.whole_body`)."""

from __future__ import annotations

from hqp_tpm.app.policy_builders.registry import register_policy
from hqp_tpm.errors import ScenarioError
from hqp_tpm.geometry.obstacles import Obstacle
from hqp_tpm.policies.whole_body import (
    WholeBody,
)


@register_policy("whole_body")
def build_whole_body(sc, robot, tasks: dict, sec, obstacles: list[Obstacle]) -> WholeBody:
    """``[policy] type = "whole_body"``: ``levels`` (task names, as the fixed stack it extends, one task per
    level) and ``avoid_at`` (index in ``levels`` where the avoidance levels go; default 1, below the sole hold)."""
    raw = sec.raw("levels", ["right_sole", "com", "left_foot", "left_hand", "right_hand"])
    if not isinstance(raw, list) or not all(isinstance(x, str) for x in raw):
        raise ScenarioError(f"{sec.where}.levels: expected a list of task names (one task per level)")
    for i, n in enumerate(raw):
        if n not in tasks:
            raise ScenarioError(f"{sec.where}.levels: unknown task {n!r}; tasks: {', '.join(tasks)}")
        if n in raw[:i]:
            raise ScenarioError(f"{sec.where}.levels[{i}]: task {n!r} is repeated (already levels[{raw.index(n)}]); "
                                "a task may appear once in a stack")
    at = sec.raw("avoid_at", 1)
    if not isinstance(at, int) or not 0 <= at <= len(raw):
        raise ScenarioError(f"{sec.where}.avoid_at: expected an integer in [0, {len(raw)}], got {at!r}")
    if sc.order != 1:
        raise ScenarioError(f"{sec.where}: the whole_body policy works at velocity level only")
    try:
        pol = WholeBody(robot, [tasks[n] for n in raw[:at]], [tasks[n] for n in raw[at:]], obstacles,
                        d_obstacle_activation=sec.number("d_obstacle_activation", 0.10),
                        d_obstacle_safe=sec.number("d_obstacle_safe", 0.03),
                        xi_obstacle=sec.number("xi_obstacle", 0.3),
                        d_self_activation=sec.number("d_self_activation", 0.05),
                        d_self_safe=sec.number("d_self_safe", 0.01),
                        xi_self=sec.number("xi_self", 0.3),
                        obstacle_rows=sec.string("obstacle_rows", "per_obstacle", choices=("per_obstacle", "closest")),
                        record_range=sec.number("record_range", 0.3))
    except ValueError as exc:
        raise ScenarioError(f"{sec.where}: {exc}") from exc
    sec.check_unused()
    return pol
