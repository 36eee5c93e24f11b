"""A stack orders tasks into priority levels: a :class:`Stack` is a list of levels (highest first), each one or more
tasks of equal priority, plus optional extra commands added to a task's command (eq. (30) of papers/000). A policy
(:class:`~hqp_tpm.control.policy.Policy`) gives the stack of every step.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from hqp_tpm.errors import ArgumentTypeError, ParameterError, shown
from hqp_tpm.robot.state import State
from hqp_tpm.solvers.levels import Level
from hqp_tpm.tasks.base import Task


@dataclass
class Stack:
    """Levels of tasks, highest priority first, and extra commands by task name."""

    levels: list[tuple[Task, ...]]
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def of(cls, *levels) -> Stack:
        """``Stack.of(task_a, (task_b, task_c))``: one level per argument (:func:`check_levels`)."""
        return cls(check_levels([tuple(lv) if isinstance(lv, (tuple, list)) else (lv,) for lv in levels]))

    def tasks(self) -> list[Task]:
        return [t for lv in self.levels for t in lv]

    def __repr__(self) -> str:
        extras = f", extras for {', '.join(self.extras)}" if self.extras else ""
        n = len(self.levels)
        return f"Stack({self.label()!r}, {n} level{'' if n == 1 else 's'}{extras})"

    def label(self) -> str:
        """``"a > b+c"``: the stack as text (recorded per step)."""
        return " > ".join("+".join(t.name for t in lv) for lv in self.levels)

    def to_levels(self, state: State, t: float, order: int) -> list[Level]:
        """Solver levels: each task's level at this state, tasks of one level merged."""
        out = []
        for lv in self.levels:
            parts = [task.level(state, t, order, self.extras.get(task.name)) for task in lv]
            out.append(parts[0] if len(parts) == 1 else merge_levels(parts))
        return out


#: what a level of a stack may be (named by the errors of :func:`check_levels`)
LEVEL_FORMS = "a Task (hqp_tpm.tasks: FramePosition, Posture, ...) or a tuple/list of Tasks of equal priority"


def check_levels(levels: list[tuple]) -> list[tuple]:
    """``levels`` if they make a stack: at least one level, every level one or more :class:`Task` objects, no task
    twice (a task is one set of rows: twice in a stack it would be solved against itself); else a typed error."""
    if not levels:
        raise ParameterError(f"Stack.of(): a stack needs at least one level; a level is {LEVEL_FORMS}")
    seen: dict[int, int] = {}
    for i, lv in enumerate(levels):
        if not lv:
            raise ParameterError(f"stack level {i} is empty; a level is {LEVEL_FORMS}")
        for task in lv:
            if not isinstance(task, Task):
                hint = " (a task's name: pass the task object itself)" if isinstance(task, str) else ""
                what = f"an array of shape {task.shape}" if isinstance(task, np.ndarray) else shown(task)
                raise ArgumentTypeError(f"stack level {i}: {what} ({type(task).__name__}) is not a task"
                                        f"{hint}; a level is {LEVEL_FORMS}")
            if id(task) in seen:
                raise ParameterError(f"task {task.name!r} is in the stack twice (levels {seen[id(task)]} and {i}); "
                                     "each task may appear once")
            seen[id(task)] = i
    return levels


def merge_levels(parts: Sequence[Level]) -> Level:
    """Tasks of equal priority as one level (equality rows become ``lower = upper = b``, active)."""
    name = "+".join(p.name for p in parts)
    J = np.vstack([p.J for p in parts])
    if all(p.is_equality for p in parts):
        return Level(J, np.concatenate([p.b for p in parts]), name=name, defer_finite=True)
    lo = np.concatenate([p.b if p.is_equality else p.lower for p in parts])
    up = np.concatenate([p.b if p.is_equality else p.upper for p in parts])
    act = np.concatenate([p.active_rows() for p in parts])
    return Level(J, lower=lo, upper=up, active=act, name=name)
