"""The compiled kernels (hqp_tpm.solvers._compiled) equal the oracles.

``past_rank`` (the full-rank shortcut, taken by ``tpm`` / ``tpm_stacked`` / ``sns_tpm`` when the stack has more
rows than joints) against ``tpm_reference`` (the paper's steps on the padded stack) wherever it solves, to 1e-12, on
random stacks past rank ``n`` (the suite's full-rank stacks with a posture level, the benchmark's shapes, dependent
stacks, scales 1e-6..1e6, exact and damped, ``x0``). On ill-conditioned draws (cond up to 1e10, the numerics
issue's) two exact formulas differ by ``cond * eps`` in rounding, so there the shortcut is held to a 50-digit
reference: as accurate as the recursion. The general path's kernel (``m <= n``) against the recursion (the kernel
off: ``tpm`` runs the recursion's source as Python). Then the side-by-side benchmark's stacks, every step of its
closed loops, and scenario runs with the compiled path forced on and off.
"""

import sys
from pathlib import Path

import mpmath
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_fullrank import ill_conditioned_past_rank

from hqp_tpm.control import _compiled_step
from hqp_tpm.solvers import _compiled, nullspace, sns_tpm, tpm, tpm_reference
from hqp_tpm.solvers._compiled import COND, MARGIN
from hqp_tpm.solvers.levels import stacked
from hqp_tpm.solvers.tpm import tpm_stacked
from hqp_tpm.testing.stacks import dependent_stack, nearly_dependent_stack, random_stack
from hqp_tpm.testing.strategies import full_rank_stacks
from hqp_tpm.testing.strategies import stacks as stack_strategy

pytestmark = pytest.mark.skipif(not _compiled.AVAILABLE, reason="numba is not installed")

TOL = 1e-12
DAMPING = [(0.0, 0.0), (0.05, 0.1), (0.1, 0.5), (1e-3, 1e-2)]


def rel_diff(a, b) -> float:
    return float(np.linalg.norm(a - b) / max(1.0, np.linalg.norm(b)))


def with_posture(levels, n, rng, scale=1.0):
    """The stack with a last level ``I_n`` (a posture task): more rows than joints."""
    return list(levels) + [(np.eye(n), scale * rng.standard_normal(n))]


def check_equal(levels, n, tol=TOL):
    """Where the shortcut solves, the same ``x`` (to ``tol``) as ``tpm_reference``, every damping. Returns the
    number of dampings for which the shortcut solved."""
    _, J, b, sizes, n = stacked(levels, n)
    solved = 0
    for lam, eps in DAMPING:
        x = _compiled.past_rank(J, b, sizes, n, lam, eps, MARGIN, COND)
        if x is not None:
            solved += 1
            ref = tpm_reference(levels, lambda_max=lam, eps=eps, n=n)
            assert rel_diff(x, ref) <= tol, (sizes, lam, eps, rel_diff(x, ref))
    return solved


@pytest.fixture
def compiled(monkeypatch):
    """Switch the solvers' dispatch: ``compiled(True)`` / ``compiled(False)``."""
    return lambda on: monkeypatch.setattr(_compiled, "ENABLED", bool(on))


def test_random_shapes_past_rank():
    rng = np.random.default_rng(2026)
    solved = 0
    for _ in range(300):
        n = int(rng.integers(2, 15))
        sizes = [int(rng.integers(1, n + 3)) for _ in range(int(rng.integers(1, 5)))]
        if sum(sizes) <= n:
            sizes.append(n - sum(sizes) + int(rng.integers(1, 4)))
        levels = random_stack(rng, n, sizes, scale=10.0 ** rng.uniform(-2, 2))
        levels = [(10.0 ** rng.uniform(-2, 2) * J, b) for J, b in levels]
        solved += check_equal(levels, n)
    assert solved >= 300


