"""papers/003 (co-manipulation, LBR iiwa 7): tasks against finite differences, the switching policy's
conditions, the eq. (8) transition, and the paper's claims on short runs against the admittance baseline."""

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.errors import ShapeError
from hqp_tpm.robot import Robot
from hqp_tpm.state import State
from hqp_tpm.tasks import Force, JointLimit, Manipulability, QuaternionOrientation
from hqp_tpm.tasks.quaternion_orientation import quaternion_error

H = 1e-6
FLANGE = "iiwa_ee"


@pytest.fixture(scope="module")
def iiwa():
    return Robot.load("iiwa7")


def states(robot, count=5, seed=0):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield pin.randomConfiguration(robot.model), rng.standard_normal(robot.nv)


def fd_jacobian(robot, fn, q):
    st = State(robot)
    cols = []
    for k in range(robot.nv):
        dq = np.zeros(robot.nv)
        dq[k] = H
        plus = np.array(fn(st.update(q + dq, np.zeros(robot.nv))), dtype=float).copy()
        minus = np.array(fn(st.update(q - dq, np.zeros(robot.nv))), dtype=float).copy()
        cols.append((plus - minus) / (2 * H))
    return np.column_stack(cols)


def fd_jdot_qdot(robot, task, q, v):
    s1 = State(robot).update(q + H * v, v)
    s0 = State(robot).update(q - H * v, v)
    return (task.jacobian(s1) - task.jacobian(s0)) @ v / (2 * H)


def test_scalar_tasks_are_gradients_of_their_values(iiwa):
    """Manipulability (14) and joint limit (11): J equals the finite-difference gradient, Jdot qd too."""
    man, lim = Manipulability(iiwa), JointLimit(iiwa)
    assert man.joints == [f"iiwa_joint_{i}" for i in range(2, 7)]
    for q, v in states(iiwa):
        st = State(iiwa).update(q, v)
        for task in (man, lim):
            np.testing.assert_allclose(task.jacobian(st), fd_jacobian(iiwa, task.value, q), atol=1e-8,
                                       err_msg=task.name)
            np.testing.assert_allclose(task.jdot_qdot(st), fd_jdot_qdot(iiwa, task, q, v), atol=1e-7,
                                       err_msg=task.name)
        J = man.jacobian(st)[0]
        assert J[0] == 0.0 and J[-1] == 0.0  # the printed (15) would have cos q_1 sin q_1 and cos q_7 sin q_7
        np.testing.assert_allclose(J[1:-1], np.sin(q[1:-1]) * np.cos(q[1:-1]))
        np.testing.assert_allclose(man.value(st), 0.5 * np.sum(np.sin(q[1:-1]) ** 2))
        span = np.array([340, 240, 340, 240, 340, 240, 350]) * np.pi / 180
        np.testing.assert_allclose(lim.value(st), np.sum((q / span) ** 2) / 14, rtol=1e-6)  # iiwa: q^* = 0
        np.testing.assert_allclose(lim.deviation(st), np.abs(q), atol=1e-12)


def test_orientation_2d_is_eq_10(iiwa):
    """(10) equals the vector part of Q_d Q^-1; its derivative is -1/2 (eta_e I + S(eps_e)) J_o qd."""
    rng = np.random.default_rng(3)
    for q, v in states(iiwa, seed=4):
        st = State(iiwa).update(q, v)
        R_d = pin.exp3(rng.standard_normal(3))
        task = QuaternionOrientation(iiwa, FLANGE, R_d)
        R = st.rotation(task.fid)
        e = quaternion_error(R_d, R)
        qe = pin.Quaternion(R_d @ R.T)
        np.testing.assert_allclose(e, np.sign(qe.w) * qe.vec(), atol=1e-12)
        np.testing.assert_allclose(task.value(st), e[:2])
        np.testing.assert_allclose(task.error(st, np.zeros(2)), e[:2])
        J_o = st.jacobian(task.fid)[3:]
        np.testing.assert_allclose(task.jacobian(st), J_o[:2])
        eta = np.sign(qe.w) * qe.w
        de_dq = -0.5 * (eta * np.eye(3) + pin.skew(e)) @ J_o
        np.testing.assert_allclose(fd_jacobian(iiwa, task.full_error, q), de_dq, atol=1e-7)
        np.testing.assert_allclose(task.jdot_qdot(st), fd_jdot_qdot(iiwa, task, q, v), atol=1e-6)
    with pytest.raises(ShapeError, match="3x3"):
        QuaternionOrientation(iiwa, FLANGE, np.eye(2))


def test_force_task(iiwa):
    """sigma_f = R_s f^s; J is the flange J_p (finite differences of its position); the command moves along f."""
    f_s = np.array([1.0, -2.0, 3.0])
    task = Force(iiwa, FLANGE, lambda st, t: f_s)
    for q, v in states(iiwa, seed=5):
        st = State(iiwa).update(q, v)
        np.testing.assert_allclose(task.value(st), st.rotation(task.fid) @ f_s)
        np.testing.assert_allclose(task.jacobian(st), fd_jacobian(iiwa, lambda s: s.position(task.fid), q),
                                   atol=1e-8)
        np.testing.assert_allclose(task.jdot_qdot(st), fd_jdot_qdot(iiwa, task, q, v), atol=1e-6)
    task.gains = type(task.gains)(kp=0.02)
    task.start(st)
    np.testing.assert_allclose(task.command(st, 0.0, 1), 0.02 * st.rotation(task.fid) @ f_s)
    bad = Force(iiwa, FLANGE, lambda st, t: np.ones(2))
    with pytest.raises(ShapeError, match="force source"):
        bad.value(st)
