"""Solve alone, side by side: hqp-tpm's lean solves and the peers' solves importable here (one process).

    python benchmarks/solve_alone.py [--configs 30] [--repeats 200] [--problems romeo_vel iiwa_vel]

Per configuration, each contender of :mod:`benchmarks.peers.contenders` (hqp-tpm ``tpm`` and ``sns_tpm`` lean,
pink, PlaCo: whichever import) is set up and its ``solve`` (the solver call on the already built problem, as in
``run.py``'s solve-alone rows) timed ``--repeats`` times, contenders in an order rotated per configuration, one
BLAS thread. Prints the median over configurations of the per-configuration medians (wall and thread CPU time)
and of the per-configuration ratio to the lean ``tpm``.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import common  # noqa: E402
from benchmarks.peers import contenders as C  # noqa: E402
from benchmarks.peers import problems as P  # noqa: E402


def contenders(robot, prob) -> list:
    out = [C.Hqp(robot, prob, "tpm"), C.Hqp(robot, prob, "sns_tpm")]
    if prob.order == 1 and importlib.util.find_spec("pink"):
        out.append(C.Pink(robot, prob, False))
    if prob.order == 1 and importlib.util.find_spec("placo"):
        out.append(C.Placo(robot, prob, False))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", type=int, default=30)
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--problems", nargs="+", default=["romeo_vel", "iiwa_vel"], choices=["romeo_vel", "iiwa_vel"])
    args = ap.parse_args(argv)
    with common.one_blas_thread():
        for name in args.problems:
            robot = P.load_robot(P.ROMEO if name.startswith("romeo") else P.IIWA)
            prob = P.romeo_problem(robot, args.configs) if name.startswith("romeo") else \
                P.iiwa_problem(robot, 1, args.configs)
            cons = contenders(robot, prob)
            wall = {c.name: [] for c in cons}
            cpu = {c.name: [] for c in cons}
            for k, cfg in enumerate(prob.configs):
                for c in cons[k % len(cons):] + cons[:k % len(cons)]:
                    c.setup(cfg)
                    c.solve()
                    tw, tc = [], []
                    for _ in range(args.repeats):
                        c0 = time.thread_time_ns()
                        t0 = time.perf_counter_ns()
                        c.solve()
                        tw.append(time.perf_counter_ns() - t0)
                        tc.append(time.thread_time_ns() - c0)
                    wall[c.name].append(np.median(tw) / 1e3)
                    cpu[c.name].append(np.median(tc) / 1e3)
            base = cons[0].name
            print(f"{name}: solve alone, {args.configs} configurations x {args.repeats} calls "
                  f"(median µs; per-configuration ratio to {base})")
            for n in wall:
                w, c = np.array(wall[n]), np.array(cpu[n])
                print(f"  {n:24s} wall {np.median(w):7.2f}  ratio {np.median(w / np.array(wall[base])):5.2f}   "
                      f"cpu {np.median(c):7.2f}  ratio {np.median(c / np.array(cpu[base])):5.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
