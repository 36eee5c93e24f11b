"""Short reprs for the objects a user prints, and the task constructors' common signature."""

import numpy as np

from hqp_tpm import CenterOfMass, Controller, FramePosition, Gains, Robot, Stack, State


def test_short_reprs():
    robot = Robot.load("lwr4")
    assert repr(robot).startswith("Robot('lwr4', nq=7, nv=7") and len(repr(robot)) < 200
    st = State(robot)
    st.update(robot.neutral(), np.zeros(7))
    assert repr(st).startswith("State('lwr4', t=0.0000") and len(repr(st)) < 200
    ee = FramePosition(robot, "lwr_ee", None, Gains(10.0), name="ee")
    stack = Stack.of(ee)
    assert repr(stack) == "Stack('ee', 1 level)"
    ctrl = Controller(robot, stack, order=1)
    res = ctrl.step()
    for obj in (ee, ctrl, res):
        assert len(repr(obj)) < 200, repr(obj)
    assert "stack='ee'" in repr(res) and repr(ctrl).startswith("Controller('lwr4', velocity level")


def test_center_of_mass_takes_the_robot_like_the_other_tasks():
    robot = Robot.load("planar5")
    new = CenterOfMass(robot, [0.1, 0.2], Gains(5.0), axes="xy")
    old = CenterOfMass([0.1, 0.2], Gains(5.0), axes="xy")  # the older form still works
    old_none = CenterOfMass(None, Gains(5.0), axes="xy")
    for task in (new, old):
        assert task.gains.kp == 5.0 and task.dim == 2
        assert np.allclose(task.reference(0.0)[0], [0.1, 0.2])
    assert old_none.gains.kp == 5.0


def test_step_result_fields_read_on_the_class_and_on_a_result():
    """The on-demand fields are descriptors: read on the class (help(), documentation tools) they give themselves,
    read on a result its value."""
    from hqp_tpm.control.step_result import StepResult

    r = StepResult(0.5, None, [], np.zeros(2), info={"a": 1}, x0=np.ones(2))
    for name in ("info", "stack", "levels", "x0", "box"):
        assert vars(StepResult)[name] is getattr(StepResult, name)
    assert r.info == {"a": 1} and r.stack is None and r.levels == [] and r.box is None
    assert np.array_equal(r.x0, np.ones(2))
