"""Peak memory of a whole ``hqp-tpm run`` at several horizons: does it grow with the number of steps?

    python benchmarks/peak_rss.py [--scenario lwr_relaxed] [--steps 18850 94250] [--figures] [--other CHECKOUT]

Each run is a fresh process (``hqp_tpm.app.run_scenario.run_scenario``, no progress bar; figures and replay only with
``--figures``) that prints its ``ru_maxrss`` at the end; ``--other`` runs the same in another checkout (e.g. a
worktree of an earlier commit) for comparison. Prints the peak RSS per run and the growth per extra step.
A measurement, not a test: the numbers depend on the machine, only their growth with the steps matters.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import resource, sys
from hqp_tpm.app.cli import run_scenario
figures = sys.argv[4] == "1"
run_scenario(sys.argv[1], sys.argv[2], steps=int(sys.argv[3]), progress=False, figures=figures, replay=figures)
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def peak_kb(checkout: Path, scenario: str, steps: int, figures: bool) -> int:
    env = {**os.environ, "PYTHONPATH": str(checkout), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory(prefix="hqp-tpm-rss-") as tmp:
        out = subprocess.run([sys.executable, "-c", CHILD, scenario, str(Path(tmp) / "run"), str(steps),
                              "1" if figures else "0"], env=env, capture_output=True, text=True, check=True,
                             cwd=checkout)
    return int(out.stdout.split()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="lwr_relaxed")
    ap.add_argument("--steps", type=int, nargs="+", default=[18850, 94250])
    ap.add_argument("--figures", action="store_true", help="also write figures and the replay")
    ap.add_argument("--other", type=Path, default=None, help="another checkout, measured alike")
    args = ap.parse_args()
    checkouts = [("this", ROOT)] + ([("other", args.other)] if args.other else [])
    for name, path in checkouts:
        peaks = []
        for steps in args.steps:
            kb = peak_kb(path, args.scenario, steps, args.figures)
            peaks.append(kb)
            print(f"{name:5s} {args.scenario} {steps:>8d} steps: peak RSS {kb / 1024:.1f} MB", flush=True)
        if len(peaks) > 1:
            per_step = (peaks[-1] - peaks[0]) * 1024 / (args.steps[-1] - args.steps[0])
            print(f"{name:5s} growth: {per_step:.3f} bytes per step ({args.steps[0]} -> {args.steps[-1]} steps)")


if __name__ == "__main__":
    main()
