"""Run every benchmark in one process and write a summary (``make bench`` calls this).

    python benchmarks/run_all.py [--quick] [--out DIR] [--draws N] [--qp-draws N] [--steps N]

Runs ``solvers.py``, ``control_step.py``, ``profile_steps.py`` and ``plant_step.py`` one after the other (each with one
BLAS thread), then writes ``summary.md`` and ``summary.csv`` (every target, met or missed, with the
figure measured in this run) next to their own result files in ``benchmarks/results/``.
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make ``benchmarks`` importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import common, control_step, plant_step, profile_steps, solvers  # noqa: E402


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="smoke test of every benchmark (seconds, numbers meaningless)")
    p.add_argument("--out", type=Path, default=common.RESULTS)
    p.add_argument("--draws", type=int, default=None, help="solvers.py --draws")
    p.add_argument("--qp-draws", type=int, default=None, help="solvers.py --qp-draws")
    p.add_argument("--steps", type=int, default=None, help="control_step.py --steps")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse(argv)
    common_args = ["--out", str(args.out), *(["--quick"] if args.quick else [])]
    solver_args = [*common_args, *(["--draws", str(args.draws)] if args.draws else []),
                   *(["--qp-draws", str(args.qp_draws)] if args.qp_draws else [])]
    step_args = [*common_args, *(["--steps", str(args.steps)] if args.steps else [])]
    t0 = time.perf_counter()
    durations = {}
    common.progress("solvers.py")
    s = solvers.main(solver_args)
    durations["solvers.py"] = time.perf_counter() - t0
    common.progress("control_step.py")
    t1 = time.perf_counter()
    c = control_step.main(step_args)
    durations["control_step.py"] = time.perf_counter() - t1
    common.progress("profile_steps.py")
    t1 = time.perf_counter()
    p = profile_steps.main(common_args)
    durations["profile_steps.py"] = time.perf_counter() - t1
    common.progress("plant_step.py")
    t1 = time.perf_counter()
    ps = plant_step.main(common_args)
    durations["plant_step.py"] = time.perf_counter() - t1
    total = time.perf_counter() - t0

    targets = [*c["targets"], *s["targets"]]
    env = dict(c["env"])
    env.pop("settings", None)
    env.pop("CPU share of this process", None)
    env["benchmark wall times"] = ", ".join(f"{k} {v:.0f} s" for k, v in durations.items()) + f"; total {total:.0f} s"
    env["CPU share (solvers / control step / profiles)"] = " / ".join(
        r["env"].get("CPU share of this process", "?") for r in (s, c, p))
    sections = [
        ("Targets (issue 6)", common.targets_markdown(targets) + "\n\nRatios are medians measured in the same run; "
         "absolute times depend on the machine and on its load (see the CPU share above: below 100 % other processes "
         "took the cores part of the time, which raises the 99th percentiles most). Every time is also measured as "
         "thread CPU time; a target counts as met only if both the wall-time and the CPU-time figures meet it."),
        *[(f"Control step — {h}", b) for h, b in c["sections"] if h != "Targets"],
        *[(f"Solvers — {h}", b) for h, b in s["sections"] if h != "Targets"],
        *p["sections"],
        *[(f"MuJoCo plant — {h}", b) for h, b in ps["sections"]],
        ("Files", "`solvers.csv`, `solvers.md`, `solvers_vs_l.png`, `solvers_vs_n.png`, `control_step.csv`, "
                  "`control_step.md`, `profile_lwr_relaxed.txt`, `profile_romeo_sns_tpm.txt`, `plant_step.csv`, "
                  "`plant_step.md`, `summary.csv`."),
    ]
    common.write_markdown(args.out / "summary.md", "Benchmark summary", env, sections)
    with open(args.out / "summary.csv", "w", newline="") as fh:
        for k, v in env.items():
            fh.write(f"# {k}: {v}\n")
        w = csv.writer(fh)
        w.writerow(["target", "goal", "measured", "met"])
        for t in targets:
            w.writerow([t.name, t.goal, t.measured, t.met])
    common.progress(f"wrote {args.out}/summary.md, summary.csv ({total:.0f} s)")
    print((args.out / "summary.md").read_text().split("## Control step")[0])
    return 0


if __name__ == "__main__":
    sys.exit(main())
