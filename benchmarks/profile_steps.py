"""Profiles of the control loop: ``lwr_relaxed`` and ``romeo_sns_tpm`` step loops under pyinstrument.

For each scenario a fresh controller runs ``--warmup`` steps, then ``--steps`` steps (Romeo: the rest
of its 5 s run) under pyinstrument (sampling every 100 µs); a second fresh controller runs the same
steps under cProfile (exact call counts, deterministic, with its own overhead). Written to
``benchmarks/results/profile_<scenario>.txt``: the pyinstrument call tree, pyinstrument's functions by
self time, and cProfile's top functions by internal and by cumulative time (all wall time: on a
busy machine read the shares).

    python benchmarks/profile_steps.py [--steps 3000] [--quick]

``--sections SCENARIO`` instead times the parts of ``ctrl.step()`` (thread CPU, each part's functions wrapped by a
timer: :data:`SECTIONS`) over ``--steps`` steps of a fresh controller and prints, per part, its median per step and
its median over the slowest 2 % of the steps (those above the 98th percentile: what the p99 step is made of). The
timers add two ``time.thread_time_ns`` calls per wrapped call (~1 µs): compare parts, and runs of one checkout.

    python benchmarks/profile_steps.py --sections romeo_obstacles_sns_tpm --steps 5000
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import time
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make ``benchmarks`` importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import common  # noqa: E402

SCENARIOS = ("lwr_relaxed", "romeo_sns_tpm")


#: The parts of a step ``--sections`` times: (module, attribute path, label); an indented label is part of the one
#: above it; ``policy.*`` is the scenario's policy class. Missing attributes are left out (and said).
SECTIONS = (
    ("hqp_tpm.robot.state", "State.update", "state update"),
    ("hqp_tpm.geometry.distances", "DistanceField.update", "distance field update"),
    ("hqp_tpm.geometry.distances", "DistanceField._query", "  coal queries"),
    ("policy", "plan", "policy plan"),
    ("hqp_tpm.geometry.distances", "DistanceField.normal_jacobian", "  obstacle rows n^T J_c"),
    ("hqp_tpm.control._planned_step", "PlannedStep._rows", "task rows"),
    ("hqp_tpm.control._planned_step", "PlannedStep._sns", "SNS-TPM solve (box, shift, kernel)"),
    ("hqp_tpm.solvers._compiled_sns", "sns_tpm_loop", "  SNS-TPM kernel"),
    ("hqp_tpm.robot.state", "State.integrate", "integration"),
    ("policy", "snapshot", "policy snapshot"),
)


def step_sections(name: str, steps: int) -> str:
    """``--sections``: the table of the parts of ``ctrl.step()`` of scenario ``name`` (module doc)."""
    import functools
    import importlib

    import numpy as np

    from hqp_tpm.app.build import build_run
    from hqp_tpm.app.scenario import load

    clock, spent = time.thread_time_ns, {}
    ctx = build_run(load(name))
    ctrl, policy = ctx.controller, ctx.policy
    labels, missing = [], []
    for module, path, label in SECTIONS:
        owner = type(policy) if module == "policy" else importlib.import_module(module)
        *outer, attr = path.split(".")
        for part in outer:
            owner = getattr(owner, part, None)
        fn = getattr(owner, attr, None) if owner is not None else None
        if fn is None:
            missing.append(f"{module}.{path}")
            continue

        def timed(*args, _fn=fn, _label=label, **kwargs):
            t0 = clock()
            try:
                return _fn(*args, **kwargs)
            finally:
                spent[_label] = spent.get(_label, 0) + clock() - t0

        setattr(owner, attr, functools.wraps(fn)(timed))
        labels.append(label)
    ctrl.step()  # (plans the compiled step)
    total, rows = np.empty(steps), []
    for i in range(steps):
        spent.clear()
        t0 = clock()
        ctrl.step()
        total[i] = clock() - t0
        rows.append(dict(spent))
    total /= 1e3
    slow = total >= np.percentile(total, 98)
    out = [f"{name}: {steps} steps, thread CPU per step (µs): median {np.median(total):.1f}, p99 "
           f"{np.percentile(total, 99):.1f}, whole run {total.sum() / 1e6:.3f} s; slowest 2 %: {int(slow.sum())} steps",
           f"{'part':40s} {'median':>8s} {'slowest 2 %':>12s}"]
    outer_sum = np.zeros(steps)
    for label in labels:
        v = np.array([r.get(label, 0) for r in rows]) / 1e3
        if not label.startswith(" "):
            outer_sum += v
        out.append(f"{label:40s} {np.median(v):8.1f} {np.median(v[slow]):12.1f}")
    rest = total - outer_sum
    out.append(f"{'rest of the step':40s} {np.median(rest):8.1f} {np.median(rest[slow]):12.1f}")
    out.append(f"{'whole step':40s} {np.median(total):8.1f} {np.median(total[slow]):12.1f}")
    if missing:
        out.append("not found (left out): " + ", ".join(missing))
    return "\n".join(out)


def _build(name: str):
    from hqp_tpm.app import build, scenario

    return build.build(scenario.load(name))[1]


def profile_scenario(name: str, steps: int | None, warmup: int, interval: float) -> dict:
    """``steps`` after ``warmup`` under pyinstrument, then the same steps of a fresh controller under cProfile."""
    from pyinstrument import Profiler

    from hqp_tpm.app import scenario

    steps = steps or scenario.load(name).steps - warmup
    ctrl = _build(name)
    for _ in range(warmup):
        ctrl.step()
    prof = Profiler(interval=interval, async_mode="disabled")
    t0 = time.perf_counter()
    prof.start()
    for _ in range(steps):
        ctrl.step()
    prof.stop()
    wall_pyi = time.perf_counter() - t0
    tree = prof.output_text(unicode=False, color=False, show_all=False)
    session = prof.last_session
    flat = _flat(session.root_frame(), steps)
    ctrl = _build(name)                     # cProfile: a fresh controller over the same steps
    for _ in range(warmup):
        ctrl.step()
    cp = cProfile.Profile()
    t0 = time.perf_counter()
    cp.enable()
    for _ in range(steps):
        ctrl.step()
    cp.disable()
    wall_cp = time.perf_counter() - t0
    st = pstats.Stats(cp)
    top_all = _top(st, steps, 10_000)
    top = top_all[:25]
    buf = io.StringIO()
    pstats.Stats(cp, stream=buf).sort_stats("cumulative").print_stats(40)
    cumulative = buf.getvalue()
    return {"scenario": name, "solver": ctrl.solver, "steps": steps, "warmup": warmup, "tree": tree, "flat": flat,
            "cpu_pyinstrument_s": session.cpu_time, "top": top, "top_all": top_all, "cumulative": cumulative,
            "wall_pyinstrument_s": wall_pyi, "wall_cprofile_s": wall_cp}


def _flat(root, steps: int) -> list[dict]:
    """pyinstrument's samples per function: self and inclusive time (outermost call only) per step."""
    total = root.time or 1.0
    acc: dict[tuple, list[float]] = {}

    def walk(frame, open_keys):
        if frame.is_synthetic:  # "[self]" leaves: already in their parent's total_self_time
            return
        key = (frame.function, frame.file_path_short, frame.line_no)
        entry = acc.setdefault(key, [0.0, 0.0])
        entry[0] += frame.total_self_time
        if key not in open_keys:
            entry[1] += frame.time
        for child in frame.children:
            walk(child, open_keys | {key})

    walk(root, frozenset())
    rows = [{"function": f"{fn} ({path}:{line})" if line else f"{fn} ({path})", "self_us_per_step": 1e6 * t / steps,
             "cum_us_per_step": 1e6 * c / steps, "self_share": t / total, "cum_share": c / total}
            for (fn, path, line), (t, c) in acc.items()]
    rows.sort(key=lambda r: -r["self_us_per_step"])
    return rows


