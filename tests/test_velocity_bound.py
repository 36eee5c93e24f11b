"""Issue 31, item 2: a run whose joint velocities leave ``[scenario] velocity_bound`` (a multiple of the URDF's
velocity limits) stops with a typed error naming the step, the joint and the value; the steps before it are
written as a partial result. On 0d7b885 nothing bounded a run: lwr_relaxed with its obstacle moved recorded ~1,850
steps of divergence (joint angles up to 1e119 rad) until a NaN."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hqp_tpm.app import scenario
from hqp_tpm.app.build import build_run
from hqp_tpm.app.cli import run_scenario
from hqp_tpm.errors import DivergedError, ScenarioError


def _planar(bound=None):
    data = scenario.read(scenario.resolve_path("planar5_exact"))
    data["scenario"]["duration"] = 0.3
    if bound is not None:
        data["scenario"]["velocity_bound"] = bound
    return data


def test_a_run_beyond_its_velocity_bound_stops_with_its_partial_result(tmp_path):
    """A bound far below what the run needs forces the stop: the error names step, joint and value, and the folder
    holds exactly the steps before it, marked partial."""
    data = _planar(0.05)
    ctx = build_run(scenario.parse(data))
    bound = ctx.velocity_bound
    # where the unbounded run first leaves it: the step and joint the error must name
    free = run_scenario(scenario.parse(_planar()), tmp_path / "free", progress=False, figures=False, replay=False)
    dq = np.load(tmp_path / "free" / "trajectory.npz")["dq"]
    over = np.abs(dq) > bound
    k = int(np.flatnonzero(over.any(axis=1))[0])
    j = int(np.argmax(np.where(over[k], np.abs(dq[k]) / bound, -1.0)))
    assert 0 < k < free["steps"] - 1
    with pytest.raises(DivergedError, match=rf"at step {k + 1} \(t = .*\) the velocity of joint "
                                            rf"{ctx.robot.joint_names[j]} is {dq[k, j]:.6g} rad/s") as err:
        run_scenario(scenario.parse(data), tmp_path / "stopped", progress=False, figures=False, replay=False)
    out = err.value.partial_result
    assert out is not None
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "partial" and manifest["steps"] == k
    kept = np.load(out / "trajectory.npz")["dq"]
    np.testing.assert_array_equal(kept, dq[:k])  # the steps before, as the unbounded run computed them
    assert (np.abs(kept) <= bound).all()


def test_the_default_bound_is_a_thousand_times_the_urdf_velocity_limits():
    ctx = build_run(scenario.load("lwr_tracking"))
    v = ctx.robot.velocity_limits()
    assert np.isfinite(v).all()
    np.testing.assert_array_equal(ctx.velocity_bound, 1000.0 * v)
    # lwr_relaxed sets 10 (its diverging obstacle placements stop near 22 rad/s)
    np.testing.assert_array_equal(build_run(scenario.load("lwr_relaxed")).velocity_bound, 10.0 * v)


def test_planar5_has_no_urdf_velocity_limits_and_gets_the_stated_value():
    from hqp_tpm.app.context import UNLIMITED_VELOCITY

    ctx = build_run(scenario.parse(_planar(2.0)))
    v = ctx.robot.velocity_limits()
    np.testing.assert_array_equal(ctx.velocity_bound, 2.0 * np.where(np.isfinite(v), v, UNLIMITED_VELOCITY))


@pytest.mark.parametrize("bad", [0.0, -1.0])
def test_a_bound_that_is_not_positive_is_a_scenario_error(bad):
    with pytest.raises(ScenarioError, match=r"planar5_exact.*velocity_bound: must be > 0"):
        scenario.parse(_planar(bad), scenario.resolve_path("planar5_exact"))
