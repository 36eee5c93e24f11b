"""The MuJoCo plant (hqp_tpm.plants): its model equals the controller's, joints map by name on fixed and floating
robots, the free-joint conventions convert both ways, the torque laws and the unmodelled effects do what they say."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

mujoco = pytest.importorskip("mujoco")

from hqp_tpm.errors import ParameterError, PlantError, ShapeError  # noqa: E402
from hqp_tpm.plants import MujocoPlant, PlantOptions, conventions  # noqa: E402
from hqp_tpm.plants.mjcf import compile_xml  # noqa: E402
from hqp_tpm.robot.model import Robot  # noqa: E402


@pytest.fixture(scope="module")
def iiwa():
    return Robot.load("iiwa7")


@pytest.fixture(scope="module")
def talos():
    """A floating-base robot whose MuJoCo joint order differs from pinocchio's (collision meshes are STL)."""
    return Robot.load("talos")


def random_state(robot, rng):
    """A configuration inside the joint limits (a random base pose for a free-flyer), a velocity, an acceleration."""
    lo, up = robot.model.lowerPositionLimit.copy(), robot.model.upperPositionLimit.copy()
    if robot.has_free_flyer:
        lo[:7], up[:7] = -1.0, 1.0
    q = lo + (up - lo) * rng.random(robot.nq)
    if robot.has_free_flyer:
        q[3:7] /= np.linalg.norm(q[3:7])
    return q, rng.standard_normal(robot.nv), rng.standard_normal(robot.nv)


def full_mass_matrix(model, data) -> np.ndarray:
    M = np.zeros((model.nv, model.nv))
    try:
        mujoco.mj_fullM(model, data, M)  # MuJoCo 4
    except TypeError:
        mujoco.mj_fullM(model, M, data.qM)  # MuJoCo 3
    return M


def at_state(plant, q, v, a=None):
    """MuJoCo's data of the plant's own model text at pinocchio's (q, v) (and qacc from a)."""
    model = compile_xml(plant.xml)
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = plant.map.q_to_mujoco(q), plant.map.v_to_mujoco(q, v)
    if a is not None:
        data.qacc[:] = plant.map.a_to_mujoco(q, v, a)
    return model, data


@pytest.mark.parametrize("name", ["iiwa7", "lwr4", "talos"])
def test_mass_matrix_of_plant_xml_equals_pinocchio(name, iiwa, talos):
    """No unmodelled effect: ``plant.xml``'s mass matrix is pinocchio's to 1e-8 (the floating base through
    ``M_pin = T^T M_mj T``, ``v_mj = T v_pin``). Written with 6 digits (MuJoCo's to_xml) it was 3.3e-8 off."""
    robot = {"iiwa7": iiwa, "talos": talos}.get(name) or Robot.load(name)
    plant = MujocoPlant(robot, 1e-3, 2)
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(10):
        q, v, _ = random_state(robot, rng)
        model, data = at_state(plant, q, v)
        mujoco.mj_forward(model, data)
        T = plant.map.velocity_matrix(q)
        M_pin = pin.crba(robot.model, robot.model.createData(), q)
        M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
        worst = max(worst, np.abs(T.T @ full_mass_matrix(model, data) @ T - M_pin).max())
    assert worst < 1e-8, worst


@pytest.mark.parametrize("name", ["iiwa7", "talos"])
def test_rnea_equals_mj_inverse(name, iiwa, talos):
    """pinocchio's inverse dynamics (the acceleration-level torque law) equals MuJoCo's on the plant's model,
    the free joint's acceleration and force converted by hqp_tpm.plants.conventions."""
    robot = iiwa if name == "iiwa7" else talos
    plant = MujocoPlant(robot, 1e-3, 2)
    rng = np.random.default_rng(1)
    for _ in range(5):
        q, v, a = random_state(robot, rng)
        model, data = at_state(plant, q, v, a)
        mujoco.mj_inverse(model, data)
        assert not np.any(data.qfrc_constraint)  # inside the limits, no contact: the two are the same problem
        tau_mj = plant.map.force_from_mujoco(q, data.qfrc_inverse)
        tau = pin.rnea(robot.model, robot.model.createData(), q, v, a)
        assert np.abs(tau_mj - tau).max() < 1e-8 * max(1.0, np.abs(tau).max())


