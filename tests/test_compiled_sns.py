"""The SNS-TPM kernel (hqp_tpm.solvers._compiled_sns) equals Algorithm 1, compiled and as Python.

Every draw is solved three ways: the kernel compiled (``sns_tpm``), the same kernel's source as Python
(``_compiled.ENABLED = False``, as ``HQP_TPM_COMPILED=0``) and ``sns_tpm_reference`` (papers/002 Algorithm 1 as
written). They take the same decisions (saturated joints in the same order, iteration count, feasibility) and give
the same command and scale factor: 1e-12 relative between the kernel's two runs, 1e-9 against the reference (its
``n x n`` SVDs, as tests/test_sns.py). Draws: the suite's SNS draws as they are (mostly ``m <= n``) and with a
posture level (more rows than joints), boxes with and without 0, Romeo-sized whole-body stacks (38 x 27 with a
posture level on the 21 actuated joints, and without it), damped Romeo-like stacks with a damped pivot above the
crossing level, ill-conditioned, rank-deficient and repeated stacks, and units from 1e-6 to 1e6 (per level too).
The kernel's outcomes are counted: it solves every stack itself (``DONE``; the box-point shift ``SHIFT`` and an
invalid box ``BAD_BOX`` are the only returns of another kind), and it reports the passes the recursion (or an SVD)
answered inside it, which the earlier kernel handed back to a numpy loop.
"""

import numpy as np
import pytest
from conftest import rel_diff
from test_fullrank import ill_conditioned_past_rank
from threadpoolctl import threadpool_limits

from hqp_tpm.errors import BoxError
from hqp_tpm.solvers import _compiled, _compiled_sns
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
    """The kernel's outcomes (``DONE``, ``SHIFT``, ``BAD_BOX``) and, under ``"recursion"``, its passes answered by
    the recursion or an SVD, counted; ``ENABLED`` restored after."""
    counts = {_compiled_sns.DONE: 0, _compiled_sns.BAD_BOX: 0, _compiled_sns.SHIFT: 0, "recursion": 0}
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
    """The three solutions agree (module doc); returns the compiled one's info. The bound between the kernel's two
    runs is ``max(tol, 100 eps cond(J W))``, ``W`` the returned saturation (numba's and numpy's matrix products
    may round differently; ``(J W)#`` amplifies it)."""
    damping = damping or {}
    x, info = sns_tpm(levels, lo, up, return_info=True, **damping)
    n = lo.shape[0]
    _, J, b, sizes, _ = stacked(levels, n)
    if info.saturated:
        free = np.ones(n, dtype=bool)
        free[list(info.saturated)] = False
        if free.any():
            tol = max(tol, 100 * np.finfo(float).eps * np.linalg.cond(J[:, free]))
    xs, info_s = sns_tpm_stacked(J, b, sizes, lo, up, return_info=True, **damping)
    np.testing.assert_array_equal(xs, x)                          # the stacked entry: the same call
    assert info_s == info
    _compiled.ENABLED = False                                     # the kernel's source as Python
    try:
        x_py, info_py = sns_tpm(levels, lo, up, return_info=True, **damping)
    finally:
        _compiled.ENABLED = True
    same_decisions(info, info_py, tol)
    assert rel_diff(x, x_py) <= tol, rel_diff(x, x_py)
    if reference:
        xr, info_r = sns_tpm_reference(levels, lo, up, return_info=True, **damping)
        same_decisions(info, info_r, ref_tol)
        assert rel_diff(x, xr) <= ref_tol, rel_diff(x, xr)
    return info


