"""Figures: written without pyplot (the user's backend is never switched), one axis per unit, labelled."""

import json
import subprocess
import sys

import numpy as np
import pytest


def test_importing_and_writing_figures_leaves_the_backend_alone(tmp_path):
    code = f"""
import sys, matplotlib
matplotlib.use("svg")  # a user's choice
import numpy as np
from hqp_tpm.app import figures
arrays = {{"t": np.linspace(0, 1, 50), "dq": np.random.default_rng(0).normal(size=(50, 3)),
          "joint_names": np.array(["a", "b", "c"])}}
figures.joint_velocities(r"{tmp_path / 'jv.png'}", arrays, [1.0, np.inf, 2.0], "test")
assert matplotlib.get_backend().lower() == "svg", matplotlib.get_backend()
assert "matplotlib.pyplot" not in sys.modules
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "jv.png").stat().st_size > 5000


@pytest.fixture(scope="module")
def romeo_short(tmp_path_factory):
    from hqp_tpm.app.cli import run_scenario

    out = tmp_path_factory.mktemp("romeo_sns_tpm")
    summary = run_scenario("romeo_sns_tpm", out, steps=150, progress=False, replay=False)
    return out, summary


def test_task_errors_one_axis_per_unit(romeo_short):
    from hqp_tpm.app import build, scenario
    from hqp_tpm.app.figures import error_groups

    _, _, tasks, _ = build.build(scenario.load("romeo_sns_tpm"))
    groups = error_groups(tasks)
    units = {name: {u for n, _, _, u in groups if n == name} for name in tasks}
    assert units["right_sole"] == {"m", "rad"}  # a pose: position and orientation on their own axes
    assert units["com"] == {"m"} and units["left_hand"] == {"m"}
    out, summary = romeo_short
    assert {"joint_velocities.png", "task_errors.png"} <= {p.name for p in out.glob("*.png")}
    assert [f.split("/")[-1] for f in summary["files"]] == ["trajectory.npz", "metrics.json", "joint_velocities.png",
                                                             "task_errors.png", "ee_path.png", "manifest.json"]


def test_metrics_once_each_with_units(romeo_short):
    from hqp_tpm.app import build, scenario
    from hqp_tpm.app.results import METRICS, schema_key

    out, _ = romeo_short
    m = json.loads((out / "metrics.json").read_text())
    _, _, tasks, _ = build.build(scenario.load("romeo_sns_tpm"))
    for key in m:
        assert schema_key(key, tasks) is not None, f"{key} is not in the metrics schema"
    assert "error_right_sole_position_max" in m and "error_right_sole_max" not in m
    numeric = [k for k, v in m.items() if isinstance(v, (int, float)) and not isinstance(v, bool)]
    assert set(numeric) <= set(m["units"]), set(numeric) - set(m["units"])
    assert m["units"]["error_right_sole_orientation_max"] == "rad" and m["units"]["mean_step_us"] == "µs"
    # no two metrics are the same number under two names (ee_error_* vs error_ee_* was)
    assert len(METRICS) == len(set(METRICS))


def test_lwr_metrics_have_no_duplicates(tmp_path):
    from hqp_tpm.app.cli import run_scenario

    m = run_scenario("lwr_relaxed", tmp_path, steps=300, progress=False, figures=True, replay=False)
    assert "ee_error_max" in m and "error_ee_max" not in m and "pointing_violation_max" not in m
    assert "error_pointing_max" not in m and "pointing_violation_max_deg" in m
    values = [(k, v) for k, v in m.items() if isinstance(v, float) and not k.endswith("_settled")]
    dup = [(a, b) for i, (a, x) in enumerate(values) for b, y in values[i + 1:] if x == y and x not in (0.0, 1.0)]
    assert not dup, dup
    assert (tmp_path / "pointing_error.png").is_file() and (tmp_path / "distances.png").is_file()
    assert np.isfinite(m["d_minimal_min"])


def test_wrote_line_names_every_file_written(tmp_path, capsys):
    from hqp_tpm.app.cli import main

    out = tmp_path / "run"
    assert main(["run", "planar5_exact", "--steps", "200", "--out", str(out)]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith(f"wrote {out}/: ")
    named = set(last.split(": ", 1)[1].split(", "))
    assert named == {p.name for p in out.iterdir()}, (named, sorted(p.name for p in out.iterdir()))


def test_task_errors_show_which_stack_is_active_when(tmp_path):
    """Issue 32, item 5: 0d7b885's figures did not show the active stack over time (only metrics.json's
    time_in_stack_s). The timeline's spans add up to those times; every stack has its row, labelled."""
    import json

    from hqp_tpm.app.build import build_run
    from hqp_tpm.app.cli import main
    from hqp_tpm.app.figures import stack_spans, task_errors
    from hqp_tpm.app.scenario import load

    out = tmp_path / "run"
    assert main(["run", "lwr_relaxed", "--steps", "2500", "--out", str(out), "--quiet", "--no-replay"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    with np.load(out / "trajectory.npz") as npz:
        arrays = {k: npz[k] for k in ("t", "stack", "error_ee", "error_pointing")}
    spans = stack_spans(arrays["t"], arrays["stack"])
    assert len(spans) >= 2 and set(spans) == set(metrics["time_in_stack_s"])
    for label, seconds in metrics["time_in_stack_s"].items():
        assert abs(sum(w for _, w in spans[label]) - seconds) < 1e-9, label
    ctx = build_run(load("lwr_relaxed"))
    fig = task_errors(tmp_path / "e.png", arrays, ctx.tasks, "t")
    panel = fig.axes[-1]
    assert panel.get_ylabel() == "active stack"
    texts = [t.get_text() for t in panel.texts]
    assert all(any(t.startswith(f"{label}  (") for t in texts) for label in spans), texts


def test_pointing_legend_says_inequality_or_equality(tmp_path):
    """0d7b885 called alpha_d "the equality's target" in the inequality scenario lwr_relaxed as well."""
    from hqp_tpm.app.figures import pointing_error

    t = np.linspace(0.0, 1.0, 50)
    arrays = {"t": t, "pointing_error": 0.01 * np.sin(t), "stack": np.array(["ee > pointing"] * 50)}
    for inequality, says in ((True, "inequality's bound"), (False, "equality's target")):
        fig = pointing_error(tmp_path / "p.png", arrays, np.deg2rad(5.0), "p", inequality=inequality)
        legend = [x.get_text() for x in fig.axes[0].get_legend().get_texts()]
        assert any(says in x for x in legend) and not any(
            ("equality's target" if inequality else "inequality") in x for x in legend), legend


def test_ee_path_in_3d(tmp_path):
    """Issue 32, item 5: the LWR run draws the EE's path in Cartesian space (0d7b885 had no such figure): the
    red line is the recorded EE (forward kinematics of the recorded q), the green one the task's reference."""
    import pinocchio as pin

    from hqp_tpm.app import runner
    from hqp_tpm.app.build import build_run
    from hqp_tpm.app.figures import ee_path, write_all
    from hqp_tpm.app.scenario import load

    ctx = build_run(load("lwr_relaxed"))
    rec, _ = runner.run(ctx.controller, 300, probes=ctx.probes(), recording=runner.Recording(
        ctx.robot.joint_names, tmp_path / "rec"))
    arrays = rec.load()
    fig = ee_path(tmp_path / "p.png", arrays, ctx.robot, ctx.scene, "p")
    ax = fig.axes[0]
    assert ax.name == "3d"
    lines = {ln.get_label(): np.array(ln.get_data_3d()).T for ln in ax.get_lines()}
    ee, desired = lines["EE (lwr_ee)"], lines["desired (ee)"]
    model, data = ctx.robot.model, ctx.robot.model.createData()
    for k in (0, len(ee) - 1):
        pin.framesForwardKinematics(model, data, np.asarray(arrays["q"][k]))
        np.testing.assert_allclose(ee[k], data.oMf[ctx.robot.frame_id("lwr_ee")].translation, atol=1e-12)
        np.testing.assert_allclose(desired[k], ctx.tasks["ee"].reference(float(arrays["t"][k]))[0], atol=1e-12)
    assert "ee_path.png" in {p.name for p in write_all(tmp_path, dict(arrays), ctx)}


def test_humanoid_figures_read_at_a_glance(tmp_path):
    """7f723e3's figures of talos_sns_tpm: the legend of five tasks lay on their curves, a numerically zero foot
    orientation error (1e-18 at t = 0) stretched the angle axis down to 1e-20, the active stack's label was
    written across its bar, and no path figure was written (the hands' circles had none)."""
    from matplotlib.transforms import Bbox

    from hqp_tpm.app import runner
    from hqp_tpm.app.build import build_run
    from hqp_tpm.app.figures import task_errors, write_all
    from hqp_tpm.app.scenario import load

    ctx = build_run(load("talos_sns_tpm"))
    rec, _ = runner.run(ctx.controller, 60, probes=ctx.probes(), recording=runner.Recording(
        ctx.robot.joint_names, tmp_path / "rec"))
    arrays = rec.load()
    assert "ee_path.png" in {p.name for p in write_all(tmp_path, dict(arrays), ctx)}
    fig = task_errors(tmp_path / "e.png", arrays, ctx.tasks, "t")
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    error_axes = [ax for ax in fig.axes if ax.get_yscale() == "log"]
    assert len(error_axes) == 2  # m and rad
    for ax in error_axes:
        assert ax.get_legend().get_window_extent().x0 >= ax.get_window_extent().x1  # right of the data
        lo, hi = ax.get_ylim()
        assert lo >= 1e-9 * hi, (ax.get_ylabel(), lo, hi)  # at most 9 decades
    panel = fig.axes[-1]
    assert panel.get_ylabel() == "active stack"
    bars = [Bbox(p.get_extents(c.get_transform()).get_points()) for c in panel.collections for p in c.get_paths()]
    texts = [t.get_window_extent(renderer) for t in panel.texts]
    assert bars and texts
    assert not any(t.overlaps(b) for t in texts for b in bars), "a stack's label lies on a bar"
