"""Issue 31, item 1: the command-rate bound at velocity level (``[limits] command_rate``), and the ``chatter`` metric.

On 0d7b885 the velocity box held position and velocity limits only: ``hqp-tpm run romeo_sns_tpm`` changed a joint
velocity by up to 7.4 rad/s in one 1 ms step (the acceleration limit is 50 rad/s^2, i.e. 0.05 rad/s per step).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_joint_boxes import literal_velocity_box

from hqp_tpm.app import build, scenario
from hqp_tpm.app.results import chatter
from hqp_tpm.errors import ParameterError
from hqp_tpm.robot.joint_boxes import BoxLimits, command_rate_box
from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State


def _limits(rng, n):
    q_min = rng.uniform(-2.0, -0.2, n)
    q_max = rng.uniform(0.2, 2.0, n)
    return q_min, q_max, rng.uniform(0.5, 3.0, n), rng.uniform(5.0, 80.0, n)


@pytest.mark.parametrize("seed", range(6))
def test_rate_box_rollouts_keep_every_limit_and_never_become_disjoint(seed):
    """Commands drawn anywhere in the box (its ends included, the worst case) for 3,000 steps: the rate and the
    position/velocity boxes always intersect (so the change is <= a_max dt), positions and velocities stay inside."""
    rng = np.random.default_rng(seed)
    n, dt = 7, 1e-3
    q_min, q_max, v_max, a_max = _limits(rng, n)
    L = BoxLimits(q_min, q_max, v_max, a_max, dt)
    q, v = rng.uniform(q_min / 2, q_max / 2), np.zeros(n)
    for k in range(3000):
        lo, up = L.velocity_box(q, v)
        assert (lo <= up).all()
        # the two boxes intersect: the rate box is not clipped away (a change beyond a_max dt never needed)
        assert (lo >= v - a_max * dt - 1e-12).all() and (up <= v + a_max * dt + 1e-12).all()
        pick = rng.integers(0, 3, n)  # lower end, upper end or inside: pushes into the limits
        x = np.where(pick == 0, lo, np.where(pick == 1, up, rng.uniform(lo, up)))
        if k % 500 < 250:
            x = up  # long runs at the upper end: braking into the position limits
        assert (np.abs(x - v) <= a_max * dt + 1e-12).all()
        assert (np.abs(x) <= v_max + 1e-12).all()
        q, v = q + x * dt, x
        assert (q >= q_min - 1e-12).all() and (q <= q_max + 1e-12).all()


def test_disjoint_boxes_the_position_and_velocity_limits_win():
    """A previous command outside the new box by more than a_max dt (a state that starts too fast): both bounds are
    the end of the position/velocity box nearest to it (the smallest change the limits allow)."""
    lo, up = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])
    dq = np.array([3.0, -3.0, 0.5])
    a, b = command_rate_box(lo, up, dq, 0.05)
    np.testing.assert_array_equal(a, [1.0, -1.0, 0.45])
    np.testing.assert_array_equal(b, [1.0, -1.0, 0.55])


def test_joint_limits_rate_box_is_the_literal_formula_to_the_bit():
    """JointLimits(command_rate=True) on a robot's state (its kernel, compiled or as Python): the literal discrete
    braking and rate box of tests/test_joint_boxes.py."""
    rng = np.random.default_rng(3)
    robot = Robot.load("lwr4")
    lim = JointLimits(robot, order=1, dt=1e-3, command_rate=True, acceleration_limit=30.0)
    q_lo, q_up = robot.position_limits()
    for _ in range(500):
        q = rng.uniform(q_lo, q_up) * rng.choice([1.0, 1.02])
        v = rng.uniform(-2.0, 2.0, robot.nv) * rng.choice([0.0, 0.01, 1.0])
        lo, up = lim(State(robot).update(q, v), 0.0)
        ref = literal_velocity_box(q[lim.qidx], lim.q_min, lim.q_max, lim.v_max, lim.a_max, 1e-3, v[lim.cols])
        np.testing.assert_array_equal(lo[lim.cols], ref[0])
        np.testing.assert_array_equal(up[lim.cols], ref[1])


def test_command_rate_needs_velocity_level():
    with pytest.raises(ParameterError, match="command_rate"):
        JointLimits(Robot.load("lwr4"), order=2, dt=1e-3, command_rate=True)


def _romeo(name, steps, lean):
    sc = scenario.load(name)
    _, ctrl, _, _ = build.build(sc)
    assert ctrl.box.command_rate  # on by default in the shipped boxed scenarios

    def step():
        return ctrl.step(record=not lean).command

    out, worst_box, worst_rate = [], 0.0, 0.0
    lim = ctrl.box
    for _ in range(steps):
        v = ctrl.v.copy()
        lo, up = lim(ctrl.state.update(ctrl.q, ctrl.v, ctrl.t), ctrl.t)
        x = step()
        worst_box = max(worst_box, float(np.max(np.maximum(lo - x, x - up))))
        worst_rate = max(worst_rate, float(np.abs(x - v)[lim.cols].max()))
        out.append(x)
    return np.array(out), worst_box, worst_rate, lim


@pytest.mark.slow
@pytest.mark.parametrize("name,steps", [("romeo_sns_tpm", 400), ("romeo_sns", 150), ("romeo_qp", 100)])
def test_romeo_commands_change_by_at_most_a_max_dt_and_lean_equals_readable(name, steps):
    """Through the start-up (from rest, the hands' reference moving at once: the bound binds): every step's change
    of a joint command <= 50 rad/s^2 x 1 ms (+1e-9), inside the joint box; the lean step the runner picks gives the
    same commands as ``ctrl.step()``."""
    fast, box_f, rate_f, lim = _romeo(name, steps, lean=True)
    slow, box_s, rate_s, _ = _romeo(name, steps, lean=False)
    bound = float(lim.a_max.max()) * lim.dt
    assert bound == pytest.approx(0.05)
    assert max(rate_f, rate_s) <= bound + 1e-9
    assert max(box_f, box_s) <= 1e-9
    # the compiled step computes the feet's rotation errors itself (log3 within a few ulps of pinocchio's, the
    # guarantee of hqp_tpm.control._planned_step): bit-equal with pinocchio >= 3.8, 5e-12 apart with pin 3.4.0
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-9)


def test_paper_literal_box_is_kept_as_an_option():
    """``command_rate = false``: papers/002's box (the position one period ahead, braking sqrt(2 a gap), velocity)."""
    data = scenario.read(scenario.resolve_path("romeo_sns_tpm"))
    data["limits"]["command_rate"] = False
    _, ctrl, _, _ = build.build(scenario.parse(data))
    assert not ctrl.box.command_rate
    st = ctrl.state.update(ctrl.q, np.full(ctrl.robot.nv, 1.0), 0.0)
    lo, up = ctrl.box(st, 0.0)
    ref = ctrl.box.limits.velocity_box(st.q[ctrl.box.qidx])
    np.testing.assert_array_equal(lo[ctrl.box.cols], ref[0])
    np.testing.assert_array_equal(up[ctrl.box.cols], ref[1])


def test_chatter_counts_sign_changes_of_the_rate_per_joint_and_second():
    t = np.arange(1001) * 1e-3  # 1 s
    flip = np.where(np.arange(1001) % 2 == 0, 1.0, -1.0)  # a command between its box's two sides every step
    smooth = np.sin(2 * np.pi * t)  # one period: its rate changes sign twice
    noise = 1e-9 * flip  # below the dead band
    per_joint = chatter(np.column_stack([flip, smooth, noise]), t)
    assert per_joint[0] == pytest.approx(999.0)  # 1,000 rates, 999 sign changes, in 1 s
    assert per_joint[1] == pytest.approx(2.0)
    assert per_joint[2] == 0.0