def _top(st: pstats.Stats, steps: int, k: int) -> list[dict]:
    """Functions by internal (self) time: calls per step, µs per step of self and cumulative time."""
    total = sum(v[2] for v in st.stats.values())
    rows = []
    for (file, line, fn), (_cc, nc, tt, ct, _callers) in st.stats.items():
        short = file.split("site-packages/")[-1].split(f"{Path(__file__).resolve().parents[1]}/")[-1]
        where = fn if file == "~" else f"{fn} ({short}:{line})"
        rows.append({"function": where, "calls_per_step": nc / steps, "self_us_per_step": 1e6 * tt / steps,
                     "cum_us_per_step": 1e6 * ct / steps, "self_share": tt / total if total else 0.0})
    rows.sort(key=lambda r: -r["self_us_per_step"])
    return rows[:k]


def top_markdown(res: dict, k: int = 15) -> str:
    """pyinstrument's functions by self time, with cProfile's call counts where the function matches."""
    calls = {r["function"]: r["calls_per_step"] for r in res["top_all"]}
    return common.md_table(
        ["function (by self time, pyinstrument)", "self % of step", "inclusive % of step", "self µs / step",
         "calls / step (cProfile)"],
        [[r["function"].replace("|", "\\|"), f"{100 * r['self_share']:.1f}", f"{100 * r['cum_share']:.1f}",
          common.fmt(r["self_us_per_step"]), f"{calls[r['function']]:.1f}" if r["function"] in calls else "–"]
         for r in res["flat"][:k]])


