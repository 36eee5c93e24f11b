"""Where hqp-tpm's full step goes on the peer problems: every call of one step, and time per function.

    python benchmarks/peers/profile_step.py [--problem iiwa_vel|romeo_vel|iiwa_acc] [--solver tpm] [--steps N] [--lean]

``--lean`` profiles the compiled step (:mod:`hqp_tpm.control._lean`) instead of ``Controller.compute(record=True)``;
its phases are
the partial state update, each task's row writer, the joint box, the finiteness test and the solver call (with
numba: each task's row-program gather or row writer and the fused kernel call, which also solves with ``tpm``),
and the readable
step is timed beside it (interleaved, same configurations) for the ratio.

1. Phases of one step timed apart in tight loops (median µs of ``--reps`` calls at one configuration,
   no profiler overhead): pinocchio's kinematics alone, ``State.update``, each task's ``level``,
   ``Stack.to_levels``, and inside ``tpm``: stacking (``stacked``), ``J^T = QR`` + pivots
   (``_Factorization``), ``F b``, ``J# y``; the rest of ``Controller.compute`` by difference.
2. One ``Controller.compute()`` traced with ``sys.setprofile``: every Python call and builtin C call
   (not Boost.Python ones such as pinocchio's), in order, with its depth, and calls per function.
3. cProfile over ``--steps`` steps (configurations of the problem in turn): calls per step and µs per
   step by function (self time and cumulative; inflated by the profiler's per-call overhead).
Writes ``benchmarks/results/peers/profile_<problem>_<solver>.txt``.
"""

from __future__ import annotations

import argparse
import cProfile
import math
import pstats
import sys
import time
from collections import Counter
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import numpy as np  # noqa: E402

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


