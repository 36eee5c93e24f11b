"""SNS-TPM (papers/002 Algorithm 1, eq. (4)) and the multi-task SNS (T-RO 2015) under joint boxes.

The random draws of (stack, box) are hypothesis examples; their number is ``HQP_TPM_SNS_DRAWS``
(default 2,000; the long run of the issue uses 100,000).
"""

import importlib
import os

import numpy as np
import pytest
from conftest import random_stack, rel_diff
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from threadpoolctl import threadpool_limits

from hqp_tpm.errors import BoxError, ShapeError, SolverFailedError
from hqp_tpm.robot.joint_boxes import acceleration_box, velocity_box
from hqp_tpm.solvers import Level, cascaded_qp, nullspace, tpm
from hqp_tpm.solvers.sns import sns, sns_tpm, sns_tpm_reference, task_scaling_factor
from hqp_tpm.testing.strategies import box_without_zero, problems, random_problem

sns_module = importlib.import_module("hqp_tpm.solvers.sns")  # the package re-exports the function sns
DRAWS = int(os.environ.get("HQP_TPM_SNS_DRAWS", "2000"))
SETTINGS = settings(max_examples=DRAWS, deadline=None, suppress_health_check=[HealthCheck.too_slow],
                    derandomize=True)
FEW = settings(max_examples=max(10, DRAWS // 100), deadline=None, suppress_health_check=[HealthCheck.too_slow],
               derandomize=True)
BOX_TOL = 1e-9


def in_box(x, lo, up, tol=BOX_TOL):
    scale = 1.0 + np.maximum(np.abs(np.nan_to_num(lo, neginf=0.0)), np.abs(np.nan_to_num(up, posinf=0.0)))
    return bool(((x >= lo - tol * scale) & (x <= up + tol * scale)).all())


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread():
    """Small matrices: BLAS threads only stall (by 10-40 ms on a busy 2-core machine), so use one."""
    with threadpool_limits(1):
        yield


# ----------------------------------------------------------------------------------------
# The box is never left; fast path = reference path.
# ----------------------------------------------------------------------------------------
@SETTINGS
@given(problems)
def test_sns_variants_never_leave_the_box(p):
    seed, kind = p
    levels, lo, up, damping = random_problem(np.random.default_rng(seed), kind)
    x, info = sns_tpm(levels, lo, up, return_info=True, **damping)
    assert info.feasible and in_box(x, lo, up), (info, x, lo, up)
    assert 0.0 <= info.scale <= 1.0
    xr, info_r = sns_tpm_reference(levels, lo, up, return_info=True, **damping)
    assert info_r.feasible and in_box(xr, lo, up)
    xs, scales, sinfo = sns(levels, lo, up, return_info=True, **damping)
    assert not sinfo.clipped and in_box(xs, lo, up), sinfo
    assert ((scales >= 0.0) & (scales <= 1.0)).all()


@SETTINGS
@given(problems)
def test_sns_tpm_fast_equals_reference(p):
    seed, kind = p
    levels, lo, up, damping = random_problem(np.random.default_rng(seed), kind)
    x, info = sns_tpm(levels, lo, up, return_info=True, **damping)
    xr, info_r = sns_tpm_reference(levels, lo, up, return_info=True, **damping)
    assert info.saturated == info_r.saturated and info.iterations == info_r.iterations
    assert abs(info.scale - info_r.scale) < 1e-9
    assert rel_diff(x, xr) < 1e-9


def first_level_residual(level, x) -> float:
    """``||J x - b||`` of an equality level, the bound violation ``||max(0, lo - J x, J x - up)||`` else."""
    lv = level if isinstance(level, Level) else Level(*level)
    y = lv.J @ x
    if lv.is_equality:
        return float(np.linalg.norm(y - lv.b))
    return float(np.linalg.norm(np.maximum(0.0, np.maximum(lv.lower - y, y - lv.upper))))


def lexicographic_qp(levels, lo, up):
    """The cascaded QP with the hard box (proxqp; daqp if proxqp gives up): the reference optimum."""
    try:
        return cascaded_qp(levels, solver="proxqp", lower=lo, upper=up)
    except SolverFailedError:
        return cascaded_qp(levels, solver="daqp", lower=lo, upper=up)


@SETTINGS
@given(problems)
def test_qp_first_level_residual_is_never_larger(p):
    """The cascade's first level is the box-constrained least-squares optimum: no SNS variant beats it."""
    seed, kind = p
    levels, lo, up, _ = random_problem(np.random.default_rng(seed), kind)  # undamped: the plain residual
    xq = lexicographic_qp(levels, lo, up)
    assert in_box(xq, lo, up)
    rq = first_level_residual(levels[0], xq)
    J1 = levels[0].J if isinstance(levels[0], Level) else levels[0][0]
    for x in (sns_tpm(levels, lo, up), sns(levels, lo, up)[0]):
        tol = 1e-7 * (1.0 + np.abs(J1).max()) * (1.0 + np.abs(x).max())  # the QP's KKT tolerance, scaled
        assert rq <= first_level_residual(levels[0], x) + tol, (rq, x, xq)


@FEW
@given(st.integers(0, 2**32 - 1))
def test_sns_tpm_fast_equals_reference_above_the_scalar_size(seed):
    """n > 40 joints: the kernel's loop, same numbers as the reference."""
    rng = np.random.default_rng(seed)
    n = 40 + int(rng.integers(1, 30))
    levels = random_stack(rng, n, [int(rng.integers(1, 7)) for _ in range(int(rng.integers(1, 5)))])
    c = np.abs(tpm(levels)).max()
    lo, up = -rng.uniform(0.2, 1.2, n) * c, rng.uniform(0.2, 1.2, n) * c
    x, info = sns_tpm(levels, lo, up, return_info=True)
    xr, info_r = sns_tpm_reference(levels, lo, up, return_info=True)
    assert info.saturated == info_r.saturated and abs(info.scale - info_r.scale) < 1e-9
    assert rel_diff(x, xr) < 1e-9 and in_box(x, lo, up)


# ----------------------------------------------------------------------------------------
# No active bound: exactly the unconstrained solvers.
# ----------------------------------------------------------------------------------------
@SETTINGS
@given(problems)
def test_box_containing_the_solution_changes_nothing(p):
    seed, kind = p
    rng = np.random.default_rng(seed)
    levels, _, _, damping = random_problem(rng, kind)
    x0 = tpm(levels, **damping)
    n = x0.size
    lo = np.minimum(x0, 0.0) - rng.uniform(0.0, 1.0, n) * np.abs(x0) - 1e-6
    up = np.maximum(x0, 0.0) + rng.uniform(0.0, 1.0, n) * np.abs(x0) + 1e-6
    x, info = sns_tpm(levels, lo, up, return_info=True, **damping)
    assert np.abs(x - x0).max() <= 1e-12 * max(1.0, np.abs(x0).max())
    assert info.saturated == () and info.scale == 1.0 and info.iterations == 1
    xr, info_r = sns_tpm_reference(levels, lo, up, return_info=True, **damping)
    assert rel_diff(xr, x0) < 1e-9 and info_r.saturated == () and info_r.scale == 1.0
    # the multi-task SNS checks the box after every level: the box must contain every partial solution
    partial = np.array([nullspace(levels[:k], n=n, **damping) for k in range(1, len(levels) + 1)])
    x_ns = partial[-1]
    lo_ns, up_ns = np.minimum(lo, partial.min(axis=0) - 1e-6), np.maximum(up, partial.max(axis=0) + 1e-6)
    xs, scales, sinfo = sns(levels, lo_ns, up_ns, return_info=True, **damping)
    assert np.abs(xs - x_ns).max() <= 1e-12 * max(1.0, np.abs(x_ns).max())
    assert (scales == 1.0).all() and all(li.saturated == () for li in sinfo.levels)


def test_infinite_box_is_tpm_bit_for_bit():
    rng = np.random.default_rng(3)
    levels = random_stack(rng, 21, [2, 3, 3, 3])
    inf = np.full(21, np.inf)
    np.testing.assert_array_equal(sns_tpm(levels, -inf, inf), tpm(levels))
    # the multi-task SNS runs projected_step in numpy, nullspace the compiled recursion: the same steps, not the
    # same bits (BLAS and numba's loops sum in other orders)
    np.testing.assert_allclose(sns(levels, -inf, inf)[0], nullspace(levels), rtol=0, atol=1e-13)


# ----------------------------------------------------------------------------------------
# With binding bounds: what the algorithms guarantee.
# ----------------------------------------------------------------------------------------
@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_binding_box_scales_the_whole_stack_uniformly(seed):
    """Full-rank undamped stack: F = I and every W used has rank(J W) = m, so J x = s xd (all levels)."""
    levels, lo, up, _ = random_problem(np.random.default_rng(seed), "full_rank")
    J = np.vstack([J for J, _ in levels])
    xd = np.concatenate([b for _, b in levels])
    x, info = sns_tpm(levels, lo, up, return_info=True)
    assert info.feasible
    assert np.linalg.norm(J @ x - info.scale * xd) <= 1e-8 * max(1.0, np.linalg.norm(xd))
    bound = np.where(np.abs(x - lo) <= np.abs(x - up), lo, up)
    for j in info.saturated:  # saturated joints sit on a bound
        assert abs(x[j] - bound[j]) <= 1e-9 * (1.0 + abs(bound[j]))


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_multi_task_sns_keeps_each_executed_level(seed):
    """Multi-task SNS, full-rank stack: J_k x = s_k xd_k for every level executed (feasible), each its own s_k."""
    levels, lo, up, _ = random_problem(np.random.default_rng(seed), "full_rank")
    x, scales, info = sns(levels, lo, up, return_info=True)
    assert not info.clipped
    assert info.levels[0].feasible  # the first level always has the feasible s = 0 when 0 is in the box
    for (J, b), s, li in zip(levels, scales, info.levels, strict=True):
        if li.feasible:
            assert np.linalg.norm(J @ x - s * b) <= 1e-8 * max(1.0, np.linalg.norm(b)), (s, li)


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_single_level_sns_equals_sns_tpm(seed):
    """One level and F = I: the multi-task SNS and SNS-TPM are the same algorithm."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 12))
    levels = random_stack(rng, n, [int(rng.integers(1, n + 1))])
    c = np.abs(tpm(levels)).max()
    lo, up = -rng.uniform(0, 1.2, n) * c, rng.uniform(0, 1.2, n) * c
    x, info = sns_tpm(levels, lo, up, return_info=True)
    xs, scales, sinfo = sns(levels, lo, up, return_info=True)
    assert rel_diff(x, xs) < 1e-9 and abs(info.scale - scales[0]) < 1e-9
    assert info.saturated == sinfo.levels[0].saturated


def test_higher_level_is_scaled_by_the_least_amount():
    """Two independent 1-D tasks on 2 joints: SNS scales only the level that needs it, SNS-TPM both."""
    J1, J2 = np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])
    levels = [(J1, np.array([0.5])), (J2, np.array([4.0]))]
    lo, up = -np.ones(2), np.ones(2)
    x, scales = sns(levels, lo, up)
    np.testing.assert_allclose(x, [0.5, 1.0])
    np.testing.assert_allclose(scales, [1.0, 0.25])
    x, info = sns_tpm(levels, lo, up, return_info=True)
    np.testing.assert_allclose(x, [0.125, 1.0])
    assert info.scale == pytest.approx(0.25)


def test_null_space_saturation_without_scaling():
    """A 1-D task on 3 joints: the pseudo-inverse overdrives joint 0, SNS saturates it and the others take over."""
    J = np.array([[1.0, 1.0, 1.0]])
    lo, up = -np.array([0.2, 1.0, 1.0]), np.array([0.2, 1.0, 1.0])
    x, info = sns_tpm([(J, np.array([1.5]))], lo, up, return_info=True)
    np.testing.assert_allclose(x, [0.2, 0.65, 0.65])
    assert info.saturated == (0,) and info.scale == 1.0 and info.iterations == 2
    x, info = sns_tpm([(J, np.array([3.0]))], lo, up, return_info=True)  # beyond capacity 2.2: scale
    np.testing.assert_allclose(x, [0.2, 1.0, 1.0])
    assert info.scale == pytest.approx(2.2 / 3.0)


# ----------------------------------------------------------------------------------------
# The classic SNS case: a 7-DOF arm (KUKA LWR IV) with a 6-D end-effector task.
# ----------------------------------------------------------------------------------------
LWR_DH = [(np.pi / 2, 0.0), (-np.pi / 2, 0.0), (-np.pi / 2, 0.4), (np.pi / 2, 0.0), (np.pi / 2, 0.39),
          (-np.pi / 2, 0.0), (0.0, 0.078)]  # (alpha, d), a = 0: reference/lwr_relaxed_constraints.md
LWR_QMAX = np.radians([170, 120, 170, 120, 170, 120, 170])
LWR_VMAX = np.radians([110, 110, 128, 128, 204, 184, 184])


def lwr_jacobian(q):
    """Geometric 6x7 Jacobian (linear; angular) of the LWR IV flange, standard DH."""
    T = np.eye(4)
    origins, axes = [T[:3, 3].copy()], [T[:3, 2].copy()]
    for qi, (alpha, d) in zip(q, LWR_DH, strict=True):
        ct, st_, ca, sa = np.cos(qi), np.sin(qi), np.cos(alpha), np.sin(alpha)
        A = np.array([[ct, -st_ * ca, st_ * sa, 0.0], [st_, ct * ca, -ct * sa, 0.0], [0.0, sa, ca, d], [0, 0, 0, 1.0]])
        T = T @ A
        origins.append(T[:3, 3].copy())
        axes.append(T[:3, 2].copy())
    p = origins[-1]
    Jv = np.column_stack([np.cross(axes[i], p - origins[i]) for i in range(7)])
    Jw = np.column_stack(axes[:7])
    return np.vstack([Jv, Jw])


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_lwr_6d_task_with_active_velocity_boxes(seed):
    rng = np.random.default_rng(seed)
    while True:  # away from singular configurations (undamped pseudo-inverses there amplify round-off)
        q = rng.uniform(-0.95, 0.95, 7) * LWR_QMAX
        J = lwr_jacobian(q)
        if np.linalg.svd(J, compute_uv=False)[-1] > 0.05:
            break
    xd = rng.standard_normal(6) * rng.choice([0.3, 1.0, 3.0])  # from reachable to far beyond the limits
    lo, up = velocity_box(q, -LWR_QMAX, LWR_QMAX, LWR_VMAX, 10.0, 1e-3)
    x, info = sns_tpm([(J, xd)], lo, up, return_info=True)
    assert info.feasible and in_box(x, lo, up)
    np.testing.assert_allclose(J @ x, info.scale * xd, atol=1e-8 * max(1.0, np.linalg.norm(xd)))
    xs, scales = sns([(J, xd)], lo, up)
    assert rel_diff(xs, x) < 1e-9 and abs(scales[0] - info.scale) < 1e-9
    assert rel_diff(sns_tpm_reference([(J, xd)], lo, up), x) < 1e-9


def test_lwr_closed_loop_keeps_the_joint_limits():
    """1 ms steps of a 6-D twist far beyond the arm's reach: SNS-TPM drives joints into their position
    limits and keeps them there (the braking term), TPM alone would leave both boxes."""
    dt = 1e-3
    q = np.array([0.923, -0.854, 0.903, 1.195, 0.971, 1.796, 0.0])
    twist = np.array([0.8, -0.5, 0.6, 1.5, -1.0, 2.0])
    saturated_steps = scaled_steps = tpm_violations = 0
    for _ in range(1500):
        J = lwr_jacobian(q)
        lo, up = velocity_box(q, -LWR_QMAX, LWR_QMAX, LWR_VMAX, 10.0, dt)
        x, info = sns_tpm([(J, twist)], lo, up, return_info=True)
        assert info.feasible and in_box(x, lo, up)
        np.testing.assert_allclose(J @ x, info.scale * twist, atol=1e-7)
        tpm_violations += not in_box(tpm([(J, twist)]), lo, up)
        saturated_steps += bool(info.saturated)
        scaled_steps += info.scale < 1.0
        q = q + x * dt
        assert (np.abs(q) <= LWR_QMAX + 1e-9).all()
    assert saturated_steps > 100 and scaled_steps > 100 and tpm_violations > 100


# ----------------------------------------------------------------------------------------
# Acceleration level: the same functions on qdd boxes.
# ----------------------------------------------------------------------------------------
@FEW
@given(st.integers(0, 2**32 - 1))
def test_acceleration_level_rollout_stays_inside(seed):
    """qdd = SNS-TPM(J, xdd - Jdot qd) under acceleration_box; 300 steps of exact integration stay in the limits.

    The zero command is often outside an acceleration box (a joint must brake); Algorithm 1 may then find
    no scale factor and the command is solved around x0 = clip(0, box) -- still inside the box and limits.
    """
    rng = np.random.default_rng(seed)
    dt = 1e-3
    a_max = np.full(7, 50.0)
    q = rng.uniform(-0.9, 0.9, 7) * LWR_QMAX
    dq = np.zeros(7)
    target = rng.standard_normal(6) * 5.0
    for k in range(300):
        J = lwr_jacobian(q)
        lo, up = acceleration_box(q, dq, -LWR_QMAX, LWR_QMAX, LWR_VMAX, a_max, dt)
        b = target - 10.0 * (J @ dq)  # a damped twist command; Jdot qd left out of this test
        qdd = sns_tpm([(J, b)], lo, up)
        assert in_box(qdd, lo, up)
        if k % 25 == 0 and np.linalg.svd(J, compute_uv=False)[-1] > 0.05:  # away from singularities
            assert rel_diff(sns_tpm_reference([(J, b)], lo, up), qdd) < 1e-9
        xs, _ = sns([(J, b)], lo, up)
        assert in_box(xs, lo, up)
        q, dq = q + dq * dt + 0.5 * qdd * dt * dt, dq + qdd * dt
        assert (np.abs(q) <= LWR_QMAX + 1e-9).all() and (np.abs(dq) <= LWR_VMAX + 1e-9).all()


@SETTINGS
@given(problems)
def test_boxes_without_zero_are_never_left(p):
    """Boxes that exclude the zero command for some joints (acceleration boxes, recovery): the output stays
    inside; where Algorithm 1 finds no scale factor it is solved around x0 = clip(0, box) (``feasible`` False)."""
    seed, kind = p
    rng = np.random.default_rng(seed)
    levels, lo, up, damping = random_problem(rng, kind)
    lo, up = box_without_zero(rng, lo, up)
    x, info = sns_tpm(levels, lo, up, return_info=True, **damping)
    assert in_box(x, lo, up)
    xr, info_r = sns_tpm_reference(levels, lo, up, return_info=True, **damping)
    assert in_box(xr, lo, up) and info_r.feasible == info.feasible
    # (where no factor is feasible the joints beyond their bounds may tie: compare the saturated sets)
    assert rel_diff(x, xr) < 1e-9 and sorted(info.saturated) == sorted(info_r.saturated)
    xs, _, sinfo = sns(levels, lo, up, return_info=True, **damping)
    assert in_box(xs, lo, up) and not sinfo.clipped


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_box_without_zero_keeps_the_task_relation(seed):
    """Full-rank stack, F = I: J x = s b when Algorithm 1 succeeds, else J x = (1 - s) J x0 + s b."""
    rng = np.random.default_rng(seed)
    levels, lo, up, _ = random_problem(rng, "full_rank")
    lo, up = box_without_zero(rng, lo, up)
    J = np.vstack([J for J, _ in levels])
    b = np.concatenate([b for _, b in levels])
    x, info = sns_tpm(levels, lo, up, return_info=True)
    x0 = np.zeros_like(x) if info.feasible else np.clip(0.0, lo, up)
    target = (1.0 - info.scale) * (J @ x0) + info.scale * b
    assert np.linalg.norm(J @ x - target) <= 1e-8 * max(1.0, np.linalg.norm(b), np.linalg.norm(J @ x0))


# ----------------------------------------------------------------------------------------
# Inequality levels, empty stacks, getTaskScalingFactor, bad input.
# ----------------------------------------------------------------------------------------
def test_inequality_levels_enter_through_their_active_rows():
    rng = np.random.default_rng(11)
    n = 9
    A = rng.standard_normal((3, n))
    ineq = Level(A, lower=np.array([0.5, -np.inf, -2.0]), upper=np.array([np.inf, 1.0, -1.0]))  # rows 0, 2 active
    task = (rng.standard_normal((3, n)), 5 * rng.standard_normal(3))
    eq = (A[[0, 2]], np.array([0.5, -1.0]))
    lo, up = -np.full(n, 0.8), np.full(n, 0.8)
    np.testing.assert_allclose(sns_tpm([ineq, task], lo, up), sns_tpm([eq, task], lo, up), atol=1e-12)
    np.testing.assert_allclose(sns([ineq, task], lo, up)[0], sns([eq, task], lo, up)[0], atol=1e-12)
    inactive = Level(A, lower=-np.ones(3), upper=np.ones(3))
    x, scales = sns([inactive, task], lo, up)
    assert scales[0] == 1.0
    np.testing.assert_allclose(x, sns([task], lo, up)[0], atol=1e-12)


def test_empty_stack_returns_the_zero_command_projected_on_the_box():
    lo, up = np.array([-1.0, 0.5, -2.0]), np.array([1.0, 2.0, -1.0])
    np.testing.assert_array_equal(sns_tpm([], lo, up), [0.0, 0.5, -1.0])
    x, scales = sns([], lo, up)
    np.testing.assert_array_equal(x, [0.0, 0.5, -1.0])
    assert scales.size == 0
    np.testing.assert_array_equal(sns_tpm([], -np.ones(3), np.ones(3)), np.zeros(3))


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_scalar_scale_factor_equals_the_numpy_one(seed):
    """The kernel's joint-by-joint loop (``_compiled_sns._pick``) and the numpy version (the reference's
    ``_scaling`` and ``_critical_joint``) pick the same factor and joint."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 12))
    lo, up = -rng.uniform(0.0, 2.0, n), rng.uniform(0.0, 2.0, n)
    lo[rng.random(n) < 0.1] = -np.inf
    up[rng.random(n) < 0.1] = np.inf
    a, b = rng.standard_normal(n), rng.standard_normal(n)
    a[rng.random(n) < 0.15] = 0.0
    free = rng.random(n) < 0.8
    on_bound = ~free & (rng.random(n) < 0.8)  # saturated joints mostly on a bound, as in the solver
    b[on_bound] = np.where(rng.random(n) < 0.5, lo, up)[on_bound]
    b[on_bound & ~np.isfinite(b)] = 0.0
    a[on_bound] = 0.0
    box = sns_module._Box(lo, up)
    x = a + b
    viol = box.violated(x)
    factor, smax = sns_module._scaling(a, b, box, free)
    j = sns_module._critical_joint(smax, free, viol)
    from hqp_tpm.solvers import _compiled_sns

    assert _compiled_sns._pick(a, b, lo, up, box.wlo, box.wup, free, viol, np.empty(n)) == (factor, j)


