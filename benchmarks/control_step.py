"""Control-loop timing: full steps of two scenarios, a whole run, and SNS-TPM solves alone.

1. One full control step (state update, coal distances, policy, solve, integration) of
   ``lwr_relaxed`` (acceleration-level TPM, Algorithm 1) and ``romeo_sns_tpm`` (velocity-level
   SNS-TPM under joint boxes), and the same scenarios built with ``solver="qp"`` (cascaded QP, proxqp):
   median and p99 µs per step after ``--warmup`` steps (``lwr_relaxed``: ``--steps`` steps; Romeo: the
   rest of its 5 s run, because the cost depends on how many joints saturate and that changes along
   the motion), and ``romeo_obstacles_sns_tpm`` (whole-body avoidance with coal distances, its own solver),
   and where the time goes (the controller's own calls wrapped with timers: state update,
   pre-policy hooks = distances, policy, task levels, box, solve, integration).
2. The complete ``lwr_relaxed`` run (18,850 steps): wall time of ``ctrl.step(record=True)`` (the readable path) in
   a loop and of ``ctrl.step()`` (its compiled step) in a loop (nothing recorded), and of
   :func:`hqp_tpm.app.runner.run` (recording every step, as ``hqp-tpm run``).
3. A 7-DOF SNS-TPM velocity solve: one 6-D task (LWR IV end-effector pose Jacobian at random
   configurations) with joint velocity boxes small enough that joints saturate; tpm and the cascaded
   QP (proxqp, same box) on the same problems for the ratio.
4. The Romeo SNS-TPM solve alone: ``(levels, box)`` captured from the ``romeo_sns_tpm`` controller every
   ``--capture-every`` steps of the whole 5 s run, solved by ``sns_tpm`` and by ``cascaded_qp(...,
   solver="proxqp")`` with the same box and damping.

    python benchmarks/control_step.py [--steps 2000] [--romeo-steps N] [--warmup 200] [--quick]

Writes ``benchmarks/results/control_step.csv`` and ``control_step.md``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from unittest import mock

import numpy as np

from hqp_tpm.errors import HqpTpmError

if __package__ in (None, ""):  # run as a script: make ``benchmarks`` importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import common  # noqa: E402
from benchmarks.common import Target, fmt  # noqa: E402

SCENARIOS = ("lwr_relaxed", "romeo_sns_tpm")
#: whole-body avoidance with coal distances (issue 14: p99 step below 1 ms), its own solver only
OBSTACLES = "romeo_obstacles_sns_tpm"
PHASES = ("state update", "pre-policy (distances)", "policy", "task levels", "box", "solve", "integration")

# targets of issue 6
LWR_RUN_S = 2.0
LWR_STEP_US = 106.0
ROMEO_MEDIAN_US = 150.0
ROMEO_P99_US = 1000.0
ROMEO_QP_RATIO = 3.0
ARM_SNS_US = 40.0
# target of issue 14
OBSTACLES_P99_US = 1000.0


def build(name: str, solver: str | None = None):
    from hqp_tpm.app import build as hb
    from hqp_tpm.app import scenario

    sc = scenario.load(name)
    robot, ctrl, tasks, policy = hb.build(sc, solver=solver)
    return sc, robot, ctrl, policy


class PhaseTimer:
    """Wraps the calls the controller makes in one step with timers, without changing the step's code."""

    def __init__(self):
        self.acc = dict.fromkeys(PHASES, 0)

    def wrap(self, phase: str, fn):
        acc = self.acc

        def timed(*args, **kwargs):
            t0 = time.perf_counter_ns()
            try:
                return fn(*args, **kwargs)
            finally:
                acc[phase] += time.perf_counter_ns() - t0

        return timed

    def patches(self, ctrl):
        """Context managers that install the timers on ``ctrl`` (and the classes/functions it calls)."""
        import hqp_tpm.control.controller as hc
        from hqp_tpm.control.stack import Stack
        from hqp_tpm.robot.state import State

        pol = type(ctrl.policy)  # the policy's class: special methods are looked up on the type
        out = [mock.patch.object(State, "update", self.wrap("state update", State.update)),
               mock.patch.object(State, "integrate", self.wrap("integration", State.integrate)),
               mock.patch.object(Stack, "to_levels", self.wrap("task levels", Stack.to_levels)),
               mock.patch.object(hc, "solve", self.wrap("solve", hc.solve)),
               mock.patch.object(pol, "__call__", self.wrap("policy", pol.__call__)),
               mock.patch.object(pol, "update", self.wrap("pre-policy (distances)", pol.update))]
        if ctrl.box is not None:
            out.append(mock.patch.object(ctrl, "box", self.wrap("box", ctrl.box)))
        return out


