"""The control loop: integration rule, null-space damping, and state kept on rejected input."""

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.control.controller import Controller
from hqp_tpm.control.policy import Policy
from hqp_tpm.control.stack import Stack
from hqp_tpm.errors import HqpTpmError, NonFiniteError, ShapeError, UnknownNameError
from hqp_tpm.references.trajectories import Harmonic
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.solvers import tpm
from hqp_tpm.tasks import FramePosition, Gains, Pointing

Q0 = np.array([0.923, -0.854, 0.903, 1.195, 0.971, 1.796, 0.0])


@pytest.fixture(scope="module")
def lwr():
    return Robot.load("lwr4")


def ellipse():
    return Harmonic(center=[0, 0.6, 0], cos_amplitude=[0.2, 0, 0.2], sin_amplitude=[0, 0.1, 0], omega=1.0)


def tracking(lwr, order=2, **kw):
    ee = FramePosition(lwr, "lwr_ee", ellipse(), Gains(40, 20) if order == 2 else Gains(40, 0), name="ee")
    pt = Pointing(lwr, "lwr_ee", [1, 0, 0], np.deg2rad(5), Gains(5, 2 if order == 2 else 0), inequality=False)
    return Controller(lwr, [ee, pt], order=order, dt=1e-3, q0=Q0, lambda_max=0.05, eps=0.1, **kw), ee


def test_acceleration_step_is_the_reference_integration(lwr):
    ctrl, _ = tracking(lwr, nullspace_damping=5.0)
    for _ in range(5):
        ctrl.step()
    q, v = ctrl.q.copy(), ctrl.v.copy()
    res = ctrl.step()
    a = res.command
    np.testing.assert_allclose(ctrl.q, q + v * 1e-3 + 0.5 * a * 1e-6, atol=1e-15)
    np.testing.assert_allclose(ctrl.v, v + a * 1e-3, atol=1e-15)
    # the command is TPM (14) with qdd_0 = -5 qd
    np.testing.assert_allclose(a, tpm(res.levels, lambda_max=0.05, eps=0.1, x0=-5.0 * v), atol=1e-12)


def test_tracking_converges_on_the_ellipse(lwr):
    for order in (1, 2):
        ctrl, ee = tracking(lwr, order=order, nullspace_damping=5.0)
        for _ in range(3000):
            res = ctrl.step()
        err = ee.error(ctrl.state.update(ctrl.q, ctrl.v, ctrl.t), ee.reference(ctrl.t)[0])
        assert np.linalg.norm(err) < 1e-3, (order, err)
        assert res.stack.label() == "ee > lwr_ee_pointing"


def test_rejected_inputs_keep_the_previous_state(lwr):
    ctrl, ee = tracking(lwr)
    for _ in range(3):
        ctrl.step()
    before = (ctrl.q.copy(), ctrl.v.copy(), ctrl.t, ctrl.steps)

    def same():
        np.testing.assert_array_equal(ctrl.q, before[0])
        np.testing.assert_array_equal(ctrl.v, before[1])
        assert (ctrl.t, ctrl.steps) == before[2:]

    with pytest.raises(NonFiniteError):
        ctrl.set_state(np.full(7, np.nan))
    same()
    with pytest.raises(ShapeError):
        ctrl.set_state(np.zeros(6))
    same()
    bad = Stack.of(ee)
    bad.extras["ee"] = np.array([np.inf, 0.0, 0.0])  # e.g. a broken repulsion vector
    ctrl.policy = lambda st, t: bad
    with pytest.raises(NonFiniteError, match="extra command"):
        ctrl.step()
    same()
    ctrl.policy = lambda st, t: Stack.of(ee)
    ctrl.solver = "qp:no_such_backend"
    with pytest.raises(HqpTpmError, match="no_such_backend"):
        ctrl.step()
    same()


def test_bad_controller_settings(lwr):
    ee = FramePosition(lwr, "lwr_ee", [0, 0.5, 0])
    with pytest.raises(UnknownNameError, match="unknown solver 'tpmm'.*'tpm'"):
        Controller(lwr, [ee], solver="tpmm")
    with pytest.raises(ValueError, match="order"):
        Controller(lwr, [ee], order=3)
    with pytest.raises(ValueError, match="dt"):
        Controller(lwr, [ee], dt=0.0)
    with pytest.raises(ShapeError, match="nq = 7"):
        Controller(lwr, [ee], q0=np.zeros(3))


@pytest.mark.parametrize("record", [False, True])
@pytest.mark.parametrize("name, bad", [("order", 3), ("order", 1.5), ("dt", -1.0), ("dt", "1e-3"), ("eps", -1.0),
                                       ("lambda_max", float("nan")), ("nullspace_damping", -5.0), ("box", "box"),
                                       ("solver", "tpmm")])
