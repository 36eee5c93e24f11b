"""Command line: ``hqp-tpm run SCENARIO --out DIR`` (and ``hqp-tpm list``, ``hqp-tpm explain RUN_DIR --t T``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from hqp_tpm.app.run_scenario import run_scenario
from hqp_tpm.errors import HqpTpmError, ParameterError

CROSSCHECK_HELP = (
    "at every step, also solve the step with a second solver (the cascaded QP for tpm/nullspace/sns_tpm/sns "
    "runs, tpm for qp runs) like for like: the same levels (inequality rows as the analytic solvers used them), "
    "null-space term, joint box, damping and, for policies that blend stacks, the same blend; the run follows "
    "its own solver. Recorded per step: the largest command difference (crosscheck_diff in trajectory.npz) and "
    "whether both solved the same problem (crosscheck_same_problem: not where a binding box is ignored by one or "
    "scaled differently, e.g. SNS-TPM vs the QP); metrics.json: crosscheck_max_diff, "
    "crosscheck_max_diff_same_problem, crosscheck_steps_different_problems (rad/s at velocity level, rad/s^2 at "
    "acceleration level)")


def wrote_line(files) -> str:
    """``wrote DIR/: a, b, c`` naming every file a run wrote."""
    paths = [Path(f) for f in files]
    if not paths:
        return "wrote nothing"
    folder = paths[0].parent
    if all(p.parent == folder for p in paths):
        return f"wrote {folder}/: {', '.join(p.name for p in paths)}"
    return "wrote " + ", ".join(str(p) for p in paths)


class _Signals:
    """SIGINT/SIGTERM while a run is going: the first one asks the step loop to stop (the steps done are
    written as a partial result), a second one aborts at once (the temporary folder is removed)."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._old: dict = {}

    def __enter__(self) -> _Signals:
        import signal

        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                self._old[sig] = signal.signal(sig, self._handle)
            except ValueError:  # not the main thread: leave the handlers alone
                pass
        return self

    def _handle(self, signum, frame) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum

    def stop(self) -> bool:
        return self.signum is not None

    def __exit__(self, *exc) -> None:
        import signal

        for sig, old in self._old.items():
            signal.signal(sig, old)

    @property
    def exit_code(self) -> int:
        return 128 + int(self.signum or 2)

    @property
    def name(self) -> str:
        import signal

        return signal.Signals(self.signum or 2).name


def _print_lines(lines) -> int:
    """Print to stdout; a reader that goes away (``hqp-tpm list | head``) ends the output quietly."""
    try:
        for line in lines:
            print(line)
        sys.stdout.flush()
    except BrokenPipeError:
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # no second error when Python flushes stdout at exit
    return 0


_VALUE_OPTIONS = {"--set", "--out", "--metric", "--solver", "--scheduler", "--cluster", "--seed", "--random",
                  "--steps", "--workers"}


def _bare_assignments(argv: list) -> list:
    """``hqp-tpm sweep S FIELD=lo:hi`` means ``--set FIELD=lo:hi`` (argparse cannot mix them with options)."""
    if not argv or argv[0] != "sweep":
        return argv
    out = argv[:2]
    for prev, tok in zip(argv[1:], argv[2:], strict=False):
        if "=" in tok and not tok.startswith("-") and prev not in _VALUE_OPTIONS:
            out.append("--set")
        out.append(tok)
    return out


def _executor_args(p, quiet: str) -> None:
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default: one per core; "
                   "0: in this process)")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT", help="run on this Dask cluster (trusted "
                   "only: Dask unpickles what the cluster sends back, so a scheduler can run code in this process)")
    p.add_argument("--cluster", default=None, metavar="local:N", help="start a Dask LocalCluster of N processes")
    p.add_argument("--quiet", action="store_true", help=quiet)


