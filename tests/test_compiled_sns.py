"""The compiled SNS-TPM loop (hqp_tpm.solvers._compiled_sns) equals the numpy fast path and Algorithm 1.

Every draw is solved four ways: the compiled loop (``sns_tpm``, kernels on), the numpy loop on the same compiled
TPM kernels (the loop handed back), everything numpy (``_compiled.ENABLED = False``, as
``HQP_TPM_COMPILED=0``) and ``sns_tpm_reference`` (papers/002 Algorithm 1 as written). They take the same
decisions (saturated joints in the same order, iteration count, feasibility) and give the same command and
scale factor: 1e-12 relative between the fast paths, 1e-9 against the reference (its ``n x n`` SVDs, as
tests/test_sns.py). Draws: the suite's SNS draws as they are (mostly ``m <= n``) and with a posture level (more
rows than joints), boxes with and without 0, Romeo-sized whole-body stacks (38 x 27 with a posture level on the
21 actuated joints, and without it), ill-conditioned stacks (cond up to 1e10) and units from 1e-6 to 1e6. The
kernel's hand-overs (a declined shortcut or damped pivot, the box-point shift, an invalid box) are counted: each
is exercised.
"""

import numpy as np
import pytest
from conftest import rel_diff
from test_fullrank import ill_conditioned_past_rank
from threadpoolctl import threadpool_limits

from hqp_tpm.errors import BoxError
from hqp_tpm.solvers import _compiled, _compiled_sns
from hqp_tpm.solvers._fullrank import COND, MARGIN
from hqp_tpm.solvers.levels import stacked
from hqp_tpm.solvers.sns import sns_tpm, sns_tpm_reference, sns_tpm_stacked
from hqp_tpm.testing.stacks import (
    box_without_zero,
    dependent_stack,
    nearly_dependent_stack,
    random_problem,
    random_stack,
)

pytestmark = pytest.mark.skipif(not _compiled.AVAILABLE, reason="numba is not installed")

TOL = 1e-12
REF_TOL = 1e-9


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread():
    with threadpool_limits(1):
        yield


@pytest.fixture
def outcomes(monkeypatch):
    """The compiled loop's outcomes (DONE or the hand-over status), counted; ``ENABLED`` restored after."""
    counts = {_compiled_sns.DONE: 0, _compiled_sns.BAD_BOX: 0, _compiled_sns.DECLINED: 0, _compiled_sns.SHIFT: 0,
              _compiled_sns.RESUME: 0}
    run = _compiled_sns.sns_tpm_loop
    monkeypatch.setattr(_compiled_sns, "sns_tpm_loop", outcomes_wrapper(counts, run))
    monkeypatch.setattr(_compiled, "ENABLED", True)
    counts["run"] = run
    return counts


def same_decisions(info, other, scale_tol):
    assert info.saturated == other.saturated, (info, other)
    assert info.iterations == other.iterations, (info, other)
    assert info.feasible == other.feasible, (info, other)
    assert abs(info.scale - other.scale) <= scale_tol, (info, other)


def check(levels, lo, up, outcomes, damping=None, tol=TOL, ref_tol=REF_TOL, reference=True):
    """The four solutions agree (module doc); returns the compiled one's info. With ``m <= n`` the compiled loop
    solves with its own QR, LAPACK's on the numpy path: there the bound is ``max(tol, 100 eps cond(J W))``,
    ``W`` the returned saturation (the round-off ``(J W)#`` amplifies)."""
    damping = damping or {}
    x, info = sns_tpm(levels, lo, up, return_info=True, **damping)
    n = lo.shape[0]
    _, J, b, sizes, _ = stacked(levels, n)
    if J.shape[0] <= n and info.saturated:
        free = np.ones(n, dtype=bool)
        free[list(info.saturated)] = False
        tol = max(tol, 100 * np.finfo(float).eps * np.linalg.cond(J[:, free]))
    xs, info_s = sns_tpm_stacked(J, b, sizes, lo, up, return_info=True, **damping)
    np.testing.assert_array_equal(xs, x)                          # the stacked entry: the same call
    assert info_s == info
    run = outcomes["run"]
    _compiled_sns.sns_tpm_loop = lambda *a: _compiled_sns.DECLINED  # the numpy loop on the compiled TPM kernels
    try:
        x_py, info_py = sns_tpm(levels, lo, up, return_info=True, **damping)
    finally:
        _compiled_sns.sns_tpm_loop = outcomes_wrapper(outcomes, run)
    same_decisions(info, info_py, tol)
    assert rel_diff(x, x_py) <= tol, rel_diff(x, x_py)
    _compiled.ENABLED = False                                     # all numpy (HQP_TPM_COMPILED=0)
    try:
        x_np, info_np = sns_tpm(levels, lo, up, return_info=True, **damping)
    finally:
        _compiled.ENABLED = True
    same_decisions(info, info_np, tol)
    assert rel_diff(x, x_np) <= tol, rel_diff(x, x_np)
    if reference:
        xr, info_r = sns_tpm_reference(levels, lo, up, return_info=True, **damping)
        same_decisions(info, info_r, ref_tol)
        assert rel_diff(x, xr) <= ref_tol, rel_diff(x, xr)
    return info


