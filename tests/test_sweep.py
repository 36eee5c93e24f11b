"""hqp-tpm sweep and campaign (issue 16): local processes and Dask, one code path; short horizons."""

import json
import pickle

import numpy as np
import pytest

from hqp_tpm.app import scenario, sweep
from hqp_tpm.app.cli import main, run_scenario
from hqp_tpm.errors import HqpTpmError, ScenarioError, SweepError

STEPS = 60
GRID = {"policy.d_m": [0.15, 0.25], "obstacles[0].center": [[0.9, 0.5, 0.0], [0.8, 0.6, 0.0]]}
SKIP = {"wall_time_s", "mean_step_us", "compile_s", "variant_wall_s", "out", "resumed"}


def run(tmp_path, **kw):
    args = {"grid": GRID, "steps": STEPS, "progress": False, "workers": 2, **kw}
    return sweep.run_sweep("planar5_exact", tmp_path / "sw", **args)


def stable(table):
    return [{k: v for k, v in r.items() if k not in SKIP} for r in table]


def test_parse_assignments():
    assert sweep.parse_assignment("policy.eps1=0.03,0.05") == ("policy.eps1", [0.03, 0.05], None)
    assert sweep.parse_assignment("obstacles.o1.center=[0,0.5,0.1],[0,0.5,0.2]") == (
        "obstacles.o1.center", [[0, 0.5, 0.1], [0, 0.5, 0.2]], None)
    assert sweep.parse_assignment("policy.eps1=0.02:0.08") == ("policy.eps1", None, (0.02, 0.08))
    assert sweep.parse_assignment("scenario.solver=qp:daqp,tpm")[1] == ["qp:daqp", "tpm"]
    with pytest.raises(SweepError, match="FIELD="):
        sweep.parse_assignment("policy.eps1")
    v = sweep.make_variants({"a.b": [1, 2]}, {"c.d": (0.0, 1.0)}, n_random=3, seed=7)
    assert len(v) == 6 and v == sweep.make_variants({"a.b": [1, 2]}, {"c.d": (0.0, 1.0)}, n_random=3, seed=7)


def test_sweep_equals_each_variant_run_alone_and_resumes(tmp_path):
    table = run(tmp_path)
    assert [r["status"] for r in table] == ["complete"] * 4 and not any(r["error"] for r in table)
    base = scenario.read(scenario.resolve_path("planar5_exact"))
    for r, v in zip(table, sweep.make_variants(GRID, {}), strict=True):
        assert r["variant"] == v.name
        alone = tmp_path / f"alone_{v.name}"
        run_scenario(sweep.variant_scenario(base, "planar5_exact", v), alone, steps=STEPS, progress=False,
                     figures=False, replay=False)
        with np.load(alone / "trajectory.npz") as a, np.load(tmp_path / "sw" / v.name / "trajectory.npz") as b:
            assert sorted(a.files) == sorted(b.files)
            for k in a.files:
                assert np.array_equal(a[k], b[k]), k  # bit-identical
        m = json.loads((tmp_path / "sw" / v.name / "manifest.json").read_text())
        assert m["status"] == "complete" and m["variant"]["overrides"] == v.overrides
    for f in ("summary.csv", "summary.md", "sweep.png", "sweep.json"):
        assert (tmp_path / "sw" / f).is_file()
    # resume: nothing re-runs; a removed variant runs again
    again = run(tmp_path)
    assert all(r.get("resumed") for r in again) and stable(again) == stable(table)
    import shutil

    shutil.rmtree(tmp_path / "sw" / "v002")
    third = run(tmp_path)
    assert [bool(r.get("resumed")) for r in third] == [True, True, False, True]
    assert stable(third) == stable(table)


def test_failing_variant_is_recorded_not_fatal(tmp_path):
    table = sweep.run_sweep("planar5_exact", tmp_path / "sw", grid={"policy.d_m": [0.2, -1.0]},
                            steps=20, progress=False, workers=0)
    ok, bad = table
    assert ok["status"] == "complete" and not ok["error"]
    assert bad["error_type"] and "planar5_exact[v001]" in bad["error"] and "d_m" in bad["error"]
    assert "planar5_exact[v001]" in (tmp_path / "sw" / "summary.md").read_text()


