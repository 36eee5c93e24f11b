"""SNS-TPM's downdated passes whose crossing level is not clearly of full column rank: the recursion from that
level on (:func:`hqp_tpm.solvers._compiled_sns._crossing_recursion`) equals the whole recursion.

When the certificates take the pivots of the levels above the crossing level but not ``A = J_k Z`` (its smallest
``|r_jj|`` or ``1/||R_A^{-1}||_F`` at or below ``COND ||J_k||``: ``_compiled.CROSSING``), the pass is the recursion's
(eqs. (5)-(6) of papers/000). Its first levels would use every direction of those certified pivots with the same
damping law, so their part is taken from the downdated factorization (``x = Q1 z``, the basis ``Z`` of their null
space) and the recursion runs from the crossing level on (:func:`hqp_tpm.solvers._compiled._recursion_from`): one
SVD fewer per level above it (on ``romeo_obstacles_sns_tpm``'s slowest steps the crossing level is the 2nd..6th of
7..8). Held equal to :func:`hqp_tpm.solvers._compiled._recursion_cols` with the levels' ranks on stacks whose
crossing level is rank-deficient in what the levels above leave, undamped and damped: exactly (1e-12 relative) or
within 1e-9 (``1e-12 * cond / 1e3`` as test_compiled's prescribed-condition stacks, times the solution's
amplification ``||x|| / ||b||``: two exact formulas differ by that much rounding there); and the SNS loop on such
stacks equal to Algorithm 1 as written.
"""

import numpy as np
import pytest

from hqp_tpm.solvers import _compiled, _compiled_sns, sns_tpm, sns_tpm_reference
from hqp_tpm.solvers._compiled import COND, MARGIN


def crossing_stack(rng, n):
    """Upper levels (well conditioned), a crossing level with a row (nearly) in their span, a posture level."""
    sizes = [int(s) for s in rng.integers(1, 4, int(rng.integers(1, 4)))]
    while sum(sizes) > n - 2:
        sizes.pop()
    upper = rng.standard_normal((sum(sizes), n))
    cross = rng.standard_normal((n - sum(sizes) + int(rng.integers(0, 2)), n))
    close = 10.0 ** -rng.choice([9.0, 20.0])
    cross[0] = rng.standard_normal(upper.shape[0]) @ upper + close * cross[0]
    J = np.vstack([upper, cross, np.eye(n)])
    return J, (*sizes, cross.shape[0], n), close


@pytest.mark.parametrize("damped", [False, True])
def test_recursion_from_the_crossing_level_equals_the_whole_recursion(damped):
    if not _compiled_sns._READY and _compiled.AVAILABLE and _compiled.ENABLED:
        _compiled_sns._compile()
    lam, eps = (0.05, 0.1) if damped else (0.0, 0.0)
    rng = np.random.default_rng(291 + damped)
    crossings = 0
    for _ in range(200):
        n = int(rng.integers(4, 12))
        J, sizes, close = crossing_stack(rng, n)
        s = np.array(sizes, dtype=np.int64)
        k, m1, mk, r = (int(v) for v in _compiled._crossing_level(s, n))
        V, tau, R1 = _compiled._rows_qr(J, m1)
        BT = np.ascontiguousarray(J[m1:m1 + mk].T)
        _compiled._apply_right_t(BT, V, tau, m1, np.empty(max(n, mk)))
        sq = np.array([np.sum(J[a:a + z] ** 2) for a, z in zip(np.cumsum((0, *sizes))[:-1], sizes, strict=True)])
        status, *_, Dp, blk, _ = _compiled._past_rank_certify(R1, BT, sq, s, k, m1, mk, r, J.shape[0], lam, eps,
                                                              _compiled._UNIT, MARGIN, COND, True)
        if status != _compiled.CROSSING:
            continue
        crossings += 1
        QT = _compiled_sns._basis(V, tau, m1, n)
        B = rng.standard_normal((J.shape[0], 2))
        ranks, want_ranks = np.empty(len(sizes), dtype=np.int64), np.empty(len(sizes), dtype=np.int64)
        got = _compiled_sns._crossing_recursion(J, B, s, n, lam, eps, _compiled._UNIT, ranks, np.ones(n, dtype=bool),
                                                0, k, m1, QT, R1, Dp, blk)
        want = _compiled._recursion_cols(J, B, s, n, lam, eps, _compiled._UNIT, want_ranks)[0]
        amplification = max(1.0, np.linalg.norm(want) / np.linalg.norm(B))   # (1e9 where undamped, 1e-9 close)
        tol = 1e-12 * max(1.0, 1e-3 / close) * amplification                  # (TOL * cond / 1e3, test_compiled)
        assert np.linalg.norm(got - want) <= tol * max(1.0, np.linalg.norm(want))
        np.testing.assert_array_equal(ranks, want_ranks)
    assert crossings >= 50


@pytest.mark.parametrize("damped", [False, True])
def test_sns_on_crossing_stacks_equals_algorithm_1(damped):
    damp = {"lambda_max": 0.05, "eps": 0.1} if damped else {}
    rng = np.random.default_rng(293 + damped)
    for _ in range(40):
        n = int(rng.integers(5, 10))
        J, sizes, _ = crossing_stack(rng, n)
        off = np.cumsum((0, *sizes))
        levels = [(J[a:e], rng.standard_normal(e - a)) for a, e in zip(off[:-1], off[1:], strict=True)]
        box = 0.2 * np.abs(rng.standard_normal(n)) + 0.02
        x, info = sns_tpm(levels, -box, box, return_info=True, **damp)
        xr, ir = sns_tpm_reference(levels, -box, box, return_info=True, **damp)
        assert info.saturated == ir.saturated and info.iterations == ir.iterations
        assert abs(info.scale - ir.scale) <= 1e-9
        assert np.linalg.norm(x - xr) <= 1e-9 * max(1.0, np.linalg.norm(xr))