def test_a_setting_assigned_later_is_checked_by_the_next_step(lwr, name, bad, record):
    """Settings assigned after construction: the next step refuses a bad one as the constructor does and changes
    nothing (``order = 3`` crashed the process on the compiled path; ``dt = -1`` ran time backwards)."""
    ctrl, _ = tracking(lwr, order=1)
    ctrl.step()
    good, t, q, steps = getattr(ctrl, name), ctrl.t, ctrl.q.copy(), ctrl.steps
    setattr(ctrl, name, bad)
    with pytest.raises(HqpTpmError, match=name if name != "solver" else "tpmm"):
        ctrl.step(record=record)
    assert (ctrl.t, ctrl.steps) == (t, steps) and np.array_equal(ctrl.q, q)
    setattr(ctrl, name, good)
    ctrl.step(record=record)
    assert ctrl.steps == steps + 1


def test_unvalidated_state_update_equals_the_validated_one():
    """The controller's update (q, v not re-checked; joint Jacobians and CoM from the kinematics just computed)
    gives the same kinematics as a checked update with them recomputed from q, free flyer included."""
    rng = np.random.default_rng(5)
    for robot in (Robot.load("lwr4"), Robot.load("romeo")):
        fast, ref = State(robot), State(robot)
        for _ in range(10):
            q, v = pin.randomConfiguration(robot.model), rng.standard_normal(robot.nv)
            if robot.has_free_flyer:
                q[:3] = rng.uniform(-1, 1, 3)
            fast.update(q, v, validate=False)
            ref.update(q, v)
            pin.computeJointJacobians(ref.model, ref.data, ref.q)
            np.testing.assert_array_equal(fast.data.J, ref.data.J)
            for fid in range(0, robot.model.nframes, 7):
                np.testing.assert_array_equal(fast.jacobian(fid), ref.jacobian(fid))
                np.testing.assert_array_equal(fast.jdot_qdot(fid), ref.jdot_qdot(fid))
            data = robot.model.createData()  # the CoM with its own forward passes from q, v
            pin.centerOfMass(robot.model, data, q, v, np.zeros(robot.nv))
            np.testing.assert_array_equal(fast.com_jdot_qdot(), data.acom[0])
            np.testing.assert_array_equal(fast.com_jacobian(), pin.jacobianCenterOfMass(robot.model, data, q, False))
            np.testing.assert_array_equal(fast.com(), data.com[0])
        with pytest.raises(NonFiniteError):
            fast.update(np.full(robot.model.nq, np.nan), v)  # validated by default


class _BrokenPosition(FramePosition):
    """A task whose Jacobian turns NaN (e.g. a user task with a bug): ``defer_finite`` levels must still be caught."""

    def jacobian(self, state):
        J = super().jacobian(state).copy()
        J[1, 3] = np.nan
        return J


@pytest.mark.parametrize("solver", ["tpm", "nullspace", "sns_tpm", "sns", "qp"])
def test_task_with_a_nan_jacobian_is_named_and_the_state_kept(lwr, solver):
    ee = FramePosition(lwr, "lwr_ee", ellipse(), Gains(40, 20), name="ee")
    broken = _BrokenPosition(lwr, "lwr_elbow", "hold", Gains(5, 2), name="elbow")
    box = (lambda st, t: (np.full(7, -10.0), np.full(7, 10.0))) if solver.startswith("sns") or solver == "qp" else None
    ctrl = Controller(lwr, [ee, broken], order=2, dt=1e-3, q0=Q0, solver=solver, box=box)
    q, v = ctrl.q.copy(), ctrl.v.copy()
    with pytest.raises(NonFiniteError, match=r"level 'elbow': J holds NaN or inf at \[\[1, 3\]\]"):
        ctrl.step()
    np.testing.assert_array_equal(ctrl.q, q)
    np.testing.assert_array_equal(ctrl.v, v)
    assert ctrl.steps == 0


class _PushingBlend(Policy):
    """A policy whose eq. (8)-style blend adds an offset far outside any joint box."""

    blends = True

    def __init__(self, tasks):
        self.stack = Stack.of(*tasks)

    def tasks(self):
        return self.stack.tasks()

    def __call__(self, state, t):
        return self.stack

    def blend(self, state, t, stack, x, resolve):
        return x + 100.0


@pytest.mark.parametrize("solver", ["sns_tpm", "sns", "qp", "tpm"])
def test_a_blended_command_keeps_the_hard_box(lwr, solver):
    ee = FramePosition(lwr, "lwr_ee", ellipse(), Gains(40, 0), name="ee")
    lo, up = np.full(7, -0.3), np.full(7, 0.3)
    box = None if solver == "tpm" else (lambda st, t: (lo, up))  # (an analytic solver refuses a box)
    ctrl = Controller(lwr, _PushingBlend([ee]), order=1, dt=1e-3, q0=Q0, solver=solver, box=box)
    res = ctrl.step()
    x = res.command
    if solver == "tpm":  # the analytic solvers ignore boxes: the blend is left alone
        np.testing.assert_allclose(x - 100.0, tpm(res.levels), atol=1e-12)
    else:
        assert ((x >= lo) & (x <= up)).all() and np.allclose(x, up)


