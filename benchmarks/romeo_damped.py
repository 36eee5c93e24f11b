"""Damped Romeo, solve alone: sns_tpm and tpm on the 200 peers configurations with the library's damping.

    OMP_NUM_THREADS=1 python benchmarks/romeo_damped.py [--configs 200] [--repeats 3] [--warm] [--ab COMMIT]
    OMP_NUM_THREADS=1 NUMBA_CACHE_DIR=$(mktemp -d) python benchmarks/romeo_damped.py --perf 20
    OMP_NUM_THREADS=1 python benchmarks/romeo_damped.py --passes 20

The stacks are those of :mod:`benchmarks.peers.problems`' ``romeo_vel`` (6 levels, m > n) with kp = 100 and
``lambda_max = 0.05, eps = 0.1`` (captured from ``Controller.compute(record=True)``, the readable step). Prints,
per solver, the median and p99 of the solve alone (thread CPU time, ``sns_tpm_stacked`` / ``tpm_stacked`` on the
captured arrays, one BLAS thread), the SNS passes (median, max), how many ``sns_tpm`` solves left the compiled
loop and how many ``tpm`` solves its kernel answered by the recursion. ``--warm``: the warm-start experiment
(closed loops; :func:`warm_start`). ``--ab COMMIT``: the SNS-TPM kernel of this tree against that commit's, one
process (:func:`kernels_at` loads the commit's kernel modules under another name), interleaved per configuration
and call, thread CPU time of ``_compiled_sns.sns_tpm_loop`` (the kernel and its small wrapper), per-configuration
ratios; also the largest difference of the two commands and whether the decisions agree. ``--perf SECONDS``:
where the SNS-TPM kernel's time goes, by compiled function (:func:`perf_profile`: Linux ``perf`` sampling this
process while it runs the kernel on the stacks; the kernels must be compiled in this process, hence the empty
``NUMBA_CACHE_DIR``). ``--passes K``: what a pass costs (:func:`pass_costs`), written with the solve-alone figures
and the warm-start experiment to ``benchmarks/results/romeo_damped.md``.
"""

from __future__ import annotations

import argparse
import collections
import importlib
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import common  # noqa: E402
from benchmarks.peers import problems as P  # noqa: E402

LAMBDA_MAX, EPS, KP = 0.05, 0.1, 100.0


def controller(robot, prob, cfg):
    from hqp_tpm import Controller, Stack

    stack = Stack.of(*P.hqp_tasks(robot, prob, cfg))
    return Controller(robot, stack, order=1, dt=P.DT, solver="sns_tpm", box=P.joint_limits_box(robot, 1), q0=cfg.q,
                      v0=cfg.v, lambda_max=LAMBDA_MAX, eps=EPS)


def stacks(n_configs: int):
    """``(J, b, sizes, lo, up)`` of each configuration (the arrays the controller's solve sees)."""
    S = importlib.import_module("hqp_tpm.solvers.sns")  # (the package exports the function ``sns``)

    robot = P.load_robot(P.ROMEO)
    prob = P.romeo_problem(robot, n_configs)
    out = []
    real = S.sns_tpm
    gains = P.KP_ROMEO, P.KP_ROMEO_POSTURE
    P.KP_ROMEO, P.KP_ROMEO_POSTURE = KP, KP           # (the problem module's gains, restored below)

    def capture(levels, lo, up, **kw):
        lv, J, b, sizes = S._stacked(levels, lo.shape[0])
        out.append((J.copy(), b.copy(), tuple(sizes), np.array(lo, float), np.array(up, float)))
        return real(levels, lo, up, **kw)

    S.sns_tpm = capture
    try:
        for cfg in prob.configs:
            controller(robot, prob, cfg).compute(record=True)  # (the readable step: its sns_tpm call)
    finally:
        S.sns_tpm = real
        P.KP_ROMEO, P.KP_ROMEO_POSTURE = gains
    return robot, prob, out


