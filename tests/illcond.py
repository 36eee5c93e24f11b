"""Random stacks whose levels are nearly dependent (cond(J) up to 1e10), for the numerics tests."""

from __future__ import annotations

import numpy as np


def nearly_dependent_stack(rng, max_cond: float = 1e10):
    """A full-row-rank stack (sum m_i <= n) with the rows of a lower level within ``delta`` of the rows above.

    Level ``k`` (random, below the first) gets rows ``C J_above + delta E`` for its first 1..m_k rows,
    ``delta`` log-uniform in [1e-11, 1e-3]; the draw is redone until cond(J) <= ``max_cond``.
    Returns ``(levels, cond)``.
    """
    while True:
        n = int(rng.integers(3, 13))
        l = int(rng.integers(2, 5))
        sizes = [int(rng.integers(1, 4)) for _ in range(l)]
        while sum(sizes) > n:
            sizes.pop()
        if len(sizes) < 2:
            continue
        Js = [rng.standard_normal((k, n)) for k in sizes]
        k = int(rng.integers(1, len(sizes)))
        above = np.vstack(Js[:k])
        delta = 10.0 ** rng.uniform(-11, -3)
        r = int(rng.integers(1, sizes[k] + 1))
        Js[k][:r] = rng.standard_normal((r, above.shape[0])) @ above + delta * rng.standard_normal((r, n))
        J = np.vstack(Js)
        cond = np.linalg.cond(J)
        if cond <= max_cond:
            levels = [(Ji, rng.standard_normal(Ji.shape[0])) for Ji in Js]
            return levels, float(cond)


def box_for(rng, x, n):
    """A box containing 0 that cuts the unconstrained command ``x`` (``lo < 0 < up``)."""
    c = np.abs(x).max() + 1e-300
    lo = -rng.uniform(0.05, 1.2, n) * c
    up = rng.uniform(0.05, 1.2, n) * c
    return lo, up