def test_two_right_hand_sides_equal_two_solves():
    """One factorization for two right-hand sides (the SNS loop's x and a: _refactor, then _refactored_rhs twice,
    the damped crossing level's QR shared) gives the bits of two _past_rank calls, and the same status, on
    random, badly scaled, damped and ill-conditioned stacks."""
    if _compiled._sizes(()) is None:
        pytest.skip("numba is not installed")
    from hqp_tpm.solvers import _compiled_sns

    if not _compiled_sns._READY:                      # (compiled kernels, as the SNS loop calls them)
        _compiled_sns._compile()
    rng = np.random.default_rng(77)
    statuses = set()
    for trial in range(400):
        n = int(rng.integers(2, 28))
        sizes = [int(rng.integers(1, n + 3)) for _ in range(int(rng.integers(1, 5)))]
        if sum(sizes) <= n:
            sizes.append(n - sum(sizes) + int(rng.integers(1, 4)))
        m = sum(sizes)
        J = rng.normal(size=(m, n)) * 10.0 ** rng.uniform(-3, 3, (m, 1))
        if trial % 4 == 0:
            J[:n] = J[:n] @ np.diag(np.logspace(0, -rng.uniform(0, 12), n))
        b1, b2 = rng.normal(size=m) * 1e3, rng.normal(size=m) * 1e-3
        lam, eps = (0.05, 0.02) if trial % 3 == 0 else (0.0, 0.0)
        s = _compiled._sizes(sizes)
        x1, x2, y1, y2 = (np.zeros(n) for _ in range(4))
        args = (s, n, lam, eps, _compiled._UNIT, MARGIN, COND)
        status, *factors = _compiled_sns._refactor(J, *args)
        assert status == _compiled._past_rank(J, b1, *args, x1) == _compiled._past_rank(J, b2, *args, x2)
        statuses.add(int(status))
        if status == _compiled.SOLVED:
            _compiled_sns._refactored_rhs(b1, *factors, lam, eps, y1)
            _compiled_sns._refactored_rhs(b2, *factors, lam, eps, y2)
            np.testing.assert_array_equal(y1, x1)
            np.testing.assert_array_equal(y2, x2)
    assert {_compiled.SOLVED, _compiled.DECLINED} <= statuses, statuses


def test_damped_qr_equals_the_dense_householder():
    """_damped_qr / _damped_solve (the QR of [R_A; lambda I] walking only its nonzeros) give the bits of
    _householder_rows on the dense 2r x r matrix, _apply_qt and _solve_upper (the kernel before them), on random
    triangles with entries over 12 orders of magnitude and lambda from 1e-8 to 10."""
    if _compiled._sizes(()) is None:
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(5)
    for _ in range(1500):
        r = int(rng.integers(0, 15))
        RA = np.triu(rng.normal(size=(r, r)) * 10.0 ** rng.uniform(-6, 6, (r, r)))
        c = rng.normal(size=r) * 10.0 ** rng.uniform(-3, 3)
        lam = 10.0 ** rng.uniform(-8, 1)
        S = np.zeros((r, 2 * r))                       # rows: the columns of [R_A; lam I]
        S[:, :r] = RA.T
        S[:, r:] = lam * np.eye(r)
        tau, R2 = np.empty(r), np.zeros((r, r))
        _compiled._householder_rows(S, tau, R2)
        rhs = np.concatenate((c, np.zeros(r)))
        _compiled._apply_qt(rhs, S, tau, r)
        want = _compiled._solve_upper(R2, rhs[:r])
        DV, Dtau, DR = _compiled._damped_qr(RA, lam)
        np.testing.assert_array_equal(DR, R2)
        np.testing.assert_array_equal(Dtau, tau)
        np.testing.assert_array_equal(_compiled._damped_solve(DV, Dtau, DR, c), want)
        M = np.vstack((RA, lam * np.eye(r)))
        if r and np.linalg.cond(M) < 1e8:              # and it is the damped least-squares minimizer
            y = np.linalg.lstsq(M, np.concatenate((c, np.zeros(r))), rcond=None)[0]
            np.testing.assert_allclose(want, y, rtol=1e-7, atol=1e-7 * np.abs(y).max())


@pytest.mark.parametrize("shape", [([6, 7], 7), ([6, 2, 3, 3, 3, 21], 27), ([6, 27], 27), ([3, 3, 7], 7),
                                   ([6, 3, 6, 12, 27], 27), ([12, 40], 40)])
def test_robot_shaped_stacks(shape):
    """EE pose > posture (iiwa), sole > CoM > foot > hands > posture (Romeo) and other whole-body shapes."""
    sizes, n = shape
    rng = np.random.default_rng(sum(sizes))
    solved = 0
    for _ in range(20):
        levels = random_stack(rng, n, sizes[:-1])
        levels = with_posture(levels, n, rng) if sizes[-1] == n else levels + random_stack(rng, n, sizes[-1:])
        solved += check_equal(levels, n)
    assert solved >= 10  # (declined: damped upper pivots, a Gaussian square crossing level near singular)


@settings(max_examples=60, deadline=None)
@given(full_rank_stacks(max_n=30), st.sampled_from([1e-6, 1e-3, 1.0, 1e3, 1e6]))
def test_suite_full_rank_stacks_with_a_posture_level(case, scale):
    """The suite's full-rank stacks (the ``tpm`` property tests' draws), units 1e-6..1e6, plus a posture."""
    levels, rng = case
    n = levels[0][0].shape[1]
    levels = [(scale * J, scale * b) for J, b in with_posture(levels, n, rng)]
    check_equal(levels, n)