def kernel_outcomes(cases):
    """``(sns_left, tpm_recursion)``: the ``sns_tpm`` solves the compiled loop handed back (left compiled code), the
    ``tpm`` solves its one kernel answered by the recursion rather than the factorization (both compiled)."""
    from hqp_tpm.solvers import _compiled, _compiled_sns

    sns_left = tpm_rec = 0
    for J, b, sizes, lo, up in cases:
        out = _compiled_sns.sns_tpm_loop(J, b, sizes, lo, up, LAMBDA_MAX, EPS, _compiled.MARGIN, _compiled.COND)
        sns_left += type(out) is not tuple or out[0] != _compiled_sns.DONE
        x = np.empty(J.shape[1])
        tpm_rec += _compiled._tpm(J, b, np.array(sizes), J.shape[1], LAMBDA_MAX, EPS, _compiled._UNIT,
                                  _compiled.MARGIN, _compiled.COND, np.empty(0), False, x) == _compiled.RECURSION
    return sns_left, tpm_rec


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", type=int, default=P.N_CONFIGS)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--warm", action="store_true")
    ap.add_argument("--ab", metavar="COMMIT", help="time this tree's SNS-TPM kernel against COMMIT's (one process)")
    ap.add_argument("--perf", metavar="SECONDS", type=float, help="profile the SNS-TPM kernel by compiled function")
    ap.add_argument("--passes", metavar="K", type=int, help="the cost of a pass on K configurations; write the results")
    args = ap.parse_args(argv)
    if args.ab:
        with common.one_blas_thread():
            return ab(args.ab, args.configs, args.repeats)
    if args.perf:
        with common.one_blas_thread():
            return perf_profile(args.configs, args.perf)
    from hqp_tpm.solvers.sns import sns_tpm_stacked
    from hqp_tpm.solvers.tpm import tpm_stacked

    with common.one_blas_thread():
        robot, prob, cases = stacks(args.configs)
        for J, b, sizes, lo, up in cases:  # compile / warm up
            sns_tpm_stacked(J, b, sizes, lo, up, lambda_max=LAMBDA_MAX, eps=EPS)
            tpm_stacked(J, b, sizes, J.shape[1], LAMBDA_MAX, EPS)
        times = collections.defaultdict(list)
        passes = []
        for J, b, sizes, lo, up in cases:
            for _ in range(args.repeats):
                t0 = time.thread_time_ns()
                _, info = sns_tpm_stacked(J, b, sizes, lo, up, lambda_max=LAMBDA_MAX, eps=EPS, return_info=True)
                times["sns_tpm"].append(time.thread_time_ns() - t0)
                t0 = time.thread_time_ns()
                tpm_stacked(J, b, sizes, J.shape[1], LAMBDA_MAX, EPS)
                times["tpm"].append(time.thread_time_ns() - t0)
            passes.append(info.iterations)
        print(f"damped Romeo (lambda_max {LAMBDA_MAX}, eps {EPS}, kp {KP}), {len(cases)} configurations x "
              f"{args.repeats} solves, m x n = {cases[0][0].shape}, thread CPU time, one BLAS thread")
        for name, v in times.items():
            v = np.array(v) / 1e3
            print(f"  {name:8s} solve alone: median {np.median(v):8.1f} us  p99 {np.percentile(v, 99):8.1f} us  "
                  f"p99/median {np.percentile(v, 99) / np.median(v):5.2f}")
        print(f"  sns_tpm passes: median {np.median(passes):.0f}, max {max(passes)}")
        if args.passes:
            env = common.environment()
            table = pass_costs(cases[:args.passes])
            warm = warm_start(robot, prob)
            common.close_environment(env)
            solve = common.md_table(["solve alone (thread CPU)", "median µs", "p99 µs"], [
                [name, common.fmt(np.median(np.array(v) / 1e3)), common.fmt(np.percentile(np.array(v) / 1e3, 99))]
                for name, v in times.items()])
            common.write_markdown(common.ROOT / "benchmarks" / "results" / "romeo_damped.md",
                                  "Damped Romeo: the SNS-TPM solve and its passes", env, [
                                      ("The solve alone", f"{len(cases)} configurations x {args.repeats} solves, "
                                       f"lambda_max {LAMBDA_MAX}, eps {EPS}, kp {KP}; SNS-TPM passes: median "
                                       f"{np.median(passes):.0f}, max {max(passes)}.\n\n{solve}"),
                                      ("What a pass costs", table), ("A warm start", warm)])
            print("wrote benchmarks/results/romeo_damped.md")
        try:
            sns_left, tpm_rec = kernel_outcomes(cases)
            print(f"  sns_tpm solves that left the compiled loop: {sns_left} of {len(cases)}; tpm solves answered "
                  f"by the recursion inside its kernel: {tpm_rec} of {len(cases)}")
        except AttributeError as e:  # (an older tree without the kernel's path report)
            print(f"  (kernel outcomes not reported by this tree: {e})")
        if args.warm and not args.passes:
            warm_start(robot, prob)
    return 0