def _median_us(fn, reps: int) -> float:
    fn()
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter_ns()
        fn()
        ts.append(time.perf_counter_ns() - t0)
    return sorted(ts)[len(ts) // 2] / 1e3


def phase_times(ctrl, reps: int) -> list[tuple[str, float]]:
    """Median µs of the phases of one ``Controller.compute()`` (see the module docstring)."""
    import importlib

    import pinocchio as pin

    lvmod = importlib.import_module("hqp_tpm.solvers.levels")
    tpm_mod = importlib.import_module("hqp_tpm.solvers.tpm")

    st, model = ctrl.state, ctrl.robot.model
    data, q, v, z = st.data, ctrl.q, ctrl.v, np.zeros(ctrl.robot.nv)
    stack = ctrl.policy(st, ctrl.t)
    out = [("Controller.compute (whole step)", _median_us(ctrl.compute, reps))]

    def kin():
        pin.forwardKinematics(model, data, q, v, z)
        pin.computeJointJacobians(model, data)
        pin.updateFramePlacements(model, data)

    out.append(("  pinocchio alone: forwardKinematics + computeJointJacobians + updateFramePlacements",
                _median_us(kin, reps)))
    out.append(("State.update (the above + cache reset)", _median_us(lambda: st.update(q, v, ctrl.t, validate=False),
                                                                       reps)))

    def levels_fresh():
        st._cache.clear()  # a fresh step: Jacobians and CoM not cached yet
        return stack.to_levels(st, ctrl.t, ctrl.order)

    out.append(("Stack.to_levels (all tasks, fresh cache)", _median_us(levels_fresh, reps)))
    for lv in stack.levels:
        for task in lv:
            def one(task=task):
                st._cache.clear()
                return task.level(st, ctrl.t, ctrl.order)
            out.append((f"  {type(task).__name__}({task.name}).level, fresh cache", _median_us(one, reps)))
    levels = levels_fresh()
    out.append(("  cache reset alone (dict.clear)", _median_us(st._cache.clear, reps)))
    nv = ctrl.robot.nv
    out.append(("tpm(levels) (solve alone)", _median_us(lambda: tpm_mod.tpm(levels, n=nv), reps)))
    out.append(("  stacked(levels): validation + vstack J, concatenate b", _median_us(lambda: lvmod.stacked(levels, nv),
                                                                                    reps)))
    _, J, b, sizes, n = lvmod.stacked(levels, nv)
    out.append(("  _Factorization: dgeqrf of J^T (padded) + pivots", _median_us(
        lambda: tpm_mod._Factorization(J, sizes, n, 0.0, 0.0), reps)))
    fac = tpm_mod._Factorization(J, sizes, n, 0.0, 0.0)
    out.append((f"    pivots alone ({len(sizes)} blocks; regular={fac.regular}, singular={fac.singular})",
                _median_us(lambda: tpm_mod._pivots(fac.qr, fac.off, 0.0, 0.0), reps)))

    def fb():
        fac._Fbar = None
        return fac.F_times(b)

    out.append(("  F b (Steps 1-4 when a pivot is not regular)", _median_us(fb, reps)))
    y = fac.F_times(b)

    def pt():
        fac._Q = None
        return fac.pinv_times(y)

    out.append(("  J# y = Q R^-T y (SVD pinv of R^T when singular) incl. dorgqr", _median_us(pt, reps)))
    out.append((f"stacked J: {J.shape[0]} x {J.shape[1]}, levels {list(sizes)}", float("nan")))
    return out


def lean_phase_times(ctrl, reps: int) -> list[tuple[str, float]]:
    """Median µs of the phases of one lean step (``LeanStep.compute``) and of the readable step beside it."""
    from hqp_tpm.control import _compiled_step
    from hqp_tpm.control import _lean as lean_mod

    fast = ctrl._compiled_step()
    st, t = ctrl.state, ctrl.t
    out = [("LeanStep.compute (whole lean step)", _median_us(fast.compute, reps)),
           ("Controller.compute(record=True) (readable step, for the ratio)",
            _median_us(lambda: ctrl.compute(record=True), reps)),
           ("  state update (partial: the writers' frames; no velocity pass at order 1)", _median_us(
               lambda: st.update(ctrl.q, ctrl.v, t, validate=False, frames=fast.frames, velocities=ctrl.order == 2),
               reps))]
    if fast._kernel is not None:  # the fused rows (hqp_tpm.control._compiled_step): gathers, one kernel call
        if ctrl.order == 1:
            out[-1] = ("  state update (State.update_positions: the frames the kernel does not place, no velocity "
                       "pass)", _median_us(lambda: st.update_positions(ctrl.q, ctrl.v, t, fast._fused_frames,
                                                                       fast._com), reps))
        prog = fast._program
        fast.compute()
        for task, write, own in zip(fast.tasks, fast._fused, fast.writers, strict=True):
            what = "row writer" if write is own else "row program's gather"
            out.append((f"  {type(task).__name__}({task.name}) {what}", _median_us(lambda w=write: w(t), reps)))
        what = {_compiled_step.TPM: "TPM, finiteness of x",
                _compiled_step.SNS: f"box ({'given' if prog.box_given else 'in the kernel'}), SNS-TPM, finiteness of x",
                }.get(prog.solve, "no solve")
        out.append((f"  fused kernel: program rows, finiteness of J and b, {what}", _median_us(
            lambda: fast._kernel(fast._buf, prog.ints, prog.floats, ctrl.q, ctrl.v), reps)))
        if ctrl.solver == "tpm":
            out.append(("  (for comparison) tpm_stacked alone", _median_us(
                lambda: lean_mod.tpm_stacked(fast.J, fast.b, fast.sizes, fast.n, fast.lambda_max, fast.eps), reps)))
    else:
        for task, write in zip(fast.tasks, fast.writers, strict=True):
            out.append((f"  {type(task).__name__}({task.name}) row writer", _median_us(lambda w=write: w(t), reps)))
        flat = fast._flat
        out.append(("  finiteness test of J and b (as in LeanStep.compute)",
                    _median_us(lambda: math.isfinite(flat @ flat) or np.isfinite(flat).all(), reps)))
        if ctrl.solver == "tpm":
            out.append(("  tpm_stacked (solve)", _median_us(
                lambda: lean_mod.tpm_stacked(fast.J, fast.b, fast.sizes, fast.n, fast.lambda_max, fast.eps), reps)))
    # the phases both paths share: the box, the SNS solve (its own call either way), the integration
    if fast.box is not None:
        out.append((f"  box ({type(fast.box).__name__})", _median_us(lambda: fast._box(st, t), reps)))
    if ctrl.solver == "sns_tpm" and fast.x0 is None:  # (the fused kernel's SNS on the same J, b, box: for comparison)
        lo, up = (a.copy() for a in fast._box(st, t))
        out.append(("  sns_tpm_stacked on J, b (solve)", _median_us(lambda: lean_mod.sns_tpm_stacked(
            fast.J, fast.b, fast.sizes, lo, up, lambda_max=fast.lambda_max, eps=fast.eps), reps)))
    out.append(("  integration (State.integrate)", _median_us(
        lambda: st.integrate(ctrl.q, ctrl.v, ctrl.v, ctrl.dt, ctrl.order), reps)))
    out.append((f"stacked J: {fast.J.shape[0]} x {fast.J.shape[1]}, levels {list(fast.sizes)}", float("nan")))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problem", default="iiwa_vel", choices=("iiwa_vel", "romeo_vel", "iiwa_acc"))
    ap.add_argument("--solver", default="tpm")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--reps", type=int, default=3000)
    ap.add_argument("--out", type=Path, default=common.RESULTS / "peers")
    ap.add_argument("--lean", action="store_true", help="profile the compiled step (hqp_tpm.control._lean)")
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
        steps = [c._compiled_step().compute if args.lean else (lambda c=c: c.compute(record=True)) for c in ctrls]
        for step in steps:  # (a lean step's first call also copies its constant references: traced below, the next)
            step()
        phases = lean_phase_times(ctrls[0], args.reps) if args.lean else phase_times(ctrls[0], args.reps)
        lines, counts = trace_one(steps[0])
        times, readable = [], []
        for k in range(args.steps):
            t0 = time.perf_counter_ns()
            steps[k % len(ctrls)]()
            t1 = time.perf_counter_ns()
            if args.lean:  # the readable step of the same configuration, interleaved
                ctrls[k % len(ctrls)].compute()
                readable.append(time.perf_counter_ns() - t1)
            times.append(t1 - t0)
        med = sorted(times)[len(times) // 2] / 1e3
        pr = cProfile.Profile()
        pr.enable()
        for k in range(args.steps):
            steps[k % len(ctrls)]()
        pr.disable()
    st = pstats.Stats(pr)
    rows = []
    for (file, line, fn), (_cc, nc, tt, ct, _) in st.stats.items():
        short = file.split("site-packages/")[-1] if "site-packages/" in file else Path(file).name
        rows.append((tt, ct, nc, f"{short}:{line}:{fn}"))
    n = args.steps
    what = "lean step (LeanStep.compute)" if args.lean else "full step (Controller.compute)"
    out = [f"# hqp-tpm {what} on {prob.name}, solver {args.solver}",
           f"median step without profiler: {med:.1f} µs over {n} steps; {sum(counts.values())} calls in one step "
           f"({sum(v for k, v in counts.items() if k.endswith('[C]'))} of them builtin C functions)"]
    if readable:
        ratios = sorted(r / s for r, s in zip(readable, times, strict=True))
        out.append(f"readable step interleaved: median {sorted(readable)[n // 2] / 1e3:.1f} µs; readable / lean "
                   f"per step: median {ratios[n // 2]:.2f}")
    out += ["",
            "## Phases (median µs, tight loops at one configuration)", ""]
    out += [f"{t:8.1f}  {name}" if t == t else f"          {name}" for name, t in phases]
    out += ["", "## Calls per function in one step", ""]
    out += [f"{v:4d}  {k}" for k, v in counts.most_common()]
    out += ["", f"## cProfile over {n} steps: per step (self µs, cumulative µs, calls), by self time", ""]
    for tt, ct, nc, name in sorted(rows, reverse=True)[:45]:
        out.append(f"{1e6 * tt / n:8.2f} {1e6 * ct / n:8.2f} {nc / n:6.2f}  {name}")
    out += ["", "## Call tree of one step", ""] + lines
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"profile_{prob.name}_{args.solver}{'_lean' if args.lean else ''}.txt"
    path.write_text("\n".join(out) + "\n")
    print("\n".join(out[:60]))
    print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