def outcomes_wrapper(counts, run):
    """``run`` counting its outcomes into ``counts`` (the compiled runs only)."""
    def counted(*args):
        out = run(*args)
        if _compiled.ENABLED:
            counts[out[0]] += 1
            counts["recursion"] += out[6]
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
    solves them (``F xd`` and ``F J xN`` in each pass) with Algorithm 1's decisions (an earlier kernel handed every
    such stack back)."""
    from test_compiled import damped_pivots, nearly_spanned_levels

    n = 27 if sum(sizes) > 10 else 12
    rng = np.random.default_rng(sum(sizes) + 7)
    damping = {"lambda_max": 0.05, "eps": 0.1}
    damped = 0
    for _ in range(30):
        levels = nearly_spanned_levels(rng, random_stack(rng, n, sizes), share=0.8, rows=(2, 3))
        _, J, _, sizes_, _ = stacked(levels, n)
        damped += damped_pivots(J, sizes_, n, **damping) > 0
        lo, up = cutting_box(rng, levels, n, damping)
        check(levels, lo, up, outcomes, damping)
    assert damped >= 15 and outcomes[_compiled_sns.DONE] >= 60, (damped, outcomes)


def test_obstacle_scenario_stacks(outcomes):
    """``romeo_obstacles_sns_tpm``'s own solves with the paper's box (17-19 rows on 27 joints, hand and foot pivots
    damped near the obstacles): the compiled loop answers every step of the first 0.9 s, and on every 6th step's
    stack it takes Algorithm 1's decisions (``check``). An earlier kernel handed 94 % of the run's steps back.
    (With the scenario's default command-rate bound the stack gains a final level pulling the change of the command
    to 0, m > n with damped upper pivots: the shortcut declines and the recursion answers inside the kernel.)"""
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
    """Nearly dependent levels (cond up to 1e10) with a posture level: where the shortcut declines the recursion
    answers inside the kernel; the same decisions compiled and as Python."""
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
    assert outcomes["recursion"] >= 5, outcomes                  # (handed back to numpy before)


def test_stacks_the_old_kernel_handed_back_at_a_pass(outcomes):
    """Free-column stacks ``J W`` the factorization's certificates cannot decide, met after some saturations (the
    old kernel stopped there, RESUME, and a numpy loop went on): with ``m > n`` the recursion gives ``J W``'s TPM,
    with ``m <= n`` the SVD of ``D J W`` decides its rank and applies ``(J W)#``, inside the kernel. The same
    decisions and command compiled and as Python (``1e3 eps cond(J)`` on these ill-conditioned draws)."""
    rng = np.random.default_rng(2)
    inside = {True: 0, False: 0}                       # by m > n: solves with a pass the old kernel handed back
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
        status, *_, nrec = _compiled_sns.sns_tpm_loop(J, b, sizes, lo, up, 0.0, 0.0)
        assert status == _compiled_sns.DONE
        if nrec and inside[J.shape[0] > n] < 6:
            inside[J.shape[0] > n] += 1
            check(levels, lo, up, outcomes, tol=max(TOL, 1e3 * np.finfo(float).eps * cond), reference=False)
    assert inside[True] >= 3 and inside[False] >= 3, inside


def test_dependent_stacks_stay_in_the_kernel(outcomes):
    """Repeated and dependent tasks above a posture level (the shortcut declines: the old kernel handed these back
    from the start), and the same stacks without it (``m <= n``, singular pivots: ``F`` with their truncated
    inverses, the first pass by the recursion): solved in the kernel, equal to Algorithm 1."""
    rng = np.random.default_rng(31)
    for within in (False, True):
        for _ in range(10):
            base = dependent_stack(rng, 12, within)
            lo, up = cutting_box(rng, base, 12)
            check(with_posture(base, 12, rng), lo, up, outcomes)
            check(base, lo, up, outcomes)
    assert outcomes[_compiled_sns.DONE] >= 40 and outcomes["recursion"] >= 40, outcomes


def damped_romeo_like(rng, n=27):
    """A Romeo-shaped stack (sole 6 > CoM 2 > foot 3 > hands 6 > posture on the 21 actuated joints: 38 x 27) whose
    CoM, foot or hand levels are nearly in the span of the levels above (pivots below ``eps = 0.1``: damped, above
    the crossing level, as on the benchmark's damped Romeo)."""
    from test_compiled import nearly_spanned_levels

    levels = nearly_spanned_levels(rng, random_stack(rng, n, [6, 2, 3, 6]), share=0.9, rows=(2, 3, 6))
    return levels + [(np.hstack([np.zeros((21, 6)), np.eye(21)]), rng.standard_normal(21))]


def test_damped_romeo_like_stacks_stay_in_the_kernel(outcomes):
    """m > n, a damped pivot above the crossing level (lambda_max 0.05, eps 0.1): the full-rank shortcut declines
    and the old kernel handed every such solve back to the numpy pass loop. Now every solve returns DONE from the
    kernel, which reports the passes the recursion answered; the same decisions and command as Algorithm 1 and as
    the kernel's source run as Python."""
    rng = np.random.default_rng(77)
    damping = {"lambda_max": 0.05, "eps": 0.1}
    iterations = []
    for _ in range(20):
        levels = damped_romeo_like(rng)
        lo, up = cutting_box(rng, levels, 27, damping)
        _, J, b, sizes, _ = stacked(levels, 27)
        status, x, sat, scale, its, feasible, nrec = _compiled_sns.sns_tpm_loop(J, b, sizes, lo, up, 0.05, 0.1)
        assert status == _compiled_sns.DONE and nrec >= 1, (status, nrec)
        iterations.append(check(levels, lo, up, outcomes, damping).iterations)
    assert outcomes[_compiled_sns.DONE] >= 20 and max(iterations) >= 5, (outcomes, iterations)


@pytest.fixture(scope="module")
def damped_romeo_cases():
    """``(J, b, sizes, lo, up)`` of 6 configurations of benchmarks/romeo_damped.py (the controller's own stacks)."""
    from benchmarks.romeo_damped import stacks

    cases = stacks(6)[2]
    assert len(cases) == 6                             # (the controller's sns_tpm calls were captured)
    return cases


def test_damped_romeo_tpm_is_factorized(damped_romeo_cases):
    """TPM of the damped Romeo stacks (m > n, damped pivots above the crossing level): the kernel answers by the
    factorization (``FACTORED``: each damped pivot's inverse from the SVD of its block, Steps 2-4 as a forward
    substitution, the crossing level by the full-rank shortcut), equal to the recursion and to ``tpm_reference`` at
    1e-12. (On 42742a8 the recursion answered 194 of the benchmark's 200.)"""
    from benchmarks.romeo_damped import EPS, LAMBDA_MAX
    from hqp_tpm.solvers.nullspace import nullspace_stacked
    from hqp_tpm.solvers.tpm import tpm_reference

    for J, b, sizes, _, _ in damped_romeo_cases:
        n = J.shape[1]
        x = np.empty(n)
        path = _compiled._tpm(J, b, np.array(sizes), n, LAMBDA_MAX, EPS, _compiled._UNIT, _compiled.MARGIN,
                              _compiled.COND, np.empty(0), False, x)
        assert path == _compiled.FACTORED
        off = np.cumsum((0, *sizes))
        levels = [(J[a:e], b[a:e]) for a, e in zip(off, off[1:], strict=False)]
        assert rel_diff(x, nullspace_stacked(J, b, sizes, n, LAMBDA_MAX, EPS)) <= TOL
        assert rel_diff(x, tpm_reference(levels, lambda_max=LAMBDA_MAX, eps=EPS)) <= TOL


def test_benchmark_damped_romeo_configurations_stay_in_the_kernel(damped_romeo_cases):
    """The side-by-side benchmark's Romeo problem with the library's damping (kp 100, lambda_max 0.05, eps 0.1):
    the controller's own stacks (6 levels, 38 x 27), each solved in the kernel to the end (DONE), equal to
    Algorithm 1. Their damped pivots above the crossing level are taken by the factorization (each pivot's damped
    inverse from the SVD of its block, the QR downdated at each saturation): the recursion answers at most one
    pass in five (on 42742a8 it answered every pass; before 7f723e3 every solve was handed back to numpy)."""
    from benchmarks.romeo_damped import EPS, LAMBDA_MAX

    passes = recursions = 0
    for i, (J, b, sizes, lo, up) in enumerate(damped_romeo_cases):
        status, x, sat, scale, its, feasible, nrec = _compiled_sns.sns_tpm_loop(J, b, sizes, lo, up, LAMBDA_MAX,
                                                                                  EPS)
        assert status == _compiled_sns.DONE and len(sat) >= 3, (status, nrec, sat)
        passes += its
        recursions += nrec
        if i < 2:                                                 # the kernel's source as Python: the same run
            _compiled.ENABLED = False
            try:
                py = _compiled_sns.sns_tpm_loop(J, b, sizes, lo, up, LAMBDA_MAX, EPS)
            finally:
                _compiled.ENABLED = True
            assert py[2] == sat and py[4] == its and py[6] == nrec, (py[2:], sat, its, nrec)
            assert rel_diff(py[1], x) <= TOL, rel_diff(py[1], x)
        off = np.cumsum((0, *sizes))
        levels = [(J[a:e], b[a:e]) for a, e in zip(off, off[1:], strict=False)]
        xr, info_r = sns_tpm_reference(levels, lo, up, lambda_max=LAMBDA_MAX, eps=EPS, return_info=True)
        assert sat == info_r.saturated and its == info_r.iterations, (sat, info_r)
        assert rel_diff(x, xr) <= REF_TOL, rel_diff(x, xr)
    assert 5 * recursions <= passes, (recursions, passes)


@pytest.mark.parametrize("damping", [{}, {"lambda_max": 0.05, "eps": 0.1}])
def test_levels_in_their_own_units_stay_in_the_kernel(damping, outcomes):
    """Each level's ``(J_i, b_i)`` in its own units (10^U(-6, 6)), rank-deficient and repeated levels among them,
    ``m > n`` and ``m <= n``: the kernel equals Algorithm 1 and, undamped (the damping law is in the levels' units),
    its decisions do not move with the units (the same saturations and command as the unscaled stack)."""
    rng = np.random.default_rng(555 + len(damping))
    for i in range(30):
        n = int(rng.integers(6, 14))
        base = dependent_stack(rng, n, bool(i % 2)) if i % 3 == 0 else random_stack(
            rng, n, [int(rng.integers(1, 4)) for _ in range(int(rng.integers(2, 5)))])
        if i % 2:
            base = with_posture(base, n, rng)
        lo, up = cutting_box(rng, base, n, damping)
        x0, info0 = sns_tpm(base, lo, up, return_info=True, **damping)
        scaled = [(u * J, u * b) for (J, b), u in zip(base, 10.0 ** rng.uniform(-6, 6, len(base)), strict=True)]
        info = check(scaled, lo, up, outcomes, damping)
        if not damping:                                          # (the damping law is in the levels' units)
            x = sns_tpm(scaled, lo, up)
            assert info.saturated == info0.saturated and rel_diff(x, x0) <= 1e-6, (info, info0, rel_diff(x, x0))
    assert outcomes[_compiled_sns.DONE] >= 30, outcomes


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
    and the saturated joints' rows are decoupled (the refactorization's factors, up to the columns' signs). Past
    the point where another level crosses rank (fewer free joints than the 17 rows above the posture), the views of
    the new crossing level factor it the same way (``R~``'s leading columns and its columns of that level)."""
    rng = np.random.default_rng(8)
    n, sizes = 27, (6, 2, 3, 6, 21)
    J = np.vstack([rng.standard_normal((17, n)), np.hstack([np.zeros((21, 6)), np.eye(21)])])
    _compiled._sizes(sizes)                                     # compiles the kernels
    status, m1, mk, r, V, tau, R1, BT, *_ = _compiled._past_rank_factor(
        J, np.array(sizes), n, 0.0, 0.0, _compiled._UNIT, _compiled.MARGIN, _compiled.COND, False)
    assert status == _compiled.SOLVED and (m1, mk) == (17, 21)
    CT, Rt = BT.copy(), np.zeros((n, m1))
    Rt[:m1] = R1
    QT, w = _compiled_sns._basis(V, tau, m1, n), np.empty(n)
    Q0 = np.eye(n)                                              # rows e_i -> Q e_i: Q = Q0^T
    _compiled._apply_q_rows(Q0, V, tau, m1)
    assert np.abs(QT - Q0).max() < 1e-14                        # the explicit basis is the reflectors' Q
    free = np.ones(n, dtype=bool)
    crossings = set()
    for s, j in enumerate(rng.permutation(n)[:16]):
        free[j] = False
        _compiled_sns._downdate(j, QT, CT, Rt, s, m1, w)
        Q = QT.T
        Qf = Q[free][:, s + 1:]
        R1s = Rt[s + 1:s + 1 + m1]
        assert np.abs(np.tril(R1s, -1)).max() == 0.0                          # still triangular
        assert np.abs(Qf.T @ Qf - np.eye(n - s - 1)).max() < 1e-13
        assert np.abs(Qf[:, :m1] @ R1s - J[:m1, free].T).max() < 1e-13 * np.abs(J).max()
        assert np.abs(J[m1:, free] @ Qf - CT[s + 1:].T).max() < 1e-13
        assert np.abs(Q[~free][:, s + 1:]).max() < 1e-14                      # saturated joints: no coupling
        k, m1k, mkk, _ = _compiled._crossing_level(np.array(sizes), n - s - 1)
        crossings.add(k)
        R1k, BTk = _compiled_sns._downdated_views(CT, Rt, s + 1, k, m1k, mkk, 4)
        assert np.abs(Qf[:, :m1k] @ R1k - J[:m1k, free].T).max() < 1e-13 * np.abs(J).max()
        assert np.abs(J[m1k:m1k + mkk, free] @ Qf - BTk.T).max() < 1e-13 * np.abs(J).max()
    assert crossings == {4, 3, 2}, crossings                # (the posture level, then the levels above it)


@pytest.mark.parametrize("tiny", [1e-200, 1e-170, 0.0])
def test_downdate_where_the_rotations_squares_underflow(tiny):
    """A saturated joint whose row of ``Q~`` has entries whose squares underflow (``|w_i| < 1e-154``): the
    downdate's rotations (``sqrt(w0^2 + w1^2)``, ``hypot`` where that underflows) still turn the row into ``+-e_s``
    and keep ``Q~`` orthogonal, ``R~`` exact on the joints left (no NaN, no zero division). Compiled and as Python."""
    n, p, j = 6, 3, 2
    w = np.array([0.6, tiny, tiny, 0.8, tiny, tiny])
    u = np.eye(n)[j] - w
    Q = np.eye(n) - 2.0 * np.outer(u, u) / (u @ u)              # orthogonal (a reflector), row j = w
    rng = np.random.default_rng(3)
    R1 = np.triu(rng.standard_normal((p, p))) + 3.0 * np.eye(p)
    Rt = np.zeros((n, p))
    Rt[:p] = R1
    M = Q[:, :p] @ R1                                            # the upper levels' J^T, n joints x p rows
    _compiled_sns._compile()                                     # (the kernels as numba dispatchers)
    for enabled in (True, False):
        QT, R = Q.T.copy(), Rt.copy()
        if enabled:
            _compiled_sns._downdate(j, QT, np.empty((0, 0)), R, 0, p, np.empty(n))
        else:
            _compiled_sns._downdate.py_func(j, QT, np.empty((0, 0)), R, 0, p, np.empty(n))
        assert np.isfinite(QT).all() and np.isfinite(R).all()
        assert abs(abs(QT[0, j]) - 1.0) < 1e-15 and np.abs(QT[1:, j]).max() < 1e-15
        assert np.abs(QT @ QT.T - np.eye(n)).max() < 1e-15
        keep = np.arange(n) != j
        assert np.abs(QT.T[keep][:, 1:p + 1] @ R[1:p + 1] - M[keep]).max() < 1e-14
