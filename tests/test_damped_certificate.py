"""The full-rank shortcut certifies its solution map with the damped pivots' inverses.

With the damping on, a pivot of the upper levels whose ``sigma_min`` is small but above its rank tolerance (certified
regular) is inverted by the damping law (``D_i``, norm at most ``1/(2 lambda)``), and ``z`` is the forward
substitution with those inverses (:func:`hqp_tpm.solvers._compiled._pivot_forward`). The certificate on the stack's
solution map (``1/COND``) now measures that map (:func:`hqp_tpm.solvers._compiled._damped_map_norm`), not the
undamped ``R1^{-1}``, whose norm ``1/sigma_min`` made the shortcut decline such stacks and hand them to the
recursion (on damped Romeo, 114 of the 151 SNS-TPM passes that took the recursion). Both give the same answer up
to the stack's own rounding sensitivity: on these stacks (upper levels 1e-4 from dependence) a relative change of
1e-16 in ``J`` moves ``tpm_reference`` by up to ~8e-12, and the recursion differs from it as much; so the shortcut
is held to ``1e-12 * cond / 1e3`` of ``tpm_reference`` and of the recursion (as ``test_compiled``'s
prescribed-condition stacks). ``_damped_map_norm`` equals the norm of the map it measures.
"""

import numpy as np

from hqp_tpm.solvers import _compiled, nullspace, sns_tpm, sns_tpm_reference, tpm_reference
from hqp_tpm.solvers.levels import stacked

DAMP = {"lambda_max": 0.05, "eps": 0.1}
TOL = 1e-12 * 1e4 / 1e3                               # (cond ~1e4: the upper levels 1e-4 from dependence)


def coupled_stack(rng):
    """A top level, a level almost in its span (its pivot's ``sigma_min`` 1e-4 of its norm: damped, regular, with
    ``||R1^{-1}||_F ~ 1e4``) and a posture level: past rank ``n`` at the posture."""
    n = int(rng.integers(4, 10))
    top = rng.standard_normal((int(rng.integers(1, 3)), n))
    mix = rng.standard_normal((int(rng.integers(1, 3)), top.shape[0])) @ top
    near = mix + 1e-4 * np.linalg.norm(mix) * rng.standard_normal(mix.shape)
    return [(top, rng.standard_normal(top.shape[0])), (near, rng.standard_normal(near.shape[0])),
            (np.eye(n), rng.standard_normal(n))], n


def test_sns_passes_take_damped_coupled_stacks_and_equal_reference():
    """The factorization of SNS-TPM's passes (``damped_map``) takes these stacks; ``tpm``'s (undamped map) declines
    them; the shortcut's ``x`` equals ``tpm_reference`` and the recursion within :data:`TOL`."""
    rng = np.random.default_rng(29)
    declined = 0
    for _ in range(60):
        levels, n = coupled_stack(rng)
        _, J, b, sizes, n = stacked(levels, n)
        s = np.asarray(sizes, dtype=np.int64)
        args = (J, s, n, DAMP["lambda_max"], DAMP["eps"], _compiled._UNIT, _compiled.MARGIN, _compiled.COND)
        declined += _compiled._past_rank_factor(*args, False)[0] == _compiled.DECLINED
        f = _compiled._past_rank_factor(*args, True)
        assert f[0] == _compiled.SOLVED                # (82bfea4: declined, the recursion answered)
        x = np.empty(n)
        _compiled._past_rank_rhs(b, *f[1:], DAMP["lambda_max"], DAMP["eps"], x)
        for ref in (tpm_reference(levels, **DAMP), nullspace(levels, n=n, **DAMP)):
            assert np.linalg.norm(x - ref) <= TOL * max(1.0, np.linalg.norm(ref))
    assert declined >= 10                              # (the draws the undamped certificate hands to the recursion)


def test_sns_tpm_on_damped_coupled_stacks_equals_reference():
    """Saturations on these stacks: the same decisions as Algorithm 1 as written, the command within 1e-10."""
    rng = np.random.default_rng(30)
    for _ in range(30):
        levels, n = coupled_stack(rng)
        box = 0.3 * np.abs(rng.standard_normal(n)) + 0.05
        x, info = sns_tpm(levels, -box, box, return_info=True, **DAMP)
        xr, ir = sns_tpm_reference(levels, -box, box, return_info=True, **DAMP)
        assert info.saturated == ir.saturated and info.iterations == ir.iterations
        assert abs(info.scale - ir.scale) <= 1e-10
        assert np.linalg.norm(x - xr) <= 1e-10 * max(1.0, np.linalg.norm(xr))


def test_damped_map_norm_is_the_norm_of_the_forward_substitution():
    rng = np.random.default_rng(31)
    for _ in range(20):
        sizes = np.array([int(s) for s in rng.integers(1, 4, int(rng.integers(1, 5)))] + [3])
        k = sizes.shape[0] - 1
        m1 = int(sizes[:k].sum())
        R1 = np.triu(rng.standard_normal((m1, m1))) + 3.0 * np.eye(m1)
        Dp, blk = _compiled._pivot_inverses(np.linalg.inv(R1), sizes, k, m1)
        a = 0
        for lev in range(k):                          # some pivots replaced by another (damped-like) inverse
            e = a + sizes[lev]
            if rng.random() < 0.5:
                Dp[a:e, a:e] = rng.standard_normal((e - a, e - a))
            a = e
        M = np.column_stack([_compiled._pivot_forward(R1, Dp, blk, col, m1) for col in np.eye(m1)])
        got = _compiled._damped_map_norm(R1, Dp, sizes, k, m1)
        assert abs(got - np.linalg.norm(M)) <= 1e-12 * np.linalg.norm(M)
