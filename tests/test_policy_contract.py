"""The written policy contract (issue 11): every policy is a Policy, records what it declares, and the
run context carries what the app needs (no attributes attached to the policy and read back)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hqp_tpm.app import build, scenario
from hqp_tpm.control.controller import Controller
from hqp_tpm.control.policy import DistancePolicy, FixedStack, FunctionPolicy, Policy, SceneItems
from hqp_tpm.control.stack import Stack
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


# ------------------------------------------------------------------------------------------ a third-party policy
class OnlyRequired(Policy):
    """A third-party policy: the two required members and nothing else (every optional one is the default)."""

    def __init__(self, stack: Stack):
        self.stack = stack

    def __call__(self, state, t):
        return self.stack

    def tasks(self):
        return self.stack.tasks()


THIRD_PARTY = """
[scenario]
name = "third_party"
description = "a policy from outside the library, registered by name"
robot = "lwr4"
level = "velocity"
solver = "sns_tpm"
period = 0.01
duration = 3.0

[initial]
q = [0.923, -0.854, 0.903, 1.195, 0.971, 1.796, 0.0]

[limits]
velocity_scale = 0.2

[[obstacles]]
name = "o1"
type = "sphere"
center = [0.3, 0.3, 0.3]
radius = 0.05

[[tasks]]
name = "ee"
type = "frame_position"
frame = "lwr_ee"
kp = 10.0
target = { type = "harmonic", center = [0.0, 0.6, 0.0], cos_amplitude = [0.2, 0.0, 0.2], \
           sin_amplitude = [0.0, 0.1, 0.0], omega = 2.0 }

[[tasks]]
name = "pointing"
type = "pointing"
frame = "lwr_ee"
axis = [1.0, 0.0, 0.0]
alpha_d_deg = 5.0
inequality = false
kp = 5.0

[policy]
type = "only_required"
"""


@pytest.fixture
def third_party(tmp_path, monkeypatch):
    """The scenario file of a run whose policy is :class:`OnlyRequired` (registered as a builder)."""
    from hqp_tpm.app.policy_builders import POLICY_BUILDERS

    def build_only_required(sc, robot, tasks, sec, obstacles):
        sec.check_unused()
        return OnlyRequired(Stack.of(*tasks.values()))

    monkeypatch.setitem(POLICY_BUILDERS, "only_required", build_only_required)
    path = tmp_path / "third_party.toml"
    path.write_text(THIRD_PARTY)
    return path


def test_a_third_party_policy_runs_through_figures_replay_and_explain(third_party, tmp_path):
    from test_viewer import commands, object_paths

    from hqp_tpm.app.cli import run_scenario
    from hqp_tpm.app.explain import explain_run

    ctx = build.build_run(scenario.load(third_party))
    assert type(ctx.policy) is OnlyRequired and ctx.channels == () and ctx.thresholds == {}
    assert [o.name for o in ctx.scene.obstacles] == ["o1"] and ctx.scene.ee_task is None  # the default scene()
    assert [t.frame for t in ctx.scene.targets] == [ctx.tasks["ee"].frame]  # its frame task's moving target
    out = tmp_path / "run"
    summary = run_scenario(third_party, out, steps=120, progress=False, explain=True)
    names = {Path(f).name for f in summary["files"]}
    assert names == {"trajectory.npz", "metrics.json", "explain.png", "joint_velocities.png", "task_errors.png",
                     "pointing_error.png", "ee_path.png", "replay.html", "manifest.json"}, names  # ee_path: the
    # default scene() draws the moving target of its frame task (SceneItems.targets)
    arrays = np.load(out / "trajectory.npz")
    assert (np.abs(arrays["dq"]) <= ctx.velocity_limits + 1e-9).all()  # the joint box held
    assert np.isclose(np.abs(arrays["dq"]), ctx.velocity_limits).any()  # and was reached: explain has bounds
    assert np.isfinite(arrays["explain_fraction"]).all()
    html = (out / "replay.html").read_text(encoding="utf-8")
    assert "/meshcat/world/obstacles/o1" in object_paths(commands(html)) and "hqp-tpm replay: run (lwr4)" in html
    text = explain_run(out, 0.6)
    assert "ee" in text and "pointing" in text
    assert json.loads((out / "metrics.json").read_text())["explain"]["degraded_s"].keys() == {"ee", "pointing"}


def test_a_third_party_policy_in_the_live_viewer(third_party):
    from hqp_tpm.app.viewer import LiveViewer

    ctx = build.build_run(scenario.load(third_party))
    with LiveViewer(ctx.robot, ctx.scene, policy=ctx.policy, every=1, quiet=True) as live:
        res = ctx.controller.step()
        assert live.probe(ctx.controller, res) == {}
        assert live.scene.cp_names == [] and live.scene.ee_fid is None and live.scene.obstacles == ctx.obstacles
