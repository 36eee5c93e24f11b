"""One scenario run from file to result folder: :func:`run_scenario` (what ``hqp-tpm run`` and the sweeps run)."""

from __future__ import annotations

from pathlib import Path

from hqp_tpm.errors import HqpTpmError

#: Figures are drawn from at most this many samples per series (every k-th step beyond it): memory stays flat.
FIGURE_SAMPLES = 20_000


def _every(arrays: dict, n: int, limit: int = FIGURE_SAMPLES) -> dict:
    """Every k-th row of the per-step arrays, so that at most ``limit`` rows remain (k = 1 up to ``limit``)."""
    import numpy as np

    k = max(1, -(-n // limit))
    if k == 1:
        return arrays
    return {key: (v[::k] if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == n else v)
            for key, v in arrays.items()}


def _naming_file(exc: HqpTpmError, name: str, where: str = "") -> HqpTpmError:
    """``exc`` (same type) with its message starting ``<name><where>: `` unless it names the file already."""
    text = str(exc)
    if name not in text:
        exc.args = (f"{name}{where}: {text}", *exc.args[1:])
    return exc


def run_scenario(spec, out: Path, *, solver: str | None = None, crosscheck: bool = False,
                 progress: bool = True, figures: bool = True, replay: bool = True, viz: bool = False,
                 steps: int | None = None, explain: bool = False, force: bool = False, stop=None,
                 manifest: dict | None = None, realtime: bool | float = False, serve: bool = False) -> dict:
    """Load, build, run and write one scenario; returns its metrics (``summary["files"]``: the files written).

    The output folder is checked before any work (:func:`hqp_tpm.app.results.check_target`; ``force``
    replaces a non-empty folder that is not a previous result) and written crash-safe: built in a
    temporary folder next to ``out`` and swapped in at the end with ``manifest.json``. ``stop``: a
    callable checked before every step; when it returns true the run ends and the steps done so far are
    written as a partial result (``summary["status"] == "partial"``; into ``<out>.partial`` when ``out``
    holds a complete result). A step that fails also leaves the steps before it as a partial result,
    then the error is raised. ``spec``: a scenario file or name, a parsed
    :class:`~hqp_tpm.app.scenario.Scenario`, or a built :class:`~hqp_tpm.app.context.RunContext` (the public
    call for a controller built in Python is :func:`hqp_tpm.app.record.record`); ``manifest``: extra entries
    of ``manifest.json``.
    ``viz``: show the run live in meshcat (``realtime``: paced to simulated time, True or a speed factor;
    ``serve``: keep the viewer up after the run until Ctrl-C).
    """
    import numpy as np
    from threadpoolctl import threadpool_limits

    from hqp_tpm.app import build, results, runner, scenario
    from hqp_tpm.app.context import RunContext

    given = spec if isinstance(spec, RunContext) else None  # a controller built in Python (hqp_tpm.app.record)
    sc = given.scenario if given else spec if isinstance(spec, scenario.Scenario) else scenario.load(spec)
    n_steps = sc.steps if steps is None else scenario.check_steps(steps, "--steps")
    from hqp_tpm.app.extras import require  # the app extra: before any work

    require(*[f for f, on in (("figures", figures), ("replay", replay), ("progress", progress), ("viewer", viz))
              if on], what=f"running {sc.name!r} with these options")
    folder = results.ResultFolder(Path(out), force=force)
    try:
        try:
            ctx = given or build.build_run(sc, solver=solver)
        except HqpTpmError as exc:  # every error of a scenario run names its file
            raise _naming_file(exc, sc.path.name) from None
        robot, ctrl, tasks = ctx.robot, ctx.controller, ctx.tasks
        probes = ctx.probes()
        explainer = None
        if explain:  # the per-step account (hqp_tpm.app.explain); nothing is computed without it
            from hqp_tpm.app.explain import Explainer

            explainer = Explainer(ctrl)
            probes.append(explainer.probe)
        other = None
        if crosscheck:
            other = "qp" if ctrl.solver in ("tpm", "nullspace", "sns_tpm", "sns") else "tpm"
        live = None
        if viz:
            from hqp_tpm.app.viewer import LiveViewer

            live = LiveViewer(robot, ctx.scene, policy=ctx.policy, realtime=realtime)
            probes.append(live.probe)
        from hqp_tpm.app import plant_run

        plant = plant_run.build_plant(ctx)  # None: kinematic (the controller integrates its command)
        if plant is not None:
            probes.append(plant_run.plant_probe(ctx, plant))  # last: it moves the controller to the measured state
        rec = runner.Recording(list(robot.joint_names), folder.path / ".columns")
        failure = None
        with threadpool_limits(limits=1):
            try:
                rec, timing = runner.run(ctrl, n_steps, progress=progress, crosscheck=other, probes=probes,
                                         label=sc.name, recording=rec, stop=stop,
                                         record=explainer is not None or live is not None,
                                         velocity_bound=ctx.velocity_bound,  # (DivergedError beyond it)
                                         bound_source=f"{sc.path.name}.scenario.velocity_bound = "
                                                      f"{sc.velocity_bound:g} x the velocity limits")
            except HqpTpmError as exc:  # the steps before the failing one are kept, as a partial result
                failure = _naming_file(exc, sc.path.name, f", step {len(rec) + 1} (t = {ctrl.t:.6g} s)")
                rec.close()
                timing = {"wall_time_s": float("nan"), "steps": len(rec), "mean_step_us": float("nan")}
        done = int(timing["steps"])
        status = "complete" if done == n_steps and failure is None else "partial"
        if done == 0:
            folder.abort()
            if failure is not None:
                raise failure
            return {"scenario": sc.name, "status": "partial", "steps": 0, "steps_requested": n_steps,
                    "out": None}
        arrays = rec.load()
        if explainer is not None:
            explainer.finish(arrays)
        results.standard_aliases(arrays, tasks)
        summary = {"scenario": sc.name, "solver": ctrl.solver, "level": sc.level, "crosscheck_solver": other,
                   **results.metrics(arrays, timing, tasks)}
        summary.update(ctx.summary(arrays))  # policy-specific numbers (e.g. the co-manipulation indices)
        summary.update(plant_run.plant_summary(ctx, plant, arrays))
        if explainer is not None:
            from hqp_tpm.app.explain import summary as explain_summary

            summary["explain"] = explain_summary(arrays)
        summary.pop("stopped", None)
        summary.update(steps=done, steps_requested=n_steps, status=status)
        results.finish_units(summary, tasks)
        files = rec.files()
        for k, v in arrays.items():  # arrays added after the run; an alias (ee_error = error_ee, pointing_error =
            if k in files or any(arrays.get(f) is v for f in files):  # error_<pointing task>) is not stored twice
                continue
            files[k] = rec.folder / f"{k}.npy"
            np.save(files[k], np.asarray(v))
        results.write_npz(folder.path / "trajectory.npz", files)
        results.write_text(folder.path / "metrics.json", results.dumps(summary))
        written = ["trajectory.npz", "metrics.json"]
        if plant_run.write_plant_xml(folder.path, plant):
            written.append("plant.xml")
        if figures and explainer is not None:
            from hqp_tpm.app.explain import figure as explain_figure

            explain_figure(folder.path / "explain.png", _every(arrays, done),
                           title=f"{sc.name}: fraction of each task met")
            written.append("explain.png")
        if figures:
            from hqp_tpm.app import figures as figs

            written += [Path(p).name for p in figs.write_all(folder.path, _every(arrays, done), ctx)]
        if replay:
            from hqp_tpm.app.viewer import write_replay

            write_replay(folder.path / "replay.html", robot, arrays, ctx.scene,
                         title=f"hqp-tpm replay: {Path(out).name} ({robot.name})")
            written.append("replay.html")
            if explainer is not None:  # the account of the current frame beside the robot
                from hqp_tpm.app.explain import annotate_replay

                annotate_replay(folder.path / "replay.html", arrays, solver=ctrl.solver)
        del arrays
        rec.discard()
        import shutil

        shutil.rmtree(rec.folder, ignore_errors=True)
        reason = None
        if failure is not None:
            reason = f"step {done + 1} failed: {failure}"
        elif status == "partial":
            reason = f"stopped after {done} of {n_steps} steps"
        dest = folder.commit({"scenario": sc.name, "scenario_file": str(sc.path), "solver": ctrl.solver,
                              "steps": done, "steps_requested": n_steps, "status": status, "reason": reason,
                              **(manifest or {})})
    except OSError as exc:  # a full disk, a file-size limit (ulimit -f): a typed error; the target is as it was
        folder.abort()
        cause = exc.__cause__ if isinstance(exc, HqpTpmError) and isinstance(exc.__cause__, OSError) else exc
        if cause is exc and isinstance(exc, HqpTpmError) or cause.errno not in results.WRITE_ERRNOS:
            raise
        raise results.output_error(cause, Path(out)) from cause
    except BaseException:
        folder.abort()
        raise
    summary["out"] = str(dest)
    summary["files"] = [str(dest / name) for name in [*written, "manifest.json"]]
    if live is not None:
        report = live.report()
        if report:
            print(f"hqp-tpm: {report}", flush=True)
        if serve and failure is None and not (stop is not None and stop()):  # a signal already ended the run: no wait
            live.serve(until=stop)  # until Ctrl-C or SIGTERM
        else:
            live.close()
    if failure is not None:
        failure.partial_result = dest
        raise failure
    return summary


#: What ``--crosscheck`` does (``--help`` and the README say the same).
