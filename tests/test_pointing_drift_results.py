"""Issue 31, item 2, as measured: ``tests/data/pointing_drift_results.json`` (written by
``PYTHONPATH=$PWD python tools/pointing_drift_report.py``: the sweep of docs/sweeps.md,
``hqp-tpm sweep lwr_relaxed --random 20 --seed 1 "obstacles.o1.center=[0.07,0.47,0.07]:[0.13,0.53,0.13]"``, with
the pointing task's ``drift_limit`` as shipped and with papers/000's law as written; docs/pointing_drift.md quotes it).

With the limit every variant runs its 18,850 steps within the velocity bound; the law as written stops some at the
bound; where the limit never acts the two laws compute the same trajectory; the reference run's drift compensation
stays below the limit. The first steps of v003 are run again here, so the file is what this code computes.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "tests" / "data" / "pointing_drift_results.json"
SCENARIOS = ROOT / "hqp_tpm" / "data" / "scenarios"
STEPS = 18_850


@pytest.fixture(scope="module")
def data():
    return json.loads(RESULTS.read_text())


def test_the_sweep_is_the_documented_one_with_the_shipped_limit(data):
    sweep = data["sweep"]
    toml = tomllib.loads((SCENARIOS / "lwr_relaxed.toml").read_text())
    pointing = next(t for t in toml["tasks"] if t["name"] == "pointing")
    assert sweep["drift_limit"] == pointing["drift_limit"] and sweep["velocity_bound"] == toml["scenario"][
        "velocity_bound"]
    assert (sweep["scenario"], sweep["random"], sweep["seed"]) == ("lwr_relaxed", 20, 1)
    assert sweep["ranges"] == {"obstacles.o1.center": [[0.07, 0.47, 0.07], [0.13, 0.53, 0.13]]}
    assert [v["name"] for v in data["variants"]] == [f"v{i:03d}" for i in range(20)]


def test_with_the_limit_every_variant_completes_within_the_velocity_bound(data):
    bound = data["sweep"]["velocity_bound"]
    for v in data["variants"]:
        r = v["limited"]
        assert r["status"] == "complete" and r["error_type"] is None and r["steps"] == STEPS, v["name"]
        assert r["velocity_ratio"] < bound and r["max_abs_dq"] <= r["velocity_ratio"] * max(
            data["sweep"]["velocity_limits"]) + 1e-12, v["name"]


def test_papers_law_stops_some_at_the_bound_and_the_limit_acts_only_there_or_where_it_differs(data):
    bound = data["sweep"]["velocity_bound"]
    stopped = [v for v in data["variants"] if v["paper"]["status"] != "complete"]
    assert stopped, "the law as written no longer diverges in this sweep: the page's reason for the limit is gone"
    for v in stopped:
        p = v["paper"]
        assert p["status"] == "partial" and p["error_type"] == "DivergedError" and p["steps"] < STEPS
        assert p["velocity_ratio"] < bound  # the kept steps are those before the bound was left
        assert not v["identical"]
    for v in data["variants"]:
        if v["identical"]:  # same trajectory: the same metrics
            assert v["limited"] == v["paper"], v["name"]


def test_the_summary_is_the_variants(data):
    vs, s = data["variants"], data["summary"]
    assert s["complete"] == {law: sum(v[law]["status"] == "complete" for v in vs) for law in ("limited", "paper")}
    assert s["identical"] == sum(v["identical"] for v in vs)
    dq = [v["limited"]["max_abs_dq"] for v in vs]
    assert s["max_abs_dq_range"] == [min(dq), max(dq)]
    both = [v for v in vs if v["paper"]["status"] == "complete"]
    assert s["ee_error_max_settled_change_max"] == max(
        abs(v["limited"]["ee_error_max_settled"] - v["paper"]["ee_error_max_settled"]) for v in both)
    assert s["ee_error_max_settled_max"] == max(v["limited"]["ee_error_max_settled"] for v in vs)


def test_the_reference_run_never_reaches_the_limit_and_is_the_benchmarked_one(data):
    ref = data["reference"]
    assert ref["status"] == "complete" and ref["steps"] == STEPS
    assert 0 < ref["max_drift_acceleration"] < data["sweep"]["drift_limit"]
    bench = json.loads((ROOT / "benchmarks" / "results" / "scenarios.json").read_text())["scenarios"]["lwr_relaxed"]
    for key in ("pointing_violation_max_deg", "ee_error_max_settled", "d_minimal_min", "stack_changes"):
        assert ref[key] == pytest.approx(bench[key], rel=1e-9, abs=1e-12), key


def test_lwr_avoid3d_ships_without_the_limit_which_would_cost_its_pointing(data):
    toml = tomllib.loads((SCENARIOS / "lwr_avoid3d.toml").read_text())
    pointing = next(t for t in toml.get("tasks", []) if t.get("name") == "pointing")
    assert pointing["drift_limit"] is False
    bench = json.loads((ROOT / "benchmarks" / "results" / "scenarios.json").read_text())["scenarios"]["lwr_avoid3d"]
    a3 = data["avoid3d"]
    assert a3["status"] == "complete" and a3["steps"] == STEPS
    assert a3["pointing_violation_max_deg"] > bench["pointing_violation_max_deg"]


def test_the_three_obstacle_variant_completes_with_the_limit(data):
    v9 = data["seed16_v009"]
    assert v9["limited"]["status"] == "complete" and v9["limited"]["steps"] == STEPS
    assert v9["limited"]["velocity_ratio"] < data["sweep"]["velocity_bound"]
    assert v9["paper"]["error_type"] == "DivergedError" and v9["paper"]["steps"] < STEPS


def test_the_file_is_this_codes(data, tmp_path):
    """v003's first steps with the limit, run again: the same largest |qdot| to the last digits."""
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import pointing_drift_report as report
    finally:
        sys.path.remove(str(ROOT / "tools"))
    from hqp_tpm.app import scenario
    from hqp_tpm.app.cli import run_scenario
    from hqp_tpm.app.sweep import make_variants, variant_scenario

    pre = data["prefix"]
    v = make_variants({}, report.RANGES, report.N_RANDOM, report.SEED)[3]
    assert v.name == pre["name"] and v.overrides == data["variants"][3]["overrides"]
    base = scenario.read(scenario.resolve_path("lwr_relaxed"))
    run_scenario(variant_scenario(base, "lwr_relaxed", v), tmp_path / "run", progress=False, figures=False,
                 replay=False, steps=pre["steps"])
    dq = np.load(tmp_path / "run" / "trajectory.npz")["dq"]
    assert dq.shape[0] == pre["steps"]
    assert np.abs(dq).max() == pytest.approx(pre["max_abs_dq"], rel=0, abs=1e-12)


def test_the_scenarios_extending_lwr_relaxed_are_unchanged_by_the_limit(data):
    """lwr_point35_equality, lwr_point35_inequality and lwr_relaxed_mujoco inherit the limit; it never acts there
    (same trajectories both ways), so their benchmarked numbers are papers/000's law's."""
    bench = json.loads((ROOT / "benchmarks" / "results" / "scenarios.json").read_text())["scenarios"]
    assert set(data["extending"]) == {"lwr_point35_equality", "lwr_point35_inequality", "lwr_relaxed_mujoco"}
    for name, e in data["extending"].items():
        assert e["identical"] and e["limited"]["status"] == "complete" and e["limited"]["steps"] == STEPS, name
        assert e["limited"] == e["paper"], name
        for key in ("pointing_violation_max_deg", "d_minimal_min", "stack_changes"):
            assert e["limited"][key] == pytest.approx(bench[name][key], rel=1e-9, abs=1e-12), (name, key)
