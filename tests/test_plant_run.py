"""Runs closed through the MuJoCo plant (``[plant] kind = "mujoco"``): what ``hqp-tpm run`` writes, that the
recorded torques replay on ``plant.xml`` with MuJoCo alone, tracking against the kinematic run, scenario errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from hqp_tpm.app import build, plant_run, runner, scenario  # noqa: E402
from hqp_tpm.app.cli import main  # noqa: E402
from hqp_tpm.errors import ScenarioError  # noqa: E402


@pytest.fixture(scope="module")
def iiwa_runs(tmp_path_factory):
    """``hqp-tpm run iiwa_mujoco`` and its kinematic twin ``iiwa_first_controller``, full length (4 s, 4,000 steps)."""
    out = {}
    for name in ("iiwa_first_controller", "iiwa_mujoco"):
        folder = tmp_path_factory.mktemp(name) / "run"
        assert main(["run", name, "--out", str(folder), "--quiet", "--no-replay", "--no-figures"]) == 0
        out[name] = folder
    return out


def test_run_writes_plant_xml_torques_and_names_the_plant(iiwa_runs):
    folder = iiwa_runs["iiwa_mujoco"]
    assert (folder / "plant.xml").is_file()
    xml = (folder / "plant.xml").read_text()
    assert 'timestep="0.001"' in xml and 'integrator="Euler"' in xml
    data = np.load(folder / "trajectory.npz")
    for key in ("tau", "q", "dq", "t"):
        assert key in data.files
    assert data["tau"].shape == data["q"].shape == data["dq"].shape == (4001, 7)
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["plant"] == "mujoco" and metrics["plant_integrator"] == "euler"
    assert metrics["units"]["tau_max"] == "N m" and 0 < metrics["tau_max"] <= 176
    kin = iiwa_runs["iiwa_first_controller"]
    assert json.loads((kin / "metrics.json").read_text())["plant"] == "kinematic"
    assert not (kin / "plant.xml").exists() and "tau" not in np.load(kin / "trajectory.npz").files


def test_recorded_torques_replay_on_plant_xml_with_mujoco_alone(iiwa_runs):
    """Nothing of hqp-tpm: plant.xml, the first recorded state and the torques give the recorded q to 1e-6 rad."""
    folder = iiwa_runs["iiwa_mujoco"]
    data = np.load(folder / "trajectory.npz")
    model = mujoco.MjModel.from_xml_path(str(folder / "plant.xml"))
    state = mujoco.MjData(model)
    state.qpos[:], state.qvel[:] = data["q"][0], data["dq"][0]
    worst = 0.0
    for q, tau in zip(data["q"], data["tau"], strict=True):
        worst = max(worst, np.abs(state.qpos - q).max())
        state.ctrl[:] = tau
        mujoco.mj_step(model, state)
    assert worst <= 1e-6, worst


def test_physics_run_tracks_like_the_kinematic_run(iiwa_runs):
    """The README's stack on the plant: the EE ends within 0.5 mm of its target (measured 0.091 mm; kinematic
    0.015 mm) and its largest error is within 1.2x the kinematic run's."""
    err = {k: np.linalg.norm(np.load(f / "trajectory.npz")["error_ee"], axis=1) for k, f in iiwa_runs.items()}
    assert err["iiwa_mujoco"][-1] < 0.5e-3
    assert err["iiwa_mujoco"].max() <= 1.2 * err["iiwa_first_controller"].max()
    assert not np.array_equal(err["iiwa_mujoco"], err["iiwa_first_controller"])  # the loop did go through MuJoCo


def test_comanipulation_operator_force_acts_on_the_flange():
    """Velocity level through the joint impedance; the operator's hand force is the flange body's external wrench
    (its force part), and the controller's state is the plant's measurement after every step."""
    sc = scenario.load("iiwa_comanipulation_mujoco")
    ctx = build.build_run(sc)
    plant = plant_run.build_plant(ctx)
    assert plant.order == 1
    probes = [*ctx.probes(), plant_run.plant_probe(ctx, plant)]
    rec, _ = runner.run(ctx.controller, 900, probes=probes)
    arrays = rec.arrays()
    rec.discard()
    op = ctx.scene.operator
    assert np.linalg.norm(op.force) > 2.0  # the hand pulls from t = 0.5 s on
    body, _ = plant.frame_body(op.fid)
    assert np.array_equal(plant.data.xfrc_applied[body, :3], op.force)
    q, v = plant.measure()
    assert np.array_equal(ctx.controller.q, q) and np.array_equal(ctx.controller.v, v)
    assert np.abs(arrays["tau"]).max() > 0


@pytest.mark.parametrize("fields, where", [
    ({"kind": "bullet"}, "plant.kind"),
    ({"kind": "mujoco", "damping": -0.1}, "plant.damping"),
    ({"kind": "mujoco", "integrator": "verlet"}, "plant.integrator"),
    ({"kind": "mujoco", "delay": 1.5}, "plant.delay"),
    ({"kind": "mujoco", "seed": "one"}, "plant.seed"),
    ({"kind": "mujoco", "torque_limits": 1}, "plant.torque_limits"),
    ({"kind": "mujoco", "timestep": 3e-4}, "plant.timestep"),
    ({"kind": "mujoco", "noise_q": "nan"}, "plant.noise_q"),
    ({"kind": "mujoco", "dampling": 0.1}, "plant"),
    ({"kind": "kinematic", "damping": 0.1}, "plant.damping"),
])
def test_bad_plant_fields_name_file_and_field(fields, where):
    data = scenario.read(scenario.resolve_path("iiwa_first_controller"))
    data["plant"] = fields
    with pytest.raises(ScenarioError, match=rf"my\.toml\.{where.replace('.', '[.]')}"):
        scenario.parse(data, scenario.Path("my.toml"))


def test_no_plant_section_is_kinematic():
    assert scenario.load("iiwa_first_controller").plant.kind == "kinematic"
    sc = scenario.load("lwr_relaxed_mujoco")
    assert sc.plant.kind == "mujoco" and sc.plant.options.integrator == "euler"


def test_lwr_relaxed_on_the_plant_cross_checks_its_distances(tmp_path):
    """Algorithm 1's control-point distances against MuJoCo's on the plant (shortened: 1,000 of 18,850 steps); the
    distance queries between steps leave the simulation as it was (the torques still replay exactly)."""
    out = tmp_path / "run"
    assert main(["run", "lwr_relaxed_mujoco", "--out", str(out), "--quiet", "--no-replay", "--no-figures",
                 "--steps", "1000"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["plant"] == "mujoco" and metrics["distance_crosscheck_steps"] == 1000
    assert metrics["distance_crosscheck_max"] < 1e-9 and metrics["units"]["distance_crosscheck_max"] == "m"
    data = np.load(out / "trajectory.npz")
    from hqp_tpm.plants import replay_torques

    q = replay_torques((out / "plant.xml").read_text(), data["q"][0], data["dq"][0], data["tau"], 1e-3)
    assert np.abs(q - data["q"]).max() <= 1e-6
