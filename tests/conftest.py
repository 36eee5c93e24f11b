"""Shared test helpers. The random stacks come from the public module users import too."""

import numpy as np

from hqp_tpm.testing.stacks import random_stack  # noqa: F401  (re-exported for the test files)


def rel_diff(a, b) -> float:
    """Relative difference ``|a - b| / max(1, |b|)`` (2-norm)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.linalg.norm(a - b) / max(1.0, np.linalg.norm(b)))
