"""Solve alone, side by side: hqp-tpm's solves and the peers' solves importable here (one process).

    python benchmarks/solve_alone.py [--configs 30] [--repeats 200] [--problems romeo_vel iiwa_vel] [--call rows_solve]

Per configuration, each contender of :mod:`benchmarks.peers.contenders` (hqp-tpm ``tpm`` and ``sns_tpm``, pink
and PlaCo with velocity limits: whichever import) is set up and its ``--call`` timed ``--repeats`` times,
contenders in an order rotated per configuration, one BLAS thread: ``rows_solve`` (default; the task rows at the
state already set and the solve, what PlaCo's ``solve`` does: like for like) or ``solve`` (the solver alone on the
built levels; PlaCo has none and is left out). Prints the median over configurations of the per-configuration
medians (wall and thread CPU time), the p99 of all calls, and the median of the per-configuration ratios to
hqp-tpm ``tpm`` and to PlaCo (when it runs).
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
        out.append(C.Pink(robot, prob, True))
    if prob.order == 1 and importlib.util.find_spec("placo"):
        out.append(C.Placo(robot, prob, True))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", type=int, default=30)
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--problems", nargs="+", default=["romeo_vel", "iiwa_vel"], choices=["romeo_vel", "iiwa_vel"])
    ap.add_argument("--call", default="rows_solve", choices=["rows_solve", "solve"])
    args = ap.parse_args(argv)
    with common.one_blas_thread():
        for name in args.problems:
            robot = P.load_robot(P.ROMEO if name.startswith("romeo") else P.IIWA)
            prob = P.romeo_problem(robot, args.configs) if name.startswith("romeo") else \
                P.iiwa_problem(robot, 1, args.configs)
            cons = [c for c in contenders(robot, prob) if getattr(c, args.call, None) is not None]
            wall = {c.name: [] for c in cons}
            cpu = {c.name: [] for c in cons}
            p99 = {c.name: [] for c in cons}
            for k, cfg in enumerate(prob.configs):
                for c in cons[k % len(cons):] + cons[:k % len(cons)]:
                    c.setup(cfg)
                    call = getattr(c, args.call)
                    call()
                    tw, tc = [], []
                    for _ in range(args.repeats):
                        c0 = time.thread_time_ns()
                        t0 = time.perf_counter_ns()
                        call()
                        tw.append(time.perf_counter_ns() - t0)
                        tc.append(time.thread_time_ns() - c0)
                    wall[c.name].append(np.median(tw) / 1e3)
                    cpu[c.name].append(np.median(tc) / 1e3)
                    p99[c.name].extend(np.array(tc) / 1e3)
            bases = [cons[0].name] + [n for n in wall if n.lower().startswith("placo")]
            print(f"{name}: {args.call}, {args.configs} configurations x {args.repeats} calls (median µs; thread CPU "
                  f"p99 over all calls; per-configuration ratios to {' and '.join(bases)})")
            for n in wall:
                w, c = np.array(wall[n]), np.array(cpu[n])
                ratios = "  ".join(f"cpu/{b.split()[-1]} {np.median(c / np.array(cpu[b])):5.2f}" for b in bases)
                print(f"  {n:24s} wall {np.median(w):7.2f}   cpu {np.median(c):7.2f}  p99 "
                      f"{np.percentile(p99[n], 99):7.2f}   {ratios}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