FACTORS = (math.inf, 8.0, 4.0, 3.0, 2.0, 1.5, 1.2, 1.0)


def pass_costs(cases, repeats: int = 21) -> str:
    """The SNS-TPM kernel (``_compiled_sns.sns_tpm_loop``) on each stack with its box widened by each of
    :data:`FACTORS` (fewer joints saturate in a wider box: one pass, then more): per factor, the medians over the
    stacks of the passes and of the solve's thread CPU (median of ``repeats`` calls), and the added µs per added
    pass from the row above. A markdown table."""
    from hqp_tpm.solvers import _compiled_sns

    res = np.empty((len(FACTORS), len(cases), 2))
    for c, (J, b, sizes, lo, up) in enumerate(cases):
        for f, factor in enumerate(FACTORS):
            lo_f, up_f = (np.full_like(lo, -np.inf), np.full_like(up, np.inf)) if math.isinf(factor) else (
                lo * factor, up * factor)
            out = _compiled_sns.sns_tpm_loop(J, b, sizes, lo_f, up_f, LAMBDA_MAX, EPS)
            ts = []
            for _ in range(repeats):
                t0 = time.thread_time_ns()
                out = _compiled_sns.sns_tpm_loop(J, b, sizes, lo_f, up_f, LAMBDA_MAX, EPS)
                ts.append(time.thread_time_ns() - t0)
            res[f, c] = out[4], np.median(ts) / 1e3
    rows, prev = [], None
    for f, factor in enumerate(FACTORS):
        p, us = np.median(res[f, :, 0]), np.median(res[f, :, 1])
        step = "–" if prev is None or p == prev[0] else common.fmt((us - prev[1]) / (p - prev[0]))
        rows.append(["none (no bound)" if math.isinf(factor) else f"{factor:g} x", f"{p:g}", common.fmt(us), step])
        prev = p, us
    return (f"{len(cases)} configurations; the URDF velocity box widened by a factor (the last row is the library's "
            "box); medians over the configurations.\n\n" + common.md_table(
                ["box", "passes", "solve µs", "µs per added pass"], rows))


def kernels_at(commit: str):
    """``_compiled_sns`` of ``commit`` (with that commit's ``_compiled``), loaded as the package ``ab_<commit>`` from
    ``git show`` into a directory of the temporary directory (kept, so numba's cache finds the same files again)."""
    root = common.ROOT
    sha = subprocess.run(["git", "rev-parse", "--short", commit], cwd=root, capture_output=True, text=True,
                         check=True).stdout.strip()
    pkg = f"ab_{sha}"
    where = Path(tempfile.gettempdir()) / "hqp_tpm_ab" / pkg
    where.mkdir(parents=True, exist_ok=True)
    (where / "__init__.py").write_text("")
    for name in ("_compiled", "_compiled_sns"):
        src = subprocess.run(["git", "show", f"{sha}:hqp_tpm/solvers/{name}.py"], cwd=root, capture_output=True,
                             text=True, check=True).stdout
        src = src.replace("from hqp_tpm.solvers import _compiled\n", f"from {pkg} import _compiled\n")
        path = where / f"{name}.py"
        if not path.exists() or path.read_text() != src:
            path.write_text(src)
    if str(where.parent) not in sys.path:
        sys.path.insert(0, str(where.parent))
    return importlib.import_module(f"{pkg}._compiled_sns"), sha