def test_assigning_q_or_v_is_validated(lwr):
    ctrl, _ = tracking(lwr)
    ctrl.step()
    q, v = ctrl.q.copy(), ctrl.v.copy()
    with pytest.raises(NonFiniteError, match="q holds non-finite values at \\[2\\]"):
        ctrl.q = np.where(np.arange(7) == 2, np.nan, q)
    with pytest.raises(ShapeError, match="v has 6 entries"):
        ctrl.v = np.zeros(6)
    np.testing.assert_array_equal(ctrl.q, q)
    np.testing.assert_array_equal(ctrl.v, v)
    ctrl.q = q + 0.01  # a valid assignment is taken, as a copy
    assert np.allclose(ctrl.q, q + 0.01) and ctrl.q is not q
    ctrl.step()


@pytest.mark.parametrize("record", [False, True])
def test_a_task_that_enters_with_a_new_policy_is_started(lwr, record):
    """A task holding its start value (target None) that enters with ``ctrl.policy = ...`` after the first step is
    started at the current state (it raised "Hold trajectory used before start()": only the first step started
    tasks)."""
    from hqp_tpm.tasks import FrameOrientation

    ctrl, ee = tracking(lwr, order=1)
    for _ in range(5):
        ctrl.step(record=record)
    held = FrameOrientation(lwr, "lwr_ee", None, Gains(5.0, 0.0), name="held")
    ctrl.policy = Stack.of(ee, held)
    R = ctrl.state.update(ctrl.q, ctrl.v, ctrl.t).placement(lwr.frame_id("lwr_ee")).rotation.copy()
    ctrl.step(record=record)
    np.testing.assert_allclose(held.target, R, atol=1e-15)


def test_a_task_that_comes_back_with_an_earlier_policy_is_not_started_again(lwr):
    """Switching to a stack without a task and back: its held and relative targets stay where the first step put
    them (the policy setter restarted every task the previous policy did not have)."""
    from hqp_tpm.tasks import Posture

    ctrl, _ = tracking(lwr, order=1)
    post = Posture(lwr, None, Gains(1.0, 0.0), name="post")
    ee = FramePosition(lwr, "lwr_ee", Harmonic(center=[0, 0, 0], cos_amplitude=[0.01, 0, 0], omega=1.0,
                                               relative=True), Gains(5.0, 0.0), name="rel")
    first = Stack.of(ee, post)
    ctrl.policy = first
    for _ in range(5):
        ctrl.step()
    held, origin = post.target.reference(0.0)[0].copy(), ee.trajectory.origin.copy()
    ctrl.policy = Stack.of(post)
    ctrl.q = ctrl.q + 0.05
    ctrl.step()
    ctrl.policy = first
    ctrl.step()
    np.testing.assert_array_equal(post.target.reference(0.0)[0], held)
    np.testing.assert_array_equal(ee.trajectory.origin, origin)


def test_solver_none_is_refused_with_the_library_error(lwr):
    ee = FramePosition(lwr, "lwr_ee", [0, 0.5, 0])
    with pytest.raises(UnknownNameError, match="solver"):
        Controller(lwr, [ee], solver=None)


@pytest.mark.parametrize("record", [False, True])
def test_a_function_policy_assigned_later_does_not_restart_the_tasks_it_shares(lwr, record):
    """``ctrl.policy = lambda state, t: ...`` after the first step: its first call started every task it returned,
    those the previous stack had started included (their held and relative targets moved to the current state)."""
    from hqp_tpm.tasks import Posture

    ctrl, _ = tracking(lwr, order=1)
    post = Posture(lwr, None, Gains(1.0, 0.0), name="post")
    ee = FramePosition(lwr, "lwr_ee", Harmonic(center=[0, 0, 0], cos_amplitude=[0.01, 0, 0], omega=1.0,
                                               relative=True), Gains(5.0, 0.0), name="rel")
    ctrl.policy = Stack.of(ee, post)
    for _ in range(5):
        ctrl.step(record=record)
    held, origin = post.target.reference(0.0)[0].copy(), ee.trajectory.origin.copy()
    ctrl.q = ctrl.q + 0.05
    ctrl.policy = lambda state, t: Stack.of(ee, post)
    ctrl.step(record=record)
    np.testing.assert_array_equal(post.target.reference(0.0)[0], held)
    np.testing.assert_array_equal(ee.trajectory.origin, origin)
    ctrl.policy = Stack.of(post)  # (and back to a stack: started by the function policy or not, they go on)
    ctrl.step(record=record)
    np.testing.assert_array_equal(post.target.reference(0.0)[0], held)
