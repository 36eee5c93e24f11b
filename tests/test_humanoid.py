"""A floating-base humanoid as a first-class case (issue 32, item 3): Talos from its half-sitting pose.

Each test failed on the code before (main at 0d7b885): ``Posture(talos, full_q)`` raised
``ShapeError: target has shape (39,), expected (32,)`` without the task or the fix, ``Robot.reference`` and the
scenario field ``[initial].reference`` did not exist, nor the scenario ``talos_sns_tpm``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm import Gains, Posture, Robot, ShapeError, UnknownNameError
from hqp_tpm.app import build, scenario
from hqp_tpm.errors import ScenarioError

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def talos():
    return Robot.load("talos")


def test_half_sitting_is_example_robot_datas_pose(talos):
    import example_robot_data as erd

    assert "half_sitting" in talos.references
    q = talos.reference("half_sitting")
    np.testing.assert_array_equal(q, erd.load("talos").q0)
    q[:] = 0.0  # a copy: the model's pose is untouched
    assert talos.reference("half_sitting")[2] > 0.9  # the base above the ground


def test_unknown_reference_lists_the_available_ones(talos):
    with pytest.raises(UnknownNameError, match="'sitting'.*'half_sitting'"):
        talos.reference("sitting")
    with pytest.raises(UnknownNameError, match="'lwr4' has none"):
        Robot.load("lwr4").reference("home")


def test_configuration_from_a_reference(talos):
    q = talos.configuration({"arm_left_4_joint": -1.0}, reference="half_sitting")
    ref = talos.reference("half_sitting")
    k = talos.model.joints[talos.model.getJointId("arm_left_4_joint")].idx_q
    assert q[k] == -1.0 and np.array_equal(np.delete(q, k), np.delete(ref, k))


def test_posture_takes_a_full_configuration(talos):
    q = talos.reference("half_sitting")
    task = Posture(talos, q, Gains(kp=1.0))
    assert task.dim == talos.nv - 6 == talos.nq - 7
    np.testing.assert_array_equal(task.reference(0.0)[0], q[7:])  # the joint angles, not the base
    arm = Posture(talos, q, joints=["arm_left_1_joint", "arm_right_1_joint"], name="arms")
    cols = [talos.model.joints[talos.model.getJointId(j)].idx_q for j in arm.joints]
    np.testing.assert_array_equal(arm.reference(0.0)[0], q[cols])
    # at the target, the error is zero
    state_q = pin.integrate(talos.model, q, np.zeros(talos.nv))
    assert np.abs(task.angles.difference(task.reference(0.0)[0], task.angles.of(state_q))).max() == 0.0


def test_posture_of_the_wrong_size_names_the_task_and_the_slice(talos):
    with pytest.raises(ShapeError, match=r"task 'legs'.*\(5,\).*\(32,\).*q\[7:39\].*\(39,\)"):
        Posture(talos, np.zeros(5), name="legs")
    with pytest.raises(ShapeError, match=r"task 'two'.*\(2,\).*q\[\[21, 37\]\]"):
        Posture(talos, np.zeros(3), joints=["arm_left_1_joint", "head_1_joint"], name="two")


def test_every_tasks_shape_error_names_the_task():
    from hqp_tpm import CenterOfMass

    with pytest.raises(ShapeError, match="task 'mine': target has shape"):
        CenterOfMass(None, np.zeros(5), name="mine")


def test_scenario_talos_starts_half_sitting_and_keeps_feet_and_limits():
    sc = scenario.load("talos_sns_tpm")
    ctx = build.build_run(sc)
    robot, ctrl = ctx.robot, ctx.controller
    np.testing.assert_array_equal(ctrl.q, robot.reference("half_sitting"))
    data = robot.model.createData()
    soles = [robot.frame_id(f) for f in ("left_sole_link", "right_sole_link")]

    def placements(q):
        pin.framesForwardKinematics(robot.model, data, q)
        return [data.oMf[f].copy() for f in soles]

    start = placements(ctrl.q)
    lo, up = robot.position_limits()
    vmax = robot.velocity_limits()
    for _ in range(40):
        res = ctrl.step()
        assert np.all(np.abs(res.command) <= vmax * (1 + 1e-9))
    for a, b in zip(start, placements(ctrl.q), strict=True):
        assert np.linalg.norm(pin.log6(a.actInv(b)).vector) < 1e-3  # soles held (kinematic: no contact model)
    angles = pin.difference(robot.model, robot.neutral(), ctrl.q)[6:]
    assert np.all(angles >= lo[6:] - 1e-9) and np.all(angles <= up[6:] + 1e-9)
    hand = ctx.tasks["left_hand"]
    assert np.linalg.norm(hand.tracking_error(ctrl.state, ctrl.state.t)) < 1e-3  # at the last step's state


def test_scenario_reference_of_a_robot_without_one_names_the_field(tmp_path):
    text = (scenario.SCENARIO_DIR / "romeo_tpm.toml").read_text()
    assert "[initial.joints_deg]" in text
    path = tmp_path / "s.toml"
    path.write_text(text.replace("[initial.joints_deg]", "[initial]\nreference = \"home\"\n\n[initial.joints_deg]", 1))
    with pytest.raises(ScenarioError, match=r"s\.toml\.initial\.reference: .*'home'"):
        build.build_run(scenario.load(path))


def test_example_script_runs():
    out = subprocess.run([sys.executable, str(ROOT / "examples" / "talos_humanoid.py"), "--steps", "20",
                          "--no-files"], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    errors = dict(line.split(": ") for line in out.stdout.splitlines())
    assert float(errors["left_foot"]) < 1e-3 and float(errors["left_hand"]) < 1e-3, errors
