"""Results from Python: run a controller (or a scenario) and write the folder ``hqp-tpm run`` writes.

    import hqp_tpm
    folder = hqp_tpm.record(ctrl, "runs/mine", steps=500, name="mine")["out"]

The folder holds ``trajectory.npz`` (per step: ``t``, ``q``, ``dq``, ``ddq``, ``stack``, ``error_<task>``, ...),
``metrics.json``, the figures (``joint_velocities.png``, ``task_errors.png``, ...), ``replay.html`` and
``manifest.json``, written as the command line writes them (:func:`hqp_tpm.app.run_scenario.run_scenario`). The
figures and the replay need the ``app`` extra (``pip install 'hqp-tpm[app]'``: matplotlib, meshcat).
"""

from __future__ import annotations

import os
from pathlib import Path

from hqp_tpm.errors import HqpTpmError, ParameterError
from hqp_tpm.robot.limits import JointLimits


def record(source, out: str | os.PathLike, *, steps: int | None = None, name: str | None = None, tasks=None,
           obstacles=(), figures: bool = True, replay: bool = True, progress: bool = False,
           force: bool = False, explain: bool = False) -> dict:
    """Run ``source`` for ``steps`` steps and write its result folder ``out``; returns the run's metrics.

    ``source``: a :class:`~hqp_tpm.control.controller.Controller` (run from its current state; ``steps``
    required), a scenario name or file, or a parsed :class:`~hqp_tpm.app.scenario.Scenario` (``steps``
    default: the scenario's duration). ``name``: the run's name in titles and ``metrics.json`` (default
    ``"run"`` for a controller). ``tasks``: the tasks whose errors are recorded (default: the controller's,
    ``ctrl.tasks()``). ``obstacles``: drawn in the replay. ``figures``, ``replay``: write the figures and
    ``replay.html``. ``force``: replace a non-empty folder that is not a previous result. ``explain``: record
    every step's account (``hqp-tpm explain OUT --t T`` prints it; a controller's run cannot be re-run for it).

    The returned dict is ``metrics.json``'s content plus ``"out"`` (the folder) and ``"files"`` (the files
    written). Read the trajectory back with ``numpy.load(Path(out) / "trajectory.npz")``.
    """
    from hqp_tpm.app.run_scenario import run_scenario
    from hqp_tpm.app.scenario import check_steps
    from hqp_tpm.control.controller import Controller

    options = dict(progress=progress, figures=figures, replay=replay, force=force, explain=explain)
    if steps is not None:  # the Python argument named, not the command line's --steps
        try:
            steps = check_steps(steps, "record: steps")
        except HqpTpmError as exc:
            raise ParameterError(str(exc)) from None
    if not isinstance(source, Controller):
        if tasks is not None or obstacles:
            raise ParameterError("record: tasks and obstacles are given by the scenario; pass them only with a "
                                 "Controller")
        return run_scenario(source, Path(out), steps=steps, **options)
    if steps is None:
        raise ParameterError("record: steps is required with a Controller (how many steps to run)")
    return run_scenario(run_context(source, int(steps), name=name, tasks=tasks, obstacles=obstacles), Path(out),
                        steps=steps, **options)


def run_context(ctrl, steps: int, *, name: str | None = None, tasks=None, obstacles=()):
    """The :class:`~hqp_tpm.app.context.RunContext` of a controller built in Python (no scenario file)."""
    from hqp_tpm.app.context import RunContext
    from hqp_tpm.app.scenario import LEVELS, Scenario
    from hqp_tpm.app.scenario_values import Section

    tasks = list(ctrl.tasks() if tasks is None else tasks)
    by_name = {}
    for task in tasks:
        if task.name in by_name:
            raise ParameterError(f"record: two tasks are named {task.name!r}; give each task its own name")
        by_name[task.name] = task
    level = next(k for k, v in LEVELS.items() if v == ctrl.order)
    where = f"record({name or 'run'})"
    sc = Scenario(name=name or "run", path=Path("<python>"), robot=ctrl.robot.name, level=level, solver=ctrl.solver,
                  period=ctrl.dt, duration=(steps - 1) * ctrl.dt, lambda_max=ctrl.lambda_max, eps=ctrl.eps,
                  nullspace_damping=ctrl.nullspace_damping, description="recorded from Python",
                  initial=Section({}, where), obstacles=[], tasks=[], policy=Section({}, where), limits=None, raw={})
    box = ctrl.box if isinstance(ctrl.box, JointLimits) else None  # the figures' limit lines
    scene = ctrl.policy.scene()
    if not scene.obstacles:
        scene.obstacles = list(obstacles)
    return RunContext(sc, ctrl.robot, ctrl, by_name, ctrl.policy, list(obstacles), box, scene)