def step_timing(name: str, solver: str | None, steps: int | None, warmup: int) -> dict:
    """Per-step times of ``ctrl.step()`` over ``steps`` steps after ``warmup`` (``None``: to the end of the
    scenario), then the phase breakdown of a second fresh controller over the same steps."""
    sc, robot, ctrl, _ = build(name, solver)
    steps = steps or sc.steps - warmup
    for _ in range(warmup):
        ctrl.step()
    times, cpu, iters = np.empty(steps), np.empty(steps), np.zeros(steps, dtype=int)
    scaled = done = 0
    failed = ""
    for i in range(steps):
        c0 = time.thread_time_ns()
        t0 = time.perf_counter_ns()
        try:
            res = ctrl.step()
        except HqpTpmError as exc:  # a step the solver cannot do: stop here (the controller keeps its state)
            failed = f"step failed at t = {ctrl.t:.3f} s: {exc}"
            break
        times[i] = time.perf_counter_ns() - t0
        cpu[i] = time.thread_time_ns() - c0
        iters[i] = res.info.get("iterations", 0)
        scaled += res.info.get("scale", 1.0) < 1.0
        done += 1
    steps = done
    times, cpu, iters = times[:done], cpu[:done], iters[:done]
    st = common.stats_us(times, cpu)
    sns = bool(iters.any())
    by_iter = {}
    if sns:  # steps in which no joint saturates (one pass of Algorithm 1) against the others
        by_iter = {"free_median_us": float(np.median(times[iters == 1])) / 1e3 if (iters == 1).any() else np.nan,
                   "saturating_median_us": float(np.median(times[iters > 1])) / 1e3 if (iters > 1).any() else np.nan,
                   "saturating_fraction": float((iters > 1).mean())}
    _, _, ctrl, _ = build(name, solver)
    for _ in range(warmup):
        ctrl.step()
    pt = PhaseTimer()
    patches = pt.patches(ctrl)
    per_step = {k: np.empty(steps) for k in (*PHASES, "rest (controller, checks, timers)", "total")}
    for p in patches:
        p.start()
    phase_steps, phase_failed = 0, ""
    try:
        for i in range(steps):
            for k in PHASES:
                pt.acc[k] = 0
            t0 = time.perf_counter_ns()
            try:
                ctrl.step()  # the same steps as above; a QP backend may still fail on one of them this time
            except HqpTpmError as exc:
                phase_failed = f"step failed at t = {ctrl.t:.3f} s: {exc}"
                break
            total = time.perf_counter_ns() - t0
            for k in PHASES:
                per_step[k][i] = pt.acc[k]
            per_step["rest (controller, checks, timers)"][i] = total - sum(pt.acc.values())
            per_step["total"][i] = total
            phase_steps += 1
    finally:
        for p in reversed(patches):
            p.stop()
    phases = {k: (float(np.median(v[:phase_steps])) / 1e3, float(v[:phase_steps].mean()) / 1e3)
              for k, v in per_step.items()}
    return {"scenario": name, "solver": ctrl.solver, "nv": robot.nv, "steps": steps, "warmup": warmup,
            "t_start": warmup * ctrl.dt, "t_end": (warmup + steps) * ctrl.dt, **st, **by_iter,
            "mean_sns_iterations": float(iters.mean()) if sns else "",
            "scaled_fraction": scaled / steps if sns else "", "phases": phases, "phase_steps": phase_steps,
            "failed": failed, "phase_failed": phase_failed}