def write(res: dict, out: Path, env: dict) -> Path:
    path = out / f"profile_{res['scenario']}.txt"
    head = "\n".join(f"# {k}: {v}" for k, v in env.items())
    text = [head, "",
            f"Scenario {res['scenario']} (solver {res['solver']}): {res['steps']} steps after {res['warmup']} warm-up "
            f"steps.", f"Wall time under pyinstrument {res['wall_pyinstrument_s']:.2f} s, under cProfile "
            f"{res['wall_cprofile_s']:.2f} s (profiler overhead included).",
            "Both profilers measure wall time: on a busy machine the slices other processes take are charged to "
            "whatever frame was running, roughly in proportion to its time, so read the shares rather than the "
            "absolute numbers; cProfile's per-call overhead also inflates functions with many small calls.", "",
            "=" * 100, "pyinstrument call tree", "=" * 100, res["tree"],
            "=" * 100, "pyinstrument, functions by self time (per control step; inclusive = outermost calls)",
            "=" * 100, f"{'self us/step':>13} {'self %':>7} {'incl. %':>8}  function"]
    text += [f"{r['self_us_per_step']:13.1f} {100 * r['self_share']:7.1f} {100 * r['cum_share']:8.1f}  {r['function']}"
             for r in res["flat"][:40]]
    text += ["",
            "=" * 100, "cProfile, top functions by self time (per control step)", "=" * 100,
            f"{'self us/step':>13} {'cum us/step':>12} {'calls/step':>11}  function"]
    text += [f"{r['self_us_per_step']:13.1f} {r['cum_us_per_step']:12.1f} {r['calls_per_step']:11.1f}  {r['function']}"
             for r in res["top"]]
    text += ["", "=" * 100, "cProfile, by cumulative time", "=" * 100, res["cumulative"]]
    root = str(Path(__file__).resolve().parents[1]) + "/"  # paths relative to the checkout (no machine paths)
    path.write_text("\n".join(text).replace(root, ""))
    return path


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=3000, help="profiled steps of lwr_relaxed")
    p.add_argument("--romeo-steps", type=int, default=None,
                   help="profiled steps of romeo_sns_tpm (default: the rest of its 5 s run)")
    p.add_argument("--warmup", type=int, default=200)
    p.add_argument("--interval", type=float, default=1e-4, help="pyinstrument sampling interval [s]")
    p.add_argument("--out", type=Path, default=common.RESULTS)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--sections", metavar="SCENARIO", default=None,
                   help="time the parts of ctrl.step() of SCENARIO over --steps steps instead (module doc)")
    args = p.parse_args(argv)
    if args.quick:
        args.steps, args.romeo_steps, args.warmup = 100, 100, 10
    return args


def main(argv=None) -> dict:
    args = parse(argv)
    if args.sections:
        with common.one_blas_thread():
            print(step_sections(args.sections, args.steps))
        return {}
    args.out.mkdir(parents=True, exist_ok=True)
    results = []
    with common.one_blas_thread():
        env = common.environment()
        for name in SCENARIOS:
            common.progress(f"  profile: {name}")
            n = args.steps if name == "lwr_relaxed" else args.romeo_steps
            results.append(profile_scenario(name, n, args.warmup, args.interval))
        common.close_environment(env)
    sections = []
    for res in results:
        path = write(res, args.out, env)
        share = 100 * res["cpu_pyinstrument_s"] / res["wall_pyinstrument_s"]
        sections.append((f"Profile of {res['scenario']} ({res['solver']}, {res['steps']} steps after "
                         f"{res['warmup']})", top_markdown(res) + f"\n\nWall time under pyinstrument "
                         f"{res['wall_pyinstrument_s']:.2f} s ({1e6 * res['wall_pyinstrument_s'] / res['steps']:.0f} "
                         f"µs/step), CPU share {share:.0f} %. Call tree and cProfile tables: `{path.name}`."))
        common.progress(f"wrote {path}")
    return {"env": env, "sections": sections, "results": results}


if __name__ == "__main__":
    main()