def _sweep(args) -> int:
    from hqp_tpm.app import sweep

    grid, ranges = {}, {}
    for text in args.set:
        name, values, rng = sweep.parse_assignment(text)
        if rng is not None:
            ranges[name] = rng
        else:
            grid[name] = values
    solvers = tuple(s.strip() for s in args.solver.split(",")) if args.solver else (None,)
    if args.solver:  # every solver named, before any variant runs
        from hqp_tpm.app.scenario import check_solver_choice

        for s in solvers:
            check_solver_choice(s, "--solver", ParameterError)
    out = args.out or Path("runs") / f"sweep_{Path(args.scenario).stem}"
    import signal

    code = [130]

    def _term(signum, frame):
        code[0] = 143
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, _term)
    try:
        table = sweep.run_sweep(args.scenario, out, grid=grid, ranges=ranges, n_random=args.random, seed=args.seed,
                                solvers=solvers, steps=args.steps, workers=args.workers, scheduler=args.scheduler,
                                cluster=args.cluster, metrics=args.metric, figures=args.figures, force=args.force,
                                progress=not args.quiet)
    except KeyboardInterrupt:
        print(f"hqp-tpm: sweep interrupted; the variants completed so far are kept in {out} (re-run the same "
              "command to resume)", file=sys.stderr)
        return code[0]
    finally:
        signal.signal(signal.SIGTERM, old)
    failed = sum(1 for r in table if r.get("error"))
    if args.quiet:
        if failed:
            print(f"hqp-tpm: sweep: {failed} of {len(table)} variants failed (see {out}/summary.md)", file=sys.stderr)
        return 1 if failed == len(table) else 0
    figure = ", sweep.png" if (out / "sweep.png").is_file() else " (no sweep.png: no metric to draw)"
    _print_lines([f"sweep: {len(table)} variants, {failed} failed; wrote {out}/summary.csv, summary.md{figure}"])
    return 1 if failed == len(table) else 0  # every variant failed: nothing to compare


def _campaign(args) -> int:
    from hqp_tpm.app import sweep

    if args.replay is not None:
        failed = sweep.sns_draw(args.seed, args.replay)
        return _print_lines([f"draw {args.replay} of seed {args.seed}: " + (", ".join(failed) or "all properties "
                                                                             "hold")]) or (1 if failed else 0)
    res = sweep.run_campaign(args.kind, args.draws, seed=args.seed, chunk=args.chunk, workers=args.workers,
                             scheduler=args.scheduler, cluster=args.cluster, progress=not args.quiet)
    _print_lines([json.dumps(res, indent=2)])
    return 1 if res["failed"] or res["errors"] else 0


#: ``hqp-tpm --help``'s description: plain text (the module docstring's RST markup would show as is).
DESCRIPTION = "Command line: hqp-tpm run SCENARIO --out DIR (and hqp-tpm list, hqp-tpm explain RUN_DIR --t T)."


def main(argv=None) -> int:
    from hqp_tpm import __version__

    parser = argparse.ArgumentParser(prog="hqp-tpm", description=DESCRIPTION)
    parser.add_argument("--version", action="version", version=f"hqp-tpm {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run a scenario (a TOML file, or the name of a shipped scenario)")
    p_run.add_argument("scenario")
    p_run.add_argument("--out", type=Path, default=None, help="output folder (default runs/<scenario>)")
    p_run.add_argument("--force", action="store_true", help="replace the contents of a non-empty --out folder "
                       "that is not a previous result of hqp-tpm")
    p_run.add_argument("--solver", default=None, help="override the scenario's solver: tpm, nullspace, sns_tpm, "
                       "sns, qp, qp:<backend>")
    p_run.add_argument("--crosscheck", action="store_true", help=CROSSCHECK_HELP)
    p_run.add_argument("--viz", action="store_true", help="show the run live in meshcat; the viewer stays up after "
                       "the run until Ctrl-C")
    p_run.add_argument("--realtime", nargs="?", type=float, const=1.0, default=0.0, metavar="SPEED",
                       help="with --viz: pace the run to simulated time (optionally SPEED times faster) and report "
                       "the frames that fell behind")
    p_run.add_argument("--no-figures", action="store_true")
    p_run.add_argument("--no-replay", action="store_true")
    p_run.add_argument("--steps", type=int, default=None, help="run only this many steps (1 .. 10,000,000)")
    p_run.add_argument("--quiet", action="store_true", help="no progress bar, no metrics, no list of files "
                       "written (metrics.json holds the metrics); errors still go to stderr")
    p_run.add_argument("--explain", action="store_true", help="record every step's account: each task's fraction "
                       "met and what blocked it (hqp-tpm explain RUN_DIR --t T prints it)")
    p_list = sub.add_parser("list", help="list the shipped scenarios")
    p_list.add_argument("--names", action="store_true", help="names only, one a line")
    p_explain = sub.add_parser("explain", help="why a task was not met at time T of a run: its account")
    p_explain.add_argument("run_dir", type=Path)
    p_explain.add_argument("--t", type=float, required=True, help="time (s); the nearest recorded step is shown")
    p_sweep = sub.add_parser("sweep", help="run a scenario over a grid or random draws of fields, on local "
                             "processes or a Dask cluster")
    p_sweep.add_argument("scenario")
    p_sweep.add_argument("--set", action="append", default=[], metavar="FIELD=v1,v2",
                         help="values of a field (repeat: grid); FIELD=lo:hi is a range for --random (a bare "
                         "FIELD=... argument is the same as --set FIELD=...)")
    p_sweep.add_argument("--random", type=int, default=0, metavar="N", help="N uniform draws of the ranges")
    p_sweep.add_argument("--seed", type=int, default=0)
    p_sweep.add_argument("--solver", default=None, help="solver(s), comma-separated: each variant runs with each")
    p_sweep.add_argument("--steps", type=int, default=None, help="steps per run (default: the scenario's)")
    p_sweep.add_argument("--out", type=Path, default=None, help="sweep folder (default runs/sweep_<scenario>)")
    p_sweep.add_argument("--metric", action="append", default=None, help="metric(s) of the table and figure")
    p_sweep.add_argument("--figures", action="store_true", help="also each variant's own figures")
    p_sweep.add_argument("--force", action="store_true")
    _executor_args(p_sweep, "no progress lines, no summary line (summary.csv holds it); failed variants are "
                   "still counted on stderr")
    p_camp = sub.add_parser("campaign", help="long property campaigns (sns: box, fast = reference, QP residual) "
                            "through the same executors")
    p_camp.add_argument("kind", choices=("sns",))
    p_camp.add_argument("--draws", type=int, default=10_000)
    p_camp.add_argument("--seed", type=int, default=0)
    p_camp.add_argument("--chunk", type=int, default=500, help="draws per task")
    p_camp.add_argument("--replay", type=int, default=None, metavar="INDEX", help="re-run one draw here")
    _executor_args(p_camp, "no progress lines (the result, which no file holds, is still printed)")
    args = parser.parse_args(_bare_assignments(sys.argv[1:] if argv is None else list(argv)))
    if not vars(args).get("quiet"):
        return _command(args)
    from hqp_tpm import _jit

    previous = _jit.set_notice_writer(lambda line: None)  # --quiet: not even the first run's compile notice
    try:
        return _command(args)
    finally:
        _jit.set_notice_writer(previous)