def whole_run(name: str, steps: int | None) -> dict:
    """Wall time of the complete run: ``ctrl.step(record=True)`` loop (the readable path), ``ctrl.step()`` loop (its
    compiled step, what ``hqp-tpm run`` steps with), then ``runner.run`` (fresh controllers; the kernels compiled or
    loaded by a few steps of another one first)."""
    from hqp_tpm.app import runner

    _, _, warm, _ = build(name)  # compile or load the compiled kernels first (benchmarks/first_call.py times that)
    for _ in range(20):
        warm.step(record=True)
        warm.step()
    sc, _, ctrl, _ = build(name)
    n = steps or sc.steps
    c0, t0 = time.process_time(), time.perf_counter()
    for _ in range(n):
        ctrl.step(record=True)
    loop = time.perf_counter() - t0
    loop_cpu = time.process_time() - c0
    _, _, ctrl, _ = build(name)
    step = ctrl.step
    c0, t0 = time.process_time(), time.perf_counter()
    for _ in range(n):
        step()
    lean = time.perf_counter() - t0
    lean_cpu = time.process_time() - c0
    _, _, ctrl, _ = build(name)
    t0 = time.perf_counter()
    rec, timing = runner.run(ctrl, n)
    recorded = time.perf_counter() - t0
    rec.discard()
    return {"scenario": name, "steps": n, "loop_s": loop, "loop_cpu_s": loop_cpu, "runner_s": recorded,
            "lean_s": lean, "lean_cpu_s": lean_cpu, "lean_us_per_step": 1e6 * lean / n,
            "loop_us_per_step": 1e6 * loop / n, "runner_us_per_step": 1e6 * recorded / n}


def arm_sns(draws: int, seed: int, v_scale: float) -> dict:
    """SNS-TPM on one 6-D LWR IV end-effector task with a small joint velocity box; tpm and QP alongside."""
    from hqp_tpm.robot.model import Robot
    from hqp_tpm.robot.state import State
    from hqp_tpm.solvers import cascaded_qp, sns_tpm, tpm

    robot = Robot.load("lwr4")
    state = State(robot)
    fid = robot.frame_id("lwr_ee")
    qlo, qup = robot.position_limits()
    vmax = robot.velocity_limits() * v_scale
    rng = np.random.default_rng(seed)
    zero = np.zeros(robot.nv)
    t_sns, t_tpm, t_qp = ([], []), ([], []), ([], [])
    sat = scaled = iters = 0
    for d in range(-5, draws):
        state.update(rng.uniform(qlo, qup), zero)
        J = state.jacobian(fid).copy()
        b = np.concatenate([rng.normal(0.0, 0.5, 3), rng.normal(0.0, 1.0, 3)])   # m/s, rad/s
        levels = [(J, b)]
        dt_s, dc_s, (x, info) = common.timed(sns_tpm, levels, -vmax, vmax, return_info=True)
        dt_t, dc_t, _ = common.timed(tpm, levels)
        if d < 0:
            continue
        t_sns[0].append(dt_s)
        t_sns[1].append(dc_s)
        t_tpm[0].append(dt_t)
        t_tpm[1].append(dc_t)
        sat += info.iterations > 1 or info.scale < 1.0   # the box binds: the TPM solution leaves it
        scaled += info.scale < 1.0
        iters += info.iterations
        if d < draws // 4:                             # the QP is slower: a quarter of the draws
            dt_q, dc_q, _ = common.timed(cascaded_qp, levels, solver="proxqp", lower=-vmax, upper=vmax)
            t_qp[0].append(dt_q)
            t_qp[1].append(dc_q)
    return {"draws": draws, "v_scale": v_scale, "sns": common.stats_us(*t_sns), "tpm": common.stats_us(*t_tpm),
            "qp": common.stats_us(*t_qp), "saturated_fraction": sat / draws, "scaled_fraction": scaled / draws,
            "mean_iterations": iters / draws}


