"""A quick side-by-side of hqp-tpm's readable and lean steps and the peers importable here (one process).

    python benchmarks/peers/quick_lean.py [--configs 30] [--repeats 100] [--problems iiwa_vel romeo_vel iiwa_acc]
                                          [--circle 2000] [--by-passes]

For each configuration every contender (hqp-tpm ``tpm`` and ``sns_tpm``, readable and lean; PlaCo with and
without limits, TSID; whichever import) is set up and its full step (``Contender.step``, as in ``run.py``) timed
``--repeats`` times, contenders in an order rotated per configuration; prints the median over configurations
of the per-configuration medians and of the ratio to the reference (PlaCo at velocity level, TSID at
acceleration level; hqp-tpm's readable ``tpm`` when neither imports). ``--circle N`` also runs the closed loop
of ``iiwa_circle`` (N steps, both levels, 3 interleaved rounds; :func:`benchmarks.peers.contenders.circle_loop`)
and prints the median CPU time per loop (thread time: wall time on a loaded machine mostly counts waits).
``--by-passes`` also groups the lean ``sns_tpm`` step's per-configuration medians by its number of SNS-TPM
passes (one more per saturated joint), with the configurations the compiled loop handed to the numpy path
apart. The full run is ``make bench-peers``.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks import common  # noqa: E402
from benchmarks.peers import contenders as C  # noqa: E402
from benchmarks.peers import problems as P  # noqa: E402


def contenders(robot, prob) -> list:
    out = [C.Hqp(robot, prob, "tpm"), C.Hqp(robot, prob, "tpm", lean=True), C.Hqp(robot, prob, "sns_tpm"),
           C.Hqp(robot, prob, "sns_tpm", lean=True)]
    if prob.order == 1 and importlib.util.find_spec("placo"):
        out += [C.Placo(robot, prob, False), C.Placo(robot, prob, True)]
    if prob.order == 2 and importlib.util.find_spec("tsid"):
        out.append(C.Tsid(robot, prob))
    return out


@contextlib.contextmanager
def numpy_sns_calls():
    """A list that gets an entry for each call of the numpy SNS-TPM loop (``sns._sns_tpm``) inside the block."""
    sns = importlib.import_module("hqp_tpm.solvers.sns")
    calls: list[int] = []
    numpy_loop = sns._sns_tpm

    def counted(*args, **kwargs):
        calls.append(1)
        return numpy_loop(*args, **kwargs)

    sns._sns_tpm = counted
    try:
        yield calls
    finally:
        sns._sns_tpm = numpy_loop


def by_passes(passes: list[int], handed: list[bool], times: list[float]) -> None:
    """The lean ``sns_tpm`` step's per-configuration medians grouped by SNS-TPM passes (handed back: apart)."""
    p, h, t = np.array(passes), np.array(handed), np.array(times)
    print("  lean sns_tpm by passes (configurations, median µs):")
    for k in sorted(set(p[~h].tolist())):
        sel = (p == k) & ~h
        print(f"    {k:3d} passes  {int(sel.sum()):4d}  {np.median(t[sel]):8.1f} µs")
    if h.any():
        print(f"    handed to the numpy loop  {int(h.sum()):4d}  {np.median(t[h]):8.1f} µs")


def circle(steps: int, rounds: int = 3) -> None:
    robot = P.load_robot(P.IIWA)
    for order in (1, 2):
        kinds = [(f"hqp-tpm {s}" + (" (lean)" if lean else ""), "hqp", {"solver": s, "lean": lean})
                 for s in ("tpm", "sns_tpm") for lean in (False, True)]
        if order == 1 and importlib.util.find_spec("placo"):
            kinds += [("PlaCo", "placo", {}), ("PlaCo + limits", "placo", {"limits": True})]
        if order == 2 and importlib.util.find_spec("tsid"):
            kinds.append(("TSID", "tsid", {}))
        totals: dict[str, list[float]] = {k[0]: [] for k in kinds}
        for r in range(rounds):
            for name, kind, kw in kinds[r % len(kinds):] + kinds[:r % len(kinds)]:
                t0 = time.thread_time_ns()  # CPU time: on a loaded machine wall time mostly counts the waits
                C.circle_loop(kind, robot, order, steps, time.perf_counter_ns, **kw)
                totals[name].append((time.thread_time_ns() - t0) / 1e6)
        ref = next((n for n in ("PlaCo", "TSID") if n in totals), "hqp-tpm tpm")
        print(f"iiwa_circle, order {order}: {steps}-step closed loop, {rounds} rounds (median CPU ms; ratio to {ref})")
        for name, v in totals.items():
            print(f"  {name:26s} {np.median(v):8.1f} ms   ratio {np.median(v) / np.median(totals[ref]):6.2f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", type=int, default=30)
    ap.add_argument("--repeats", type=int, default=100)
    ap.add_argument("--problems", nargs="+", default=["iiwa_vel", "romeo_vel", "iiwa_acc"],
                    choices=("iiwa_vel", "romeo_vel", "iiwa_acc"))
    ap.add_argument("--circle", type=int, default=0, help="closed-loop steps (0: no closed loop)")
    ap.add_argument("--by-passes", action="store_true", help="lean sns_tpm times by SNS-TPM passes")
    args = ap.parse_args(argv)
    with common.one_blas_thread():
        if args.circle:
            circle(args.circle)
        for kind in args.problems:
            robot = P.load_robot(P.ROMEO if kind == "romeo_vel" else P.IIWA)
            prob = (P.romeo_problem(robot, args.configs) if kind == "romeo_vel" else
                    P.iiwa_problem(robot, 1 if kind == "iiwa_vel" else 2, args.configs))
            cons = contenders(robot, prob)
            med: dict[str, list[float]] = {c.name: [] for c in cons}
            passes: list[int] = []
            handed: list[bool] = []
            for k, cfg in enumerate(prob.configs):
                for c in cons[k % len(cons):] + cons[:k % len(cons)]:
                    try:
                        c.setup(cfg)
                        c.step()
                        c.step()
                        ts = []
                        for _ in range(args.repeats):
                            t0 = time.perf_counter_ns()
                            c.step()
                            ts.append(time.perf_counter_ns() - t0)
                        med[c.name].append(float(np.median(ts)) / 1e3)
                    except Exception:  # a peer failing on a configuration (PlaCo + limits: infeasible QP)
                        med[c.name].append(float("nan"))
                    if args.by_passes and c.name == "hqp-tpm sns_tpm (lean)":
                        with numpy_sns_calls() as calls:
                            c.step()
                        passes.append(int((c.fast.info or {}).get("iterations", 0)))
                        handed.append(bool(calls))
            ref = next((n for n in ("PlaCo", "TSID") if n in med), "hqp-tpm tpm")
            base = np.array(med[ref])
            print(f"{kind} ({len(prob.configs)} configurations, {args.repeats} repeats; ratio to {ref})")
            for name, v in med.items():
                v = np.array(v)
                print(f"  {name:26s} {np.nanmedian(v):8.1f} µs   ratio {np.nanmedian(v / base):6.2f}")
            if args.by_passes and passes:
                by_passes(passes, handed, med["hqp-tpm sns_tpm (lean)"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
