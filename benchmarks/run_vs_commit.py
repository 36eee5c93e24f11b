"""A scenario's whole run (its step in a loop, nothing recorded) here and in another checkout, interleaved.

    python benchmarks/run_vs_commit.py OTHER_CHECKOUT [--scenario lwr_relaxed] [--rounds 2]

``OTHER_CHECKOUT`` is a directory with the package of an earlier commit (e.g. ``git worktree add
../old 37dff08``); each run is a fresh process of this interpreter with that checkout (or this one)
first on ``sys.path``, one BLAS thread, the two alternating. Each checkout steps with its lean step where
it has one (``hqp_tpm.app.runner.lean_stepper``: what ``hqp-tpm run`` uses), else ``ctrl.step()``
(``--step readable``: ``ctrl.step()`` in both). Prints wall and CPU seconds per run and the ratio of the
medians (other / this).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
from threadpoolctl import threadpool_limits
threadpool_limits(1)
from hqp_tpm.app.build import build
from hqp_tpm.app.scenario import load
sc = load(sys.argv[1])
_, ctrl, _, _ = build(sc)
steps = int(sys.argv[2])
step, kind = ctrl.step, "readable"
if sys.argv[3] == "fastest":  # the lean step the runner takes, where the checkout has one
    try:
        from hqp_tpm.app.runner import lean_stepper
    except ImportError:
        lean_stepper = None
    fast = lean_stepper(ctrl) if lean_stepper is not None else None
    if fast is not None:
        step, kind = fast[0], "lean"
c0, t0 = time.process_time(), time.perf_counter()
for _ in range(steps):
    step()
print(json.dumps({"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0, "steps": steps,
                  "q": [float(v) for v in ctrl.q], "kind": kind}))
"""


def one(checkout: Path, scenario: str, steps: int, step: str = "fastest") -> dict:
    env = {**os.environ, "PYTHONPATH": str(checkout), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", CHILD, scenario, str(steps), step], env=env, capture_output=True,
                         text=True, check=True, cwd=checkout)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", type=Path)
    ap.add_argument("--scenario", default="lwr_relaxed")
    ap.add_argument("--steps", type=int, default=18850)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--step", choices=("fastest", "readable"), default="fastest",
                    help="fastest: each checkout's lean step where it has one (what `hqp-tpm run` steps with), "
                         "else ctrl.step(); readable: ctrl.step() in both")
    args = ap.parse_args()
    res = {"this": [], "other": []}
    for r in range(args.rounds):
        for name, path in ((("this", ROOT), ("other", args.other)) if r % 2 == 0 else
                           (("other", args.other), ("this", ROOT))):
            d = one(path, args.scenario, args.steps, args.step)
            res[name].append(d)
            print(f"round {r} {name:5s}: {d['wall']:.2f} s wall, {d['cpu']:.2f} s CPU, {d['steps']} steps "
                  f"({d['kind']} step)", flush=True)
    med = {k: (statistics.median(d["wall"] for d in v), statistics.median(d["cpu"] for d in v)) for k, v in res.items()}
    dq = max(abs(a - b) for a, b in zip(res["this"][0]["q"], res["other"][0]["q"], strict=True))
    print(f"{args.scenario}: this {med['this'][0]:.2f} s ({med['this'][1]:.2f} s CPU), other {med['other'][0]:.2f} s "
          f"({med['other'][1]:.2f} s CPU); speed-up other/this {med['other'][0] / med['this'][0]:.2f}x wall, "
          f"{med['other'][1] / med['this'][1]:.2f}x CPU; final q differs by {dq:.1e}; load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
