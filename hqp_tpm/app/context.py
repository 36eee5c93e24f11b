"""The run context: everything a run hands to the runner, results, figures and viewer, built once.

:func:`hqp_tpm.app.build.build_run` makes it from a scenario. Nothing is attached to the policy and
read back later: the obstacles, the joint box and its velocity limits, the thresholds, what the viewer
may draw and which per-step channels the policy records all live here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from hqp_tpm.app.scenario import Scenario
from hqp_tpm.control.controller import Controller, StepResult
from hqp_tpm.control.policy import Policy, SceneItems
from hqp_tpm.geometry.obstacles import Obstacle
from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.robot.model import Robot
from hqp_tpm.tasks.base import Task

#: rad/s: the velocity limit a run's divergence bound uses where the model gives none (``velocity_bound``).
UNLIMITED_VELOCITY = 10.0

#: ``probe(ctrl, result) -> dict``: values recorded after every successful step.
Probe = Callable[[Controller, StepResult], dict]


@dataclass
class RunContext:
    """One built scenario: robot, controller, tasks, policy and what the app needs around them.

    Handed over as it is (never probed): the figures read ``scenario.name``, ``tasks``, ``robot``,
    ``velocity_limits`` and ``thresholds``; the viewers take ``scene`` (and the live viewer ``policy``);
    the runner ``controller`` and ``probes()``. A policy with only the required members gets the
    :class:`~hqp_tpm.control.policy.Policy` defaults: no channels, no thresholds, an empty scene to which
    :func:`~hqp_tpm.app.build.build_run` adds the scenario's obstacles.
    """

    scenario: Scenario
    robot: Robot
    controller: Controller
    tasks: dict[str, Task]
    policy: Policy
    obstacles: list[Obstacle] = field(default_factory=list)
    #: the scenario's ``[limits]`` box (None: no box); also the controller's ``box``
    limits: JointLimits | None = None
    #: what a viewer may draw (obstacles, control points, EE frame and task, pointing task, distance field)
    scene: SceneItems = field(default_factory=SceneItems)

    @property
    def velocity_limits(self) -> np.ndarray | None:
        """Joint velocity limits of the box (rad/s, ``inf`` on free-flyer columns), None without ``[limits]``."""
        return self.limits.velocity_limits if self.limits is not None else None

    @property
    def velocity_bound(self) -> np.ndarray:
        """Per velocity column, the joint velocity (rad/s) at which the run stops as diverged
        (:class:`~hqp_tpm.errors.DivergedError`): the scenario's ``velocity_bound`` times the URDF's velocity limit,
        or times :data:`UNLIMITED_VELOCITY` where the model gives none (also on free-flyer columns)."""
        v = self.robot.velocity_limits()
        return self.scenario.velocity_bound * np.where(np.isfinite(v), v, UNLIMITED_VELOCITY)

    @property
    def thresholds(self) -> dict[str, dict[str, float]]:
        """Recorded channel -> {threshold name: value} (from the policy)."""
        return self.policy.thresholds

    @property
    def channels(self) -> tuple[str, ...]:
        """The per-step keys the policy's probe records (the runner also records ``t, q, dq, ddq, stack``,
        ``error_<task>``, and ``scale``/``iterations``/``saturated`` when the solver reports them)."""
        return tuple(self.policy.channels)

    def probes(self) -> list[Probe]:
        """The per-step recorders of a run: every task's error, then the policy's channels."""
        from hqp_tpm.app.results import task_error_probe

        return [task_error_probe(self.tasks), self.policy.probe]

    def summary(self, arrays: dict) -> dict:
        """The policy's run summary numbers."""
        return self.policy.summary(arrays)
