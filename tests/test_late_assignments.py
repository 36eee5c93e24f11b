"""Assignments to a task after its run started (three user-found bugs; both paths, ``step()`` and ``record=True``).

A relative target assigned after the first step was evaluated with a zero origin (a circle about the world origin,
not about the EE): it is now refused until started. A Pointing's ``alpha_d`` was read once (its reference and its
cone's activity kept the old one), the planned step's row writer kept the ``drift_limit`` of its build, and ``target``
and ``axis`` were plain attributes (``axis`` replaced the method): now checked and used from the next step on, or
refused. ``task.gains = 5.0`` was taken and the next step raised a bare AttributeError: now refused."""

import numpy as np
import pytest

from hqp_tpm import Controller, FramePosition, Gains, Harmonic, Pointing, Posture, Robot, Stack
from hqp_tpm.errors import ArgumentTypeError, ParameterError, ShapeError, StateError
from hqp_tpm.references.line import Line
from hqp_tpm.references.trajectories import Constant, Hold

Q0 = np.deg2rad([0, 30, 0, -60, 0, 90, 0])
CIRCLE = {"center": [0.0, 0.0, 0.0], "cos_amplitude": [0.0, 0.05, 0.0], "sin_amplitude": [0.0, 0.0, 0.05],
          "omega": 1.0, "relative": True}


@pytest.fixture(scope="module")
def iiwa():
    return Robot.load("iiwa7")


def _reach(robot):
    ee = FramePosition(robot, "iiwa_ee", None, Gains(kp=10.0), name="ee")
    return ee, Controller(robot, Stack.of(ee, Posture(robot, Q0, Gains(kp=1.0))), order=1, dt=1e-3, q0=Q0)


@pytest.mark.parametrize("record", [False, True])
def test_a_relative_target_assigned_after_the_start_is_refused_until_started(iiwa, record):
    """Before: no error, ``x_d`` circled the world origin (``[0, 0.05, 0]`` at t = 0.001), on both paths."""
    ee, ctrl = _reach(iiwa)
    ctrl.step(record=record)
    assert ctrl.compiled()  # (record=False: the compiled step)
    late = (Harmonic(**CIRCLE), Constant(value=[0.0, 0.05, 0.0], relative=True), Hold(),
            Line(start_point=np.zeros(3), end_point=[0.0, 0.1, 0.0], relative=True))
    for target in late:
        ee.target = target
        q, t = ctrl.q, ctrl.t
        with pytest.raises(StateError, match=rf"^task 'ee': relative {type(target).__name__} target used before "
                                             r"start\(\).* call ctrl\.start\(\[task\]\) after assigning it"):
            ctrl.step(record=record)  # (both paths: the same words)
        assert ctrl.q is q and ctrl.t == t  # (the step refused: nothing changed)
    ee.target = Harmonic(**CIRCLE)
    ctrl.start([ee])  # (at the current state: ctrl.state was the last step's)
    origin = ctrl.state.position(ee.fid).copy()
    res = ctrl.step(record=record)
    np.testing.assert_allclose(ee.reference(res.t)[0], origin + [0.0, 0.05 * np.cos(res.t), 0.05 * np.sin(res.t)])
    assert np.linalg.norm(origin) > 0.3  # (the EE's circle, far from the world origin's)


def test_a_relative_target_assigned_before_the_first_step_is_started_by_it(iiwa):
    ee, ctrl = _reach(iiwa)
    ee.target = Harmonic(**CIRCLE)
    ctrl.step()
    p0 = ctrl.state.update(Q0, np.zeros(7)).position(ee.fid)
    np.testing.assert_allclose(ee.reference(0.0)[0], p0 + [0.0, 0.05, 0.0])
    with pytest.raises(StateError, match=r"^relative Hold target used before start\(\)"):
        Hold().reference(0.0)


def _cone(robot):
    cone = Pointing(robot, "iiwa_ee", [0, 0.2, -1], 0.0, Gains(kp=10, kd=6), inequality=False, name="cone")
    ctrl = Controller(robot, Stack.of(cone, Posture(robot, Q0, Gains(kp=1.0, kd=2.0))), order=2, dt=1e-3, q0=Q0)
    for _ in range(200):
        ctrl.step()
    return cone, ctrl