@pytest.mark.parametrize("within", [False, True])
def test_dependent_stacks_with_a_posture_level(within):
    """Exactly dependent, nearly dependent and repeated tasks: the shortcut declines (rank lost above)."""
    rng = np.random.default_rng(7 + within)
    for _ in range(30):
        check_equal(with_posture(dependent_stack(rng, 12, within), 12, rng), 12)


def test_x0_and_tpm_stacked(compiled):
    """Through ``tpm`` and ``tpm_stacked`` (the lean step's call), with ``x0``: kernel on == kernel off."""
    rng = np.random.default_rng(11)
    for _ in range(100):
        n = int(rng.integers(3, 12))
        levels = with_posture(random_stack(rng, n, [int(rng.integers(1, n))]), n, rng)
        x0 = rng.standard_normal(n)
        _, J, b, sizes, _ = stacked(levels, n)
        for lam, eps in DAMPING:
            out = []
            for on in (False, True):
                compiled(on)
                out.append((tpm(levels, lambda_max=lam, eps=eps, x0=x0), tpm_stacked(J, b, sizes, n, lam, eps, x0)))
            (ref, ref_s), (x, x_s) = out
            assert rel_diff(x, ref) <= TOL and rel_diff(x_s, ref_s) <= TOL
            assert rel_diff(x_s, ref) <= TOL


# ----------------------------------------------------------------------------------------
# Ill-conditioned draws: both as accurate as a 50-digit reference allows.
# ----------------------------------------------------------------------------------------
def mp_past_rank(levels, n, lam=0.0):
    """``x1 + Z (A^T A + lam^2 I)^{-1} A^T (b_k - J_k x1)`` in 50 digits (``A = J_k Z``, undamped or the damping
    of a crossing level with more rows than the null space): the shortcut's exact answer."""
    with mpmath.workdps(50):
        k, m1 = 0, 0
        while m1 + levels[k][0].shape[0] < n:
            m1 += levels[k][0].shape[0]
            k += 1
        Jk, bk = (mpmath.matrix(v.tolist()) for v in levels[k])
        if m1:
            J1 = mpmath.matrix(np.vstack([J for J, _ in levels[:k]]).tolist())
            b1 = mpmath.matrix(np.concatenate([b for _, b in levels[:k]]).tolist())
            x1 = J1.T * mpmath.lu_solve(J1 * J1.T, b1)
            Q, _ = mpmath.qr(J1.T, mode="full")
            Z = Q[:, m1:]
        else:
            x1, Z = mpmath.matrix(n, 1), mpmath.eye(n)
        A = Jk * Z
        y = mpmath.lu_solve(A.T * A + lam**2 * mpmath.eye(n - m1), A.T * (bk - Jk * x1))
        return np.array([float(v) for v in x1 + Z * y])


def ill_conditioned(rng, i):
    """The numerics issue's nearly dependent stacks (cond up to 1e10) with a posture level, or test_fullrank's
    draws (upper levels within 1e-11..1e-3 of dependence, a crossing level nearly in their span)."""
    if i % 2:
        levels, _ = nearly_dependent_stack(rng, max_cond=1e10)
        n = levels[0][0].shape[1]
        return with_posture(levels, n, rng), n
    return ill_conditioned_past_rank(rng)


