"""Where a step of the standing humanoid goes: motion stack, contact QP, MuJoCo step (``romeo_standing``).

    python benchmarks/standing_step.py [--steps 3000] [--warmup 300]

One BLAS thread, the lean step as ``hqp-tpm run`` uses it, the plant as ``hqp-tpm run`` builds it
(:func:`hqp_tpm.app.plant_run.build_plant`). Per part, median and 99th percentile of the wall time and of the thread
CPU time (µs) over ``--steps`` steps after ``--warmup``: the motion stack (state update, rows, TPM solve,
integration: the lean step), the contact QP (its state update, the QP, the torques: the plant's torque law), the
MuJoCo step (``mj_step`` and the measurement), and the whole loop step (controller step, plant step, measured state
back into the controller). Prints a Markdown table.
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
    from hqp_tpm.app import build, plant_run, scenario

    ctx = build.build_run(scenario.load("romeo_standing"))
    plant = plant_run.build_plant(ctx)
    ctrl, law = ctx.controller, plant.law
    parts = {k: ([], []) for k in ("motion stack (lean TPM step)", "contact QP (torque law)",
                                   "MuJoCo step + measurement", "whole loop step")}

    def timed(key, fn, *a):
        w0, c0 = time.perf_counter(), time.thread_time()
        out = fn(*a)
        parts[key][0].append(time.perf_counter() - w0)
        parts[key][1].append(time.thread_time() - c0)
        return out

    def loop_step():
        a = timed("motion stack (lean TPM step)", lambda: ctrl.step().command)
        q, v = plant.measure()
        tau = timed("contact QP (torque law)", law, q, v, a)
        timed("MuJoCo step + measurement", plant.apply, tau)
        ctrl.set_state(*plant.measure())

    with threadpool_limits(limits=1):
        for _ in range(args.warmup + args.steps):
            timed("whole loop step", loop_step)
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
