"""Issue 31, item 2: the pointing task's ``drift_limit`` on lwr_relaxed, measured (docs/pointing_drift.md).

Runs the sweep of docs/sweeps.md,
``hqp-tpm sweep lwr_relaxed --random 20 --seed 1 "obstacles.o1.center=[0.07,0.47,0.07]:[0.13,0.53,0.13]"``,
twice: as shipped (``drift_limit = 40``) and with papers/000's law as written (``tasks.pointing.drift_limit=false``,
the same 20 draws), and writes ``tests/data/pointing_drift_results.json`` (``tests/test_pointing_drift_results.py``
reads it):

* per variant and law: status, steps, the error type of a stopped run, ``max_abs_dq`` (rad/s), ``velocity_ratio``
  (the largest ``|qdot_i| / qdot_max_i`` over joints and steps: the run stops beyond the scenario's
  ``velocity_bound``), the pointing violation (deg), the EE error (m), ``D_minimal`` (m);
* ``identical``: whether the two laws computed the same trajectory (``q``, ``qdot``, ``qddot`` bit for bit: the limit
  never acted);
* ``reference``: the largest ``|Jdot_rp qdot| / ||J_rp||`` (rad/s^2) over the recorded states of the shipped
  lwr_relaxed run, the joint acceleration its drift compensation asks for (below ``drift_limit``, so the limit never
  acts there);
* ``extending``: the scenarios that extend lwr_relaxed and keep its limit (``EXTENDING``), each run with the limit
  and with the law as written, and whether the two trajectories are the same bit for bit;
* ``avoid3d``: lwr_avoid3d (shipped with ``drift_limit = false``) run with ``drift_limit = 40``;
* ``seed16_v009``: variant v009 of the three-obstacle sweep (``--random 10 --seed 16``, o1, o2, o3 moved), both laws;
* ``summary``: the counts and extremes docs/pointing_drift.md quotes (runs complete per law, variants identical,
  the range of ``max_abs_dq``, the largest change of the settled EE error between the laws);
* ``prefix``: v003's largest ``|qdot|`` over its first ``PREFIX`` steps with the limit (the test recomputes it).

Usage: ``PYTHONPATH=$PWD python tools/pointing_drift_report.py [--out DIR] [--workers N]`` (DIR keeps the runs;
a complete sweep there is reused). About 5 minutes on one core of a shared two.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "tests" / "data" / "pointing_drift_results.json"
SCENARIO = "lwr_relaxed"
RANGES = {"obstacles.o1.center": ([0.07, 0.47, 0.07], [0.13, 0.53, 0.13])}
N_RANDOM, SEED = 20, 1
#: the three-obstacle sweep whose v009 overflowed with papers/000's law
RANGES16 = {"obstacles.o1.center": ([0.07, 0.47, 0.07], [0.13, 0.53, 0.13]),
            "obstacles.o2.center": ([-0.23, 0.27, 0.17], [-0.17, 0.33, 0.23]),
            "obstacles.o3.center": ([-0.13, 0.37, -0.13], [-0.07, 0.43, -0.07])}
PAPER = {"tasks.pointing.drift_limit": False}
#: the shipped scenarios that extend lwr_relaxed and inherit its drift_limit
EXTENDING = ("lwr_point35_equality", "lwr_point35_inequality", "lwr_relaxed_mujoco")
#: v003's first steps (past where papers/000's law leaves the bound, step 5,619) are recorded for the test
PREFIX = 5700


def row(run_dir: Path, vlim: np.ndarray, error_type: str | None = None) -> dict:
    """One run's numbers (module doc), from its folder (a stopped run keeps its steps there as a partial result)."""
    man = json.loads((run_dir / "manifest.json").read_text())
    metrics = json.loads((run_dir / "metrics.json").read_text())
    dq = np.load(run_dir / "trajectory.npz")["dq"]
    out = {"status": man["status"], "error_type": error_type, "steps": int(dq.shape[0]),
           "max_abs_dq": float(np.abs(dq).max()), "velocity_ratio": float((np.abs(dq) / vlim).max())}
    for k in ("pointing_violation_max_deg", "ee_error_max_settled", "ee_error_rms", "d_minimal_min", "stack_changes"):
        if metrics.get(k) is not None:
            out[k] = metrics[k]
    return out


def same(a: Path, b: Path) -> bool:
    ta, tb = np.load(a / "trajectory.npz"), np.load(b / "trajectory.npz")
    return all(ta[k].shape == tb[k].shape and np.array_equal(ta[k], tb[k]) for k in ("q", "dq", "ddq"))


def run_one(sc, out: Path, vlim: np.ndarray) -> dict:
    """One scenario run into ``out`` and its numbers; a run stopped by an error gives its partial result's."""
    from hqp_tpm.app.cli import run_scenario
    from hqp_tpm.errors import HqpTpmError

    try:
        run_scenario(sc, out, progress=False, figures=False, replay=False, force=True)
    except HqpTpmError as exc:
        return row(Path(exc.partial_result or out), vlim, type(exc).__name__)
    return row(out, vlim)


def max_drift_acceleration(ctx, run_dir: Path) -> float:
    """The largest ``|Jdot_rp qdot| / ||J_rp||`` over the recorded states of a run (rad/s^2)."""
    from hqp_tpm.robot.state import State

    task = ctx.tasks["pointing"]
    st = State(ctx.robot)
    traj = np.load(run_dir / "trajectory.npz")
    q, dq = traj["q"], traj["dq"]
    st.update(q[0], dq[0], 0.0)
    task.start(st)
    worst = 0.0
    for qi, vi in zip(q, dq, strict=True):
        st.update(qi, vi, 0.0)
        J = task.jacobian(st)[0]
        n = float(np.linalg.norm(J))
        if n > 0:
            worst = max(worst, abs(float(task.jdot_qdot(st)[0])) / n)
    return worst