def test_ill_conditioned_draws_as_accurate_as_numpy():
    """Where the shortcut solves, its ``x`` is within 1e-12 of the 50-digit answer or no farther from it than the
    recursion's (x 2)."""
    rng = np.random.default_rng(1410)
    solved = 0
    for i in range(400):
        levels, n = ill_conditioned(rng, i)
        _, J, b, sizes, _ = stacked(levels, n)
        lam, eps = DAMPING[(i // 2) % 2]
        x = _compiled.past_rank(J, b, sizes, n, lam, eps, MARGIN, COND)
        if x is None:
            continue
        ref = nullspace(levels, lambda_max=lam, eps=eps, n=n)
        solved += 1
        xm = mp_past_rank(levels, n, lam)
        err, err_ref = rel_diff(x, xm), rel_diff(ref, xm)
        assert err <= max(TOL, 2.0 * err_ref), (i, err, err_ref)
    assert solved >= 25


@settings(max_examples=40, deadline=None)
@given(stack_strategy(n=(3, 20), levels=(1, 4), rows=(1, 4), full_rank=True, cond=(1e2, 1e10), scale=(1e-6, 1.0, 1e6)))
def test_prescribed_condition_numbers(case):
    """The suite's prescribed-condition stacks (cond 1e2..1e10) with a posture level: same decisions, and
    where solved equal to ``TOL * cond`` (the rounding two exact formulas may differ by)."""
    levels = with_posture(case.levels, case.n, case.rng)
    check_equal(levels, case.n, tol=TOL * max(1.0, case.cond / 1e3))


# ----------------------------------------------------------------------------------------
# The side-by-side benchmark's stacks, closed loops, scenarios.
# ----------------------------------------------------------------------------------------
def _peers():
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: ``benchmarks``
    from benchmarks.peers import problems

    return problems


@pytest.mark.parametrize("kind", ["iiwa_vel", "iiwa_acc", "romeo_vel"])
def test_benchmark_stacks(kind):
    P = _peers()
    robot = P.load_robot(P.ROMEO if kind.startswith("romeo") else P.IIWA)
    prob = P.romeo_problem(robot, n=30) if kind.startswith("romeo") else \
        P.iiwa_problem(robot, order=1 if kind == "iiwa_vel" else 2, n=30)
    for cfg in prob.configs:
        levels = P.hqp_controller(robot, prob, cfg).compute().levels
        assert check_equal(levels, robot.nv) >= 1  # undamped: always (damped EE pivots may decline)


@pytest.mark.parametrize("order", [1, 2])
def test_closed_loop_steps(order, compiled):
    """Every step of 300 of the iiwa circle loop: the same commands and states with the kernel on and off."""
    P = _peers()
    robot = P.load_robot(P.IIWA)
    ctrls = [P.hqp_circle_controller(robot, order)[0] for _ in range(2)]
    for _ in range(300):
        steps = []
        for on, ctrl in zip((False, True), ctrls, strict=True):
            compiled(on)
            steps.append(ctrl.step())
        ref, res = steps
        assert rel_diff(res.command, ref.command) <= TOL
        assert rel_diff(ctrls[1].q, ctrls[0].q) <= TOL
        _, J, b, sizes, n = stacked(res.levels, robot.nv)
        compiled(True)
        assert rel_diff(tpm_stacked(J, b, sizes, n), tpm_reference(res.levels, n=n)) <= TOL


def test_sns_tpm_takes_the_kernel_inside_the_box(compiled):
    rng = np.random.default_rng(12)
    for _ in range(50):
        n = int(rng.integers(3, 10))
        levels = with_posture(random_stack(rng, n, [int(rng.integers(1, n))]), n, rng)
        x = tpm(levels)
        lo, up = -2 * np.abs(x) - 1e-3, 2 * np.abs(x) + 1e-3
        compiled(False)
        ref = sns_tpm(levels, lo, up)
        compiled(True)
        assert rel_diff(sns_tpm(levels, lo, up), ref) <= TOL


@pytest.mark.parametrize("name", ["romeo_tpm"])
def test_scenario_runs_equal_with_the_kernel_on_and_off(name, compiled):
    """A bundled scenario run (its whole trajectory) with the compiled path forced on and off."""
    from hqp_tpm.app.build import build
    from hqp_tpm.app.scenario import load

    runs = []
    for on in (False, True):
        compiled(on)
        ctrl = build(load(name))[1]
        qs = [ctrl.step().command for _ in range(200)]
        runs.append(np.array(qs))
    assert np.max(np.abs(runs[1] - runs[0])) <= TOL * max(1.0, np.abs(runs[0]).max())


@pytest.mark.parametrize("on", [False, True])
def test_sns_tpm_saturations_past_rank_take_the_shortcut(on, compiled, monkeypatch):
    """SNS-TPM with more rows than joints (Romeo's benchmark stack under its joint box): the TPM of ``J W`` at
    each saturation goes through the full-rank shortcut (compiled or numpy), not the padded general path
    (``Factorization``: ~0.5 ms at 38 x 27 each, which made SNS-TPM's Romeo step 2-3x slower once the m > n
    extension kept saturating; the kernel now counts the passes that took the recursion instead: most passes take
    the shortcut); the results equal the reference."""

    from hqp_tpm.solvers import _compiled_sns
    from hqp_tpm.solvers.sns import sns_tpm_reference

    compiled(on)
    calls = []
    real = _compiled_sns.sns_tpm_loop
    P = _peers()
    robot = P.load_robot(P.ROMEO)
    prob = P.romeo_problem(robot, n=30)
    iterations = 0
    for cfg in prob.configs:
        ctrl = P.hqp_controller(robot, prob, cfg, "sns_tpm")
        levels = ctrl.compute().levels
        lo, up = ctrl.box(ctrl.state, ctrl.t)
        # only this (undamped) solve is counted: compute() solves the controller's damped stack, through
        # sns_tpm_loop when off but through the compiled step's own call of _sns_loop when on, and every damped
        # Romeo stack takes the recursion by design (485 passes of 493 on these configurations, both ways)
        with monkeypatch.context() as mp:
            mp.setattr(_compiled_sns, "sns_tpm_loop", lambda *a: (out := real(*a)) and calls.append(out[6]) or out)
            x, info = sns_tpm(levels, lo, up, return_info=True)
        iterations += info.iterations
        assert rel_diff(x, sns_tpm_reference(levels, lo, up)) <= 1e-10
    assert len(calls) == len(prob.configs)
    # (the passes that took the recursion inside the kernel: 50 of 546 on these 30 configurations, compiled and as
    # Python, the free-column stacks whose hand rows are nearly dependent in what the levels above leave)
    assert iterations >= 60 and sum(calls) <= 0.2 * iterations, (iterations, sum(calls))


# ----------------------------------------------------------------------------------------
# The general path's kernel (m <= n: regular or damped pivots; singular: the recursion): tpm_stacked on == off.
# ----------------------------------------------------------------------------------------
EPS = np.finfo(float).eps


def check_general(levels, n, rng, compiled, tol=TOL, conditioned=False):
    """``tpm_stacked`` (and ``tpm``) with the kernel on and off, every damping, with and without ``x0``.
    Returns how many of these the kernel solved itself (the others: the recursion).

    ``conditioned``: the tolerance is ``max(tol, 10 eps cond(J))`` (``J`` the stacked Jacobian, full rank): two
    backward-stable QR solves differ by about ``eps cond(J)``. Over 12,000 solves of the property tests' draws
    (``full_rank_stacks``, units 1e-6..1e6, every damping) the largest difference was 3.8 ``eps cond(J)``; the
    largest above 1e-12 was 2.3e-12, at ``cond(J) = 2.7e4``."""
    _, J, b, sizes, n = stacked(levels, n)
    if conditioned:
        s = np.linalg.svd(J, compute_uv=False)
        tol = max(tol, 10 * np.finfo(float).eps * s[0] / s[-1])
    x0 = rng.standard_normal(n)
    solved = 0
    for lam, eps in DAMPING:
        for x0_ in (None, x0):
            compiled(False)
            ref = tpm_stacked(J, b, sizes, n, lam, eps, x0_)
            compiled(True)
            x = tpm_stacked(J, b, sizes, n, lam, eps, x0_)
            assert rel_diff(x, ref) <= tol, (sizes, lam, eps, rel_diff(x, ref))
            solved += _compiled.general(J, b, sizes, n, lam, eps, x0_) is not None
    compiled(False)
    ref = tpm(levels, x0=x0)
    compiled(True)
    assert rel_diff(tpm(levels, x0=x0), ref) <= tol
    return solved


def _switch(on):
    _compiled.ENABLED = bool(on)


@settings(max_examples=80, deadline=None)
@given(full_rank_stacks(), st.sampled_from([1e-6, 1e-3, 1.0, 1e3, 1e6]))
def test_general_path_on_the_suite_full_rank_stacks(case, scale):
    """The ``tpm`` property tests' draws (up to 40 joints, 10 levels), units 1e-6..1e6."""
    levels, rng = case
    n = levels[0][0].shape[1]
    levels = [(scale * J, scale * b) for J, b in levels]
    before = _compiled.ENABLED
    try:
        check_general(levels, n, rng, _switch, conditioned=True)
    finally:
        _switch(before)


def test_general_path_on_random_and_dependent_stacks(compiled):
    rng = np.random.default_rng(77)
    solved = 0
    for _ in range(150):
        n = int(rng.integers(2, 30))
        sizes = [int(rng.integers(1, 6)) for _ in range(int(rng.integers(1, 6)))]
        while sum(sizes) > n:
            sizes.pop()
        if sizes:
            solved += check_general(random_stack(rng, n, sizes, 10.0 ** rng.uniform(-3, 3)), n, rng, compiled)
    assert solved >= 600
    for within in (False, True):  # exactly dependent and repeated tasks: singular pivots, the recursion answers
        for _ in range(10):
            assert check_general(dependent_stack(rng, 12, within), 12, rng, compiled) == 0


def test_general_path_ill_conditioned_draws(compiled):
    """The numerics issue's nearly dependent stacks (cond up to 1e10, pivots still regular): kernel and numpy
    path both within ``10 eps cond`` of the 50-digit minimum-norm solution (what a backward-stable solve can
    promise; they differ from each other by ~eps cond in rounding), same as numpy's to 1e-12 up to cond 1e3."""
    from test_numerics import mp_min_norm

    rng = np.random.default_rng(1412)
    solved = 0
    for _ in range(150):
        levels, cond = nearly_dependent_stack(rng, max_cond=1e10)
        n = levels[0][0].shape[1]
        _, J, b, sizes, _ = stacked(levels, n)
        compiled(False)
        ref = tpm_stacked(J, b, sizes, n)
        x = _compiled.general(J, b, sizes, n, 0.0, 0.0)
        if x is None:
            continue
        solved += 1
        xm = mp_min_norm(levels)
        assert rel_diff(x, xm) <= max(TOL, 10 * EPS * cond) and rel_diff(ref, xm) <= max(TOL, 10 * EPS * cond)
        if cond <= 1e3:
            assert rel_diff(x, ref) <= TOL
    assert solved >= 100


@pytest.mark.parametrize("name", ["lwr_tracking", "planar5_exact", "iiwa_admittance"])
def test_tpm_scenarios_equal_with_the_kernel_on_and_off(name, compiled, monkeypatch):
    """Bundled ``tpm`` scenarios (m <= n: the general path's kernel), 300 steps each, kernel on and off."""
    from hqp_tpm.app.build import build
    from hqp_tpm.app.scenario import load

    paths = []
    _compiled._sizes((1,))                             # (compiled first: the wrapper below is not)
    kernel = _compiled._tpm
    monkeypatch.setattr(_compiled, "_tpm", lambda *a: paths.append(kernel(*a)) or paths[-1])
    planned = []  # (a policy's planned step solves through the stacked kernel: hqp_tpm.control._planned_step)
    stacked = _compiled_step.stacked_kernel

    def counted():
        solve = stacked()
        return None if solve is None else (lambda *a: planned.append(solve(*a)) or planned[-1])

    monkeypatch.setattr(_compiled_step, "stacked_kernel", counted)
    runs = []
    for on in (False, True):
        compiled(on)
        ctrl = build(load(name))[1]
        runs.append(np.array([ctrl.step().command for _ in range(300)]))
    assert np.max(np.abs(runs[1] - runs[0])) <= TOL * max(1.0, np.abs(runs[0]).max())
    # the factorization's kernel solved a step's worth of calls
    assert paths.count(_compiled.FACTORED) + planned.count(_compiled_step.SOLVED) >= 300


@pytest.mark.parametrize("kind", ["full_rank", "any", "damped"])
def test_sns_tpm_equal_with_the_kernel_on_and_off(kind, compiled, monkeypatch):
    """SNS-TPM on the suite's boxed draws (``random_problem``; boxes cutting the TPM solution or not): the same
    command with the kernels on and off (the kernel's source as Python)."""
    from hqp_tpm.testing.stacks import random_problem

    rng = np.random.default_rng({"full_rank": 1, "any": 2, "damped": 3}[kind])
    inside = 0
    for _ in range(200):
        levels, lo, up, damp = random_problem(rng, kind)
        if rng.random() < 0.5:  # a box that holds the TPM solution
            lo, up = lo - 10 * np.abs(lo).max() - 1.0, up + 10 * np.abs(up).max() + 1.0
        compiled(False)
        ref = sns_tpm(levels, lo, up, **damp)
        compiled(True)
        x = sns_tpm(levels, lo, up, **damp)
        assert rel_diff(x, ref) <= TOL
        _, J, b, sizes, n = stacked(levels, lo.shape[0])
        x_tpm = _compiled.general(J, b, sizes, n, **{"lambda_max": 0.0, "eps": 0.0, **damp}) \
            if sizes and J.shape[0] <= n else None
        if x_tpm is not None and ((x_tpm >= lo) & (x_tpm <= up)).all():  # the TPM solution is the answer
            inside += 1
    assert inside >= 30


def test_general_path_damped_one_row_pivots_between_regular_levels(compiled):
    """Regular levels, then 1-row levels nearly in their span (relative pivot 3e-3..5e-2: damped), more levels after
    them: Steps 2-4 of the kernel (the update of the rows above by later pivots) == the recursion's answer."""
    rng = np.random.default_rng(99)
    solved = 0
    for _ in range(200):
        n = int(rng.integers(6, 20))
        sizes = [int(rng.integers(1, 4)) for _ in range(int(rng.integers(3, 7)))]
        while sum(sizes) > n:
            sizes.pop()
        levels = nearly_spanned_levels(rng, random_stack(rng, n, sizes), rows=(1,))
        solved += check_general(levels, n, rng, compiled)
    assert solved >= 400


def nearly_spanned_levels(rng, levels, share=0.7, rows=(1, 2, 3)):
    """``levels`` with some later levels (of ``rows`` rows, with probability ``share``) replaced by rows nearly in
    the span of the levels above (relative residual 3e-3..5e-2): their pivots are small and, with ``eps`` in
    ``DAMPING``, damped."""
    levels = list(levels)
    n = levels[0][0].shape[1]
    for k in range(1, len(levels)):
        r = levels[k][0].shape[0]
        if r in rows and rng.random() < share:
            above = np.vstack([J for J, _ in levels[:k]])
            block = rng.standard_normal((r, above.shape[0])) @ above
            scale = 10.0 ** rng.uniform(-2.5, -1.3, (r, 1)) * np.linalg.norm(block, axis=1, keepdims=True)
            levels[k] = (block + scale * rng.standard_normal((r, n)) / np.sqrt(n), levels[k][1])
    return levels


def damped_pivots(J, sizes, n, lambda_max, eps):
    """How many pivot blocks of more than one row are damped and not singular (the paper's ``R_ii`` of the QR of
    ``J^T``, ``sigma_min`` in ``(tol, eps)``)."""
    from hqp_tpm.solvers.damping import rank_tol

    R = np.linalg.qr(J.T, mode="r")
    count, a = 0, 0
    for k in sizes:
        smin = np.linalg.svd(R[a:a + k, a:a + k], compute_uv=False)[-1]
        count += bool(k > 1 and lambda_max > 0.0 and rank_tol(np.linalg.norm(J[a:a + k]), max(J.shape)) < smin < eps)
        a += k
    return count


def test_general_path_damped_pivots_of_several_rows(compiled):
    """Levels of 2 and 3 rows nearly in the span of the levels above (damped pivots of several rows, decided by
    the SVD of the block in the kernel as ``pivot`` does), between regular levels: the kernel solves them itself
    and equals the recursion. (Before, the kernel handed every damped pivot of more than one row back.)"""
    rng = np.random.default_rng(2024)
    solved = damped_blocks = 0
    for _ in range(200):
        n = int(rng.integers(8, 24))
        sizes = [int(rng.integers(1, 4)) for _ in range(int(rng.integers(3, 7)))]
        while sum(sizes) > n:
            sizes.pop()
        levels = nearly_spanned_levels(rng, random_stack(rng, n, sizes), rows=(2, 3))
        _, J, _, sizes_, _ = stacked(levels, n)
        damped_blocks += damped_pivots(J, sizes_, n, 0.05, 0.1)
        solved += check_general(levels, n, rng, compiled, conditioned=True)  # undamped: cond(J) up to ~1e4
    assert damped_blocks >= 200 and solved >= 1500, (damped_blocks, solved)  # (the old kernel: 828 of 1600)


READ_ONLY_SCRIPT = """
import numpy as np, hqp_tpm.solvers as s, hqp_tpm.solvers._compiled as C, hqp_tpm._jit as jit
rng = np.random.default_rng(0)
lv = [(rng.standard_normal((6, 7)), rng.standard_normal(6)), (np.eye(7), rng.standard_normal(7))]
x = s.tpm(lv)
C.ENABLED = False
print(float(np.abs(x - s.tpm(lv)).max()), jit.cache_dir())
"""


@pytest.mark.slow
def test_read_only_install_caches_in_the_user_directory(tmp_path):
    """The package in a read-only folder (a wheel in a read-only site-packages): the kernels compile once and
    :mod:`hqp_tpm._jit` caches them in the user's cache directory (``~/.cache/hqp_tpm``); the next process loads
    them. Needs root for a read-only bind mount in a private mount namespace (``unshare -m``), skipped otherwise."""
    import os
    import shutil
    import subprocess

    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("needs root and unshare for a read-only bind mount")
    ro, home = tmp_path / "ro", tmp_path / "home"
    home.mkdir()
    shutil.copytree(Path(_compiled.__file__).parents[1], ro / "hqp_tpm", ignore=shutil.ignore_patterns("__pycache__"))
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "HQP_TPM_COMPILED")}
    env.update(HOME=str(home), PYTHONPATH=str(ro))
    cmd = f"mount --bind {ro} {ro} && mount -o remount,ro,bind {ro} && cd {tmp_path} && " \
          f"{sys.executable} -c '{READ_ONLY_SCRIPT}'"
    outs = []
    for _ in range(2):
        out = subprocess.run(["unshare", "-m", "sh", "-c", cmd], env=env, capture_output=True, text=True, timeout=900)
        if out.returncode != 0 and "unshare" in out.stderr:
            pytest.skip(f"no private mount namespace here: {out.stderr.strip()}")
        assert out.returncode == 0, out.stderr
        outs.append(out.stdout.split())
    for diff, path in outs:
        assert float(diff) <= 1e-12 and Path(path).is_relative_to(home / ".cache" / "hqp_tpm")
    assert not list(ro.rglob("*.nbi")) and list((home / ".cache" / "hqp_tpm").rglob("*.nbi"))