def romeo_capture(every: int, steps: int | None):
    """``(levels, lower, upper)`` of the ``romeo_sns_tpm`` controller every ``every`` steps (and its damping)."""
    sc, _, ctrl, _ = build("romeo_sns_tpm")
    n = steps or sc.steps
    captured = []
    for i in range(n):
        res = ctrl.step()
        if i % every == 0:
            lo, up = ctrl.box(ctrl.state, res.t)   # the state the levels were computed at (t is unused)
            captured.append((res.levels, lo, up, res.command.copy()))
    return captured, ctrl.lambda_max, ctrl.eps


def romeo_solves(every: int, steps: int | None, repeats: int) -> dict:
    from hqp_tpm.solvers import cascaded_qp, sns_tpm

    captured, lam, eps = romeo_capture(every, steps)
    t_sns, t_qp = ([], []), ([], [])
    t_free, t_sat = [], []
    same, scaled, iters, failures = 0.0, 0, 0, 0
    for levels, lo, up, command in captured:
        for _ in range(repeats):
            dt, dc, (x, info) = common.timed(sns_tpm, levels, lo, up, lambda_max=lam, eps=eps, return_info=True)
            t_sns[0].append(dt)
            t_sns[1].append(dc)
            (t_free if info.iterations == 1 else t_sat).append(dt)
        same = max(same, common.rel_err(x, command))
        scaled += info.scale < 1.0
        iters += info.iterations
        try:
            dt, dc, _ = common.timed(cascaded_qp, levels, solver="proxqp", lower=lo, upper=up, lambda_max=lam, eps=eps)
            t_qp[0].append(dt)
            t_qp[1].append(dc)
        except Exception:  # a failed QP is counted, not timed
            failures += 1
    n = len(captured)
    sns, qp = common.stats_us(*t_sns), common.stats_us(*t_qp)
    return {"stacks": n, "repeats": repeats, "sns": sns, "qp": qp, "ratio_median": qp["median_us"] / sns["median_us"],
            "ratio_cpu_median": qp["cpu_median_us"] / sns["cpu_median_us"],
            "free": common.stats_us(t_free), "saturating": common.stats_us(t_sat),
            "ratio_p99": qp["p99_us"] / sns["p99_us"], "scaled_fraction": scaled / n, "mean_iterations": iters / n,
            "max_rel_diff_to_controller": same, "qp_failures": failures,
            "sizes": [lv.m for lv in captured[0][0]], "nv": captured[0][1].size}


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=2000, help="timed steps of lwr_relaxed (both solvers)")
    p.add_argument("--romeo-steps", type=int, default=None,
                   help="timed steps of romeo_sns_tpm (both solvers; default: the rest of the 5 s run)")
    p.add_argument("--warmup", type=int, default=200)
    p.add_argument("--run-steps", type=int, default=None, help="steps of the whole lwr_relaxed run (default: all)")
    p.add_argument("--arm-draws", type=int, default=2000)
    p.add_argument("--arm-v-scale", type=float, default=0.5, help="velocity box = this x the URDF limits")
    p.add_argument("--capture-every", type=int, default=25, help="Romeo stacks captured every k steps")
    p.add_argument("--repeats", type=int, default=5, help="sns_tpm solves per captured Romeo stack")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--out", type=Path, default=common.RESULTS)
    p.add_argument("--quick", action="store_true", help="smoke test: few steps and draws")
    args = p.parse_args(argv)
    if args.quick:
        args.steps, args.romeo_steps, args.warmup = 100, 100, 20
        args.run_steps, args.arm_draws, args.capture_every, args.repeats = 1000, 100, 500, 2
    return args