def ab(commit: str, n_configs: int, repeats: int) -> int:
    """This tree's ``sns_tpm_loop`` against ``commit``'s on the damped Romeo stacks (module doc)."""
    from hqp_tpm.solvers import _compiled_sns as new

    old, sha = kernels_at(commit)
    _, _, cases = stacks(n_configs)
    for J, b, sizes, lo, up in cases:  # compile / warm up; the two commands and decisions
        new.sns_tpm_loop(J, b, sizes, lo, up, LAMBDA_MAX, EPS)
        old.sns_tpm_loop(J, b, sizes, lo, up, LAMBDA_MAX, EPS)
    t_new, t_old, ratios, diff, same = [], [], [], 0.0, 0
    for k, (J, b, sizes, lo, up) in enumerate(cases):
        tn, to = [], []
        for r in range(repeats):
            for which in ((new, old) if (k + r) % 2 == 0 else (old, new)):
                t0 = time.thread_time_ns()
                out = which.sns_tpm_loop(J, b, sizes, lo, up, LAMBDA_MAX, EPS)
                (tn if which is new else to).append(time.thread_time_ns() - t0)
                if which is new:
                    o_new = out
                else:
                    o_old = out
        t_new += tn
        t_old += to
        ratios.append(np.median(tn) / np.median(to))
        diff = max(diff, float(np.max(np.abs(o_new[1] - o_old[1]))) / max(1.0, float(np.max(np.abs(o_old[1])))))
        same += o_new[0] == o_old[0] and o_new[2] == o_old[2] and o_new[4] == o_old[4] and o_new[5] == o_old[5]
    t_new, t_old = np.array(t_new) / 1e3, np.array(t_old) / 1e3
    print(f"damped Romeo SNS-TPM kernel, this tree vs {sha}: {len(cases)} configurations x {repeats} calls each, "
          f"interleaved, thread CPU time, one BLAS thread")
    for name, v in (("this tree", t_new), (sha, t_old)):
        print(f"  {name:10s} median {np.median(v):7.1f} us  p99 {np.percentile(v, 99):7.1f} us")
    print(f"  ratio this/{sha}: median {np.median(t_new) / np.median(t_old):.3f}, p99 "
          f"{np.percentile(t_new, 99) / np.percentile(t_old, 99):.3f}, median of per-configuration ratios "
          f"{np.median(ratios):.3f}")
    print(f"  same decisions (status, saturated joints, passes, feasibility): {same} of {len(cases)}; largest "
          f"command difference (relative to max(1, |x|)): {diff:.2e}")
    return 0


def _perf_map(modules) -> int:
    """Write ``perf-<pid>.map`` (perf's map of JIT code) for the compiled functions of ``modules``'
    dispatchers, as LLVM named them (kernels numba inlined are counted in their callers); each function's size up
    to the next one's address. Returns the number of functions (0 when the kernels came from numba's cache: their
    libraries keep no LLVM module to name the functions)."""
    import os

    found = set()
    for mod in modules:
        for disp in vars(mod).values():
            for cres in getattr(disp, "overloads", {}).values():
                lib = cres.library
                module = getattr(lib, "_final_module", None)
                if module is None:
                    continue
                for fn in module.functions:
                    if not fn.is_declaration:
                        addr = lib.get_pointer_to_function(fn.name)
                        if addr:
                            found.add((addr, fn.name))
    rows = sorted(found)
    with open(Path("/tmp") / f"perf-{os.getpid()}.map", "w") as fh:  # where perf looks
        for i, (addr, name) in enumerate(rows):
            size = min(rows[i + 1][0] - addr, 1 << 20) if i + 1 < len(rows) else 1 << 16
            short = name.split("solvers", 1)[-1].lstrip("0123456789")
            fh.write(f"{addr:x} {size:x} {short}\n")
    return len(rows)