@pytest.mark.parametrize("name", ["iiwa7", "talos"])
def test_joints_map_by_name(name, iiwa, talos):
    """Every link is where pinocchio puts it and moves as pinocchio says, at random states: positions and
    velocities (the free joint's world-frame linear velocity included) map joint by joint, by name."""
    robot = iiwa if name == "iiwa7" else talos
    plant = MujocoPlant(robot, 1e-3, 2)
    if name == "talos":  # the orders differ: a mapping by index would be wrong
        assert not np.array_equal(plant.map.v_pin, plant.map.v_mj - 0)
        assert plant.map.free is not None
    model, data = plant.model, plant.data
    pdata = robot.model.createData()
    rng = np.random.default_rng(2)
    bodies = [b for b in range(1, model.nbody) if robot.model.existFrame(model.body(b).name)]
    assert len(bodies) >= 8
    for _ in range(3):
        q, v, _ = random_state(robot, rng)
        data.qpos[:], data.qvel[:] = plant.map.q_to_mujoco(q), plant.map.v_to_mujoco(q, v)
        mujoco.mj_forward(model, data)
        pin.forwardKinematics(robot.model, pdata, q, v)
        pin.updateFramePlacements(robot.model, pdata)
        for b in bodies:
            fid = robot.model.getFrameId(model.body(b).name)
            assert np.allclose(data.xpos[b], pdata.oMf[fid].translation, atol=1e-12)
            assert np.allclose(data.xmat[b].reshape(3, 3), pdata.oMf[fid].rotation, atol=1e-12)
            vel = np.zeros(6)
            mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, b, vel, 0)  # [w, v] at xipos, world axes
            vel[3:] += np.cross(vel[:3], data.xpos[b] - data.xipos[b])  # at the body's origin (pinocchio's frame)
            twist = pin.getFrameVelocity(robot.model, pdata, fid, pin.LOCAL_WORLD_ALIGNED)
            assert np.allclose(vel, np.concatenate([twist.angular, twist.linear]), atol=1e-10)
        assert np.allclose(plant.map.q_from_mujoco(data.qpos), q, atol=1e-15)
        assert np.allclose(plant.map.v_from_mujoco(q, data.qvel), v, atol=1e-14)


def test_free_joint_conventions():
    """wxyz <-> xyzw; the linear velocity to the world frame and back; a force converts so that the power is the same
    on both sides (the duality that makes the force rule the velocity rule)."""
    rng = np.random.default_rng(3)
    q7 = np.concatenate([rng.standard_normal(3), (u := rng.standard_normal(4)) / np.linalg.norm(u)])
    qpos = conventions.free_position_to_mujoco(q7)
    assert np.array_equal(qpos[3:], [q7[6], q7[3], q7[4], q7[5]])
    assert np.array_equal(conventions.free_position_from_mujoco(qpos), q7)
    R = pin.Quaternion(q7[6], *q7[3:6]).toRotationMatrix()  # pinocchio's own quaternion (w, x, y, z constructor)
    assert np.allclose(conventions.rotation_xyzw(q7[3:7]), R, atol=1e-15)
    v, f = rng.standard_normal(6), rng.standard_normal(6)
    v_mj = conventions.free_motion_to_mujoco(q7, v)
    assert np.allclose(v_mj[:3], R @ v[:3]) and np.array_equal(v_mj[3:], v[3:])
    assert np.allclose(conventions.free_motion_from_mujoco(q7, v_mj), v, atol=1e-15)
    assert np.isclose(conventions.free_motion_to_mujoco(q7, f) @ v_mj, f @ v)


