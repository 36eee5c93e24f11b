"""``sns_tpm_stacked(..., x0=x0)``: the joint-space term as one more, lowest level ``I x = x0`` (as the registry adds
it), stacked without ``np.vstack``/``np.eye`` per call: the same solution and info as the rows stacked by hand, bit
for bit, with joints saturating and without."""

import numpy as np

from hqp_tpm.solvers.sns import _identity, sns_tpm_stacked


def test_the_term_level_equals_the_rows_stacked_by_hand():
    rng = np.random.default_rng(8)
    saturated = set()
    for _ in range(300):
        n = int(rng.integers(3, 12))
        sizes = tuple(int(k) for k in rng.integers(1, 4, size=int(rng.integers(1, 4))))
        m = sum(sizes)
        J, b, x0 = rng.normal(size=(m, n)), rng.normal(size=m), rng.normal(size=n) * 0.3
        half = rng.uniform(0.2, 3.0, size=n)
        lo, up = -half, half
        damping = {"lambda_max": 0.05, "eps": 0.1} if rng.random() < 0.5 else {}
        x, info = sns_tpm_stacked(J, b, sizes, lo, up, return_info=True, x0=x0, **damping)
        want, info_w = sns_tpm_stacked(np.vstack((J, np.eye(n))), np.concatenate((b, x0)), (*sizes, n), lo, up,
                                       return_info=True, **damping)
        np.testing.assert_array_equal(x, want)
        assert info == info_w
        saturated.add(bool(info.saturated))
    assert saturated == {True, False}


def test_the_identity_it_stacks_stays_the_identity():
    """The cached identity is read-only: a caller's rows never change it (two calls, the same answer)."""
    rng = np.random.default_rng(9)
    J, b, x0 = rng.normal(size=(2, 5)), rng.normal(size=2), rng.normal(size=5)
    lo, up = np.full(5, -1.0), np.full(5, 1.0)
    first = sns_tpm_stacked(J, b, (2,), lo, up, x0=x0)
    eye = _identity(5)
    assert not eye.flags.writeable and np.array_equal(eye, np.eye(5))
    np.testing.assert_array_equal(sns_tpm_stacked(J, b, (2,), lo, up, x0=x0), first)