def main(argv=None) -> dict:
    args = parse(argv)
    with common.one_blas_thread():
        env = common.environment()
        env["settings"] = (f"lwr_relaxed {args.steps} steps, romeo_sns_tpm {args.romeo_steps or 'all'} steps, "
                           f"after {args.warmup} warm-up steps; "
                           f"{args.arm_draws} arm draws; Romeo stacks every {args.capture_every} steps")
        steps = []
        for name in SCENARIOS:
            for solver in (None, "qp"):
                common.progress(f"  control step: {name} solver={solver or 'scenario'}")
                n = args.steps if name == "lwr_relaxed" else args.romeo_steps
                steps.append(step_timing(name, solver, n, args.warmup))
        common.progress(f"  control step: {OBSTACLES}")
        steps.append(step_timing(OBSTACLES, None, args.romeo_steps, args.warmup))
        common.progress("  control step: whole lwr_relaxed run")
        run = whole_run("lwr_relaxed", args.run_steps)
        common.progress("  control step: 7-DOF SNS-TPM solve")
        arm = arm_sns(args.arm_draws, args.seed, args.arm_v_scale)
        common.progress("  control step: Romeo SNS-TPM solve vs cascaded QP")
        romeo = romeo_solves(args.capture_every, None if not args.quick else 1000, args.repeats)
        common.close_environment(env)
    return report(args, env, steps, run, arm, romeo)


def _step(steps, name, qp: bool):
    return next(s for s in steps if s["scenario"] == name and (s["solver"] == "qp") == qp)


def targets(steps, run, arm, romeo) -> list[Target]:
    """Met only if both the wall-time and the thread-CPU-time figures meet the goal."""
    rs = _step(steps, "romeo_sns_tpm", False)
    ro = _step(steps, OBSTACLES, False)
    rq = _step(steps, "romeo_sns_tpm", True)
    lwr_median = _step(steps, "lwr_relaxed", False)["median_us"]
    scaled = "" if run["steps"] >= 18850 else f" (scaled to {run['steps']} steps)"
    sns, qp = romeo["sns"], romeo["qp"]
    return [
        Target("lwr_relaxed whole run, ctrl.step() loop", f"≤ {LWR_RUN_S:g} s wall{scaled}",
               f"{run['loop_s']:.2f} s for {run['steps']} steps (CPU {run['loop_cpu_s']:.2f} s); "
               f"runner.run {run['runner_s']:.2f} s", run["loop_s"] <= LWR_RUN_S * run["steps"] / 18850),
        Target("lwr_relaxed whole run, lean step loop (what hqp-tpm run steps with)", f"≤ {LWR_RUN_S:g} s wall{scaled}",
               f"{run['lean_s']:.2f} s (CPU {run['lean_cpu_s']:.2f} s): {run['loop_cpu_s'] / run['lean_cpu_s']:.2f}x "
               f"the ctrl.step() loop in CPU time", run["lean_s"] <= LWR_RUN_S * run["steps"] / 18850),
        Target(f"{OBSTACLES} control step (coal distances, SNS-TPM), p99", f"≤ {OBSTACLES_P99_US:g} µs",
               f"{ro['p99_us']:.0f} µs (CPU {ro['cpu_p99_us']:.0f} µs); median {ro['median_us']:.0f} µs "
               f"(CPU {ro['cpu_median_us']:.0f} µs)", max(ro["p99_us"], ro["cpu_p99_us"]) <= OBSTACLES_P99_US),
        Target("lwr_relaxed per step incl. coal distances", f"≤ {LWR_STEP_US:g} µs",
               f"{run['loop_us_per_step']:.0f} µs (whole-run mean); median step {lwr_median:.0f} µs",
               run["loop_us_per_step"] <= LWR_STEP_US),
        Target("Romeo SNS-TPM control step, median", f"≤ {ROMEO_MEDIAN_US:g} µs",
               f"{rs['median_us']:.0f} µs (CPU {rs['cpu_median_us']:.0f} µs)",
               max(rs["median_us"], rs["cpu_median_us"]) <= ROMEO_MEDIAN_US),
        Target("Romeo SNS-TPM control step, p99", f"≤ {ROMEO_P99_US:g} µs",
               f"{rs['p99_us']:.0f} µs (CPU {rs['cpu_p99_us']:.0f} µs)",
               max(rs["p99_us"], rs["cpu_p99_us"]) <= ROMEO_P99_US),
        Target("Romeo SNS-TPM solve vs cascaded QP (proxqp), same levels and box", f"≥ {ROMEO_QP_RATIO:g}× faster",
               f"{romeo['ratio_median']:.1f}× (median {sns['median_us']:.0f} vs {qp['median_us']:.0f} µs; "
               f"CPU time {romeo['ratio_cpu_median']:.1f}×); full steps {rq['median_us'] / rs['median_us']:.1f}×",
               min(romeo["ratio_median"], romeo["ratio_cpu_median"]) >= ROMEO_QP_RATIO),
        Target("7-DOF SNS-TPM velocity solve (6-D task, saturating box), median", f"≤ {ARM_SNS_US:g} µs",
               f"{arm['sns']['median_us']:.1f} µs (CPU {arm['sns']['cpu_median_us']:.1f} µs; "
               f"the box binds in {100 * arm['saturated_fraction']:.0f}% of the draws)",
               max(arm["sns"]["median_us"], arm["sns"]["cpu_median_us"]) <= ARM_SNS_US),
    ]


