"""Command line: ``hqp-tpm run SCENARIO --out DIR`` (and ``hqp-tpm list``, ``hqp-tpm explain RUN_DIR --t T``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from hqp_tpm.errors import HqpTpmError


def run_scenario(spec, out: Path, *, solver: str | None = None, crosscheck: bool = False,
                 progress: bool = True, figures: bool = True, replay: bool = True, viz: bool = False,
                 steps: int | None = None, explain: bool = False) -> dict:
    """Load, build, run and write one scenario; returns its metrics (``summary["files"]``: the files written)."""
    from threadpoolctl import threadpool_limits

    from hqp_tpm.app import build, results, runner, scenario

    sc = scenario.load(spec)
    robot, ctrl, tasks, policy = build.build(sc, solver=solver)
    probes = [results.task_error_probe(tasks)]
    if hasattr(policy, "probe"):
        probes.append(policy.probe)
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

        live = LiveViewer(robot, policy)
        probes.append(live.probe)
    with threadpool_limits(limits=1):
        rec, timing = runner.run(ctrl, steps or sc.steps, progress=progress, crosscheck=other, probes=probes,
                                 label=sc.name)
    arrays = rec.arrays()
    if explainer is not None:
        explainer.finish(arrays)
    results.standard_aliases(arrays, tasks)
    summary = {"scenario": sc.name, "solver": ctrl.solver, "level": sc.level, "crosscheck_solver": other,
               **results.metrics(arrays, timing, tasks)}
    if hasattr(policy, "summary"):  # policy-specific numbers (e.g. the co-manipulation indices)
        summary.update(policy.summary(arrays))
    if explainer is not None:
        from hqp_tpm.app.explain import summary as explain_summary

        summary["explain"] = explain_summary(arrays)
    results.finish_units(summary, tasks)
    results.write(out, arrays, summary)
    written = [out / "trajectory.npz", out / "metrics.json"]
    if figures and explainer is not None:
        from hqp_tpm.app.explain import figure as explain_figure

        explain_figure(out / "explain.png", arrays, title=f"{sc.name}: fraction of each task met")
        written.append(out / "explain.png")
    if figures:
        from hqp_tpm.app import figures as figs

        written += figs.write_all(out, arrays, sc, tasks, policy)
    if replay:
        try:
            from hqp_tpm.app.viewer import write_replay
        except ImportError:
            write_replay = None
        if write_replay is not None:
            written.append(write_replay(out / "replay.html", robot, arrays, policy))
    summary["files"] = [str(p) for p in written]
    return summary


#: What ``--crosscheck`` does (``--help`` and the README say the same).
CROSSCHECK_HELP = (
    "at every step, also solve the step's levels (the active stack, inequality rows as the run's solver used "
    "them) with a second solver: the cascaded QP for tpm/nullspace/sns_tpm/sns runs, tpm for qp runs, with the "
    "same joint box, damping and null-space term. The run itself follows its own solver; the largest difference "
    "of the two commands is recorded per step (crosscheck_diff in trajectory.npz, crosscheck_max_diff in "
    "metrics.json; rad/s at velocity level, rad/s^2 at acceleration level)")


def wrote_line(files) -> str:
    """``wrote DIR/: a, b, c`` naming every file a run wrote."""
    paths = [Path(f) for f in files]
    if not paths:
        return "wrote nothing"
    folder = paths[0].parent
    if all(p.parent == folder for p in paths):
        return f"wrote {folder}/: {', '.join(p.name for p in paths)}"
    return "wrote " + ", ".join(str(p) for p in paths)


def main(argv=None) -> int:
    from hqp_tpm import __version__

    parser = argparse.ArgumentParser(prog="hqp-tpm", description=__doc__)
    parser.add_argument("--version", action="version", version=f"hqp-tpm {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run a scenario (a TOML file, or the name of a shipped scenario)")
    p_run.add_argument("scenario")
    p_run.add_argument("--out", type=Path, default=None, help="output folder (default runs/<scenario>)")
    p_run.add_argument("--solver", default=None, help="override the scenario's solver: tpm, nullspace, sns_tpm, "
                       "sns, qp, qp:<backend>")
    p_run.add_argument("--crosscheck", action="store_true", help=CROSSCHECK_HELP)
    p_run.add_argument("--viz", action="store_true", help="show the run live in meshcat")
    p_run.add_argument("--no-figures", action="store_true")
    p_run.add_argument("--no-replay", action="store_true")
    p_run.add_argument("--steps", type=int, default=None, help="run only this many steps")
    p_run.add_argument("--quiet", action="store_true", help="no progress bar")
    p_run.add_argument("--explain", action="store_true", help="record every step's account: each task's fraction "
                       "met and what blocked it (hqp-tpm explain RUN_DIR --t T prints it)")
    p_list = sub.add_parser("list", help="list the shipped scenarios")
    p_list.add_argument("--names", action="store_true", help="names only, one a line")
    p_explain = sub.add_parser("explain", help="why a task was not met at time T of a run: its account")
    p_explain.add_argument("run_dir", type=Path)
    p_explain.add_argument("--t", type=float, required=True, help="time (s); the nearest recorded step is shown")
    args = parser.parse_args(argv)
    try:
        if args.command == "explain":
            from hqp_tpm.app.explain import explain_run

            print(explain_run(args.run_dir, args.t))
            return 0
        if args.command == "list":
            from hqp_tpm.app.scenario import SCENARIO_DIR, load

            files = sorted(SCENARIO_DIR.glob("*.toml"))
            width = max((len(f.stem) for f in files), default=0)
            for f in files:
                print(f.stem if args.names else f"{f.stem:{width}s}  {load(f).description}")
            return 0
        out = args.out or Path("runs") / Path(args.scenario).stem
        summary = run_scenario(args.scenario, out, solver=args.solver, crosscheck=args.crosscheck,
                               progress=not args.quiet, figures=not args.no_figures, replay=not args.no_replay,
                               viz=args.viz, steps=args.steps, explain=args.explain)
    except HqpTpmError as exc:
        print(f"hqp-tpm: error: {exc}", file=sys.stderr)
        return 2
    keys = [k for k in summary if k.endswith(("_max", "_rms", "_min")) or k in ("max_dq_jump", "wall_time_s",
                                                                             "crosscheck_max_diff")]
    print(json.dumps({k: summary[k] for k in keys}, indent=2))
    print(wrote_line(summary["files"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
