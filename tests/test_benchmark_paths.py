"""The benchmarks time the fast paths: on the benchmark stacks they equal the reference paths to 1e-12 (TPM on
stacks with a repeated or dependent task: the recursion, which tpm is there).

Stacks from ``benchmarks/stacks.py`` (independent full-rank, and dependent/conflicting tasks), a few
sizes of the TPM paper's timing set-up (3 rows per task), undamped and with the damping of the Romeo
scenarios; SNS-TPM with the benchmarks' binding box.
"""

import sys
from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from hqp_tpm.solvers import nullspace, sns_tpm, sns_tpm_reference, tpm, tpm_reference

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: ``benchmarks`` package

from benchmarks import stacks  # noqa: E402

TOL = 1e-12
SIZES = [(1, 30), (3, 30), (5, 20), (10, 30), (5, 100), (5, 300)]
DAMPING = {"none": {}, "romeo": {"lambda_max": 0.05, "eps": 0.1}}
DRAWS = 8


def rel_err(a, b) -> float:
    """``max|a - b| / max(1, max|b|)``."""
    return float(np.abs(a - b).max() / max(1.0, np.abs(b).max()))


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread():
    with threadpool_limits(1):
        yield


@pytest.mark.parametrize("damping", list(DAMPING))
@pytest.mark.parametrize("l,n", SIZES)
@pytest.mark.parametrize("kind", stacks.KINDS)
def test_fast_paths_equal_reference_paths(kind, l, n, damping):
    damp = DAMPING[damping]
    rng = np.random.default_rng(1000 * l + n)
    bound = 0
    for _ in range(DRAWS):
        levels = stacks.stack(kind, rng, l, n)
        x = tpm(levels, **damp)
        if kind == "independent":  # every pivot regular: the paper's steps as written
            assert rel_err(x, tpm_reference(levels, **damp)) <= TOL
        else:  # a repeated or dependent task: tpm is the recursion there (hqp_tpm.solvers.tpm module doc)
            assert rel_err(x, nullspace(levels, **damp)) <= TOL
        lo, up = stacks.binding_box(x)
        xs, info = sns_tpm(levels, lo, up, return_info=True, **damp)
        xr, info_r = sns_tpm_reference(levels, lo, up, return_info=True, **damp)
        assert rel_err(xs, xr) <= TOL
        assert info.saturated == info_r.saturated and info.iterations == info_r.iterations
        assert abs(info.scale - info_r.scale) <= TOL and info.feasible and info_r.feasible
        assert (xs >= lo).all() and (xs <= up).all()
        bound += info.iterations > 1 or info.scale < 1.0
    assert bound == DRAWS  # the box binds on every draw: SNS-TPM saturates or scales


@pytest.mark.parametrize("l,n", SIZES)
def test_stack_generators(l, n):
    rng = np.random.default_rng(l + n)
    ind = stacks.independent(rng, l, n)
    assert [J.shape for J, _ in ind] == [(stacks.ROWS, n)] * l
    assert np.linalg.matrix_rank(np.vstack([J for J, _ in ind])) == stacks.ROWS * l
    dep = stacks.dependent(rng, l, n)
    J = np.vstack([J for J, _ in dep])
    assert J.shape == (stacks.ROWS * l, n)
    if l >= 2:
        assert np.linalg.matrix_rank(J) < stacks.ROWS * l  # dependent tasks
    if l >= 3:
        np.testing.assert_array_equal(dep[-1][0], dep[0][0])  # the first task repeated, another target
        assert not np.array_equal(dep[-1][1], dep[0][1])
    with pytest.raises(ValueError, match="unknown stack kind"):
        stacks.stack("other", rng, l, n)
