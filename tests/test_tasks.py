"""Task Jacobians against finite differences; J-dot q-dot against a finite difference of J along q-dot."""

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.errors import NonFiniteError, RobotFileError, ShapeError, StateError, UnknownFrameError
from hqp_tpm.references.trajectories import Constant, Harmonic, Hold
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks import CenterOfMass, FrameOrientation, FramePosition, Gains, Pointing, Posture
from hqp_tpm.testing import assert_task_derivatives

H = 1e-6


@pytest.fixture(scope="module")
def panda():
    return Robot.load("panda")


@pytest.fixture(scope="module")
def romeo():
    return Robot.load("romeo")


def random_state(robot, rng):
    q = pin.randomConfiguration(robot.model)
    if robot.has_free_flyer:
        q[:3] = rng.uniform(-1, 1, 3)
        q[3:7] = pin.Quaternion(pin.SE3.Random().rotation).coeffs()
    return q, rng.standard_normal(robot.nv)


def tasks_for(robot):
    if robot.name == "panda":
        return [FramePosition(robot, "panda_hand", [0.3, 0, 0.5]), FramePosition(robot, "panda_link4", axes="xz"),
                Pointing(robot, "panda_hand", [1, 0, 0], np.deg2rad(5)), Posture(robot, np.zeros(9)),
                CenterOfMass(axes="xy")]
    return [CenterOfMass(axes="xy"), FramePosition(robot, "l_wrist"), Pointing(robot, "r_sole", [0, 0, 1], 0.1)]


@pytest.mark.parametrize("robot_name", ["panda", "romeo"])
def test_jacobians_and_jdot_qdot_match_finite_differences(robot_name, panda, romeo):
    robot = panda if robot_name == "panda" else romeo
    rng = np.random.default_rng(0)
    states = [random_state(robot, rng) for _ in range(5)]
    for task in tasks_for(robot):  # J vs central differences, Jdot qd vs a difference of J along qd (pin.integrate)
        assert_task_derivatives(task, robot, states, h=H, atol=2e-6, rtol=0.0, jdot_atol=2e-5)


def test_orientation_jacobian_and_error(panda):
    rng = np.random.default_rng(1)
    q, v = random_state(panda, rng)
    st = State(panda).update(q, v)
    task = FrameOrientation(panda, "panda_hand")
    task.start(st)
    np.testing.assert_allclose(task.error(st, None), 0.0, atol=1e-12)
    # a rotation of the frame by a small world-frame angle w: error ~ -w
    fid = task.fid
    dq = np.linalg.pinv(task.jacobian(st)) @ np.array([0.0, 0.0, 1e-4])
    st2 = State(panda).update(pin.integrate(panda.model, q, dq), v)
    np.testing.assert_allclose(task.error(st2, None), [0, 0, -1e-4], atol=1e-7)
    s1 = State(panda).update(pin.integrate(panda.model, q, H * v), v)
    s0 = State(panda).update(pin.integrate(panda.model, q, -H * v), v)
    jdqd_fd = (s1.jacobian(fid)[3:] - s0.jacobian(fid)[3:]) @ v / (2 * H)
    np.testing.assert_allclose(task.jdot_qdot(st), jdqd_fd, atol=2e-5)


def test_acceleration_command_is_the_papers_law(panda):
    rng = np.random.default_rng(2)
    q, v = random_state(panda, rng)
    st = State(panda).update(q, v)
    task = FramePosition(panda, "panda_hand", [0.3, 0.1, 0.5], Gains(kp=40, kd=20))
    e = np.array([0.3, 0.1, 0.5]) - st.position(task.fid)
    b = task.command(st, 0.0, 2)
    np.testing.assert_allclose(b, 40 * e + 20 * (0 - task.jacobian(st) @ v) - task.jdot_qdot(st), atol=1e-12)
    np.testing.assert_allclose(task.command(st, 0.0, 1), 40 * e, atol=1e-12)


