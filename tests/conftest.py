"""Shared test helpers."""

import numpy as np


def rel_diff(a, b) -> float:
    """Relative difference ``|a - b| / max(1, |b|)`` (2-norm)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.linalg.norm(a - b) / max(1.0, np.linalg.norm(b)))


def random_stack(rng, n, sizes, scale=1.0):
    """Independent Gaussian levels ``(J_i, b_i)`` with the given row counts."""
    return [(rng.standard_normal((m, n)), scale * rng.standard_normal(m)) for m in sizes]
