"""The general TPM kernel without the pivot SVD (issue 29, the first run): a pivot block whose certificate cannot
decide is handed back (``PIVOT_SVD``) and ``_general_svd`` answers with the bits of the one kernel that decided
every pivot; the block's SVD is numba's LAPACK ``dgesdd`` call, the same bits as numba's ``np.linalg.svd``.

Stacks that reach the hand-back: ``m <= n``, damping on, a level of two or more rows nearly dependent (its
certificate ``1/||R_ii^{-1}||_F`` below ``eps``).
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hqp_tpm.control import _compiled_step
from hqp_tpm.solvers import _compiled
from hqp_tpm.solvers._fullrank import COND, MARGIN
from hqp_tpm.solvers.tpm import tpm_stacked

pytestmark = pytest.mark.skipif(not _compiled.AVAILABLE, reason="numba is not installed")

ROOT = Path(__file__).resolve().parents[1]


def near_dependent_stacks(seed: int, count: int):
    """``(J, b, sizes, n, x0)`` with ``m <= n`` whose levels of 2-4 rows have a row within ``delta`` of another."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        n = int(rng.integers(5, 12))
        sizes, m = [], 0
        while m < n - 1 and len(sizes) < 4:
            k = min(int(rng.integers(2, 5)), n - m)
            sizes.append(k)
            m += k
        J = rng.standard_normal((m, n)) * 10.0 ** rng.uniform(-1, 1)
        a = 0
        for k in sizes:
            if k > 1 and rng.random() < 0.7:
                J[a + k - 1] = J[a] + rng.choice([1e-9, 1e-4, 1e-2, 5e-2]) * rng.standard_normal(n)
            a += k
        x0 = rng.standard_normal(n) if rng.random() < 0.5 else None
        yield J, rng.standard_normal(m), tuple(sizes), n, x0


def test_status_is_none_of_the_compiled_steps():
    """The hand-back passes through the compiled steps' statuses unchanged (they add 3-7)."""
    steps = {_compiled_step.NONFINITE_ROWS, _compiled_step.NONFINITE_X, _compiled_step.WRITTEN,
             _compiled_step.SNS_HANDED_BACK, _compiled_step.BOX_HANDED_BACK}
    solver = {_compiled.SOLVED, _compiled.DECLINED, _compiled.UNDECIDED, _compiled.SINGULAR}
    assert _compiled.PIVOT_SVD not in steps | solver


def test_block_svd_equals_numbas_svd():
    """The pivot block's SVD by numba's ``dgesdd`` driver gives numba's ``np.linalg.svd`` bits (U, s, Vt)."""
    import numba

    _compiled._sizes(())  # the kernels made

    @numba.njit
    def numba_svd(R, a, e):
        k = e - a
        B = np.zeros((k, k))
        for i in range(k):
            for j in range(i, k):
                B[i, j] = R[a + i, a + j]
        return np.linalg.svd(B)

    rng = np.random.default_rng(11)
    for _ in range(200):
        m = int(rng.integers(2, 12))
        R = np.triu(rng.standard_normal((m, m)) * 10.0 ** rng.uniform(-3, 3, (m, m)))
        a = int(rng.integers(0, m - 1))
        e = int(rng.integers(a + 2, m + 1))
        if rng.random() < 0.3:
            R[e - 1, e - 1] *= 1e-12  # nearly singular
        for got, want in zip(_compiled._block_svd(R, a, e), numba_svd(R, a, e), strict=True):
            np.testing.assert_array_equal(got, want)


