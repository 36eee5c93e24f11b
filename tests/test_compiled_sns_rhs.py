"""The SNS-TPM kernel's two right-hand sides in one loop (``_compiled_sns._crossing_rhs2``) give, bit for bit, what
two calls of ``_compiled._crossing_rhs`` give (the same sums in the same order), compiled and as Python.

Factors from ``_compiled._past_rank_factor`` (with the downdated passes' damped-map certificate) on stacks with
more rows than joints: damped Romeo-like stacks (damped pivots above the crossing level: the forward substitution
with the pivots' inverses; damped crossing level), well-conditioned ones (``R1^-T`` by substitution, ``R_A^-1``),
stacks whose first level alone reaches rank ``n`` (``m1 = 0``). The kernel's own passes (``_downdated_rhs``,
built on it) are held to the numpy loop and Algorithm 1 by ``tests/test_compiled_sns.py``;
``benchmarks/romeo_damped.py --ab`` reports its commands bit-equal to the kernel before it.
"""

import numpy as np
import pytest
from test_compiled_sns import damped_romeo_like

from hqp_tpm.solvers import _compiled, _compiled_sns
from hqp_tpm.solvers.levels import stacked
from hqp_tpm.testing.stacks import random_stack

pytestmark = pytest.mark.skipif(not _compiled.AVAILABLE, reason="numba is not installed")

N = 27


def stacks(rng):
    """``(J, sizes, lambda_max, eps)``: damped Romeo-like stacks, Romeo-shaped well-conditioned ones (undamped and
    damped), first levels of ``n + 3`` rows, and 3 configurations of benchmarks/romeo_damped.py (the controller's
    own stacks)."""
    from benchmarks.romeo_damped import EPS, LAMBDA_MAX
    from benchmarks.romeo_damped import stacks as romeo_stacks

    out = []
    for _ in range(12):
        _, J, _, sizes, _ = stacked(damped_romeo_like(rng, N), N)
        out.append((J, sizes, 0.05, 0.1))
    posture = np.hstack([np.zeros((21, 6)), np.eye(21)])
    for _ in range(4):
        levels = random_stack(rng, N, [6, 2, 3, 6]) + [(posture, rng.standard_normal(21))]
        _, J, _, sizes, _ = stacked(levels, N)
        out += [(J, sizes, 0.0, 0.0), (J, sizes, 0.05, 0.1)]
    for _ in range(3):
        _, J, _, sizes, _ = stacked(random_stack(rng, N, [N + 3, 4]), N)
        out.append((J, sizes, 0.05, 0.1))
    out += [(J, sizes, LAMBDA_MAX, EPS) for J, _, sizes, _, _ in romeo_stacks(3)[2]]
    return out


def py(fn):
    """The Python source of a kernel (its dispatcher's ``py_func`` when compiled)."""
    return getattr(fn, "py_func", fn)


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "python"])
def test_two_right_hand_sides_equal_two_solves(compiled):
    if compiled:
        _compiled_sns._compile()
    rng = np.random.default_rng(2912)
    one = _compiled._crossing_rhs if compiled else py(_compiled._crossing_rhs)
    two = _compiled_sns._crossing_rhs2 if compiled else py(_compiled_sns._crossing_rhs2)
    seen = {"damped pivots": 0, "damped crossing": 0, "plain": 0, "m1 = 0": 0}
    for J, sizes, lambda_max, eps in stacks(rng):
        sizes = np.array(sizes, dtype=np.int64)
        (status, m1, mk, r, V, tau, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp,
         blk) = _compiled._past_rank_factor(J, sizes, N, lambda_max, eps, _compiled._UNIT, _compiled.MARGIN,
                                           _compiled.COND, True)
        if status != _compiled.SOLVED:
            continue
        seen["damped pivots"] += Dp.shape[0] > 0
        seen["damped crossing"] += DR.shape[0] > 0
        seen["plain"] += Dp.shape[0] == 0 and DR.shape[0] == 0
        seen["m1 = 0"] += m1 == 0
        for _ in range(3):
            b1, b2 = rng.standard_normal(J.shape[0]), rng.standard_normal(J.shape[0]) * 1e3
            x1, x2 = np.full(N, np.nan), np.full(N, np.nan)
            one(b1, m1, mk, r, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, x1)
            one(b2, m1, mk, r, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, x2)
            sc = np.full((10, max(J.shape)), np.nan)        # (scratch: nothing read before it is written)
            o1, o2 = np.full(N, np.nan), np.full(N, np.nan)
            two(b1, b2, m1, mk, r, R1, BT, AT, tauA, RA, DV, Dtau, DR, Dp, blk, sc, o1, o2)
            np.testing.assert_array_equal(o1[:m1 + r], x1[:m1 + r])
            np.testing.assert_array_equal(o2[:m1 + r], x2[:m1 + r])
            assert np.isfinite(o1[:m1 + r]).all() and np.isfinite(o2[:m1 + r]).all()
    assert all(v >= 2 for v in seen.values()), seen