def test_unmodelled_armature_and_damping_reach_the_plant_only(iiwa):
    """The options change MuJoCo's model (armature on the mass matrix diagonal, damping as a passive force) and
    nothing of the controller's."""
    plant = MujocoPlant(iiwa, 1e-3, 2, PlantOptions(armature=0.01, damping=0.1, friction=0.2))
    q, v, _ = random_state(iiwa, np.random.default_rng(4))
    model, data = at_state(plant, q, v)
    mujoco.mj_forward(model, data)
    M_pin = pin.crba(iiwa.model, iiwa.model.createData(), q)
    M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
    assert np.allclose(full_mass_matrix(model, data) - M_pin, 0.01 * np.eye(7), atol=1e-12)
    assert np.allclose(data.qfrc_passive, -0.1 * v, atol=1e-12)
    assert np.allclose(model.dof_frictionloss, 0.2)
    assert not np.any(np.asarray(iiwa.model.armature))


def test_torque_limits_from_the_urdf(iiwa):
    """Torques are clipped to the URDF's effort (176, 176, 110, 110, 110, 40, 40 N m) when asked, not otherwise."""
    effort = np.asarray(iiwa.model.effortLimit)
    big = 1e4 * np.ones(7)
    limited = MujocoPlant(iiwa, 1e-3, 2)
    assert np.array_equal(limited.apply(big), effort)
    assert np.array_equal(limited.data.ctrl, effort)
    free = MujocoPlant(iiwa, 1e-3, 2, PlantOptions(torque_limits=False))
    assert np.array_equal(free.apply(big), big)


def test_inverse_dynamics_holds_the_arm_still(iiwa):
    """Zero acceleration command: rnea's gravity torques hold the arm where it is (Euler, 1 s) to 1e-9 rad."""
    plant = MujocoPlant(iiwa, 1e-3, 2)
    q0 = np.deg2rad([0, 30, 0, -60, 0, 90, 0])
    plant.reset(q0)
    for _ in range(1000):
        plant.step(np.zeros(7))
    q, v = plant.state()
    assert np.abs(q - q0).max() < 1e-9 and np.abs(v).max() < 1e-8


def test_joint_impedance_follows_a_velocity_command(iiwa):
    """Velocity level: a constant qd is followed (the integrated command reached to 1e-6 rad after 1 s). With a
    joint damping ``d`` the controller does not know, it lags by the computed-torque PD's steady error
    ``e = M^-1 d qd / kp`` once settled (kp M e balances d qd): 0.07 rad on the light joint 7 for d = 0.05,
    kp = 400."""
    q0 = np.deg2rad([0, 30, 0, -60, 0, 90, 0])
    qd = np.array([0.1, -0.1, 0.2, 0.1, -0.2, 0.1, 0.3])
    plant = MujocoPlant(iiwa, 1e-3, 1)
    plant.reset(q0)
    for _ in range(1000):
        plant.step(qd)
    q, v = plant.state()
    assert np.abs(q - (q0 + qd)).max() < 1e-6 and np.abs(v - qd).max() < 1e-5
    plant = MujocoPlant(iiwa, 1e-3, 1, PlantOptions(damping=0.05))
    plant.reset(q0)
    for _ in range(2000):
        plant.step(qd)
    q, v = plant.state()
    M = pin.crba(iiwa.model, iiwa.model.createData(), q)
    M = np.triu(M) + np.triu(M, 1).T
    lag = np.linalg.solve(M, 0.05 * qd) / 400.0
    assert np.abs((q0 + 2 * qd) - q - lag).max() < 0.05 * np.abs(lag).max(), ((q0 + 2 * qd) - q, lag)


def test_sensor_noise_is_seeded_and_delay_is_k_steps(iiwa):
    q0 = np.deg2rad([0, 30, 0, -60, 0, 90, 0])
    tau = np.array([5.0, 0, 0, 0, 0, 0, 0])
    runs = []
    for seed in (7, 7, 8):
        plant = MujocoPlant(iiwa, 1e-3, 2, PlantOptions(noise_q=1e-3, noise_v=1e-2, seed=seed))
        plant.reset(q0)
        plant.apply(tau)
        q_m, v_m = plant.measure()
        q, v = plant.state()
        runs.append(q_m)
        assert 0 < np.abs(q_m - q).max() < 6e-3 and 0 < np.abs(v_m - v).max() < 6e-2
    assert np.array_equal(runs[0], runs[1]) and not np.array_equal(runs[0], runs[2])
    plant = MujocoPlant(iiwa, 1e-3, 2, PlantOptions(delay=3))
    plant.reset(q0)
    truth = [plant.state()[0]]
    for _ in range(6):
        plant.apply(tau)
        truth.append(plant.state()[0])
        assert np.array_equal(plant.measure()[0], truth[max(0, len(truth) - 1 - 3)])