def report(args, env, steps, run, arm, romeo) -> dict:
    tg = targets(steps, run, arm, romeo)
    rows = []
    for s in steps:
        rows.append({"benchmark": "control_step", "case": s["scenario"], "method": s["solver"], "nv": s["nv"],
                     "count": s["count"], "median_us": s["median_us"], "p99_us": s["p99_us"], "mean_us": s["mean_us"],
                     "cpu_median_us": s["cpu_median_us"],
                     "note": f"steps from t = {s['t_start']:.3f} s to {s['t_end']:.3f} s; sns iterations/step "
                             f"{s['mean_sns_iterations']}; scaled fraction {s['scaled_fraction']}; median without/with "
                             f"saturation {s.get('free_median_us', '')}/{s.get('saturating_median_us', '')} us"
                             + (f"; {s['failed']}" if s["failed"] else "")})
        for ph, (med, mean) in s["phases"].items():
            rows.append({"benchmark": "phase", "case": s["scenario"], "method": s["solver"], "nv": s["nv"],
                         "count": s["phase_steps"], "median_us": med, "mean_us": mean, "note": ph})
    rows.append({"benchmark": "whole_run", "case": "lwr_relaxed", "method": "ctrl.step loop", "count": run["steps"],
                 "wall_s": run["loop_s"], "cpu_s": run["loop_cpu_s"], "mean_us": run["loop_us_per_step"]})
    rows.append({"benchmark": "whole_run", "case": "lwr_relaxed", "method": "lean step loop", "count": run["steps"],
                 "wall_s": run["lean_s"], "cpu_s": run["lean_cpu_s"], "mean_us": run["lean_us_per_step"]})
    rows.append({"benchmark": "whole_run", "case": "lwr_relaxed", "method": "runner.run", "count": run["steps"],
                 "wall_s": run["runner_s"], "mean_us": run["runner_us_per_step"]})
    keys = ("count", "median_us", "p99_us", "mean_us", "cpu_median_us", "cpu_p99_us")
    label = {"sns": "sns_tpm", "tpm": "tpm", "qp": "cascaded_qp proxqp"}
    for m in ("sns", "tpm", "qp"):
        rows.append({"benchmark": "arm_7dof_velocity", "case": "lwr4 6-D EE task", "method": label[m], "nv": 7,
                     **{k: arm[m][k] for k in keys},
                     "note": f"box = {arm['v_scale']} x URDF velocity limits; "
                             f"box binds in {arm['saturated_fraction']:.2f} of draws"})
    for m in ("sns", "qp"):
        rows.append({"benchmark": "romeo_solve", "case": "romeo_sns_tpm captured stacks", "method": label[m],
                     "nv": romeo["nv"], **{k: romeo[m][k] for k in keys},
                     "note": f"{romeo['stacks']} stacks; ratio qp/sns median {romeo['ratio_median']:.2f}"})
    common.write_csv(args.out / "control_step.csv", rows, env)

    step_table = common.md_table(
        ["scenario", "solver", "nv", "steps (t in s)", "median µs", "p99 µs", "mean µs", "CPU median µs",
         "SNS iterations / step", "steps scaled", "median µs: steps without / with saturation (share)"],
        [[s["scenario"], s["solver"], s["nv"], f"{s['count']} ({s['t_start']:.1f}–{s['t_end']:.1f})",
          fmt(s["median_us"]), fmt(s["p99_us"]), fmt(s["mean_us"]), fmt(s["cpu_median_us"]),
          f"{s['mean_sns_iterations']:.2f}" if s["mean_sns_iterations"] != "" else "–",
          f"{100 * s['scaled_fraction']:.0f}%" if s["scaled_fraction"] != "" else "–",
          f"{fmt(s['free_median_us'])} / {fmt(s['saturating_median_us'])} ({100 * s['saturating_fraction']:.0f}%)"
          if "free_median_us" in s else "–"] for s in steps])
    ratio_rows = []
    for name in SCENARIOS:
        a, q = _step(steps, name, False), _step(steps, name, True)
        window = "same steps" if a["t_end"] == q["t_end"] else (
            f"{a['scenario']}/{a['solver']} t = {a['t_start']:.1f}–{a['t_end']:.1f} s, qp t = {q['t_start']:.1f}–"
            f"{q['t_end']:.1f} s")
        ratio_rows.append([name, f"{q['median_us'] / a['median_us']:.2f}", f"{q['p99_us'] / a['p99_us']:.2f}",
                           window])
    failures = [f"* {s['scenario']} / {s['solver']}: {s['failed']}; the figures cover the {s['count']} steps "
                f"before it." for s in steps if s["failed"]]
    failures += [f"* {s['scenario']} / {s['solver']}, phase-timer pass (a second fresh controller): "
                 f"{s['phase_failed']}; the phase table covers the {s['phase_steps']} steps before it (the same "
                 f"steps succeeded in the timing pass: the backend is not deterministic here)."
                 for s in steps if s.get("phase_failed")]
    if failures:
        step_table += "\n\nRuns that stopped early (a step raised; the controller cannot go on):\n\n" + "\n".join(
            failures)
    phase_table = common.md_table(
        ["phase: median (mean) µs per step", *(f"{s['scenario']} / {s['solver']}" for s in steps)],
        [[ph, *(f"{fmt(s['phases'][ph][0])} ({fmt(s['phases'][ph][1])})" for s in steps)]
         for ph in steps[0]["phases"]])
    run_table = common.md_table(
        ["lwr_relaxed complete run", "steps", "wall s", "µs / step", "process CPU s"],
        [["ctrl.step() loop, no recording", run["steps"], f"{run['loop_s']:.2f}", fmt(run["loop_us_per_step"]),
          f"{run['loop_cpu_s']:.2f}"],
         ["lean step loop (PlannedStep), no recording", run["steps"], f"{run['lean_s']:.2f}",
          fmt(run["lean_us_per_step"]), f"{run['lean_cpu_s']:.2f}"],
         ["hqp_tpm.app.runner.run (lean step, recording)", run["steps"], f"{run['runner_s']:.2f}",
          fmt(run["runner_us_per_step"]), ""]])
    arm_table = common.md_table(
        ["7-DOF, 6-D EE task", "draws", "median µs", "p99 µs", "mean µs", "CPU median µs"],
        [[m, arm[k]["count"], fmt(arm[k]["median_us"]), fmt(arm[k]["p99_us"]), fmt(arm[k]["mean_us"]),
          fmt(arm[k]["cpu_median_us"])]
         for m, k in (("sns_tpm", "sns"), ("tpm (no box)", "tpm"), ("cascaded_qp proxqp (box)", "qp"))])
    arm_note = (f"Velocity box ±{arm['v_scale']} × URDF limits, targets N(0, 0.5) m/s and N(0, 1) rad/s: "
                f"the box binds (the TPM solution leaves it) in {100 * arm['saturated_fraction']:.0f}% of the draws, "
                f"{arm['mean_iterations']:.2f} "
                f"iterations on average. Ratios (median): sns_tpm/tpm "
                f"{arm['sns']['median_us'] / arm['tpm']['median_us']:.2f}, qp/sns_tpm "
                f"{arm['qp']['median_us'] / arm['sns']['median_us']:.2f}. "
                f"{100 * arm['scaled_fraction']:.0f}% of the draws end scaled (s < 1): a 6-D task on 7 joints "
                f"has one redundant joint, so the second saturation (the first if it is the elbow, joint 4: "
                f"without it the LWR's 6×6 Jacobian is singular) ends the algorithm with rank(JW) < m.")
    romeo_table = common.md_table(
        ["Romeo solve alone", "solves", "median µs", "p99 µs", "mean µs", "CPU median µs"],
        [[m, romeo[k]["count"], fmt(romeo[k]["median_us"]), fmt(romeo[k]["p99_us"]), fmt(romeo[k]["mean_us"]),
          fmt(romeo[k]["cpu_median_us"])] for m, k in (("sns_tpm", "sns"), ("cascaded_qp proxqp", "qp"))])
    romeo_note = (f"{romeo['stacks']} stacks (levels of m = {romeo['sizes']} rows, n = {romeo['nv']}) captured every "
                  f"{args.capture_every} steps of the run; box from `ctrl.box`, damping λ_max, ε of the scenario. "
                  f"QP/SNS-TPM: **{romeo['ratio_median']:.2f}×** (median), {romeo['ratio_p99']:.2f}× (p99), "
                  f"{romeo['ratio_cpu_median']:.2f}× (median thread CPU time). "
                  f"{100 * romeo['scaled_fraction']:.0f}% of the stacks are scaled (s < 1), "
                  f"{romeo['mean_iterations']:.1f} iterations on average. SNS-TPM median on the stacks where no joint "
                  f"saturates (one pass): {fmt(romeo['free']['median_us'])} µs ({romeo['free']['count']} solves), "
                  f"where joints saturate: {fmt(romeo['saturating']['median_us'])} µs "
                  f"({romeo['saturating']['count']} solves). The re-solve equals the controller's "
                  f"command to {romeo['max_rel_diff_to_controller']:.1e}; QP failures: {romeo['qp_failures']}.")
    sections = [
        ("Targets", common.targets_markdown(tg)),
        ("Full control step (µs per `ctrl.step()`)", step_table),
        ("Cascaded QP / analytic, full steps (same run)",
         common.md_table(["scenario", "median ratio", "p99 ratio", "steps compared"], ratio_rows)),
        ("Where a step's time goes (controller calls wrapped with timers)",
         phase_table + "\n\nThe controller's own calls are wrapped with timers on a second fresh controller over "
         "the same steps: state update = `State.update` (pinocchio kinematics), pre-policy = the policy's hooks (coal "
         "distances of Algorithm 1), policy = the policy call (stack choice, distance Jacobians), task levels = "
         "`Stack.to_levels`, box = the joint-limit box, solve = `hqp_tpm.solvers.registry.solve`, integration = "
         "`State.integrate`; rest = the step minus these."),
        ("Complete run", run_table),
        ("7-DOF SNS-TPM velocity solve", arm_table + "\n\n" + arm_note),
        ("Romeo SNS-TPM solve against the cascaded QP, same levels and box", romeo_table + "\n\n" + romeo_note),
    ]
    common.write_markdown(args.out / "control_step.md", "Control-step timing", env, sections)
    common.progress(f"wrote {args.out}/control_step.csv, control_step.md")
    return {"env": env, "targets": tg, "sections": sections, "steps": steps, "run": run, "arm": arm, "romeo": romeo}


if __name__ == "__main__":
    main()