def test_field_that_resolves_nowhere_is_refused_before_any_work(tmp_path):
    with pytest.raises(SweepError, match=r"obstacles\.nope.*names: 'o1'"):
        sweep.run_sweep("planar5_exact", tmp_path / "sw", grid={"obstacles.nope.center": [[0, 0, 0]]}, workers=0)
    assert not (tmp_path / "sw").exists()


def test_everything_that_crosses_processes_pickles(tmp_path):
    v = sweep.make_variants(GRID, {})[0]
    base = scenario.read(scenario.resolve_path("planar5_exact"))
    job = sweep.Job(v, base, "planar5_exact", str(tmp_path / "x"), 5)
    sc = sweep.variant_scenario(base, "planar5_exact", v)
    for obj in (v, job, sc, ScenarioError("a.toml.policy.d_m: bad"), SweepError("x")):
        back = pickle.loads(pickle.dumps(obj))
        assert type(back) is type(obj)
    row = sweep.run_job(job)
    assert pickle.loads(pickle.dumps(row)) == row
    assert isinstance(pickle.loads(pickle.dumps(ScenarioError("m"))), HqpTpmError)


def test_dask_local_cluster_gives_the_same_table(tmp_path):
    pytest.importorskip("distributed")
    local = run(tmp_path / "a")
    dask = sweep.run_sweep("planar5_exact", tmp_path / "b" / "sw", grid=GRID, steps=STEPS, progress=False,
                           cluster="local:2")
    assert stable(dask) == stable(local)
    meta = json.loads((tmp_path / "b" / "sw" / "sweep_run.json").read_text())
    assert "LocalCluster" in meta["executor"]