def test_substeps_and_integrator_are_in_the_model(iiwa):
    plant = MujocoPlant(iiwa, 1e-3, 2, PlantOptions(timestep=2.5e-4, integrator="rk4"))
    assert plant.substeps == 4
    assert plant.model.opt.timestep == 2.5e-4 and plant.model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    assert 'integrator="RK4"' in plant.xml and 'timestep="0.00025"' in plant.xml
    plant.apply(np.zeros(7))
    assert plant.time == pytest.approx(1e-3, abs=1e-15)
    with pytest.raises(ParameterError, match="timestep"):
        MujocoPlant(iiwa, 1e-3, 2, PlantOptions(timestep=3e-4))


def test_push_is_a_force_at_the_frame(iiwa):
    """``push(frame, f)``: MuJoCo's generalized force from xfrc_applied is ``J(frame)^T f`` (pinocchio's Jacobian
    of the frame origin, world axes)."""
    plant = MujocoPlant(iiwa, 1e-3, 2)
    q = np.deg2rad([10, 30, -20, -60, 15, 90, 5])
    plant.reset(q)
    model, data = plant.model, plant.data
    mujoco.mj_forward(model, data)
    base = data.qfrc_smooth.copy()
    f = np.array([3.0, -2.0, 5.0])
    for frame in ("iiwa_ee", "iiwa_link_5"):
        plant.push(frame, f)
        mujoco.mj_forward(model, data)
        pdata = iiwa.model.createData()
        pin.computeJointJacobians(iiwa.model, pdata, q)
        pin.updateFramePlacements(iiwa.model, pdata)
        J = pin.getFrameJacobian(iiwa.model, pdata, iiwa.frame_id(frame), pin.LOCAL_WORLD_ALIGNED)[:3]
        assert np.allclose(data.qfrc_smooth - base, J.T @ f, atol=1e-10)
        data.xfrc_applied[:] = 0


def test_bad_inputs_are_typed_errors(iiwa):
    with pytest.raises(ParameterError, match="damping"):
        PlantOptions(damping=-1.0)
    with pytest.raises(ParameterError, match="integrator"):
        PlantOptions(integrator="verlet")
    with pytest.raises(ParameterError, match="delay"):
        PlantOptions(delay=1.5)
    plant = MujocoPlant(iiwa, 1e-3, 2)
    with pytest.raises(ShapeError):
        plant.step(np.zeros(6))
    with pytest.raises(PlantError, match="no URDF"):
        MujocoPlant(Robot(iiwa.model, name="bare"), 1e-3, 2)


