"""The name -> builder table of the scenario files' ``[policy] type`` (filled by the builder modules)."""

from __future__ import annotations

from collections.abc import Callable

#: ``type`` in a scenario's ``[policy]`` section -> ``build(scenario, robot, tasks, section, obstacles) -> policy``.
POLICY_BUILDERS: dict[str, Callable] = {}


def register_policy(kind: str):
    """Decorator: ``@register_policy("algorithm1") def build(scenario, robot, tasks, section, obstacles)``."""
    def deco(fn):
        POLICY_BUILDERS[kind] = fn
        return fn
    return deco