def test_cli_sweep_and_campaign(tmp_path, capsys):
    assert main(["sweep", "planar5_exact", "--set", "policy.d_m=0.15,0.25", "--steps", "10", "--workers", "0",
                 "--out", str(tmp_path / "s"), "--quiet"]) == 0
    assert capsys.readouterr().out == ""  # quiet: summary.csv holds the table
    assert main(["sweep", "planar5_exact", "policy.d_m=0.1:0.3", "--random", "3", "--seed", "1", "--steps", "10",
                 "--workers", "0", "--out", str(tmp_path / "r"), "--quiet"]) == 0
    rows = (tmp_path / "r" / "summary.csv").read_text().splitlines()
    assert len(rows) == 4
    capsys.readouterr()
    assert main(["campaign", "sns", "--draws", "30", "--chunk", "10", "--workers", "2", "--quiet"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["draws"] == 30 and res["failed"] == {} and res["errors"] == []
    assert main(["campaign", "sns", "--replay", "7", "--seed", "0"]) == 0


def test_existing_dask_scheduler_by_address(tmp_path, monkeypatch):
    """--scheduler tcp://HOST:PORT: the sweep connects to a running cluster (here a LocalCluster's scheduler)."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as lc:
        table = sweep.run_sweep("planar5_exact", tmp_path / "sw", grid={"policy.d_m": [0.15, 0.25]}, steps=20,
                                progress=False, scheduler=lc.scheduler_address)
    assert [r["status"] for r in table] == ["complete", "complete"]
    monkeypatch.setattr(sweep, "CONNECT_TIMEOUT", 2)
    with pytest.raises(SweepError, match="cannot connect"):
        sweep.run_sweep("planar5_exact", tmp_path / "sw2", grid={"policy.d_m": [0.15]}, steps=5, progress=False,
                        scheduler="tcp://127.0.0.1:1")


def test_sweep_figure_is_readable(tmp_path):
    """Issue 32, item 5: 0d7b885's sweep.png had no title or units, offset notation ("1e-7+4.4475e-2"),
    wall_time_s plotted as a metric and the grid points of the second field indistinguishable."""
    table = [{"variant": f"v{k}", "tasks.ee.kp": kp, "lambda_max": lam, "error": None,
              "ee_error_max": 0.044475 + 1e-7 * k, "wall_time_s": 1.0 + k, "units": {"ee_error_max": "m"}}
             for k, (kp, lam) in enumerate((kp, lam) for kp in (10.0, 20.0, 40.0) for lam in (0.0, 0.05))]
    fig = sweep.figure(tmp_path / "s.png", table, ["tasks.ee.kp", "lambda_max"], ["ee_error_max", "wall_time_s"])
    assert (tmp_path / "s.png").is_file()
    assert fig.axes and len(fig.axes) == 2  # one metric row (no wall time) x two fields
    assert fig._suptitle is not None and "ee_error_max" in fig._suptitle.get_text()
    assert fig.axes[0].get_ylabel() == "ee_error_max [mm]"  # 0.044 m: 44.475 mm (scaled_unit)
    fig.canvas.draw()
    for ax in fig.axes:
        assert ax.yaxis.get_offset_text().get_text() == "" and ax.xaxis.get_offset_text().get_text() == ""
        assert "1e-7" not in " ".join(t.get_text() for t in ax.get_yticklabels())
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels == ["lambda_max = 0", "lambda_max = 0.05"], labels  # colour = the other field
    colours = {tuple(ln.get_markerfacecolor()) for ln in fig.axes[0].get_lines()}
    assert len(colours) == 2


def test_sweep_figure_small_metrics_equal_results_and_long_titles(tmp_path):
    """7f723e3's sweep.png, seen on `hqp-tpm sweep lwr_relaxed --set policy.eps1=0.05,0.07 --set
    policy.eps2=0.15,0.2,0.25`: "1e-3" multipliers over ee_error_rms [m], equal results of the colour groups
    drawn on top of each other (one colour seen), the title cut at both sides of the figure."""
    metrics = ["d_minimal_min", "d_ee_min", "ee_error_rms", "ee_error_max_settled", "pointing_violation_max_deg"]
    table = [{"variant": f"v{k}", "policy.eps1": e1, "policy.eps2": e2, "error": None,
              "d_minimal_min": 0.0629 + e1 / 100, "d_ee_min": 0.167239, "ee_error_rms": 0.0061262 - 0.0001 * e1,
              "ee_error_max_settled": 2.5e-4, "pointing_violation_max_deg": 6.3956,
              "units": {"d_minimal_min": "m", "d_ee_min": "m", "ee_error_rms": "m", "ee_error_max_settled": "m",
                        "pointing_violation_max_deg": "deg"}}
             for k, (e1, e2) in enumerate((a, b) for a in (0.05, 0.07) for b in (0.15, 0.2, 0.25))]
    fig = sweep.figure(tmp_path / "s.png", table, ["policy.eps1", "policy.eps2"], metrics)
    fig.canvas.draw()
    rows = {m: fig.axes[2 * i] for i, m in enumerate(metrics)}
    assert rows["ee_error_rms"].get_ylabel() == "ee_error_rms [mm]"
    assert rows["ee_error_max_settled"].get_ylabel() == "ee_error_max_settled [mm]"
    assert rows["d_ee_min"].get_ylabel() == "d_ee_min [m]"  # 0.167 m reads as it is
    assert rows["pointing_violation_max_deg"].get_ylabel() == "pointing_violation_max_deg [deg]"
    for ax in fig.axes:
        assert ax.yaxis.get_offset_text().get_text() == "" and ax.xaxis.get_offset_text().get_text() == ""
    ys = np.concatenate([ln.get_ydata() for ln in rows["ee_error_rms"].get_lines()])
    assert 6.0 < ys.min() and ys.max() < 6.2  # in mm
    # d_ee_min is equal for all: each colour group at its own x next to the grid value
    xs = [tuple(np.round(ln.get_xdata(), 6)) for ln in rows["d_ee_min"].get_lines()]
    assert len(xs) == 3 and len(set(xs)) == 3
    box = fig._suptitle.get_window_extent()
    assert box.x0 >= 0 and box.x1 <= fig.bbox.width, (box, fig.bbox.width)  # the title inside the figure
