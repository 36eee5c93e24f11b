"""The policy contract: what the controller, the runner and the app may ask of a policy.

:class:`Policy`: ``__call__(state, t) -> Stack`` and ``tasks()`` required, every other member a do-nothing default
(never probed for). :class:`StackPolicy`, :class:`PlanningPolicy`: the compiled step. :class:`DistancePolicy`: the
policies driven by a :class:`~hqp_tpm.geometry.distances.DistanceField`.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from hqp_tpm.control.stack import Stack
from hqp_tpm.errors import ArgumentTypeError
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.base import Task

if TYPE_CHECKING:
    from hqp_tpm.control.step_result import StepResult
    from hqp_tpm.geometry.distances import DistanceField
    from hqp_tpm.geometry.obstacles import Obstacle
    from hqp_tpm.references.operator import Operator
    from hqp_tpm.tasks.pointing import Pointing

#: ``resolve(stack) -> x``: another stack solved with the controller's solver, at the same state and settings.
Resolve = Callable[["Stack"], np.ndarray]


@dataclass
class SceneItems:
    """What a viewer may draw for a policy (every item optional; the viewer takes exactly this type)."""

    obstacles: list[Obstacle] = field(default_factory=list)
    control_points: list[str] = field(default_factory=list)  # frame names of Algorithm 1's control points
    #: the EE frame's name (None: the frame of ``ee_task``, :attr:`Task.frame`)
    ee_frame: str | None = None
    #: the EE task: its trajectory is drawn as the desired path (when it is a 3-D position)
    ee_task: Task | None = None
    #: the pointing task: its cone is drawn at its frame
    pointing: Pointing | None = None
    #: the distance field: the segment from the critical control point to its nearest obstacle
    field: DistanceField | None = None
    #: ``markers(t, q) -> [(name, position, rgba), ...]``: extra points to draw at time ``t``, configuration ``q``
    markers: Callable[[float, np.ndarray], list] | None = None
    #: the simulated co-manipulation operator (its markers, the flange its force acts on)
    operator: Operator | None = None
    #: frame tasks whose 3-D target is drawn (a sphere at the target, its path over the run): the hands of a humanoid
    targets: list[Task] = dataclasses.field(default_factory=list)  # (the name `field` is taken above)


def moving_targets(tasks) -> list[Task]:
    """The tasks of ``tasks`` whose target is a moving 3-D point of a robot frame (a :class:`FramePosition` on a
    time-varying trajectory): what :attr:`SceneItems.targets` draws by default."""
    return [t for t in tasks if t.frame is not None and t.dim == 3 and t.trajectory.time_varying]


class Policy(ABC):
    """Base of every policy: two required members, the optional ones with do-nothing defaults."""

    #: True if :meth:`blend` changes the solution (the controller then also clips it into a hard box).
    blends: ClassVar[bool] = False
    #: Keys of the dict :meth:`probe` returns (the per-step channels the policy records).
    channels: tuple[str, ...] = ()
    #: Recorded channel -> {threshold name: value}, drawn with the channel in the figures.
    thresholds: dict[str, dict[str, float]] = {}

    # required ----------------------------------------------------------------------------------
    @abstractmethod
    def __call__(self, state: State, t: float) -> Stack:
        """The stack of this step (called once per step, after :meth:`update`)."""

    @abstractmethod
    def tasks(self) -> list[Task]:
        """Every task the policy may use (the controller starts them at the first step)."""

    # optional ----------------------------------------------------------------------------------
    def update(self, state: State, t: float) -> None:  # noqa: B027 - optional, does nothing by default
        """Once per step after the state update, before :meth:`__call__` (operator, distances...)."""

    def blend(self, state: State, t: float, stack: Stack, x: np.ndarray, resolve: Resolve) -> np.ndarray:
        """The command from the solution ``x`` of ``stack`` (used only when :attr:`blends` is True): eq. (8) of
        papers/003, eqs. (19), (30)-(31) of papers/004."""
        return x

    def probe(self, ctrl: Any, res: StepResult) -> dict:
        """Per-step values to record after a successful step (keys: :attr:`channels`)."""
        return {}

    def summary(self, arrays: dict) -> dict:
        """Policy-specific run summary from the recorded arrays."""
        return {}

    def scene(self) -> SceneItems:
        """What a viewer may draw (default: the moving targets of the frame tasks, :func:`moving_targets`)."""
        return SceneItems(targets=moving_targets(self.tasks()))

    def compiled_step(self, ctrl: Any) -> Any:
        """The compiled step of this policy under ``ctrl``'s settings (``compute() -> command``, ``result(t, q, v,
        command) -> StepResult``, ``current() -> bool``: the readable step's numbers), or None: the readable path."""
        return None

    def snapshot(self) -> Any:
        """The state that carries over from step to step (default: none)."""
        return None

    def restore(self, snapshot: Any) -> None:  # noqa: B027 - optional, nothing to restore by default
        """Put back a :meth:`snapshot` (a rejected step changes nothing)."""