def perf_profile(n_configs: int, seconds: float) -> int:
    """Sample this process with Linux ``perf`` while ``_compiled_sns.sns_tpm_loop`` runs on the damped Romeo stacks
    for ``seconds`` (after compiling and warming up, the garbage collector off) and print each compiled function's
    share of the samples (the kernels' share of allocation, reference counting and the Python wrapper listed
    beside them)."""
    import gc
    import os
    import shutil

    from hqp_tpm.solvers import _compiled, _compiled_sns

    if shutil.which("perf") is None:
        print("perf is not installed")
        return 1
    _, _, cases = stacks(n_configs)
    for J, b, sizes, lo, up in cases:
        _compiled_sns.sns_tpm_loop(J, b, sizes, lo, up, LAMBDA_MAX, EPS)
    if not _compiled_sns._READY:
        print("the kernels are not compiled (HQP_TPM_COMPILED=0 or no numba): nothing to profile")
        return 1
    if not _perf_map((_compiled, _compiled_sns)):
        print("the kernels came from numba's cache: run with an empty NUMBA_CACHE_DIR (module doc)")
        return 1
    out = Path(tempfile.mkdtemp()) / "perf.data"
    gc.collect()
    gc.disable()
    rec = subprocess.Popen(["perf", "record", "-q", "-F", "4000", "-p", str(os.getpid()), "-o", str(out)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)                                   # (perf attached)
    calls = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for J, b, sizes, lo, up in cases:
            _compiled_sns.sns_tpm_loop(J, b, sizes, lo, up, LAMBDA_MAX, EPS)
        calls += len(cases)
    rec.send_signal(2)
    rec.wait()
    gc.enable()
    rep = subprocess.run(["perf", "report", "-i", str(out), "--no-children", "--sort", "dso,symbol", "--stdio",
                          "-q"], capture_output=True, text=True).stdout
    shares = collections.Counter()
    for line in rep.splitlines():
        parts = line.split()
        if len(parts) < 4 or not parts[0].endswith("%"):
            continue
        sym = line.split("[.]", 1)[-1].strip() if "[.]" in line else parts[-1]
        name = sym.split()[0]
        for tag in ("_compiled_sns", "_compiled"):   # (numba's mangled names: ..._compiled_sns9_sns_loopB2v1..)
            if tag in name:
                name = name.split(tag, 1)[1].lstrip("0123456789").split("B", 1)[0]
                if "_" not in name[1:] and not name.startswith("_"):
                    name = "_" + name
                break
        else:
            if any(k in name for k in ("malloc", "free", "memset", "memmove", "unlink_chunk", "consolidate")):
                name = "(libc malloc/free/memset)"
            elif name.startswith("NRT_"):
                name = f"({name})"
            elif "python" in line or name.startswith("_Py") or name.startswith("Py"):
                name = "(Python: the wrapper, the loop)"
        shares[name] += float(parts[0][:-1])
    total = sum(shares.values())
    print(f"damped Romeo SNS-TPM kernel, perf samples by function: {calls} calls in {seconds:.0f} s "
          f"({1e6 * seconds / max(calls, 1):.1f} us a call, wall), one BLAS thread")
    for name, v in shares.most_common(25):
        print(f"  {name:40s} {100.0 * v / total:5.1f} %")
    return 0


def warm_start(robot, prob, runs: int = 10, steps: int = 20):
    """Closed loops (``runs`` configurations, ``steps`` control steps each): passes per solve, cold vs warm-started
    from the previous step's saturated joints (``_compiled_sns.sns_tpm_loop(..., warm=...)``: at the first
    saturation the previous joints that are beyond a bound are saturated at once, then the full algorithm goes on
    and decides), and how often the warm start changes the command; printed and returned as markdown."""
    from hqp_tpm.solvers import _compiled_sns

    S = importlib.import_module("hqp_tpm.solvers.sns")
    real = S.sns_tpm
    seen = []

    def capture(levels, lo, up, **kw):
        lv, J, b, sizes = S._stacked(levels, lo.shape[0])
        seen.append((J.copy(), b.copy(), tuple(sizes), np.array(lo, float), np.array(up, float)))
        return real(levels, lo, up, **kw)

    cold_p, warm_p, same, diffs, t_cold, t_warm = [], [], 0, [], [], []
    S.sns_tpm = capture
    gains = P.KP_ROMEO, P.KP_ROMEO_POSTURE
    P.KP_ROMEO, P.KP_ROMEO_POSTURE = KP, KP
    try:
        for cfg in prob.configs[:runs]:
            ctrl = controller(robot, prob, cfg)
            prev = ()
            for _ in range(steps):
                seen.clear()
                ctrl.compute(record=True)             # (the readable step: its sns_tpm call is captured)
                J, b, sizes, lo, up = seen[0]
                ctrl.step()
                t0 = time.thread_time_ns()
                cold = _compiled_sns.sns_tpm_loop(J, b, sizes, lo, up, LAMBDA_MAX, EPS)
                t1 = time.thread_time_ns()
                warm = _compiled_sns.sns_tpm_loop(J, b, sizes, lo, up, LAMBDA_MAX, EPS, warm=prev)
                t_cold.append(t1 - t0)
                t_warm.append(time.thread_time_ns() - t1)
                cold_p.append(cold[4])
                warm_p.append(warm[4])
                d = float(np.max(np.abs(cold[1] - warm[1])))
                diffs.append(d)
                same += d <= 1e-9 * max(1.0, float(np.max(np.abs(cold[1]))))
                prev = cold[2]
    finally:
        S.sns_tpm = real
        P.KP_ROMEO, P.KP_ROMEO_POSTURE = gains
    cold_p, warm_p = np.array(cold_p), np.array(warm_p)
    print(f"  warm start, {len(cold_p)} closed-loop steps ({runs} runs x {steps}): passes cold median "
          f"{np.median(cold_p):.0f} mean {cold_p.mean():.2f}, warm median {np.median(warm_p):.0f} mean "
          f"{warm_p.mean():.2f}; solve median cold {np.median(t_cold) / 1e3:.1f} us, warm "
          f"{np.median(t_warm) / 1e3:.1f} us; same command (1e-9) {same} of {len(cold_p)}, largest difference "
          f"{max(diffs):.2e}")
    return (f"{len(cold_p)} closed-loop steps ({runs} configurations x {steps} steps of the library's controller); "
            "each step's stack solved cold (Algorithm 1 from W = I) and warm (the previous step's saturated joints "
            "that are beyond a bound saturated at once at the first saturation, then Algorithm 1 goes on).\n\n"
            + common.md_table(["start", "passes median", "passes mean", "solve median µs"], [
                ["cold", f"{np.median(cold_p):.0f}", f"{cold_p.mean():.2f}", common.fmt(np.median(t_cold) / 1e3)],
                ["warm", f"{np.median(warm_p):.0f}", f"{warm_p.mean():.2f}", common.fmt(np.median(t_warm) / 1e3)]])
            + f"\n\nThe warm start gives the cold command (to 1e-9) in {same} of {len(cold_p)} steps; the largest "
            f"difference is {max(diffs):.3g} rad/s (the saturated set depends on the order of the saturations).")


if __name__ == "__main__":
    sys.exit(main())
