"""Joint boxes (hqp_tpm.robot.joint_boxes): docs/setups.md's velocity box, the derived acceleration box,
their invariance over long random rollouts, the recovery from states outside the limits, bad input."""

import os
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from threadpoolctl import threadpool_limits

from hqp_tpm.errors import BoxError, HqpTpmError, ShapeError
from hqp_tpm.robot import _compiled
from hqp_tpm.robot.joint_boxes import BoxLimits, acceleration_box, is_viable, velocity_box

#: Number of hypothesis draws of (limits, state); rollouts are 2,000 steps each.
DRAWS = int(os.environ.get("HQP_TPM_SNS_DRAWS", "2000"))
ROLLOUT_DRAWS = max(10, DRAWS // 100)   # each a 2,000-step rollout of 20 joints
STEPS = 2000
TOL = 1e-9
SETTINGS = settings(max_examples=DRAWS, deadline=None, suppress_health_check=[HealthCheck.too_slow])
ROLLOUT_SETTINGS = settings(max_examples=ROLLOUT_DRAWS, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def random_limits(rng, n):
    """Joint ranges from 1e-3 to 6 rad (some one-sided or unbounded), v_max, a_max and a period."""
    q_min = rng.uniform(-3.0, 1.0, n)
    q_max = q_min + np.exp(rng.uniform(np.log(1e-3), np.log(6.0), n))
    q_min[rng.random(n) < 0.05] = -np.inf
    q_max[rng.random(n) < 0.05] = np.inf
    v_max = np.exp(rng.uniform(np.log(0.05), np.log(10.0), n))
    a_max = np.exp(rng.uniform(np.log(0.1), np.log(100.0), n))
    dt = float(rng.choice([1e-3, 5e-3, 1e-2, 0.1]))
    return q_min, q_max, v_max, a_max, dt


def inside(rng, q_min, q_max):
    """Positions inside the limits, a fifth of them exactly on a limit."""
    lo = np.where(np.isfinite(q_min), q_min, np.where(np.isfinite(q_max), q_max - 5.0, -5.0))
    up = np.where(np.isfinite(q_max), q_max, lo + 5.0)
    q = rng.uniform(lo, up)
    edge = rng.random(q.size)
    q = np.where(edge < 0.1, lo, np.where(edge < 0.2, up, q))
    return q


def viable_velocity(rng, q, q_min, q_max, v_max, a_max, dt):
    """A velocity from which the joint can still stop before its limits (see acceleration_box)."""
    ad = a_max * dt
    with np.errstate(invalid="ignore"):
        v_up = -0.5 * ad + np.sqrt(0.25 * ad * ad + 2.0 * a_max * (q_max - q))
        v_lo = 0.5 * ad - np.sqrt(0.25 * ad * ad + 2.0 * a_max * (q - q_min))
    v_up = np.minimum(np.nan_to_num(v_up, posinf=np.inf), v_max)
    v_lo = np.maximum(np.nan_to_num(v_lo, neginf=-np.inf), -v_max)
    v = rng.uniform(v_lo, v_up)
    edge = rng.random(q.size)
    return np.where(edge < 0.15, v_lo, np.where(edge < 0.3, v_up, v))


def command_in(rng, lower, upper):
    """A command inside the box: its edges half of the time, else uniform."""
    u = rng.uniform(lower, upper)
    pick = rng.random(lower.size)
    return np.where(pick < 0.25, lower, np.where(pick < 0.5, upper, u))


def assert_within(q, q_min, q_max, what):
    scale = 1.0 + np.abs(np.where(np.isfinite(q), q, 0.0))
    bad = (q < q_min - TOL * scale) | (q > q_max + TOL * scale)
    assert not bad.any(), f"{what}: joints {np.flatnonzero(bad)} left [{q_min[bad]}, {q_max[bad]}]: {q[bad]}"


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread():
    """Small matrices: BLAS threads only stall (by 10-40 ms on a busy 2-core machine), so use one."""
    with threadpool_limits(1):
        yield


seeds = st.integers(0, 2**32 - 1)


# ----------------------------------------------------------------------------------------
# Velocity level.
# ----------------------------------------------------------------------------------------
@SETTINGS
@given(seeds)
def test_velocity_box_is_the_reference_formula_and_keeps_the_next_position(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 8))
    q_min, q_max, v_max, a_max, dt = random_limits(rng, n)
    q = inside(rng, q_min, q_max)
    lower, upper = velocity_box(q, q_min, q_max, v_max, a_max, dt)
    with np.errstate(invalid="ignore"):
        ref_lo = np.maximum.reduce([(q_min - q) / dt, -v_max, -np.sqrt(2 * a_max * (q - q_min))])
        ref_up = np.minimum.reduce([(q_max - q) / dt, v_max, np.sqrt(2 * a_max * (q_max - q))])
    np.testing.assert_allclose(lower, ref_lo, rtol=1e-14, atol=0)
    np.testing.assert_allclose(upper, ref_up, rtol=1e-14, atol=0)
    assert (lower <= 0.0).all() and (upper >= 0.0).all()
    for u in (lower, upper, command_in(rng, lower, upper)):
        assert_within(q + u * dt, q_min, q_max, "one step")


@ROLLOUT_SETTINGS
@given(seeds)
def test_velocity_box_rollouts_stay_inside(seed):
    """2,000 steps of commands drawn inside the box (half of them on its edges), 20 joints at once."""
    rng = np.random.default_rng(seed)
    q_min, q_max, v_max, a_max, dt = random_limits(rng, 20)
    q = inside(rng, q_min, q_max)
    for k in range(STEPS):
        lower, upper = velocity_box(q, q_min, q_max, v_max, a_max, dt)
        assert (lower <= upper).all(), f"step {k}: empty box"
        q = q + command_in(rng, lower, upper) * dt
        assert_within(q, q_min, q_max, f"step {k}")


@ROLLOUT_SETTINGS
@given(seeds)
def test_velocity_box_recovery_from_outside(seed):
    """A joint outside its range is driven back at min((distance)/dt, v_max) and then stays inside."""
    rng = np.random.default_rng(seed)
    n = 20
    q_min, q_max, v_max, a_max, dt = random_limits(rng, n)
    q_min, q_max = np.nan_to_num(q_min, neginf=-3.0), np.nan_to_num(q_max, posinf=4.0)
    out = rng.uniform(1e-6, 1.0, n) * np.minimum(1.0, 300 * v_max * dt) * np.where(rng.random(n) < 0.5, -1.0, 1.0)
    q = np.where(out < 0, q_min + out, q_max + out)
    lower, upper = velocity_box(q, q_min, q_max, v_max, a_max, dt)
    assert (lower <= upper).all() and (np.abs(lower) <= v_max).all() and (np.abs(upper) <= v_max).all()
    rate = np.minimum(np.maximum(q_min - q, q - q_max) / dt, v_max)
    below = out < 0
    np.testing.assert_allclose(lower[below], rate[below], rtol=1e-12)
    np.testing.assert_allclose(upper[~below], -rate[~below], rtol=1e-12)
    steps_back = np.ceil(np.abs(out) / (v_max * dt) * (1 + 1e-9)).astype(int) + 1
    back = np.zeros(n, dtype=bool)
    for k in range(int(steps_back.max()) + 50):
        lower, upper = velocity_box(q, q_min, q_max, v_max, a_max, dt)
        assert (lower <= upper).all()
        q = q + command_in(rng, lower, upper) * dt
        now_in = (q >= q_min - 1e-12) & (q <= q_max + 1e-12)
        assert not (back & ~now_in).any(), f"step {k}: a joint left its range again"
        back |= now_in
        assert (back | (k + 1 < steps_back)).all(), f"step {k}: not back inside after {steps_back} steps"
    assert back.all()


# ----------------------------------------------------------------------------------------
# Acceleration level.
# ----------------------------------------------------------------------------------------
@SETTINGS
@given(seeds)
def test_acceleration_box_is_nonempty_and_keeps_the_next_state_viable(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 8))
    q_min, q_max, v_max, a_max, dt = random_limits(rng, n)
    q = inside(rng, q_min, q_max)
    dq = viable_velocity(rng, q, q_min, q_max, v_max, a_max, dt)
    assert is_viable(q, dq, q_min, q_max, v_max, a_max, dt, tol=1e-12).all()
    lower, upper = acceleration_box(q, dq, q_min, q_max, v_max, a_max, dt)
    assert (lower <= upper).all()
    assert (lower >= -a_max).all() and (upper <= a_max).all()
    for u in (lower, upper, command_in(rng, lower, upper)):
        q1 = q + dq * dt + 0.5 * u * dt * dt
        dq1 = dq + u * dt
        assert_within(q1, q_min, q_max, "one step, position")
        assert_within(dq1, -v_max, v_max, "one step, velocity")
        assert is_viable(q1, dq1, q_min, q_max, v_max, a_max, dt, tol=1e-9).all()