def test_mujoco_distances_equal_the_distance_field(iiwa):
    """The cross-check of runs with a distance field (hqp_tpm.plants.distances): MuJoCo's mj_geomDistance on the
    plant's capsules and the field's coal distances (capsules vs box, capsule and sphere obstacles; control points
    in closed form) agree at random states, and differ as soon as the plant is elsewhere."""
    from hqp_tpm.geometry.distances import DistanceField
    from hqp_tpm.geometry.obstacles import Obstacle
    from hqp_tpm.plants.distances import DistanceCheck, field_geoms

    obstacles = [Obstacle.box("box", [0.5, 0.3, 0.4], [0.1, 0.05, 0.2]),
                 Obstacle.capsule("bar", [-0.4, -0.4, 0.2], [-0.4, 0.4, 0.6], 0.05),
                 Obstacle.sphere("ball", [0.3, -0.4, 0.9], 0.1), Obstacle.sphere("dot", [0.0, 0.5, 0.5])]
    field = DistanceField(iiwa.model, iiwa.collision_model, ["iiwa_ee", "iiwa_elbow"], obstacles, surveillance=10.0)
    assert "geometry" in field.kinds and "point" in field.kinds
    plant = MujocoPlant(iiwa, 1e-3, 2, geoms=field_geoms(iiwa, field))
    check = DistanceCheck(plant, field)
    assert check.pairs == len(field.names) * len(obstacles)
    data = iiwa.model.createData()
    rng = np.random.default_rng(5)
    for _ in range(5):
        q, _, _ = random_state(iiwa, rng)
        pin.forwardKinematics(iiwa.model, data, q)
        pin.updateFramePlacements(iiwa.model, data)
        field.update(data)
        plant.reset(q)
        assert field.computed.all()
        worst = check()
        assert worst < 1e-6, worst
    plant.reset(q + 0.01)
    assert check() > 1e-3
    # the added geoms carry no mass and no contact: the dynamics are the robot's
    assert np.all(plant.model.geom_contype == 0) and plant.model.nbody == MujocoPlant(iiwa, 1e-3, 2).model.nbody


def test_floating_base_falls_freely(talos):
    """Talos without a floor and without torques falls as one body: after n Euler steps the base is
    ``g T^2 n (n+1) / 2`` lower, its orientation unchanged, and the measured velocity (pinocchio's body frame) is
    ``R^T (0, 0, -g n T)``: the free joint converted both ways along the plant's own path."""
    plant = MujocoPlant(talos, 1e-3, 2, PlantOptions(collision=False))
    q0 = talos.neutral()
    q0[:3] = [0.1, -0.2, 1.0]
    q0[3:7] = [0.1, -0.2, 0.3, 0.9] / np.linalg.norm([0.1, -0.2, 0.3, 0.9])
    plant.reset(q0)
    n, g = 100, 9.81
    for _ in range(n):
        plant.apply(np.zeros(talos.nv))
    q, v = plant.measure()
    R = pin.Quaternion(q0[6], *q0[3:6]).toRotationMatrix()
    assert q[2] == pytest.approx(1.0 - g * 1e-6 * n * (n + 1) / 2, abs=1e-12)
    assert np.allclose(q[3:7], q0[3:7], atol=1e-12) and np.allclose(q[7:], q0[7:], atol=1e-12)
    assert np.allclose(v[:3], R.T @ [0.0, 0.0, -g * n * 1e-3], atol=1e-10) and np.abs(v[3:]).max() < 1e-10


def test_contact_geoms_touch_the_floor_only(iiwa):
    """An added geom with ``contact`` (a sole for a robot built without its meshes) collides with the floor and
    with nothing else; the robot's own geoms touch the floor when ``floor`` and each other only with
    ``self_collision``."""
    from hqp_tpm.plants.distances import ExtraGeom

    sole = ExtraGeom("sole", "box", (0.05, 0.05, 0.01), iiwa.frame_id("iiwa_ee"), pin.SE3.Identity(), contact=True)
    plant = MujocoPlant(iiwa, 1e-3, 2, PlantOptions(floor=True), geoms=[sole])
    m = plant.model
    floor, g = m.geom("floor").id, m.geom("sole").id
    assert (m.geom_contype[g], m.geom_conaffinity[g]) == (1, 0)
    assert (m.geom_contype[floor], m.geom_conaffinity[floor]) == (0, 1)
    robot = [k for k in range(m.ngeom) if k not in (floor, g)]
    assert all(m.geom_contype[k] == 1 and m.geom_conaffinity[k] == 0 for k in robot)
    plant.reset(np.deg2rad([0, 110, 0, -90, 0, 0, 0]))  # flange at z = -0.29 m, below the floor
    mujoco.mj_forward(m, plant.data)
    assert plant.data.ncon > 0
    assert all(floor in (c.geom1, c.geom2) for c in plant.data.contact[:plant.data.ncon])
    selfish = MujocoPlant(iiwa, 1e-3, 2, PlantOptions(self_collision=True)).model
    assert all(selfish.geom_conaffinity[k] == 1 for k in range(selfish.ngeom))