def test_handed_back_stacks_solve_as_one_kernel():
    """On stacks whose pivot blocks need their SVD: ``_general`` hands back and solves nothing, ``_general_svd`` (the
    kernel deciding every pivot) answers; ``tpm_stacked``, ``general`` and ``tpm_stacked(kernel_status=PIVOT_SVD)``
    give its bits (``tests/test_compiled.py`` holds that kernel to the references)."""
    handed = 0
    for J, b, sizes, n, x0 in near_dependent_stacks(3, 300):
        s = _compiled._sizes(sizes)
        use = x0 is not None
        for lam, eps in ((0.05, 0.1), (0.1, 0.5)):
            out = np.full(n, np.nan)
            args = (J, b, s, x0 if use else _compiled._NO_X0, use, lam, eps, _compiled._UNIT)
            status = _compiled._general_first(*args, out)
            if status != _compiled.PIVOT_SVD:
                continue
            handed += 1
            assert np.isnan(out).all()  # nothing written
            x = np.empty(n)
            if _compiled._general_svd(*args, x) != _compiled.SOLVED:
                continue  # a singular pivot: the recursion answers (tests/test_compiled.py)
            np.testing.assert_array_equal(tpm_stacked(J, b, sizes, n, lam, eps, x0), x)
            np.testing.assert_array_equal(tpm_stacked(J, b, sizes, n, lam, eps, x0, kernel_status=status), x)
            np.testing.assert_array_equal(_compiled.general(J, b, sizes, n, lam, eps, x0), x)
    assert handed >= 100, handed


def test_planned_step_kernel_hands_back_and_tpm_stacked_finishes(monkeypatch):
    """The planned step's compiled solve (``_general`` fused with the rows' checks) hands these stacks back; the
    caller's ``tpm_stacked(kernel_status=...)`` gives the bits of ``tpm_stacked`` alone, and from then on
    ``_general`` is the kernel deciding every pivot (no more hand-backs)."""
    kernel = _compiled_step.stacked_kernel()
    if kernel is None:
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(4)
    handed = 0
    for J, b, sizes, n, _ in near_dependent_stacks(8, 120):
        v = rng.standard_normal(n)
        for damping in (0.0, 3.0):
            monkeypatch.setattr(_compiled, "_general", _compiled._general_first)  # (as in a fresh process)
            x, x0 = np.empty(n), np.empty(n)
            status = kernel(J, b, _compiled._sizes(sizes), v, damping, 0.05, 0.1, _compiled._UNIT, MARGIN, COND,
                            x0, x)
            ref = tpm_stacked(J, b, sizes, n, 0.05, 0.1, -damping * v if damping else None)
            if status == _compiled_step.SOLVED:
                np.testing.assert_array_equal(x, ref)
            elif status == _compiled.PIVOT_SVD:
                handed += 1
                got = tpm_stacked(J, b, sizes, n, 0.05, 0.1, x0 if damping else None, kernel_status=status)
                np.testing.assert_array_equal(got, ref)
                assert _compiled._general is _compiled._general_svd
                x2 = np.empty(n)  # the same stack again: solved at once, the same bits
                assert kernel(J, b, _compiled._sizes(sizes), v, damping, 0.05, 0.1, _compiled._UNIT, MARGIN, COND,
                              np.empty(n), x2) in (_compiled.SOLVED, _compiled.UNDECIDED)
                if np.isfinite(x2).all() and _compiled._general_svd(J, b, _compiled._sizes(sizes), x0,
                                                                    damping > 0, 0.05, 0.1, _compiled._UNIT,
                                                                    np.empty(n)) == _compiled.SOLVED:
                    np.testing.assert_array_equal(x2, ref)
    assert handed >= 20, handed


def test_a_run_without_the_pivot_svd_does_not_make_it():
    """A process whose stacks never need a pivot block's SVD makes (compiles or loads) ``_general`` only: not
    ``_general_svd``, not the block's SVD. With the SVD needed once, ``_general_svd`` too."""
    code = (
        "import numpy as np\n"
        "from hqp_tpm.solvers import _compiled\n"
        "from hqp_tpm.solvers.tpm import tpm_stacked\n"
        "rng = np.random.default_rng(0)\n"
        "J = rng.standard_normal((4, 7)); b = rng.standard_normal(4)\n"
        "tpm_stacked(J, b, (3, 1), 7, 0.05, 0.1)\n"
        "before = (len(_compiled._general.signatures), len(_compiled._general_svd.signatures),\n"
        "          len(_compiled._block_svd.signatures))\n"
        "J[2] = J[0] + 1e-3 * rng.standard_normal(7)\n"
        "tpm_stacked(J, b, (3, 1), 7, 0.05, 0.1)\n"
        "after = len(_compiled._general_svd.signatures)\n"
        "print(before, after)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "HQP_TPM_COMPILED"}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600,
                         check=True)
    assert out.stdout.split("\n")[0].strip() == "(1, 0, 0) 1", out.stdout + out.stderr