def _cone_row(cone, ctrl) -> float:
    """The cone's ``b`` on the compiled path, checked against the readable path's and ``cone.command``."""
    fast, ref = ctrl.compute().levels[0].b, ctrl.compute(record=True).levels[0].b
    own = cone.command(ctrl.state, ctrl.t, 2)
    np.testing.assert_allclose(fast, ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(ref, own)
    return float(ref[0])


def test_a_pointing_task_uses_alpha_d_and_drift_limit_assigned_later(iiwa):
    """Before: ``drift_limit`` changed the readable path's row and not the compiled one's (its writer read it when
    built); ``alpha_d`` changed neither path (the reference and the cone's ``cos(alpha_d)`` were computed once)."""
    cone, ctrl = _cone(iiwa)
    b0 = _cone_row(cone, ctrl)
    jdq = float(cone.jdot_qdot(ctrl.state)[0])
    cone.drift_limit = 1e-9  # (any drift is then left out of the command: added back)
    assert cone.drift_limit == 1e-9 and _cone_row(cone, ctrl) == pytest.approx(b0 + jdq, abs=1e-12) and jdq != 0.0
    cone.drift_limit = None
    assert _cone_row(cone, ctrl) == pytest.approx(b0, abs=1e-12)
    cone.alpha_d = 0.3
    twin = Pointing(iiwa, "iiwa_ee", [0, 0.2, -1], 0.3, Gains(kp=10, kd=6), inequality=False)
    assert _cone_row(cone, ctrl) == twin.command(ctrl.state, ctrl.t, 2)[0] != b0
    assert cone.pointing_error(ctrl.state) == twin.pointing_error(ctrl.state)
    ctrl.step()
    ctrl.step(record=True)


def test_a_pointing_task_refuses_bad_or_read_only_assignments(iiwa):
    cone, ctrl = _cone(iiwa)
    b0, trajectory = _cone_row(cone, ctrl), cone.trajectory
    for name, value, what in (("alpha_d", 3.5, r"\[0, pi\) radians"), ("alpha_d", "wide", "radians"),
                              ("alpha_d", None, "radians"), ("drift_limit", -2.0, "None \\(no limit\\)"),
                              ("drift_limit", np.inf, "finite"), ("drift_limit", True, "finite"),
                              ("target", [1.0], "assign alpha_d"), ("axis", [0.0, 0.0, 1.0], "new Pointing")):
        with pytest.raises(ParameterError, match=rf"task 'cone': {name} = .* refused: .*{what}"):
            setattr(cone, name, value)
    assert cone.alpha_d == 0.0 and cone.drift_limit is None and cone.trajectory is trajectory
    assert "target" not in vars(cone) and "axis" not in vars(cone) and cone.axis(ctrl.state).shape == (3,)
    assert _cone_row(cone, ctrl) == b0
    z_d = cone.z_d
    for value, error in (([0.0, 0.6], ShapeError), ([0.0, 0.0, np.nan], ParameterError), ("up", ShapeError)):
        with pytest.raises(error, match=r"Pointing 'cone': axis .*"):
            cone.z_d = value
    assert cone.z_d is z_d and _cone_row(cone, ctrl) == b0
    cone.z_d = [0.0, 0.0, -2.0]  # (a unit axis from the next step on, as the constructor makes it)
    np.testing.assert_array_equal(cone.z_d, [0.0, 0.0, -1.0])
    with pytest.raises(ParameterError, match=r"task 'c': alpha_d = -0\.1 refused"):
        Pointing(iiwa, "iiwa_ee", [0, 0, 1], -0.1, name="c")


@pytest.mark.parametrize("bad", [5.0, (10.0, 1.0), "high", {"kp": 1.0}])
def test_gains_that_are_not_gains_are_refused(iiwa, bad):
    """Before: taken; the next step raised ``AttributeError: 'float' object has no attribute 'kp'``."""
    ee, ctrl = _reach(iiwa)
    ctrl.step()
    gains = ee.gains
    with pytest.raises(ArgumentTypeError, match=r"task 'ee': gains .* is not a Gains; use Gains\(kp, kd\)"):
        ee.gains = bad
    assert ee.gains is gains
    ctrl.step()
    ctrl.step(record=True)
    with pytest.raises(ArgumentTypeError, match=r"task 'p': gains .* is not a Gains"):
        FramePosition(iiwa, "iiwa_ee", None, bad, name="p")


def test_gains_assigned_later_are_used_and_none_is_the_defaults(iiwa):
    ee, ctrl = _reach(iiwa)
    ctrl.step()
    ee.gains = Gains(kp=3.0)
    assert ee.gains == Gains(kp=3.0)
    np.testing.assert_array_equal(ctrl.compute().command, ctrl.compute(record=True).command)
    ee.gains = None
    assert ee.gains == Gains()
