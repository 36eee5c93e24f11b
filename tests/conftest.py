"""Shared test helpers. The random stacks come from the public module users import too.

Property tests (hypothesis) draw the same examples on every run (``derandomize``): the suite gates CI, and a
fresh draw that lands on a rare case would make a run red at random. ``HQP_TPM_HYPOTHESIS=explore`` draws new
examples each run (to look for such cases; any one found gets a test of its own).
"""

import os

import numpy as np
from hypothesis import settings

from hqp_tpm.testing.stacks import random_stack  # noqa: F401  (re-exported for the test files)

settings.register_profile("deterministic", derandomize=True, database=None)
settings.register_profile("explore")
settings.load_profile("explore" if os.environ.get("HQP_TPM_HYPOTHESIS") == "explore" else "deterministic")


def rel_diff(a, b) -> float:
    """Relative difference ``|a - b| / max(1, |b|)`` (2-norm)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.linalg.norm(a - b) / max(1.0, np.linalg.norm(b)))