def outcomes_wrapper(counts, run):
    """``run`` counting its outcomes into ``counts``."""
    def counted(*args):
        out = run(*args)
        kind = type(out)
        counts[_compiled_sns.DONE if kind is tuple else _compiled_sns.RESUME if kind is _compiled_sns.LoopState
               else out] += 1
        return out
    return counted


def with_posture(levels, n, rng, scale=1.0):
    return list(levels) + [(np.eye(n), scale * rng.standard_normal(n))]


def cutting_box(rng, levels, n, damping=None):
    """A box containing 0 that cuts the TPM solution (random_problem's law)."""
    x = sns_tpm(levels, np.full(n, -np.inf), np.full(n, np.inf), **(damping or {}))
    c = np.abs(x).max() + 1e-300
    return -rng.uniform(0.0, 1.2, n) * c, rng.uniform(0.0, 1.2, n) * c


@pytest.mark.parametrize("kind", ["full_rank", "any", "damped"])
def test_suite_sns_draws_with_a_posture_level(kind, outcomes):
    """The SNS draws of tests/test_sns.py (their box: 5 % infinite sides, 3 % locked joints), a posture level
    appended: the extension's loop (m > n) on the compiled path."""
    rng = np.random.default_rng({"full_rank": 1, "any": 2, "damped": 3}[kind])
    saturated = 0
    for _ in range(150):
        levels, lo, up, damping = random_problem(rng, kind)
        n = lo.shape[0]
        info = check(with_posture(levels, n, rng), lo, up, outcomes, damping)
        saturated += len(info.saturated)
        check(levels, lo, up, outcomes, damping)                  # the draw itself (m > n for some of kind any)
    assert outcomes[_compiled_sns.DONE] >= 150 and saturated >= 100, (outcomes, saturated)


@pytest.mark.parametrize("kind", ["full_rank", "any", "damped"])
def test_suite_sns_draws_with_fewer_rows_than_joints(kind, outcomes):
    """The SNS draws with ``m <= n`` (the paper's algorithm): the compiled loop when every pivot is regular and
    undamped, handed back otherwise; boxes with and without 0."""
    rng = np.random.default_rng({"full_rank": 21, "any": 22, "damped": 23}[kind])
    saturated = small = 0
    for _ in range(300):
        levels, lo, up, damping = random_problem(rng, kind)
        if stacked(levels, lo.shape[0])[1].shape[0] > lo.shape[0]:
            continue
        small += 1
        saturated += len(check(levels, lo, up, outcomes, damping).saturated)
        check(levels, *box_without_zero(rng, lo, up), outcomes, damping)
    assert outcomes[_compiled_sns.DONE] >= small and saturated >= 50, (outcomes, small, saturated)


@pytest.mark.parametrize("sizes", [(6, 2, 3, 3, 3), (6, 2, 3), (6, 3, 6, 6)])
def test_whole_body_stacks_without_posture(sizes, outcomes):
    """Romeo's obstacle scenario's shape (sole > CoM > foot > hands, no posture: 17 rows on 27 joints), damped
    and not, velocity boxes that cut the command."""
    n = 27
    rng = np.random.default_rng(sum(sizes) + 1)
    iterations = []
    for damping in ({}, {"lambda_max": 0.05, "eps": 0.1}):
        for _ in range(15):
            levels = random_stack(rng, n, sizes)
            lo, up = cutting_box(rng, levels, n, damping)
            iterations.append(check(levels, lo, up, outcomes, damping).iterations)
    assert outcomes[_compiled_sns.DONE] >= 25 and max(iterations) >= 5, (outcomes, iterations)


