"""``ctrl.step()`` of the policy scenarios here and in another checkout, interleaved: thread CPU per step.

    python benchmarks/policy_steps.py OTHER_CHECKOUT [--scenarios romeo_obstacles_sns_tpm ...] [--steps N]
                                      [--rounds 2]

Each run is a fresh process of this interpreter with one checkout first on ``sys.path`` (started in a neutral
directory, so that the other checkout's package is the one imported), one BLAS thread; the two checkouts alternate.
Per scenario: the median and p99 of the thread CPU time of ``ctrl.step()`` over the run (its first step, which plans
the compiled step, left out), the share of the SNS-TPM kernel in it (``sns_tpm_loop`` timed; 0 for the other
solvers), the policy's ``probe`` (what the runner records after each step), and whether the step ran compiled.
Prints the medians over the rounds and their ratios (this / other).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ("romeo_obstacles_sns_tpm", "lwr_relaxed", "iiwa_comanipulation", "iiwa_admittance", "planar5_exact",
             "planar5_pwdls")

CHILD = r"""
import importlib, json, sys, time
import numpy as np
from threadpoolctl import threadpool_limits
threadpool_limits(1)
import hqp_tpm
assert hqp_tpm.__file__.startswith(sys.argv[3]), hqp_tpm.__file__
from hqp_tpm.solvers import _compiled_sns
sns = importlib.import_module("hqp_tpm.solvers.sns")
spent = [0]
loop = _compiled_sns.sns_tpm_loop
def timed(*args, **kwargs):
    t0 = time.thread_time_ns()
    try:
        return loop(*args, **kwargs)
    finally:
        spent[0] += time.thread_time_ns() - t0
_compiled_sns.sns_tpm_loop = timed
sns._compiled_sns = _compiled_sns
from hqp_tpm.app.build import build_run
from hqp_tpm.app.scenario import load
ctx = build_run(load(sys.argv[1]))
ctrl, policy, steps = ctx.controller, ctx.policy, int(sys.argv[2])
policy.probe(ctrl, ctrl.step())
spent[0] = 0
times, probe = [], 0
for _ in range(steps):
    t0 = time.thread_time_ns()
    res = ctrl.step()
    t1 = time.thread_time_ns()
    policy.probe(ctrl, res)
    probe += time.thread_time_ns() - t1
    times.append(t1 - t0)
t = np.array(times) / 1e3
print(json.dumps({"median_us": float(np.median(t)), "p99_us": float(np.percentile(t, 99)),
                  "step_s": float(t.sum() / 1e6), "sns_s": spent[0] / 1e9, "probe_s": probe / 1e9,
                  "compiled": ctrl.compiled()}))
"""


def one(checkout: Path, scenario: str, steps: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(checkout), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as cwd:  # (python -c puts the working directory first on sys.path)
        out = subprocess.run([sys.executable, "-c", CHILD, scenario, str(steps), str(checkout)], env=env,
                             capture_output=True, text=True, check=True, cwd=cwd)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", type=Path)
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    other = args.other.resolve()
    for scenario in args.scenarios:
        res = {"this": [], "other": []}
        for r in range(args.rounds):
            for name, path in ((("this", ROOT), ("other", other)) if r % 2 == 0 else
                               (("other", other), ("this", ROOT))):
                res[name].append(one(path, scenario, args.steps))
        med = {k: {f: statistics.median(d[f] for d in v) for f in ("median_us", "p99_us", "step_s", "sns_s",
                                                                      "probe_s")} for k, v in res.items()}
        print(f"{scenario} ({args.steps} steps, {args.rounds} rounds; compiled: this "
              f"{res['this'][0]['compiled']}, other {res['other'][0]['compiled']}; load {os.getloadavg()[0]:.1f})")
        for f in med["this"]:
            a, b = med["this"][f], med["other"][f]
            print(f"  {f:10s} this {a:10.3f}  other {b:10.3f}  this/other {a / b if b else float('nan'):.2f}")


if __name__ == "__main__":
    main()