def test_sizes_as_a_list_or_an_array(compiled):
    """``tpm_stacked``'s ``sizes`` may be a tuple, a list or an array (a list used to raise TypeError in the
    kernels' size cache)."""
    rng = np.random.default_rng(4)
    for sizes, n in (((2, 3), 7), ((6, 7), 7)):
        levels = random_stack(rng, n, list(sizes))
        _, J, b, _, _ = stacked(levels, n)
        compiled(False)
        ref = tpm_stacked(J, b, sizes, n)
        compiled(True)
        for s in (tuple(sizes), list(sizes), np.array(sizes)):
            assert rel_diff(tpm_stacked(J, b, s, n), ref) <= TOL


def test_building_blocks_against_lapack():
    """The kernels' Householder QR (four columns at a time, then one by one), the reflectors applied from the
    right to ``B^T`` (four terms of each sum per pass, then one), ``Q x``, ``Q^T x``, the row-by-row ``R^{-1}``
    and the row norms equal LAPACK's ``dgeqrf``/``dorgqr``/``dtrtri`` and numpy to 1e-12 on every shape with
    up to 13 columns and 16 rows (all the loops' block and remainder lengths, ``_dot``'s four partial sums
    among them), including columns already zero below the diagonal (``tau = 0``, a reflector skipped).
    ``Q`` applied to several vectors at once (``_apply_q_rows``) gives each one's ``_apply_q`` exactly, and
    the norm of a triangle (``_fro_upper``) is that of its block."""
    from scipy.linalg import lapack

    _compiled._sizes((1,))                             # compile the kernels
    rng = np.random.default_rng(14)
    for p in range(1, 14):
        for q in range(p, 17):
            M = rng.standard_normal((q, p)) * 10.0 ** rng.uniform(-3, 3)
            if rng.random() < 0.3:
                M[1:, 0] = 0.0                         # the first column is already reduced: tau_0 = 0
            qr, tau_ref, _, info = lapack.dgeqrf(M)
            assert info == 0
            V, tau, R = np.ascontiguousarray(M.T), np.empty(p), np.zeros((p, p))
            _compiled._householder_rows(V, tau, R)
            scale = np.abs(M).max()
            assert np.abs(R - np.triu(qr[:p])).max() <= TOL * scale, (p, q)
            assert np.abs(tau - tau_ref).max() <= TOL, (p, q)
            Qfull = np.zeros((q, q))
            Qfull[:, :p] = qr
            Q = lapack.dorgqr(Qfull, tau_ref)[0]
            x = rng.standard_normal(q)
            y = x.copy()
            _compiled._apply_q(y, V, tau, p)
            assert rel_diff(y, Q @ x) <= TOL
            y = x.copy()
            _compiled._apply_qt(y, V, tau, p)
            assert rel_diff(y, Q.T @ x) <= TOL
            X = rng.standard_normal((3, q))                # several vectors at once: each as _apply_q alone
            Y = X.copy()
            _compiled._apply_q_rows(Y, V, tau, p)
            for r in range(3):
                y = X[r].copy()
                _compiled._apply_q(y, V, tau, p)
                np.testing.assert_array_equal(Y[r], y)
            for rows in (1, 3, 7):
                B = rng.standard_normal((rows, q))
                BT = B.T.copy()
                _compiled._apply_right_t(BT, V, tau, p, np.empty(rows))
                assert rel_diff(BT.T, B @ Q) <= TOL, (p, q, rows)
            Rr = np.triu(qr[:p]) / scale + 3.0 * np.eye(p) * np.sign(np.diag(qr[:p]) + 0.5)
            Rinv = _compiled._triangular_inverse(Rr)
            assert rel_diff(Rinv, lapack.dtrtri(Rr, lower=0)[0]) <= TOL
            for a, e in ((0, p), (0, (p + 1) // 2), (p // 2, p)):  # the triangle's norm: the block's, exactly
                assert _compiled._fro_upper(Rinv, a, e) == _compiled._fro_block(Rinv, a, e, a, e)
            a, e = sorted(int(v) for v in rng.integers(0, q + 1, 2))
            ref = float(np.sum(M[a:e] ** 2))
            got = _compiled._sumsq_rows(np.ascontiguousarray(M), a, e, np.empty(p))
            assert abs(got - ref) <= 1e-14 * max(ref, 1e-300)