@pytest.mark.parametrize("sizes", [(6, 2, 2, 3, 3, 3), (6, 1, 2, 3, 3, 3), (4, 3, 2)])
def test_damped_pivots_of_several_rows(sizes, outcomes):
    """``m <= n`` stacks whose later levels are nearly in the span of the levels above (the obstacle scenario's
    hand and foot levels near a singularity): damped pivots of several rows, so ``F != I``. The compiled loop
    solves them (``F xd`` and ``F J xN`` in each pass) with the numpy loop's decisions; before, it handed every
    such stack back."""
    from test_compiled import nearly_spanned_levels

    from hqp_tpm.solvers._kernels import Factorization

    n = 27 if sum(sizes) > 10 else 12
    rng = np.random.default_rng(sum(sizes) + 7)
    damping = {"lambda_max": 0.05, "eps": 0.1}
    damped = 0
    for _ in range(30):
        levels = nearly_spanned_levels(rng, random_stack(rng, n, sizes), share=0.8, rows=(2, 3))
        _, J, _, sizes_, _ = stacked(levels, n)
        damped += any(not p.regular and k > 1 for p, k in zip(Factorization(J, sizes_, n, **damping).pivots, sizes_,
                                                                    strict=True))
        lo, up = cutting_box(rng, levels, n, damping)
        check(levels, lo, up, outcomes, damping)
    assert damped >= 15 and outcomes[_compiled_sns.DONE] >= 60, (damped, outcomes)


def test_obstacle_scenario_stacks(outcomes):
    """``romeo_obstacles_sns_tpm``'s own solves with the paper's box (17-19 rows on 27 joints, hand and foot pivots
    damped near the obstacles): the compiled loop answers every step of the first 0.9 s, and on every 6th step's
    stack it takes the numpy loop's and Algorithm 1's decisions (``check``). Before, it handed 94 % of the run's
    steps back. (With the scenario's default command-rate bound the stack gains a final level pulling the change
    of the command to 0, m > n with damped upper pivots: the compiled shortcut declines and the numpy pass loop
    runs, over the compiled recursion; issue 29.)"""
    from hqp_tpm.app.build import build
    from hqp_tpm.app.scenario import merge, parse, read, resolve_path

    def load(name):
        path = resolve_path(name)
        return parse(merge(read(path), {"limits": {"command_rate": False}}), path)

    captured = []
    counted = _compiled_sns.sns_tpm_loop

    def capture(J, xd, sizes, lo, up, lambda_max, eps, *rest):
        if len(captured) % 6 == 0 or not captured:
            captured.append((J.copy(), xd.copy(), tuple(sizes), lo.copy(), up.copy(), lambda_max, eps))
        else:
            captured.append(None)
        return counted(J, xd, sizes, lo, up, lambda_max, eps, *rest)

    _compiled_sns.sns_tpm_loop = capture
    try:
        ctrl = build(load("romeo_obstacles_sns_tpm"))[1]
        for _ in range(900):
            ctrl.step()
    finally:
        _compiled_sns.sns_tpm_loop = counted
    assert outcomes[_compiled_sns.DONE] == len(captured) == 900, outcomes
    saturated = 0
    for J, xd, sizes, lo, up, lambda_max, eps in filter(None, captured):
        off = np.cumsum((0, *sizes))
        levels = [(J[a:e], xd[a:e]) for a, e in zip(off, off[1:], strict=False)]
        info = check(levels, lo, up, outcomes, {"lambda_max": lambda_max, "eps": eps})
        saturated += bool(info.saturated)
    assert saturated >= 50, saturated


@pytest.mark.parametrize("kind", ["full_rank", "any", "damped"])
def test_boxes_without_zero(kind, outcomes):
    """30 % of the joints' boxes shifted (0 may leave the box): the box-point shift is handed back."""
    rng = np.random.default_rng({"full_rank": 11, "any": 12, "damped": 13}[kind])
    for _ in range(150):
        levels, lo, up, damping = random_problem(rng, kind)
        n = lo.shape[0]
        lo, up = box_without_zero(rng, lo, up)
        check(with_posture(levels, n, rng), lo, up, outcomes, damping)
    assert outcomes[_compiled_sns.SHIFT] >= 2 and outcomes[_compiled_sns.DONE] >= 50, outcomes