def test_pointing_cone_level_is_active_only_outside(panda):
    q = pin.neutral(panda.model)
    st = State(panda).update(q, np.zeros(panda.nv))
    z = st.rotation(panda.frame_id("panda_hand"))[:, 2]
    inside = Pointing(panda, "panda_hand", z, np.deg2rad(5))
    assert not inside.is_active(st) and not inside.level(st, 0, 2).active_rows().any()
    other = np.cross(z, [1.0, 0, 0])
    outside = Pointing(panda, "panda_hand", other / np.linalg.norm(other), np.deg2rad(5))
    assert outside.is_active(st) and outside.level(st, 0, 2).active_rows().all()
    eq = Pointing(panda, "panda_hand", z, np.deg2rad(5), inequality=False)
    assert eq.level(st, 0, 2).is_equality


def test_bad_robot_inputs_raise_typed_errors(panda, tmp_path):
    with pytest.raises(UnknownFrameError, match="unknown frame 'no_such_frame'.*'panda_hand'"):
        FramePosition(panda, "no_such_frame")
    with pytest.raises(RobotFileError, match="missing.urdf"):
        Robot.load(tmp_path / "missing.urdf")
    st = State(panda)
    with pytest.raises(ShapeError, match="nq = 9"):
        st.update(np.zeros(3), np.zeros(9))
    with pytest.raises(NonFiniteError, match=r"q holds non-finite values at \[2\]"):
        st.update(np.array([0, 0, np.nan, 0, 0, 0, 0, 0, 0.0]), np.zeros(9))
    with pytest.raises(NonFiniteError, match="target"):
        FramePosition(panda, "panda_hand", [0.0, np.inf, 0.0])
    with pytest.raises(ShapeError, match=r"expected \(3,\)"):
        FramePosition(panda, "panda_hand", [0.0, 1.0])


def test_fast_task_paths_equal_their_literal_formulas(panda):
    """Pointing J-dot q-dot on floats, the row views of FramePosition/CenterOfMass: equal to the literal forms."""
    rng = np.random.default_rng(4)
    tasks = [Pointing(panda, "panda_hand", [1, 0, 0], np.deg2rad(5)), FramePosition(panda, "panda_hand"),
             FramePosition(panda, "panda_link4", axes="xz"), CenterOfMass(axes="xy"), CenterOfMass()]
    for _ in range(20):
        st = State(panda).update(*random_state(panda, rng))
        pt = tasks[0]
        z_e, omega = st.rotation(pt.fid)[:, 2], st.velocity(pt.fid)[3:]
        alpha = st.jdot_qdot(pt.fid)[3:]
        np.testing.assert_array_equal(pt.jdot_qdot(st), [pt.z_d @ (np.cross(alpha, z_e)
                                                                   + np.cross(omega, np.cross(omega, z_e)))])
        np.testing.assert_array_equal(pt.jacobian(st), (np.cross(z_e, pt.z_d) @ st.jacobian(pt.fid)[3:])[None])
        assert pt.value(st)[0] == pt.z_d @ z_e and pt.pointing_error(st) == np.cos(np.deg2rad(5)) - pt.z_d @ z_e
        ee = FramePosition(panda, "panda_hand", [0.3, 0.1, 0.5], Gains(kp=40, kd=20))
        e = np.array([0.3, 0.1, 0.5]) - st.position(ee.fid)
        np.testing.assert_array_equal(ee.command(st, 0.0, 2),  # eq. (12) with @ for J qd
                                      0.0 + 20.0 * (0.0 - ee.jacobian(st) @ st.v) + 40.0 * e - ee.jdot_qdot(st))
        for task in tasks[1:3]:
            np.testing.assert_array_equal(task.jacobian(st), st.jacobian(task.fid)[task.rows])
            np.testing.assert_array_equal(task.jdot_qdot(st), st.jdot_qdot(task.fid)[task.rows])
        for task in tasks[3:]:
            np.testing.assert_array_equal(task.jacobian(st), st.com_jacobian()[task.rows])
            np.testing.assert_array_equal(task.jdot_qdot(st), st.com_jdot_qdot()[task.rows])


