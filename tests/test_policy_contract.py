"""The written policy contract (issue 11): every policy is a Policy, records what it declares, and the
run context carries what the app needs (no attributes attached to the policy and read back)."""

from __future__ import annotations

import numpy as np
import pytest

from hqp_tpm.app import build, scenario
from hqp_tpm.control.controller import Controller
from hqp_tpm.control.policy import DistancePolicy, FunctionPolicy, Policy, SceneItems
from hqp_tpm.control.stack import FixedStack, Stack
from hqp_tpm.policies.admittance import Admittance
from hqp_tpm.policies.algorithm1 import Algorithm1
from hqp_tpm.policies.petric import Petric
from hqp_tpm.policies.switching import Switching
from hqp_tpm.policies.whole_body import WholeBody

#: one shipped scenario per policy type
CASES = {"lwr_tracking": FixedStack, "lwr_relaxed": Algorithm1, "planar5_exact": Petric,
         "romeo_obstacles_sns_tpm": WholeBody, "iiwa_comanipulation": Switching, "iiwa_admittance": Admittance}


def test_the_policies_follow_the_contract():
    for cls in (Algorithm1, Petric, WholeBody):
        assert issubclass(cls, DistancePolicy)
    for cls in (FixedStack, Switching, Admittance, FunctionPolicy):
        assert issubclass(cls, Policy) and not issubclass(cls, DistancePolicy)
    assert Switching.blends and Petric.blends and not Algorithm1.blends and not FixedStack.blends
    with pytest.raises(TypeError):
        Policy()  # the two required members are abstract


@pytest.mark.parametrize("name", sorted(CASES))
def test_run_context_and_recorded_channels(name):
    sc = scenario.load(name)
    ctx = build.build_run(sc)
    assert type(ctx.policy) is CASES[name] and ctx.controller.policy is ctx.policy
    assert isinstance(ctx.scene, SceneItems)
    assert [o.name for o in ctx.scene.obstacles] == [o.name for o in ctx.obstacles]
    assert (ctx.limits is None) == (sc.limits is None) and ctx.controller.box is ctx.limits
    assert (ctx.velocity_limits is None) == (ctx.limits is None)
    ctrl = ctx.controller
    for _ in range(2):
        res = ctrl.step()
    assert set(ctx.policy.probe(ctrl, res)) == set(ctx.channels)
    assert all(isinstance(v, dict) for v in ctx.thresholds.values())
    # x0 and the box of the solve are computed in one place and handed over with the step's result
    x0, box = ctrl.solve_inputs(ctrl.state, res.t, ctrl.state.v)
    assert (x0 is None) == (res.x0 is None) and (box is None) == (res.box is None)
    if box is not None:
        np.testing.assert_array_equal(box[0], res.box[0])
        np.testing.assert_array_equal(box[1], res.box[1])


def test_plain_callables_and_stacks_become_policies():
    from hqp_tpm.robot.model import Robot
    from hqp_tpm.tasks import FramePosition, Gains

    robot = Robot.load("lwr4")
    ee = FramePosition(robot, "lwr_ee", "hold", Gains(1.0), name="ee")
    assert isinstance(Controller(robot, [ee], order=1).policy, FixedStack)
    assert isinstance(Controller(robot, Stack.of(ee), order=1).policy, FixedStack)
    ctrl = Controller(robot, lambda st, t: Stack.of(ee), order=1)
    assert isinstance(ctrl.policy, FunctionPolicy) and ctrl.tasks() == []
    ctrl.policy = [ee]  # assigning wraps too
    assert isinstance(ctrl.policy, FixedStack)
    with pytest.raises(TypeError):
        Controller(robot, 3.0)