def main(argv=None) -> None:
    from hqp_tpm.app import scenario
    from hqp_tpm.app.build import build_run
    from hqp_tpm.app.sweep import Variant, make_variants, run_sweep, variant_scenario

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="keep the runs here (default: a temporary folder)")
    ap.add_argument("--workers", type=int, default=1, help="sweep processes (default 1)")
    args = ap.parse_args(argv)
    out = (args.out or Path(tempfile.mkdtemp(prefix="pointing_drift_"))).absolute()
    base = scenario.read(scenario.resolve_path(SCENARIO))
    shipped = build_run(scenario.parse(base, scenario.resolve_path(SCENARIO)))
    vlim = shipped.robot.velocity_limits()
    limit = shipped.tasks["pointing"].drift_limit
    bound = float(base["scenario"]["velocity_bound"])

    tables = {}
    for law, grid in (("limited", {}), ("paper", {k: [v] for k, v in PAPER.items()})):
        t0 = time.perf_counter()
        tables[law] = {r["variant"]: r for r in run_sweep(SCENARIO, out / f"sweep_{law}", grid=grid, ranges=RANGES,
                                                         n_random=N_RANDOM, seed=SEED, workers=args.workers)}
        print(f"sweep {law}: {time.perf_counter() - t0:.0f} s")
    variants = []
    for v in make_variants({}, RANGES, N_RANDOM, SEED):
        entry = {"name": v.name, "overrides": v.overrides}
        for law in ("limited", "paper"):
            r = tables[law][v.name]
            entry[law] = row(out / f"sweep_{law}" / v.name, vlim, r.get("error_type") or None)
        entry["identical"] = (entry["limited"]["status"] == entry["paper"]["status"] == "complete"
                              and same(out / "sweep_limited" / v.name, out / "sweep_paper" / v.name))
        variants.append(entry)

    ref_dir = out / "reference"
    reference = {**run_one(variant_scenario(base, SCENARIO, Variant("reference", {})), ref_dir, vlim),
                 "max_drift_acceleration": max_drift_acceleration(shipped, ref_dir)}

    extending = {}
    for name in EXTENDING:
        data = scenario.read(scenario.resolve_path(name))
        e_vlim = build_run(scenario.parse(data, scenario.resolve_path(name))).robot.velocity_limits()
        runs = {law: run_one(variant_scenario(data, name, Variant(law, extra)), out / f"{name}_{law}", e_vlim)
                for law, extra in (("limited", {}), ("paper", PAPER))}
        extending[name] = {**runs, "identical": same(out / f"{name}_limited", out / f"{name}_paper")}
        print(f"{name}: identical {extending[name]['identical']}")

    a3 = scenario.read(scenario.resolve_path("lwr_avoid3d"))
    a3_dir = out / "lwr_avoid3d_limited"
    a3_vlim = build_run(scenario.parse(a3, scenario.resolve_path("lwr_avoid3d"))).robot.velocity_limits()
    avoid3d = {"drift_limit": limit, **run_one(variant_scenario(a3, "lwr_avoid3d", Variant(
        "limited", {"tasks.pointing.drift_limit": limit})), a3_dir, a3_vlim)}

    v9 = make_variants({}, RANGES16, 10, 16)[9]
    seed16 = {"name": v9.name, "overrides": v9.overrides}
    for law, extra in (("limited", {}), ("paper", PAPER)):
        seed16[law] = run_one(variant_scenario(base, SCENARIO, Variant(v9.name, {**v9.overrides, **extra})),
                              out / f"seed16_{law}", vlim)

    from hqp_tpm.app.cli import run_scenario

    v3 = make_variants({}, RANGES, N_RANDOM, SEED)[3]
    pd = out / "v003_prefix"
    run_scenario(variant_scenario(base, SCENARIO, v3), pd, progress=False, figures=False, replay=False,
                 force=True, steps=PREFIX)
    prefix = {"name": v3.name, "steps": PREFIX, "max_abs_dq": float(np.abs(np.load(pd / "trajectory.npz")["dq"]).max())}

    both = [e for e in variants if e["paper"]["status"] == "complete"]
    summary = {
        "complete": {law: sum(e[law]["status"] == "complete" for e in variants) for law in ("limited", "paper")},
        "identical": sum(e["identical"] for e in variants),
        "max_abs_dq_range": [min(e["limited"]["max_abs_dq"] for e in variants),
                             max(e["limited"]["max_abs_dq"] for e in variants)],
        "ee_error_max_settled_change_max": max(abs(e["limited"]["ee_error_max_settled"]
                                                   - e["paper"]["ee_error_max_settled"]) for e in both),
        "ee_error_max_settled_max": max(e["limited"]["ee_error_max_settled"] for e in variants)}
    RESULTS.write_text(json.dumps({
        "command": "PYTHONPATH=$PWD python tools/pointing_drift_report.py",
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "sweep": {"scenario": SCENARIO, "random": N_RANDOM, "seed": SEED,
                  "ranges": {k: list(v) for k, v in RANGES.items()}, "drift_limit": limit,
                  "velocity_bound": bound, "velocity_limits": vlim.tolist()},
        "variants": variants, "reference": reference, "extending": extending,
        "avoid3d": avoid3d, "seed16_v009": seed16,
        "prefix": prefix, "summary": summary}, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