def test_trajectory_numbers_change_only_by_assignment():
    """A trajectory's arrays are read-only copies: writing into one raises, the caller's array stays theirs, and
    an assigned value is seen by the next reference (the constant references' cache is dropped; the compiled row
    writers key on identity). Before, ``Constant.value = ...`` after a first reference kept the old target."""
    from hqp_tpm.references.trajectories import Constant, Harmonic

    c = Constant(value=[1.0, 2.0])
    np.testing.assert_array_equal(c.reference(0.0)[0], [1.0, 2.0])
    c.value = [3.0, 4.0]
    np.testing.assert_array_equal(c.reference(0.0)[0], [3.0, 4.0])
    mine = np.array([0.1, 0.2, 0.3])
    h = Harmonic(center=mine, cos_amplitude=[0.0, 0.1, 0.0], sin_amplitude=[0.0, 0.0, 0.1], omega=2.0)
    mine[0] = 9.0                                      # the caller's array: not the trajectory's
    assert h.center[0] == 0.1
    for name in ("center", "cos_amplitude", "sin_amplitude"):
        with pytest.raises(ValueError, match="read-only"):
            getattr(h, name)[0] = 1.0
    h.start(np.zeros(3))
    h.center = [1.0, 1.0, 1.0]
    assert h.reference(0.0)[0][0] == 1.0 + 0.0 + 0.0
    h.relative = True                                  # (its fields as floats are kept between references)
    h.center = [1.0, 1.0, 1.0]
    with pytest.raises(StateError, match="relative Harmonic target used before start"):  # (no zero origin)
        h.reference(0.0)
    h.start(np.zeros(3))
    for change, x0, xd1 in ((lambda: setattr(h, "cos_amplitude", [2.0, 0.0, 0.0]), 3.0, 0.0),
                            (lambda: setattr(h, "sin_amplitude", [0.0, 5.0, 0.0]), 3.0, 10.0),  # w = 2
                            (lambda: h.start(np.array([1.0, 0.0, 0.0])), 4.0, 10.0),
                            (lambda: setattr(h, "center", [0.0, 0.0, 0.0]), 3.0, 10.0)):
        change()                                       # seen by the next reference, after a first one
        x, xd, _ = h.reference(0.0)
        assert (x[0], xd[1]) == (x0, xd1), (x, xd)


def test_references_equal_their_numpy_formulas():
    """Harmonic on floats (math.cos/sin) equals the array expressions; constant references are computed once per
    start, read-only, and follow a new start."""
    rng = np.random.default_rng(6)
    for k in range(100):
        a, b, c, x0 = rng.standard_normal((4, 3))
        w, phi = float(rng.choice([1.0, np.pi, rng.uniform(0.0, 10.0)])), float(rng.uniform(-3.0, 3.0))
        h = Harmonic(center=c, cos_amplitude=a, sin_amplitude=b, omega=w, phase=phi, relative=bool(k % 2))
        h.start(x0)
        for t in np.concatenate([np.arange(0.0, 20.0, 0.037), rng.uniform(0.0, 1e3, 20)]):
            cos, sin = np.cos(w * t + phi), np.sin(w * t + phi)
            x, xd, xdd = h.reference(float(t))
            np.testing.assert_allclose(x, c + (x0 if k % 2 else 0.0) + a * cos + b * sin, rtol=0, atol=1e-15)
            np.testing.assert_allclose(xd, w * (-a * sin + b * cos), rtol=0, atol=1e-15)
            np.testing.assert_allclose(xdd, -w * w * (a * cos + b * sin), rtol=0, atol=1e-15)
    for traj in (Constant(value=[1.0, 2.0], relative=True), Hold()):
        traj.start(np.array([0.5, 0.5]))
        x, xd, xdd = traj.reference(0.0)
        assert traj.reference(1.0)[0] is x and not x.flags.writeable and not xd.any() and not xdd.any()
        with pytest.raises(ValueError):
            x[0] = 0.0
        traj.start(np.array([1.0, 1.0]))
        np.testing.assert_array_equal(traj.reference(2.0)[0], traj.offset(2) + getattr(traj, "value", 0.0))
