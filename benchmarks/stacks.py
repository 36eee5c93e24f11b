"""Random prioritized stacks for the benchmarks (and ``tests/test_benchmark_paths.py``).

The TPM paper's timing set-up (reference/romeo_four_tasks.md): ``l`` tasks of 3 rows on ``n``
joints, Gaussian Jacobians and targets. Two kinds of stack:

* ``independent``: every task full rank and independent of the others (``3 l <= n``);
* ``dependent``: dependent and conflicting tasks. Every odd-indexed task (the 2nd, 4th, ...)
  is a random linear combination of the rows of the tasks above it, with its own target (so it
  conflicts with them); from the 4th task on, every other such task keeps only two dependent rows
  and gets one new row (a rank-deficient but non-zero TPM pivot). The last task (``l >= 3``)
  repeats the first task's Jacobian with another target: a pure conflict.

:func:`binding_box` gives a symmetric joint box that the TPM solution leaves, so that SNS-TPM
saturates joints. Only numpy is used here, so the test suite can import it cheaply.
"""

from __future__ import annotations

import numpy as np

ROWS = 3
KINDS = ("independent", "dependent")


def independent(rng: np.random.Generator, l: int, n: int, rows: int = ROWS) -> list[tuple[np.ndarray, np.ndarray]]:
    """``l`` Gaussian tasks ``(J_i, b_i)`` of ``rows`` rows on ``n`` joints (full rank when ``rows * l <= n``)."""
    return [(rng.standard_normal((rows, n)), rng.standard_normal(rows)) for _ in range(l)]


def dependent(rng: np.random.Generator, l: int, n: int, rows: int = ROWS) -> list[tuple[np.ndarray, np.ndarray]]:
    """``l`` tasks with dependent and conflicting ones (see the module doc)."""
    levels: list[tuple[np.ndarray, np.ndarray]] = []
    for i in range(l):
        if i >= 2 and i == l - 1:                      # the first task again, another target
            J = levels[0][0].copy()
        elif i % 2 == 1:                               # a combination of the rows above
            above = np.vstack([lv[0] for lv in levels])
            J = rng.standard_normal((rows, above.shape[0])) @ above
            if i % 4 == 3:                             # ... partly: one new row
                J[-1] = rng.standard_normal(n)
        else:
            J = rng.standard_normal((rows, n))
        levels.append((J, rng.standard_normal(rows)))
    return levels


def stack(kind: str, rng: np.random.Generator, l: int, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """A stack of the given kind (``"independent"`` or ``"dependent"``)."""
    if kind == "independent":
        return independent(rng, l, n)
    if kind == "dependent":
        return dependent(rng, l, n)
    raise ValueError(f"unknown stack kind {kind!r}; valid: {', '.join(KINDS)}")


def binding_box(x: np.ndarray, fraction: float = 0.7) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric box ``|x_j| <= fraction * max|x|``: the joints beyond it saturate (0 stays inside)."""
    c = fraction * float(np.abs(x).max())
    c = c if c > 0.0 else 1.0
    n = x.shape[0]
    return np.full(n, -c), np.full(n, c)
