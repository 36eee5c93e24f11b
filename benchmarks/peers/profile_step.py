"""Where hqp-tpm's full step goes on the peer problems: every call of one step, and time per function.

    python benchmarks/peers/profile_step.py [--problem iiwa_vel|romeo_vel|iiwa_acc] [--solver tpm] [--steps 2000]

1. One ``Controller.compute()`` traced with ``sys.setprofile``: every Python and C call, in order,
   with its depth (the call tree of one step) and the number of calls per function.
2. cProfile over ``--steps`` steps (configurations of the problem in turn): calls per step and µs per
   step by function (self time and cumulative).
Writes ``benchmarks/results/peers/profile_<problem>_<solver>.txt``.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from collections import Counter
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks import common  # noqa: E402
from benchmarks.peers import problems as P  # noqa: E402


def _name(frame, arg, event) -> str:
    if event.startswith("c_"):
        mod = getattr(arg, "__module__", None) or type(getattr(arg, "__self__", None)).__name__
        return f"{mod}.{getattr(arg, '__qualname__', getattr(arg, '__name__', '?'))} [C]"
    co = frame.f_code
    path = co.co_filename
    short = path.split("site-packages/")[-1] if "site-packages/" in path else Path(path).name
    return f"{short}:{co.co_firstlineno}:{co.co_qualname if hasattr(co, 'co_qualname') else co.co_name}"


def trace_one(fn) -> tuple[list[str], Counter]:
    lines, counts, depth = [], Counter(), [0]

    def prof(frame, event, arg):
        if event in ("call", "c_call"):
            n = _name(frame, arg, event)
            lines.append("  " * depth[0] + n)
            counts[n] += 1
            depth[0] += 1
        elif event in ("return", "c_return", "c_exception"):
            depth[0] = max(0, depth[0] - 1)

    sys.setprofile(prof)
    try:
        fn()
    finally:
        sys.setprofile(None)
    return lines[:-1], counts  # the last call is sys.setprofile itself


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problem", default="iiwa_vel", choices=("iiwa_vel", "romeo_vel", "iiwa_acc"))
    ap.add_argument("--solver", default="tpm")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--out", type=Path, default=common.RESULTS / "peers")
    args = ap.parse_args(argv)
    with common.one_blas_thread():
        if args.problem == "romeo_vel":
            robot = P.load_robot(P.ROMEO)
            prob = P.romeo_problem(robot, 50)
        else:
            robot = P.load_robot(P.IIWA)
            prob = P.iiwa_problem(robot, 1 if args.problem == "iiwa_vel" else 2, 50)
        ctrls = [P.hqp_controller(robot, prob, cfg, args.solver) for cfg in prob.configs]
        for c in ctrls:
            c.compute()
        lines, counts = trace_one(ctrls[0].compute)
        times = []
        for k in range(args.steps):
            t0 = time.perf_counter_ns()
            ctrls[k % len(ctrls)].compute()
            times.append(time.perf_counter_ns() - t0)
        med = sorted(times)[len(times) // 2] / 1e3
        pr = cProfile.Profile()
        pr.enable()
        for k in range(args.steps):
            ctrls[k % len(ctrls)].compute()
        pr.disable()
    st = pstats.Stats(pr)
    rows = []
    for (file, line, fn), (_cc, nc, tt, ct, _) in st.stats.items():
        short = file.split("site-packages/")[-1] if "site-packages/" in file else Path(file).name
        rows.append((tt, ct, nc, f"{short}:{line}:{fn}"))
    n = args.steps
    out = [f"# hqp-tpm full step (Controller.compute) on {prob.name}, solver {args.solver}",
           f"median step without profiler: {med:.1f} µs over {n} steps; {sum(counts.values())} calls in one step "
           f"({sum(v for k, v in counts.items() if k.endswith('[C]'))} of them C functions)", "",
           "## Calls per function in one step", ""]
    out += [f"{v:4d}  {k}" for k, v in counts.most_common()]
    out += ["", f"## cProfile over {n} steps: per step (self µs, cumulative µs, calls), by self time", ""]
    for tt, ct, nc, name in sorted(rows, reverse=True)[:45]:
        out.append(f"{1e6 * tt / n:8.2f} {1e6 * ct / n:8.2f} {nc / n:6.2f}  {name}")
    out += ["", "## Call tree of one step", ""] + lines
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"profile_{prob.name}_{args.solver}.txt"
    path.write_text("\n".join(out) + "\n")
    print("\n".join(out[:60]))
    print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