@pytest.mark.parametrize("sizes", [(6, 2, 3, 6), (6, 3, 6, 12), (6, 3)])
def test_whole_body_sized_stacks(sizes, outcomes):
    """Romeo's shape: sole 6 > CoM > foot > hands, then a posture on the 21 actuated joints (38 x 27 for the
    first), velocity boxes that cut the command: up to ~20 saturations per solve."""
    n = 27
    rng = np.random.default_rng(sum(sizes))
    iterations = []
    for damping in ({}, {"lambda_max": 0.05, "eps": 0.1}):
        for _ in range(15):
            posture = np.hstack([np.zeros((21, 6)), np.eye(21)])
            levels = random_stack(rng, n, sizes) + [(posture, rng.standard_normal(21))]
            lo, up = cutting_box(rng, levels, n, damping)
            iterations.append(check(levels, lo, up, outcomes, damping).iterations)
    assert outcomes[_compiled_sns.DONE] >= 20 and max(iterations) >= 8, (outcomes, iterations)


@pytest.mark.parametrize("units", [(1e-6, 1.0), (1.0, 1e-6), (1e6, 1.0), (1.0, 1e6), (1e-3, 1e3), (1e6, 1e-6)])
def test_badly_scaled(units, outcomes):
    """Jacobian and targets in units from 1e-6 to 1e6 (the box scales with the command)."""
    sj, sb = units
    rng = np.random.default_rng(int(np.log10(sj) * 10 + np.log10(sb)) + 100)
    for _ in range(40):
        n = int(rng.integers(3, 15))
        sizes = [int(rng.integers(1, 4)) for _ in range(int(rng.integers(1, 4)))]
        while sum(sizes) > n - 1 and len(sizes) > 1:
            sizes.pop()
        levels = with_posture(random_stack(rng, n, sizes), n, rng)
        levels = [(sj * J, sb * b) for J, b in levels]
        lo, up = cutting_box(rng, levels, n)
        check(levels, lo, up, outcomes)
    assert outcomes[_compiled_sns.DONE] >= 30, outcomes


def test_ill_conditioned(outcomes):
    """Nearly dependent levels (cond up to 1e10) with a posture level: where the shortcut declines the kernel
    hands back, elsewhere the same decisions as numpy and Algorithm 1."""
    rng = np.random.default_rng(1010)
    conds = []
    for _ in range(80):
        levels, n = ill_conditioned_past_rank(rng)
        lo, up = cutting_box(rng, levels, n)
        check(levels, lo, up, outcomes, tol=1e-9, reference=False)
        levels, cond = nearly_dependent_stack(rng, 1e10)
        n = levels[0][0].shape[1]
        levels = with_posture(levels, n, rng)
        lo, up = cutting_box(rng, levels, n)
        check(levels, lo, up, outcomes, tol=max(TOL, 1e3 * np.finfo(float).eps * cond), reference=False)
        conds.append(cond)
    assert max(conds) > 1e8 and outcomes[_compiled_sns.DONE] >= 40, (outcomes, max(conds))
    assert outcomes[_compiled_sns.DECLINED] >= 5, outcomes


def test_numpy_loop_resumes_where_the_compiled_loop_stopped(monkeypatch):
    """A free-column stack ``J W`` the kernels' certificates cannot decide, met after some saturations: the compiled
    loop hands back its state (:class:`~hqp_tpm.solvers._compiled_sns.LoopState`) and the numpy loop goes on from
    that pass, with ``m > n`` (the extension: ``J W`` by the padded factorization) and ``m <= n`` (``F`` from the
    stack's factorization, ``(J W)#`` by the SVD). The same decisions and command as the numpy loop from the start
    (1e-12, or ``1e3 eps cond(J)`` on these ill-conditioned draws), and ``(J W)#`` built only for the passes
    from there (the numpy loop built it for every saturation again before)."""
    import importlib

    sns_mod = importlib.import_module("hqp_tpm.solvers.sns")  # (the package exports the function ``sns``)
    monkeypatch.setattr(_compiled, "ENABLED", True)
    passes = []
    real_free = sns_mod._free_solver
    monkeypatch.setattr(sns_mod, "_free_solver", lambda *a: passes.append(1) or real_free(*a))
    rng = np.random.default_rng(2)
    resumed = {True: 0, False: 0}                      # by m > n
    for i in range(400):
        if i % 2:
            levels, cond = nearly_dependent_stack(rng, 1e12)
            n = levels[0][0].shape[1]
        else:
            levels, cond = nearly_dependent_stack(rng, 1e10)
            n = levels[0][0].shape[1]
            levels = with_posture(levels, n, rng)
        lo, up = cutting_box(rng, levels, n)
        _, J, b, sizes, _ = stacked(levels, n)
        state = _compiled_sns.sns_tpm_loop(J, b, sizes, lo, up, 0.0, 0.0, MARGIN, COND)
        if type(state) is not _compiled_sns.LoopState:
            continue
        resumed[J.shape[0] > n] += 1
        passes.clear()
        x, info = sns_tpm_stacked(J, b, sizes, lo, up, return_info=True)
        assert len(passes) <= info.iterations - state.iterations + 1, (len(passes), info, state.iterations)
        from_resume = len(passes)
        passes.clear()
        x_start, info_start = sns_tpm_stacked(J, b, sizes, lo, up, return_info=True, compiled=False)
        tol = max(TOL, 1e3 * np.finfo(float).eps * cond)
        same_decisions(info, info_start, tol)
        assert rel_diff(x, x_start) <= tol, rel_diff(x, x_start)
        assert len(passes) == from_resume + len(state.order) - 1, (len(passes), from_resume, state.order)
    assert resumed[True] >= 3 and resumed[False] >= 3, resumed