def _command(args) -> int:
    """Run the parsed subcommand; its exit code."""
    try:
        if args.command == "sweep":
            return _sweep(args)
        if args.command == "campaign":
            return _campaign(args)
        if args.command == "explain":
            from hqp_tpm.app.explain import explain_run

            return _print_lines([explain_run(args.run_dir, args.t)])
        if args.command == "list":
            from hqp_tpm.app.scenario import SCENARIO_DIR, load

            files = sorted(SCENARIO_DIR.glob("*.toml"))
            width = max((len(f.stem) for f in files), default=0)
            return _print_lines(f.stem if args.names else f"{f.stem:{width}s}  {load(f).description}" for f in files)
        if args.solver is not None:  # the option's mistake, named as such, before the run starts
            from hqp_tpm.app.scenario import check_solver_choice

            check_solver_choice(args.solver, "--solver", ParameterError)
        out = args.out or Path("runs") / Path(args.scenario).stem
        with _Signals() as signals:
            summary = run_scenario(args.scenario, out, solver=args.solver, crosscheck=args.crosscheck,
                                   progress=not args.quiet, figures=not args.no_figures, replay=not args.no_replay,
                                   viz=args.viz, steps=args.steps, explain=args.explain, force=args.force,
                                   stop=signals.stop, realtime=args.realtime if args.viz else 0.0,
                                   serve=args.viz)
    except HqpTpmError as exc:
        where = exc.partial_result
        extra = f" (the steps before it are in {where}, marked partial)" if where is not None else ""
        print(f"hqp-tpm: error: {exc}{extra}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("hqp-tpm: interrupted; nothing written, the output folder is as it was", file=sys.stderr)
        return 130
    if signals.signum is not None:
        if summary.get("out") is None:
            print(f"hqp-tpm: interrupted ({signals.name}) before the first step; nothing written", file=sys.stderr)
        else:
            print(f"hqp-tpm: interrupted ({signals.name}) after {summary['steps']} of {summary['steps_requested']} "
                  f"steps: {summary['status']} result in {summary['out']}", file=sys.stderr)
        return signals.exit_code
    if args.quiet:
        return 0
    from hqp_tpm.app.results import strict

    keys = [k for k in summary if k.endswith(("_max", "_rms", "_min")) or k in ("max_dq_jump", "chatter",
                                                                             "wall_time_s", "crosscheck_max_diff")]
    return _print_lines([json.dumps(strict({k: summary[k] for k in keys}), indent=2), wrote_line(summary["files"])])


if __name__ == "__main__":
    sys.exit(main())