@SETTINGS
@given(seeds)
def test_acceleration_box_is_nonempty_for_any_state_inside_the_limits(seed):
    """Also for states inside the position and velocity limits that can no longer stop in time."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 8))
    q_min, q_max, v_max, a_max, dt = random_limits(rng, n)
    q = inside(rng, q_min, q_max)
    dq = rng.uniform(-v_max, v_max)
    lower, upper = acceleration_box(q, dq, q_min, q_max, v_max, a_max, dt)
    assert (lower <= upper).all() and (lower >= -a_max).all() and (upper <= a_max).all()
    # too fast to stop in time: back to the limit at the next sample, or the hardest braking allowed
    fast_up = ~is_viable(q, dq, q_min, q_max, v_max, a_max, dt) & (dq > 0)
    hardest = np.clip((-v_max - dq) / dt, -a_max, a_max)
    q1 = q + dq * dt + 0.5 * upper * dt * dt
    assert ((q1 <= q_max + 1e-12 * (1 + np.abs(q_max))) | (upper == hardest))[fast_up].all()


@ROLLOUT_SETTINGS
@given(seeds)
def test_acceleration_box_rollouts_stay_inside(seed):
    """2,000 steps, q <- q + qd dt + qdd dt^2/2, qd <- qd + qdd dt, qdd drawn inside the box (edges half the time)."""
    rng = np.random.default_rng(seed)
    q_min, q_max, v_max, a_max, dt = random_limits(rng, 20)
    q = inside(rng, q_min, q_max)
    dq = viable_velocity(rng, q, q_min, q_max, v_max, a_max, dt)
    for k in range(STEPS):
        lower, upper = acceleration_box(q, dq, q_min, q_max, v_max, a_max, dt)
        assert (lower <= upper).all(), f"step {k}: empty box"
        u = command_in(rng, lower, upper)
        q, dq = q + dq * dt + 0.5 * u * dt * dt, dq + u * dt
        assert_within(q, q_min, q_max, f"step {k}, position")
        assert_within(dq, -v_max, v_max, f"step {k}, velocity")


@ROLLOUT_SETTINGS
@given(seeds)
def test_acceleration_box_recovery_from_outside(seed):
    """Outside the range (or too fast): lower <= upper, |qdd| <= a_max, and the joint comes back and stays."""
    rng = np.random.default_rng(seed)
    n = 20
    q_min, q_max, v_max, a_max, dt = random_limits(rng, n)
    q_min, q_max = np.nan_to_num(q_min, neginf=-3.0), np.nan_to_num(q_max, posinf=4.0)
    a_max = v_max * rng.uniform(5.0, 50.0, n)  # time constants v_max/a_max <= 0.2 s keep the rollout short
    dt = 1e-2
    out = rng.uniform(1e-6, 0.5, n) * np.where(rng.random(n) < 0.5, -1.0, 1.0)
    q = np.where(out < 0, q_min + out, q_max + out)
    dq = rng.uniform(-2.0, 2.0, n) * v_max  # possibly beyond v_max as well
    lower, upper = acceleration_box(q, dq, q_min, q_max, v_max, a_max, dt)
    assert (lower <= upper).all() and (np.abs(lower) <= a_max).all() and (np.abs(upper) <= a_max).all()
    # above the range and not moving back: either back inside in one step or the hardest admissible return
    above = (out > 0) & (dq >= 0)
    hardest = np.clip((-v_max - dq) / dt, -a_max, a_max)
    q1 = q + dq * dt + 0.5 * upper * dt * dt
    assert ((q1 <= q_max + 1e-12) | (upper == hardest))[above].all()
    back = np.zeros(n, dtype=bool)
    for k in range(20000):
        lower, upper = acceleration_box(q, dq, q_min, q_max, v_max, a_max, dt)
        assert (lower <= upper).all()
        u = command_in(rng, lower, upper)
        q, dq = q + dq * dt + 0.5 * u * dt * dt, dq + u * dt
        ok = is_viable(q, dq, q_min, q_max, v_max, a_max, dt, tol=1e-9)
        assert not (back & ~ok).any(), f"step {k}: a recovered joint left the viable set"
        back |= ok
        if back.all():
            break
    assert back.all(), "joints not back inside within 200 s"  # a few v_max/a_max + distance/v_max suffice


# ----------------------------------------------------------------------------------------
# Bad input.
# ----------------------------------------------------------------------------------------
def test_lower_limit_above_upper_names_the_joint():
    with pytest.raises(BoxError, match=r"joint 2.*q_min\[2\] = 1\.5 > .*q_max\[2\] = 1\.0"):
        velocity_box(np.zeros(3), [-1, -1, 1.5], [1, 1, 1.0], 1.0, 1.0, 0.01)
    with pytest.raises(BoxError, match="joint 1"):
        acceleration_box(np.zeros(2), np.zeros(2), [-1, 2], [1, 1], 1.0, 1.0, 0.01)


@pytest.mark.parametrize("fn", ["velocity", "acceleration"])
def test_wrong_lengths_and_nan(fn):
    def call(q, q_min, q_max, v_max=1.0, a_max=1.0, dt=0.01, dq=None):
        if fn == "velocity":
            return velocity_box(q, q_min, q_max, v_max, a_max, dt)
        return acceleration_box(q, np.zeros(np.size(q)) if dq is None else dq, q_min, q_max, v_max, a_max, dt)

    with pytest.raises(ShapeError, match=r"q_max has shape \(2,\), expected \(3,\)"):
        call(np.zeros(3), -np.ones(3), np.ones(2))
    with pytest.raises(ShapeError, match="v_max"):
        call(np.zeros(3), -np.ones(3), np.ones(3), v_max=np.ones(4))
    with pytest.raises(BoxError, match=r"q_min\[1\] is NaN.*joint 1"):
        call(np.zeros(3), [-1, np.nan, -1], np.ones(3))
    with pytest.raises(BoxError, match=r"q\[0\].*joint 0"):
        call([np.nan, 0, 0], -np.ones(3), np.ones(3))
    with pytest.raises(BoxError, match=r"a_max\[2\] = -1.0 is negative"):
        call(np.zeros(3), -np.ones(3), np.ones(3), a_max=[1, 1, -1])
    with pytest.raises(BoxError, match="dt"):
        call(np.zeros(3), -np.ones(3), np.ones(3), dt=0.0)
    if fn == "acceleration":
        with pytest.raises(ShapeError, match="dq"):
            call(np.zeros(3), -np.ones(3), np.ones(3), dq=np.zeros(2))
        with pytest.raises(BoxError, match=r"dq\[2\]"):
            call(np.zeros(3), -np.ones(3), np.ones(3), dq=[0, 0, np.inf])
    with pytest.raises(HqpTpmError):
        call(np.zeros((2, 2)), -np.ones(2), np.ones(2))


def test_infinite_limits_and_zero_rates():
    lower, upper = velocity_box([0.0, 5.0], [-np.inf, -np.inf], [np.inf, np.inf], [1.0, 2.0], [3.0, 0.0], 0.01)
    np.testing.assert_array_equal(lower, [-1.0, -2.0])  # no limit to brake for
    np.testing.assert_array_equal(upper, [1.0, 2.0])
    lower, upper = velocity_box([0.0], [-1.0], [1.0], [1.0], [0.0], 0.01)
    np.testing.assert_array_equal([lower[0], upper[0]], [0.0, 0.0])  # a_max = 0 and a limit: cannot move
    lower, upper = acceleration_box([0.0], [0.5], [-np.inf], [np.inf], [1.0], [3.0], 0.01)
    np.testing.assert_allclose([lower[0], upper[0]], [-3.0, 3.0])


# ----------------------------------------------------------------------------------------
# The kernels (BoxLimits, JointLimits, the compiled SNS step) against the literal formulas.
# ----------------------------------------------------------------------------------------
def literal_velocity_box(q, q_min, q_max, v_max, a_max, dt, dq=None):
    """velocity_box as first written: every term per call, np.errstate for 0 * inf; with ``dq`` (the previous
    command) the discrete braking term (docs/internals.md#joint-boxes), then the command-rate box. Also whether every
    position box was non-empty (the kernels' flag)."""
    ad = a_max * dt
    with np.errstate(invalid="ignore", divide="ignore"):
        def braking(gap):
            if dq is None:
                return np.sqrt(2.0 * a_max * gap)
            m = np.floor((np.sqrt(1.0 + 8.0 * (gap / (ad * dt))) - 1.0) * 0.5)
            return (gap / dt + ad * (m * (m + 1.0)) * 0.5) / (m + 1.0)

        stop_lo = -braking(np.maximum(q - q_min, 0.0))
        stop_up = braking(np.maximum(q_max - q, 0.0))
    stop_lo = np.where(np.isneginf(q_min), -np.inf, np.where(a_max == 0.0, 0.0, stop_lo))
    stop_up = np.where(np.isposinf(q_max), np.inf, np.where(a_max == 0.0, 0.0, stop_up))
    p_lo, p_up = np.maximum((q_min - q) / dt, stop_lo), np.minimum((q_max - q) / dt, stop_up)
    lo, up = literal_project(p_lo, p_up, -v_max, v_max, q < q_min, q > q_max)
    if dq is not None:
        lo, up = np.minimum(np.maximum(dq - ad, lo), up), np.minimum(np.maximum(dq + ad, lo), up)
    return lo, up, bool((p_lo <= p_up).all())


def literal_acceleration_box(q, dq, q_min, q_max, v_max, a_max, dt):
    """acceleration_box as first written; also whether every state was viable (the kernels' flag)."""
    def braking(delta):
        ad = a_max * dt
        with np.errstate(invalid="ignore"):
            root = -ad + np.sqrt(ad * ad + 2.0 * a_max * np.maximum(delta, 0.0))
        root = np.where(np.isposinf(delta), np.inf, root)
        return np.where(delta >= 0.0, root, 2.0 * delta / dt)

    delta_up, delta_lo = q_max - q - 0.5 * dq * dt, q - q_min + 0.5 * dq * dt
    p_lo, p_up = (-braking(delta_lo) - dq) / dt, (braking(delta_up) - dq) / dt
    lo, up = literal_project(p_lo, p_up, np.clip((-v_max - dq) / dt, -a_max, a_max),
                             np.clip((v_max - dq) / dt, -a_max, a_max), delta_lo < 0.0, delta_up < 0.0)
    return lo, up, bool(((delta_lo >= 0.0) & (delta_up >= 0.0) & (p_lo <= p_up)).all())


def literal_project(p_lo, p_up, lo, up, violated_lo, violated_up):
    empty = p_lo > p_up
    p_up = np.where(empty & violated_lo, p_lo, p_up)
    p_lo = np.where(empty & ~violated_lo & violated_up, p_up, p_lo)
    p_up = np.maximum(p_up, p_lo)
    return np.clip(p_lo, lo, up), np.clip(p_up, lo, up)


def assert_same_box(got, expected):
    """The same bits, even the zeros' signs."""
    for g, e in zip(got, expected[:2], strict=True):
        np.testing.assert_array_equal(g, e)
        assert np.signbit(g).tolist() == np.signbit(e).tolist()


def random_case(rng, n):
    """Limits (infinite, zero-width, v_max = 0, a_max = 0 among them) and a state inside, on, just beyond and far
    beyond them."""
    q_min, q_max, v_max, a_max, dt = random_limits(rng, n)
    q_max = np.where(rng.random(n) < 0.05, np.where(np.isfinite(q_min), q_min, q_max), q_max)
    v_max[rng.random(n) < 0.05] = 0.0
    a_max[rng.random(n) < 0.1] = 0.0
    q = np.where(rng.random(n) < 0.7, inside(rng, q_min, q_max), rng.uniform(-8.0, 8.0, n))
    beyond = rng.random(n)
    q = np.where((beyond < 0.05) & np.isfinite(q_min), np.nextafter(q_min, -np.inf), q)
    q = np.where((beyond > 0.95) & np.isfinite(q_max), np.nextafter(q_max, np.inf), q)
    dq = rng.uniform(-2.0, 2.0, n) * v_max * rng.choice([0.0, 0.01, 1.0, 3.0])
    return q_min, q_max, v_max, a_max, dt, q, dq


def test_box_limits_equal_the_literal_formulas_without_warnings():
    """Same bits as the literal boxes, with zero a_max, infinite limits and states outside; no RuntimeWarning."""
    rng = np.random.default_rng(11)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for _ in range(500):
            n = int(rng.integers(1, 30))
            q_min, q_max, v_max, a_max, dt, q, dq = random_case(rng, n)
            limits = BoxLimits(q_min, q_max, v_max, a_max, dt)
            assert_same_box(limits.velocity_box(q), literal_velocity_box(q, q_min, q_max, v_max, a_max, dt))
            assert_same_box(velocity_box(q, q_min, q_max, v_max, a_max, dt), limits.velocity_box(q))
            assert_same_box(limits.velocity_box(q, dq), literal_velocity_box(q, q_min, q_max, v_max, a_max, dt, dq))
            assert_same_box(limits.acceleration_box(q, dq),
                            literal_acceleration_box(q, dq, q_min, q_max, v_max, a_max, dt))
            assert_same_box(acceleration_box(q, dq, q_min, q_max, v_max, a_max, dt), limits.acceleration_box(q, dq))
        viable = is_viable([0.0, 0.5], [0.0, 0.1], [-1.0, -1.0], [1.0, 1.0], 1.0, [0.0, 0.0], 0.01)  # a_max = 0
        assert viable.tolist() == [True, False]


@pytest.mark.parametrize("source", [False, True], ids=["as-run", "python-source"])
def test_kernels_equal_the_literal_formulas_and_flag_recovery(source):
    """The box kernels (compiled when numba is on, and their Python source) at scattered state and box indices, as
    JointLimits and the compiled SNS step call them: the literal boxes' bits, the other entries untouched, and False
    exactly when a position box was empty (velocity) or a state not viable (acceleration)."""
    kernels = [getattr(k, "py_func", k) if source else k for k in (_compiled.velocity_box, _compiled.acceleration_box)]
    rng = np.random.default_rng(12)
    flags = set()
    for _ in range(300):
        n = int(rng.integers(1, 12))
        q_min, q_max, v_max, a_max, dt, q, dq = random_case(rng, n)
        P = BoxLimits(q_min, q_max, v_max, a_max, dt).rows
        idx = np.vstack([rng.permutation(n + 3)[:n], rng.permutation(n + 2)[:n]]).astype(np.int64)
        q_all, v_all = np.full(n + 3, np.nan), np.full(n + 2, np.nan)
        q_all[idx[0]], v_all[idx[1]] = q, dq
        for which, expected in ((0, literal_velocity_box(q, q_min, q_max, v_max, a_max, dt)),
                                (1, literal_velocity_box(q, q_min, q_max, v_max, a_max, dt, dq)),
                                (2, literal_acceleration_box(q, dq, q_min, q_max, v_max, a_max, dt))):
            lo, up = np.full(n + 2, 7.0), np.full(n + 2, 7.0)
            if which == 0:
                ok = kernels[0](q_all, P, idx, dt, lo, up)
            elif which == 1:
                ok = kernels[0](q_all, P, idx, dt, lo, up, v_all)
            else:
                ok = kernels[1](q_all, v_all, P, idx, dt, lo, up)
            assert_same_box((lo[idx[1]], up[idx[1]]), expected)
            assert ok == expected[2]
            flags.add(ok)
            rest = np.setdiff1d(np.arange(n + 2), idx[1])
            assert (lo[rest] == 7.0).all() and (up[rest] == 7.0).all()
    assert flags == {True, False}


def test_box_limits_check_the_limits_once_at_construction():
    with pytest.raises(BoxError, match=r"joint 1.*q_min\[1\] = 2\.0 > .*q_max\[1\] = 1\.0"):
        BoxLimits([-1.0, 2.0], [1.0, 1.0], 1.0, 1.0, 0.01)
    with pytest.raises(BoxError, match=r"v_max\[0\]"):
        BoxLimits([-1.0], [1.0], [np.nan], 1.0, 0.01)
    with pytest.raises(ShapeError, match="q_min"):
        BoxLimits(np.zeros((2, 2)), np.ones(2), 1.0, 1.0, 0.01)
