"""Side-by-side timing of hqp-tpm and the peers installed in this environment (one process).

    python benchmarks/peers/run.py --env NAME [--configs 200] [--repeats 10] [--steps 2000] [--quick]

Runs every problem of :mod:`benchmarks.peers.problems` with every contender that imports here
(hqp-tpm ``tpm``, ``sns_tpm``, cascaded QP with daqp; pink; PlaCo; TSID), contenders interleaved:
for each configuration every contender does 2 warm-up calls and ``--repeats`` timed calls of its
step (state fed in, targets moved, kinematics, rows, solve), then of its rows + solve, then of its solve alone
(where the library separates them), in an order rotated from one configuration to the next; wall and thread CPU
time of every call. Per configuration the median of the repeats is taken and divided by hqp-tpm ``tpm``'s median
at the same configuration (the ratio), and, for hqp-tpm, by the reference peer's (:data:`REFERENCE`: PlaCo with
velocity limits at velocity level, TSID at acceleration level; thread CPU time) -- ``vs_ratio_median`` -- beside
the ratio of the 99th percentiles of all calls (``vs_ratio_p99``). The summary also gives the quality of each
contender's command at each configuration (top-level residual against hqp-tpm's first level, joint-velocity box
violation). Closed loops (the iiwa circle): each library's loop as its users write it, the steps alone timed.
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


#: The peer every hqp-tpm contender is also compared with, in the environment where it runs (the issue's yardstick).
REFERENCE = {1: "PlaCo + limits", 2: "TSID"}
PHASES = ("step", "rows_solve", "solve")


def contenders_for(problem, robot, quick: bool):
    out = [C.Hqp(robot, problem, s) for s in HQP_SOLVERS]
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
    """Every contender at every configuration, interleaved (the order rotated per configuration), each phase of
    :data:`PHASES` it has timed ``repeats`` times after 2 warm-up calls."""
    cons = contenders_for(problem, robot, quick)
    names = [c.name for c in cons]
    v_max = robot.velocity_limits() if problem.order == 1 else None
    n_cfg = len(problem.configs)
    per = {n: {"res": [], "viol": [], "rel": [], "own": [],
               **{f"{ph}_{k}": [] for ph in PHASES for k in ("wall", "cpu", "all", "all_cpu")},
               **{f"{ph}_cfg": np.full(n_cfg, np.nan) for ph in PHASES},       # wall median per configuration
               **{f"{ph}_cfg_cpu": np.full(n_cfg, np.nan) for ph in PHASES}}   # CPU median per configuration
           for n in names}
    failures: dict[str, str] = {}   # first error message per contender
    failed = dict.fromkeys(names, 0)  # configurations where the contender raised
    ref = C.Hqp(robot, problem, "tpm")
    for k, cfg in enumerate(problem.configs):
        ref.setup(cfg)
        J0, b0 = np.array(ref.levels[0].J), np.array(ref.levels[0].b)
        order = cons[k % len(cons):] + cons[:k % len(cons)]
        for c in order:
            try:
                c.setup(cfg)
                c.step()   # (the moved targets: the step alternates, so the next call has the configuration's own)
                x = np.asarray(c.step(), dtype=float)
                timed = {ph: time_calls(getattr(c, ph), repeats) for ph in PHASES if getattr(c, ph, None)}
            except Exception as exc:  # a peer failing on a configuration is counted and reported, not fatal
                failures.setdefault(c.name, f"{type(exc).__name__}: {exc}"[:160])
                failed[c.name] += 1
                continue
            d = per[c.name]
            for ph, (tw, tc) in timed.items():
                d[f"{ph}_wall"].append(np.median(tw))
                d[f"{ph}_cpu"].append(np.median(tc))
                d[f"{ph}_all"] += tw
                d[f"{ph}_all_cpu"] += tc
                d[f"{ph}_cfg"][k] = np.median(tw)
                d[f"{ph}_cfg_cpu"][k] = np.median(tc)
            res, viol = P.quality(J0, b0, x, v_max)
            own = getattr(c, "own_residual", None)
            d["own"].append(own(x) if own is not None else res)
            d["res"].append(res)
            d["rel"].append(res / max(np.linalg.norm(b0), 1e-12))
            d["viol"].append(viol)

    def ratios(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        ok = np.isfinite(a) & np.isfinite(b) & (b > 0)
        return a[ok] / b[ok]

    peer = REFERENCE[problem.order] if REFERENCE[problem.order] in names else None
    rows = []
    for n in names:
        d = per[n]
        for phase in PHASES:
            if not d[f"{phase}_wall"]:
                if phase == "step" and failed[n]:   # (a phase the library does not separate: no row)
                    rows.append({"problem": problem.name, "phase": phase, "contender": n, "configs": 0,
                                 "failed_configs": failed[n], "failed": failures.get(n, "")})
                continue
            t = np.array(d[f"{phase}_wall"]) / 1e3
            base = per["hqp-tpm tpm"]
            ratio = ratios(d[f"{phase}_cfg"], base[f"{phase}_cfg"])
            cpu_ratio = ratios(d[f"{phase}_cfg_cpu"], base[f"{phase}_cfg_cpu"])
            viol = np.array(d["viol"])
            row = {
                "problem": problem.name, "phase": phase, "contender": n, "configs": len(t),
                "median_us": float(np.median(t)), "p99_us": float(np.percentile(np.array(d[f"{phase}_all"]) / 1e3, 99)),
                "p99_cfg_us": float(np.percentile(t, 99)),
                "ratio_median": float(np.median(ratio)), "ratio_p99": float(np.percentile(ratio, 99)),
                "cpu_median_us": float(np.median(d[f"{phase}_cpu"]) / 1e3),
                "cpu_p99_us": float(np.percentile(np.array(d[f"{phase}_all_cpu"]) / 1e3, 99)),
                "cpu_ratio_median": float(np.nanmedian(cpu_ratio)),
                "cpu_ratio_p99": float(np.nanpercentile(cpu_ratio, 99)),
                "top_residual_median": float(np.median(d["res"])), "top_residual_max": float(np.max(d["res"])),
                "top_residual_rel_median": float(np.median(d["rel"])),
                "own_top_residual_median": float(np.median(d["own"])), "own_top_residual_max": float(np.max(d["own"])),
                "box_violation_max": float(np.nanmax(viol)) if np.isfinite(viol).any() else float("nan"),
                "box_violated_configs": int(np.sum(viol > 1e-9)) if np.isfinite(viol).any() else -1,
                "failed_configs": failed[n], "failed": failures.get(n, ""),
            }
            # against the reference peer, the same phase (PlaCo's solve builds its task matrices: its rows_solve,
            # compared with hqp-tpm's rows_solve), thread CPU time per configuration and of all calls' p99
            if peer is not None and per[peer][f"{phase}_all_cpu"] and n.startswith("hqp-tpm"):
                vs = ratios(d[f"{phase}_cfg_cpu"], per[peer][f"{phase}_cfg_cpu"])
                row.update(vs_peer=peer, vs_ratio_median=float(np.median(vs)),
                           vs_ratio_cfg_p99=float(np.percentile(vs, 99)),
                           vs_ratio_p99=float(np.percentile(d[f"{phase}_all_cpu"], 99)
                                              / np.percentile(per[peer][f"{phase}_all_cpu"], 99)))
            rows.append(row)
    return rows


def run_circle(robot, order: int, steps: int, rounds: int) -> list[dict]:
    kinds = [("hqp-tpm tpm", "hqp", {"solver": "tpm"}), ("hqp-tpm sns_tpm", "hqp", {"solver": "sns_tpm"})]
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
                # each step's thread CPU time: the steps are short, and a core taken by another process for a
                # while (this machine is shared) would otherwise make the p99 of whoever ran then
                times, qs, cmds = C.circle_loop(kind, robot, order, steps, time.thread_time_ns, **kw)
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

    def loop_time(a):   # the steps alone, thread CPU time (the loop's set-up and the harness between steps not counted)
        return np.median([sum(a["steps"][r * steps:(r + 1) * steps]) for r in range(len(a["total"]))])

    base = loop_time(acc["hqp-tpm tpm"]) if acc["hqp-tpm tpm"]["total"] else float("nan")
    peer = REFERENCE[order] if acc.get(REFERENCE[order], {}).get("total") else None
    for n, a in acc.items():
        if not a["total"]:
            rows.append({"problem": name, "phase": "loop", "contender": n, "failed": failures.get(n, "")})
            continue
        st = np.array(a["steps"]) / 1e3
        row = {
            "problem": name, "phase": "loop", "contender": n, "configs": len(a["total"]),
            "median_us": float(np.median(st)), "p99_us": float(np.percentile(st, 99)),
            "loop_ms": float(loop_time(a) / 1e6),
            "ratio_median": float(loop_time(a) / base), "ratio_p99": float("nan"),
            "tracking_rms_mm": 1e3 * a["track"][0], "tracking_max_mm": 1e3 * a["track"][1],
            "box_violation_max": a["viol"] if a["viol"] is not None else float("nan"),
            "box_violated_configs": a.get("viol_steps", -1), "failed": failures.get(n, ""),
        }
        if peer is not None and n.startswith("hqp-tpm"):
            ps = np.array(acc[peer]["steps"]) / 1e3
            row.update(vs_peer=peer, vs_ratio_median=float(np.median(st) / np.median(ps)),
                       vs_ratio_p99=float(np.percentile(st, 99) / np.percentile(ps, 99)),
                       vs_loop_ratio=float(loop_time(a) / loop_time(acc[peer])))
        rows.append(row)
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