def test_dependent_stacks_hand_back(outcomes):
    """Repeated and dependent tasks above a posture level: the shortcut declines, the numpy path solves."""
    rng = np.random.default_rng(31)
    for within in (False, True):
        for _ in range(10):
            levels = with_posture(dependent_stack(rng, 12, within), 12, rng)
            lo, up = cutting_box(rng, levels, 12)
            check(levels, lo, up, outcomes)
    assert outcomes[_compiled_sns.DECLINED] >= 10, outcomes


def test_invalid_box_is_handed_back(outcomes):
    """An empty or NaN box through the stacked entry: the typed error of sns_tpm (the kernel hands back)."""
    rng = np.random.default_rng(5)
    J, b = rng.standard_normal((10, 7)), rng.standard_normal(10)
    for lo, up in ((np.full(7, -1.0), np.r_[np.ones(6), -2.0]), (np.r_[np.nan, -np.ones(6)], np.ones(7))):
        with pytest.raises(BoxError):
            sns_tpm_stacked(J, b, (6, 4), lo, up)
        with pytest.raises(BoxError):
            sns_tpm([(J[:6], b[:6]), (J[6:], b[6:])], lo, up)
    assert outcomes[_compiled_sns.BAD_BOX] == 2, outcomes   # (sns_tpm checks the box before stacking)


def test_downdated_factorization_equals_the_free_columns():
    """The QR downdate of the SNS loop (m > n): after each saturation, ``Q~[free rows, s:]`` is orthonormal, with
    ``R1`` it factors the upper levels' free columns ``J_<k W^T``, ``C~[:, s:]`` is ``J_k W Q~[free rows, s:]``,
    and the saturated joints' rows are decoupled (the refactorization's factors, up to the columns' signs)."""
    rng = np.random.default_rng(8)
    n, sizes = 27, (6, 2, 3, 6, 21)
    J = np.vstack([rng.standard_normal((17, n)), np.hstack([np.zeros((21, 6)), np.eye(21)])])
    _compiled._sizes(sizes)                                     # compiles the kernels
    status, m1, mk, r, V, tau, R1, BT, *_ = _compiled._past_rank_factor(
        J, np.array(sizes), n, 0.0, 0.0, _compiled._UNIT, MARGIN, COND)
    assert status == _compiled.SOLVED and (m1, mk) == (17, 21)
    CT, Rt = BT.copy(), np.zeros((n, m1))
    Rt[:m1] = R1
    cs, sn, w = np.zeros((n, n)), np.zeros((n, n)), np.empty(n)
    free = np.ones(n, dtype=bool)
    for s, j in enumerate(rng.permutation(n)[:9]):
        free[j] = False
        _compiled_sns._q_row(j, V, tau, m1, cs, sn, s, w)
        _compiled_sns._downdate(w, CT, Rt, s, m1, cs, sn)
        QT = np.eye(n)                                          # rows e_i -> Q~ e_i: Q~ = QT^T
        _compiled_sns._q_times_rows(QT, V, tau, m1, cs, sn, s + 1)
        Q = QT.T
        Qf = Q[free][:, s + 1:]
        R1s = Rt[s + 1:s + 1 + m1]
        assert np.abs(np.tril(R1s, -1)).max() == 0.0                          # still triangular
        assert np.abs(Qf.T @ Qf - np.eye(n - s - 1)).max() < 1e-13
        assert np.abs(Qf[:, :m1] @ R1s - J[:m1, free].T).max() < 1e-13 * np.abs(J).max()
        assert np.abs(J[m1:, free] @ Qf - CT[s + 1:].T).max() < 1e-13
        assert np.abs(Q[~free][:, s + 1:]).max() < 1e-14                      # saturated joints: no coupling
