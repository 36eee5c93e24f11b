"""First-call cost of the compiled kernels: compile (empty numba cache) and load (warm cache), in fresh processes.

    python benchmarks/first_call.py [--rounds 2] [--out benchmarks/results/first_call.md]

Each measurement is a fresh Python process with ``NUMBA_CACHE_DIR`` set to a directory of its own: an empty one
(the first use on a machine: every kernel a step calls is compiled), then the same one again (a later process:
the kernels are loaded from numba's disk cache). In that process: the import of ``hqp_tpm``, building the
controller, then the first lean step (``ctrl.step()``: its compiled step) the median of the
next 200 (compiled: the steady state). Cases: the iiwa EE pose > posture with ``tpm``
and with ``sns_tpm`` under the joint box (the fused kernel), Romeo's five levels with ``sns_tpm``, and
``lwr_relaxed`` (the planned step: distance, row and TPM kernels).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import common  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

#: the child process: builds one case and times its first two steps (prints one JSON line)
CHILD = r"""
import json, sys, time
t0, c0 = time.perf_counter(), time.process_time()
sys.path.insert(0, {root!r})
import hqp_tpm
case = {case!r}
if case == "lwr_relaxed":
    from hqp_tpm.app.build import build
    from hqp_tpm.app.scenario import load
    ctrl = build(load("lwr_relaxed"))[1]
    step = ctrl.step
else:
    from benchmarks.peers import problems as P
    kind, solver = case.split(":")
    robot = P.load_robot(P.ROMEO if kind == "romeo_vel" else P.IIWA)
    prob = P.romeo_problem(robot, n=1) if kind == "romeo_vel" else P.iiwa_problem(robot, order=1, n=1)
    ctrl = P.hqp_controller(robot, prob, prob.configs[0], solver)
    step = ctrl.step
t1, c1 = time.perf_counter(), time.process_time()
step()
t2, c2 = time.perf_counter(), time.process_time()
later = []
for _ in range(200):
    t = time.perf_counter()
    step()
    later.append(time.perf_counter() - t)
later.sort()
print(json.dumps({{"setup": [t1 - t0, c1 - c0], "first": [t2 - t1, c2 - c1], "later": later[len(later) // 2]}}))
"""

CASES = ("iiwa_vel:tpm", "iiwa_vel:sns_tpm", "romeo_vel:sns_tpm", "lwr_relaxed")


def child(case: str, cache: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", CHILD.format(root=str(ROOT), case=case)], env=env, check=True,
                         capture_output=True, text=True, cwd=ROOT).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", type=Path, default=common.RESULTS / "first_call.md")
    args = ap.parse_args(argv)
    env = common.environment()
    rows = []
    for case in CASES:
        runs = {"compile": [], "load": []}
        for _ in range(args.rounds):
            with tempfile.TemporaryDirectory(prefix="hqp-tpm-numba-") as cache:
                runs["compile"].append(child(case, cache))
                runs["load"].append(child(case, cache))
        for kind, rs in runs.items():
            best = min(rs, key=lambda r: r["first"][1])
            rows.append(f"| `{case}` | {kind} | {1e3 * best['setup'][0]:.0f} | {1e3 * best['first'][0]:.0f} | "
                        f"{1e3 * best['first'][1]:.0f} | {1e6 * best['later']:.1f} |")
            common.progress(rows[-1])
    text = ("# First call of the compiled kernels\n\n"
            f"Written by `python benchmarks/first_call.py --rounds {args.rounds}`; "
            + "; ".join(f"{k}: {v}" for k, v in env.items()) + ".\n\n"
            "Fresh processes, each with its own numba cache directory: *compile* = empty cache (the first use on a "
            "machine), *load* = the cache the compile run wrote. Setup = Python start to a built controller "
            "(imports, robot model); the first step compiles or loads every kernel it calls. The fastest of "
            f"{args.rounds} rounds by first-step CPU time.\n\n"
            "| case | cache | setup ms (wall) | first step ms (wall) | first step ms (CPU) | later steps µs |\n"
            "|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n")
    args.out.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
