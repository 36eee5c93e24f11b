"""Romeo under joint velocity limits (papers/002): the SNS solvers and the QP keep every box, TPM does not."""

import numpy as np
import pytest

from hqp_tpm.app import build, scenario
from hqp_tpm.solvers import sns_tpm, tpm


def run(name, steps, command_rate=True):
    data = scenario.read(scenario.resolve_path(name))
    data["limits"]["command_rate"] = command_rate
    _, ctrl, _, _ = build.build(scenario.parse(data))
    worst = 0.0
    scales, saturated = [], 0
    for _ in range(steps):
        lo, up = ctrl.box(ctrl.state.update(ctrl.q, ctrl.v, ctrl.t), ctrl.t)
        res = ctrl.step()
        worst = max(worst, float(np.max(np.maximum(lo - res.command, res.command - up))))
        scales.append(res.info.get("scale", 1.0))
        saturated += bool(res.info.get("saturated"))
    return worst, np.array(scales), ctrl, saturated


@pytest.mark.parametrize("name", ["romeo_sns_tpm", "romeo_sns"])
def test_sns_solvers_stay_in_the_joint_velocity_box(name):
    """papers/002's box (``command_rate = false``): the boxes bind and the scale factor is used."""
    worst, scales, _, _ = run(name, 1300, command_rate=False)  # through the first hand-circle quarter
    assert worst <= 1e-9
    assert scales.min() < 1.0  # the boxes did bind: the scale factor was used


@pytest.mark.parametrize("name", ["romeo_sns_tpm", "romeo_sns"])
def test_sns_solvers_stay_in_the_rate_bounded_box(name):
    """The shipped box (``command_rate = true``, issue 31): solved for the change of the command
    (hqp_tpm.control.command_rate), the box still holds and binds (joints saturate) through the start-up."""
    worst, _, _, saturated = run(name, 400)
    assert worst <= 1e-9
    assert saturated > 0


def test_tpm_alone_leaves_the_box_and_sns_tpm_equals_tpm_when_nothing_binds():
    sc = scenario.load("romeo_sns_tpm")
    _, ctrl, _, _ = build.build(sc)
    res = ctrl.step()  # first step: far from any bound
    lo, up = ctrl.box(ctrl.state, ctrl.t)
    x_tpm = tpm(res.levels, lambda_max=0.05, eps=0.1)
    x_sns = sns_tpm(res.levels, np.full_like(lo, -1e9), np.full_like(up, 1e9), lambda_max=0.05, eps=0.1)
    np.testing.assert_allclose(x_sns, x_tpm, atol=1e-12)
    sc = scenario.load("romeo_tpm")
    _, ctrl, _, _ = build.build(sc)
    v = ctrl.robot.velocity_limits()
    over = 0
    for _ in range(1300):
        res = ctrl.step()
        over += bool((np.abs(res.command) > v + 1e-9).any())
    assert over > 0  # papers/002: TPM alone exceeds the limits