def test_task_scaling_factor():
    lo, up = -np.ones(3), np.ones(3)
    s, j = task_scaling_factor([2.0, -4.0, 0.5], [0.0, 0.0, 0.0], lo, up)
    assert s == 0.25 and j == 1
    s, j = task_scaling_factor([0.1, 0.1, 0.1], [0.0, 0.5, 0.0], lo, up)
    assert s == 1.0  # never above 1
    s, j = task_scaling_factor([1.0, 0.0, 0.0], [0.0, 2.0, 0.0], lo, up)
    assert s == -1.0 and j == 1  # b outside with no way to move it: infeasible, joint 1 is the culprit
    s, j = task_scaling_factor([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], lo, up, free=[True, False, True])
    assert s == 1.0 and j == 0  # joint 1 is saturated (on its bound, not scaled): not critical
    s, _ = task_scaling_factor([1.0, 0.0, 0.0], [0.0, 1.5, 0.0], lo, up, free=[True, False, True])
    assert s == -1.0  # a saturated joint off its box: no factor helps
    s, _ = task_scaling_factor([1.0, 1.0, 1.0], [1.5, 0.0, 0.0], lo, up)
    assert s == -1.0  # s would have to be negative


def test_bad_boxes_and_shapes():
    levels = [(np.ones((2, 4)), np.ones(2))]
    with pytest.raises(BoxError, match=r"joint 2.*lower\[2\] = 1.0 > upper\[2\] = 0.5"):
        sns_tpm(levels, [-1, -1, 1.0, -1], [1, 1, 0.5, 1])
    with pytest.raises(BoxError, match=r"upper\[1\] is NaN"):
        sns(levels, -np.ones(4), [1, np.nan, 1, 1])
    for lo, up in (([-1, np.inf, -1, -1], [1, np.inf, 1, 1]), ([-1, -np.inf, -1, -1], [1, -np.inf, 1, 1])):
        for solver in (sns_tpm, sns, sns_tpm_reference):
            with pytest.raises(BoxError, match=r"joint 1 is empty.*finite command"):
                solver(levels, lo, up)
    with pytest.raises(ShapeError, match="stack has 4 columns but the box has 3 joints"):
        sns_tpm(levels, -np.ones(3), np.ones(3))
    with pytest.raises(ShapeError):
        sns_tpm_reference(levels, -np.ones(4), np.ones(5))
    with pytest.raises(ShapeError, match="stack has 4 columns but the box has 3"):
        sns(levels, -np.ones(3), np.ones(3))