class StackPolicy(Policy):
    """A policy whose stack (its ``__call__``) the compiled step (:mod:`hqp_tpm.control._planned_step`) takes as it
    is."""


class PlanningPolicy(Policy):
    """A policy whose stack is one task per level: :meth:`plan` gives it, :meth:`__call__` wraps it in a Stack (the
    compiled step reads the plan)."""

    @abstractmethod
    def plan(self, state: State, t: float) -> tuple[tuple[Task, ...], dict]:
        """This step's tasks, one per level (highest first), and the extra commands by task name."""

    def __call__(self, state: State, t: float) -> Stack:
        tasks, extras = self.plan(state, t)
        return Stack([(task,) for task in tasks], extras)


class DistancePolicy(Policy):
    """A policy that owns a distance field, updated once per step before the stack is chosen (subclasses set
    ``self.field`` and ``self.obstacles``)."""

    field: DistanceField
    obstacles: list[Obstacle]

    def update(self, state: State, t: float) -> None:
        self.field.update(state.data, None, t)

    def snapshot(self) -> Any:
        return self.field.snapshot()

    def restore(self, snapshot: Any) -> None:
        self.field.restore(snapshot)


class FunctionPolicy(Policy):
    """A plain callable ``f(state, t) -> Stack`` as a policy. The controller starts ``tasks`` at the first step; any
    other task the function returns is started when a stack first holds it (a held or ``relative`` target: its value
    then), and listed by :meth:`tasks` from then on."""

    def __init__(self, fn: Callable[[State, float], Stack], tasks: list[Task] | None = None):
        if not callable(fn):
            raise ArgumentTypeError(f"FunctionPolicy: fn must be a callable f(state, t) -> Stack, got "
                                    f"{type(fn).__name__}")
        self.fn = fn
        self._tasks = list(tasks or [])
        self._listed = {id(task) for task in self._tasks}
        self._entered: dict[int, Task] = {}  # id -> task: the tasks not in ``tasks`` started so far
        self._known: set[int] = set()  # (ids of tasks started before this policy: :meth:`started`)

    def __call__(self, state: State, t: float) -> Stack:
        stack = self.fn(state, t)
        if not isinstance(stack, Stack):
            raise ArgumentTypeError(f"the policy function {self.fn!r} returned {type(stack).__name__}, expected a "
                                    "Stack (e.g. Stack.of(task_a, (task_b, task_c)))")
        for task in stack.tasks():
            if id(task) not in self._listed and id(task) not in self._entered:
                if id(task) not in self._known:
                    task.start(state)
                self._entered[id(task)] = task
        return stack

    def started(self, tasks) -> None:
        """``tasks`` were started before (a controller's, under another policy): not started again when held."""
        self._known.update(id(task) for task in tasks)

    def tasks(self) -> list[Task]:
        return [*self._tasks, *self._entered.values()]

    def snapshot(self) -> Any:
        return dict(self._entered)

    def restore(self, snapshot: Any) -> None:
        self._entered = dict(snapshot)


class FixedStack(Policy):
    """The policy that returns the same stack at every step."""

    def __init__(self, stack: Stack | Sequence):
        self.stack = stack if isinstance(stack, Stack) else Stack.of(*stack)

    def tasks(self) -> list[Task]:
        return self.stack.tasks()

    def __call__(self, state: State, t: float) -> Stack:
        return self.stack

    def __repr__(self) -> str:
        return f"FixedStack({self.stack.label()!r})"
