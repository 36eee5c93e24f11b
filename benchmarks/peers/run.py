"""Side-by-side timing of hqp-tpm and the peers installed in this environment (one process).

    python benchmarks/peers/run.py --env NAME [--configs 200] [--repeats 10] [--steps 2000] [--quick]

Runs every problem of :mod:`benchmarks.peers.problems` with every contender that imports here
(hqp-tpm ``tpm``, ``sns_tpm``, cascaded QP with daqp; pink; PlaCo; TSID), contenders interleaved:
for each configuration every contender does 2 warm-up calls and ``--repeats`` timed calls of its
full step, then of its solve alone, in an order rotated from one configuration to the next. Per
configuration the median of the repeats is taken and divided by hqp-tpm ``tpm``'s median at the same
configuration (the ratio); the summary gives the medians over configurations, the ratios' median and
99th percentile, the 99th percentile of all calls, and the quality of each contender's command at
each configuration (top-level residual against hqp-tpm's first level, joint-velocity box violation).
Writes ``benchmarks/results/peers/<env>.csv`` and ``<env>.env.csv``; ``report.py`` merges them.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks import common  # noqa: E402
from benchmarks.peers import contenders as C  # noqa: E402
from benchmarks.peers import problems as P  # noqa: E402

OUT = common.RESULTS / "peers"
PEER_PACKAGES = ("pin", "pin-pink", "placo", "tsid", "daqp", "qpsolvers", "numpy", "scipy", "eigenpy", "coal")
HQP_SOLVERS = ("tpm", "sns_tpm", "qp:daqp")


def has(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def env_info(name: str) -> dict[str, str]:
    env = common.environment()
    for pkg in PEER_PACKAGES:
        env[pkg] = common._version(pkg)
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             cwd=common.ROOT, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        rev = "?"
    env["hqp-tpm"] = f"{common._version('hqp-tpm')} (checkout {rev})"
    env["environment"] = name
    return env


def contenders_for(problem, robot, quick: bool):
    out = [C.Hqp(robot, problem, s) for s in HQP_SOLVERS]
    out.insert(1, C.Hqp(robot, problem, "tpm", lean=True))   # the lean step (hqp_tpm.control.lean)
    if "sns_tpm" in HQP_SOLVERS:
        out.insert(out.index(next(c for c in out if c.solver == "sns_tpm" and not c.lean)) + 1,
                   C.Hqp(robot, problem, "sns_tpm", lean=True))
    if problem.order == 1:
        if has("pink"):
            out += [C.Pink(robot, problem, False), C.Pink(robot, problem, True),
                    C.Pink(robot, problem, False, hard_top=True)]
        if has("placo"):
            out += [C.Placo(robot, problem, False), C.Placo(robot, problem, True)]
    elif has("tsid"):
        out.append(C.Tsid(robot, problem))
    return out


def time_calls(fn, repeats: int) -> tuple[list[int], list[int]]:
    """Wall and thread-CPU ns of ``repeats`` calls after 2 warm-up calls (the CPU time leaves out the
    slices other processes took the core for; on this shared machine it keeps long calls honest)."""
    fn()
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        c0 = time.thread_time_ns()
        t0 = time.perf_counter_ns()
        fn()
        t1 = time.perf_counter_ns()
        cpu.append(time.thread_time_ns() - c0)
        wall.append(t1 - t0)
    return wall, cpu


def run_problem(problem, robot, repeats: int, quick: bool) -> list[dict]:
    cons = contenders_for(problem, robot, quick)
    names = [c.name for c in cons]
    v_max = robot.velocity_limits() if problem.order == 1 else None
    per = {n: {"step": [], "solve": [], "step_all": [], "solve_all": [], "res": [], "viol": [], "rel": [],
               "step_ratio": [], "solve_ratio": [], "own": [], "step_cpu": [], "solve_cpu": [],
               "step_cpu_ratio": [], "solve_cpu_ratio": []} for n in names}
    failures: dict[str, str] = {}   # first error message per contender
    failed = dict.fromkeys(names, 0)  # configurations where the contender raised
    ref = C.Hqp(robot, problem, "tpm")
    for k, cfg in enumerate(problem.configs):
        ref.setup(cfg)
        J0, b0 = np.array(ref.levels[0].J), np.array(ref.levels[0].b)
        order = cons[k % len(cons):] + cons[:k % len(cons)]
        here = {}
        for c in order:
            try:
                c.setup(cfg)
                x = np.asarray(c.step(), dtype=float)
                ts, ts_cpu = time_calls(c.step, repeats)
                tv, tv_cpu = time_calls(c.solve, repeats)
            except Exception as exc:  # a peer failing on a configuration is counted and reported, not fatal
                failures.setdefault(c.name, f"{type(exc).__name__}: {exc}"[:160])
                failed[c.name] += 1
                continue
            d = per[c.name]
            d["step"].append(np.median(ts))
            d["solve"].append(np.median(tv))
            d["step_cpu"].append(np.median(ts_cpu))
            d["solve_cpu"].append(np.median(tv_cpu))
            d["step_all"] += ts
            d["solve_all"] += tv
            res, viol = P.quality(J0, b0, x, v_max)
            own = getattr(c, "own_residual", None)
            d["own"].append(own(x) if own is not None else res)
            d["res"].append(res)
            d["rel"].append(res / max(np.linalg.norm(b0), 1e-12))
            d["viol"].append(viol)
            here[c.name] = {key: d[key][-1] for key in ("step", "solve", "step_cpu", "solve_cpu")}
        if "hqp-tpm tpm" in here:  # per-configuration ratios to hqp-tpm tpm at the same configuration
            base = here["hqp-tpm tpm"]
            for n, vals in here.items():
                for key, val in vals.items():
                    per[n][f"{key}_ratio"].append(val / base[key] if base[key] > 0 else float("nan"))
    rows = []
    for n in names:
        d = per[n]
        for phase in ("step", "solve"):
            if not d[phase]:
                rows.append({"problem": problem.name, "phase": phase, "contender": n, "configs": 0,
                             "failed_configs": failed[n], "failed": failures.get(n, "")})
                continue
            t = np.array(d[phase]) / 1e3
            ratio = np.array(d[f"{phase}_ratio"])
            cpu_ratio = np.array(d[f"{phase}_cpu_ratio"])
            viol = np.array(d["viol"])
            rows.append({
                "problem": problem.name, "phase": phase, "contender": n, "configs": len(t),
                "median_us": float(np.median(t)), "p99_us": float(np.percentile(np.array(d[f"{phase}_all"]) / 1e3, 99)),
                "p99_cfg_us": float(np.percentile(t, 99)),
                "ratio_median": float(np.median(ratio)), "ratio_p99": float(np.percentile(ratio, 99)),
                "cpu_median_us": float(np.median(d[f"{phase}_cpu"]) / 1e3),
                "cpu_ratio_median": float(np.nanmedian(cpu_ratio)),
                "cpu_ratio_p99": float(np.nanpercentile(cpu_ratio, 99)),
                "top_residual_median": float(np.median(d["res"])), "top_residual_max": float(np.max(d["res"])),
                "top_residual_rel_median": float(np.median(d["rel"])),
                "own_top_residual_median": float(np.median(d["own"])), "own_top_residual_max": float(np.max(d["own"])),
                "box_violation_max": float(np.nanmax(viol)) if np.isfinite(viol).any() else float("nan"),
                "box_violated_configs": int(np.sum(viol > 1e-9)) if np.isfinite(viol).any() else -1,
                "failed_configs": failed[n], "failed": failures.get(n, ""),
            })
    return rows


def run_circle(robot, order: int, steps: int, rounds: int) -> list[dict]:
    kinds = [("hqp-tpm tpm", "hqp", {"solver": "tpm"}), ("hqp-tpm tpm (lean)", "hqp", {"solver": "tpm", "lean": True}),
             ("hqp-tpm sns_tpm", "hqp", {"solver": "sns_tpm"}),
             ("hqp-tpm sns_tpm (lean)", "hqp", {"solver": "sns_tpm", "lean": True})]
    if order == 1:
        if has("pink"):
            kinds += [("pink", "pink", {}), ("pink + limits", "pink", {"limits": True})]
        if has("placo"):
            kinds += [("PlaCo", "placo", {}), ("PlaCo + limits", "placo", {"limits": True})]
    elif has("tsid"):
        kinds.append(("TSID", "tsid", {}))
    fid = robot.frame_id(P.IIWA_EE)
    data = robot.model.createData()
    q0 = P.circle_start(robot)
    import pinocchio as pin

    pin.framesForwardKinematics(robot.model, data, q0)
    p0 = data.oMf[fid].translation.copy()
    v_max = robot.velocity_limits()
    acc: dict[str, dict] = {k[0]: {"total": [], "cpu": [], "steps": [], "track": None, "viol": None} for k in kinds}
    failures: dict[str, str] = {}
    for r in range(rounds):
        order_k = kinds[r % len(kinds):] + kinds[:r % len(kinds)]
        for name, kind, kw in order_k:
            if name in failures:
                continue
            try:
                c0 = time.thread_time_ns()
                t0 = time.perf_counter_ns()
                times, qs, cmds = C.circle_loop(kind, robot, order, steps, time.perf_counter_ns, **kw)
                total = time.perf_counter_ns() - t0
                total_cpu = time.thread_time_ns() - c0
            except Exception as exc:
                failures[name] = f"{type(exc).__name__}: {exc}"[:200]
                continue
            a = acc[name]
            a["total"].append(total)
            a["cpu"].append(total_cpu)
            a["steps"] += times
            if a["track"] is None:  # quality from the first round (the loops are deterministic)
                err = []
                for k, q in enumerate(qs):
                    pin.framesForwardKinematics(robot.model, data, q)
                    p_d, _, _ = P.circle_reference(p0, (k + 1) * P.DT)
                    err.append(np.linalg.norm(data.oMf[fid].translation - p_d))
                a["track"] = (float(np.sqrt(np.mean(np.square(err)))), float(np.max(err)))
                cm = np.array(cmds)
                if order == 1:
                    a["viol"] = float(max(0.0, np.max(np.abs(cm) - v_max)))
                    a["viol_steps"] = int(np.sum((np.abs(cm) - v_max > 1e-9).any(axis=1)))
    rows = []
    name = "iiwa_circle_vel" if order == 1 else "iiwa_circle_acc"
    base = np.median(acc["hqp-tpm tpm"]["total"]) if acc["hqp-tpm tpm"]["total"] else float("nan")
    base_cpu = np.median(acc["hqp-tpm tpm"]["cpu"]) if acc["hqp-tpm tpm"]["cpu"] else float("nan")
    for n, a in acc.items():
        if not a["total"]:
            rows.append({"problem": name, "phase": "loop", "contender": n, "failed": failures.get(n, "")})
            continue
        st = np.array(a["steps"]) / 1e3
        rows.append({
            "problem": name, "phase": "loop", "contender": n, "configs": len(a["total"]),
            "median_us": float(np.median(st)), "p99_us": float(np.percentile(st, 99)),
            "loop_ms": float(np.median(a["total"]) / 1e6),
            "ratio_median": float(np.median(a["total"]) / base), "ratio_p99": float("nan"),
            "cpu_ratio_median": float(np.median(a["cpu"]) / base_cpu),
            "tracking_rms_mm": 1e3 * a["track"][0], "tracking_max_mm": 1e3 * a["track"][1],
            "box_violation_max": a["viol"] if a["viol"] is not None else float("nan"),
            "box_violated_configs": a.get("viol_steps", -1), "failed": failures.get(n, ""),
        })
    return rows


def run_scenarios(steps: int, warmup: int) -> list[dict]:
    """hqp-tpm only: ``lwr_relaxed``'s step (coal distances, Algorithm 1) and ``romeo_obstacles_sns_tpm``'s."""
    from hqp_tpm.app import build as hb
    from hqp_tpm.app import scenario

    rows = []
    for name, n in (("lwr_relaxed", steps), ("romeo_obstacles_sns_tpm", None)):
        sc = scenario.load(name)
        _, ctrl, _, _ = hb.build(sc)
        total = n if n is not None else int(round(float(sc.duration) / sc.period))
        times = []
        for k in range(warmup + total - (warmup if n is None else 0)):
            t0 = time.perf_counter_ns()
            ctrl.step()
            dt = time.perf_counter_ns() - t0
            if k >= warmup:
                times.append(dt)
        t = np.array(times) / 1e3
        rows.append({"problem": name, "phase": "step", "contender": f"hqp-tpm {sc.solver}", "configs": len(t),
                     "median_us": float(np.median(t)), "p99_us": float(np.percentile(t, 99)),
                     "ratio_median": float("nan"), "ratio_p99": float("nan"), "failed": ""})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", required=True, help="name of this environment (pin4, pin38, pin34)")
    ap.add_argument("--configs", type=int, default=P.N_CONFIGS)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--steps", type=int, default=P.CIRCLE_STEPS)
    ap.add_argument("--rounds", type=int, default=3, help="closed-loop runs per contender (interleaved)")
    ap.add_argument("--scenarios", action="store_true", help="also time the hqp-tpm scenario steps (e)")
    ap.add_argument("--quick", action="store_true", help="smoke test: few configurations and steps")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    if args.quick:
        args.configs, args.repeats, args.steps, args.rounds = 4, 2, 50, 1
    rows: list[dict] = []
    with common.one_blas_thread():
        env = env_info(args.env)
        iiwa = P.load_robot(P.IIWA)
        if has("pink") or has("placo"):
            common.progress(f"[{args.env}] iiwa velocity level")
            rows += run_problem(P.iiwa_problem(iiwa, 1, args.configs), iiwa, args.repeats, args.quick)
            common.progress(f"[{args.env}] Romeo velocity level")
            romeo = P.load_robot(P.ROMEO)
            rows += run_problem(P.romeo_problem(romeo, args.configs), romeo, args.repeats, args.quick)
            common.progress(f"[{args.env}] iiwa circle, velocity level")
            rows += run_circle(iiwa, 1, args.steps, args.rounds)
        if has("tsid"):
            common.progress(f"[{args.env}] iiwa acceleration level")
            rows += run_problem(P.iiwa_problem(iiwa, 2, args.configs), iiwa, args.repeats, args.quick)
            common.progress(f"[{args.env}] iiwa circle, acceleration level")
            rows += run_circle(iiwa, 2, args.steps, args.rounds)
        if args.scenarios:
            common.progress(f"[{args.env}] hqp-tpm scenario steps")
            rows += run_scenarios(200 if args.quick else 2000, 20 if args.quick else 200)
        common.close_environment(env)
    for r in rows:
        r["env"] = args.env
        r["pin"] = env["pin"]
    common.write_csv(args.out / f"{args.env}.csv", rows, env)
    common.progress(f"[{args.env}] wrote {args.out / (args.env + '.csv')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
