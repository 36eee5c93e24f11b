"""Where a step of the standing humanoid goes: motion stack, contact QP, MuJoCo step (``romeo_standing``).

    python benchmarks/standing_step.py [--steps 3000] [--warmup 300]

One BLAS thread, the lean step as ``hqp-tpm run`` uses it. Per part, median and 99th percentile of the wall
time and of the thread CPU time (µs) over ``--steps`` steps after ``--warmup``: the motion stack (state update,
rows, TPM solve: :meth:`LeanStep.compute`), the contact QP (its own state update, the QP, the torques:
:meth:`ContactInverseDynamics.solve`), the plant (``mj_step`` and the measured state), and the whole step
(``ContactController.advance``). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--warmup", type=int, default=300)
    args = p.parse_args(argv)
    from hqp_tpm.app import build, scenario

    ctrl = build.build_run(scenario.load("romeo_standing")).controller
    lean = ctrl.lean()
    parts = {k: ([], []) for k in ("motion stack (TPM)", "contact QP", "plant (mj_step + measure)", "whole step")}
    clock = (time.perf_counter, time.thread_time)

    def timed(key, fn):
        w0, c0 = clock[0](), clock[1]()
        out = fn()
        parts[key][0].append(clock[0]() - w0)
        parts[key][1].append(clock[1]() - c0)
        return out

    def command():
        return timed("motion stack (TPM)", lean.compute)

    solve, step = ctrl.contacts.solve, ctrl.plant.step
    ctrl.contacts.solve = lambda *a: timed("contact QP", lambda: solve(*a))
    ctrl.plant.step = lambda tau: timed("plant (mj_step + measure)", lambda: step(tau))
    with threadpool_limits(limits=1):
        for _ in range(args.warmup + args.steps):
            timed("whole step", lambda: ctrl.advance(command))
    print(f"romeo_standing, {args.steps} steps after {args.warmup} (t = {ctrl.t:.2f} s), one BLAS thread, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}\n")
    print("| part | wall median µs | wall p99 µs | CPU median µs | CPU p99 µs |\n|---|---|---|---|---|")
    for key, (wall, cpu) in parts.items():
        w, c = 1e6 * np.array(wall[args.warmup:]), 1e6 * np.array(cpu[args.warmup:])
        print(f"| {key} | {np.median(w):.0f} | {np.percentile(w, 99):.0f} | {np.median(c):.0f} | "
              f"{np.percentile(c, 99):.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
