"""The compiled solver kernels against their numpy references, interleaved in one process.

    python benchmarks/compiled.py [--configs 200] [--reps 30] [--out benchmarks/results/compiled.md]

On the side-by-side benchmark's problems (benchmarks/peers/problems.py: iiwa EE pose > posture at velocity and
acceleration level, Romeo sole > CoM > foot > hands > posture), per configuration, the stacked ``J``, ``b``:

* ``tpm_stacked`` with the compiled kernel (``hqp_tpm.solvers._compiled``), the lean step's solve;
* ``tpm_stacked`` on the numpy path (``_compiled.ENABLED = False``): the readable reference;
* ``tpm_reference``: the paper's steps (padded ``J``, SVD of ``R^T``), what ``tpm`` did on these stacks before the
  full-rank shortcut;
* the same stack without its posture level (``m <= n``: the general path's kernel), compiled and numpy;
* ``tpm(levels)`` and ``sns_tpm(levels, box)`` (URDF velocity limits at velocity level; validation included),
  compiled and numpy.

Contenders run in turn at each configuration (``--reps`` calls each, median), one BLAS thread; the table gives the
median over configurations of the per-call median (µs) and of the ratio to the compiled ``tpm_stacked`` at the
same configuration. Also: the process's first-call time (compile, or load from numba's on-disk cache).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from benchmarks import common  # noqa: E402
from benchmarks.peers import problems as P  # noqa: E402


def _median_ns(fn, reps: int) -> float:
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter_ns()
        fn()
        ts.append(time.perf_counter_ns() - t0)
    return float(np.median(ts))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", type=int, default=200)
    ap.add_argument("--reps", type=int, default=30)
    ap.add_argument("--problems", default="iiwa_vel,iiwa_acc,romeo_vel")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "compiled.md")
    args = ap.parse_args(argv)
    t0, c0 = time.perf_counter(), time.process_time()
    from hqp_tpm.solvers import _compiled
    from hqp_tpm.solvers.levels import stacked
    from hqp_tpm.solvers.sns import sns_tpm
    from hqp_tpm.solvers.tpm import tpm, tpm_reference, tpm_stacked

    J = np.vstack([np.random.default_rng(0).standard_normal((6, 7)), np.eye(7)])
    tpm_stacked(J, np.ones(13), (6, 7), 7)
    first = (time.perf_counter() - t0, time.process_time() - c0)

    def switch(on):
        _compiled.ENABLED = on

    rows = []
    env = {}
    with common.one_blas_thread():
        env = common.environment()
        for name in args.problems.split(","):
            robot = P.load_robot(P.ROMEO if name.startswith("romeo") else P.IIWA)
            prob = P.romeo_problem(robot, args.configs) if name.startswith("romeo") else \
                P.iiwa_problem(robot, 1 if name == "iiwa_vel" else 2, args.configs)
            n = robot.nv
            cases = {}
            for cfg in prob.configs:
                ctrl = P.hqp_controller(robot, prob, cfg, "sns_tpm")
                levels = ctrl.compute().levels
                lo, up = ctrl.box(ctrl.state, ctrl.t)
                _, J, b, sizes, _ = stacked(levels, n)
                cand = {
                    "tpm_stacked, compiled": (True, lambda J=J, b=b, s=sizes, n=n: tpm_stacked(J, b, s, n)),
                    "tpm_stacked, numpy": (False, lambda J=J, b=b, s=sizes, n=n: tpm_stacked(J, b, s, n)),
                    "tpm_reference (the paper's steps)": (False, lambda lv=levels, n=n: tpm_reference(lv, n=n)),
                    "tpm(levels), compiled": (True, lambda lv=levels, n=n: tpm(lv, n=n)),
                    "tpm(levels), numpy": (False, lambda lv=levels, n=n: tpm(lv, n=n)),
                    "sns_tpm(levels, box), compiled": (True, lambda lv=levels, lo=lo, up=up: sns_tpm(lv, lo, up)),
                    "sns_tpm(levels, box), numpy": (False, lambda lv=levels, lo=lo, up=up: sns_tpm(lv, lo, up)),
                }
                _, Jt, bt, st, _ = stacked(levels[:-1], n)  # without the posture level: m <= n, the general path
                cand.update({
                    "top levels only (m <= n): tpm_stacked, compiled": (True, lambda J=Jt, b=bt, s=st, n=n:
                                                                        tpm_stacked(J, b, s, n)),
                    "top levels only (m <= n): tpm_stacked, numpy": (False, lambda J=Jt, b=bt, s=st, n=n:
                                                                     tpm_stacked(J, b, s, n)),
                })
                for key, (on, fn) in cand.items():
                    switch(on)
                    fn()
                    cases.setdefault(key, []).append(_median_ns(fn, args.reps))
                switch(True)
            base = np.array(cases["tpm_stacked, compiled"])
            for key, ts in cases.items():
                ts = np.array(ts)
                rows.append((name, f"{robot.name}: {J.shape[0]} x {n}, levels {list(sizes)}", key,
                             np.median(ts) / 1e3, np.percentile(ts, 99) / 1e3, float(np.median(ts / base))))
            print(f"{name} done", file=sys.stderr)
        common.close_environment(env)
    out = ["# Compiled solver kernels vs the numpy reference", "",
           f"Written by `python benchmarks/compiled.py --configs {args.configs} --reps {args.reps}`. "
           + "; ".join(f"{k}: {v}" for k, v in env.items()) + ".", "",
           f"First call in this process (import of the solvers + numba, then compile or load the cache): "
           f"{first[0] * 1e3:.0f} ms wall, {first[1] * 1e3:.0f} ms CPU.", "",
           "| problem | stack | contender | median µs | p99 µs | ratio to compiled `tpm_stacked` (median) |",
           "|---|---|---|---|---|---|"]
    for name, shape, key, med, p99, ratio in rows:
        out.append(f"| {name} | {shape} | {key} | {med:.1f} | {p99:.1f} | {ratio:.2f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(out) + "\n")
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
