"""SNS-TPM with more rows than joints whose first pass the recursion answers: the later passes downdate the first
pass's QR (``hqp_tpm.solvers._compiled_sns``) instead of each falling to the recursion.

The first pass is the stack's TPM, held to the undamped certificate of ``tpm`` (1e-12 to ``tpm_reference``); where
it declines (damped upper levels near dependence: ``tests/test_damped_certificate.py``'s coupled stacks, and
``romeo_obstacles_sns_tpm``'s stacks with the command-rate level) the recursion answers it. Its QR of ``J_<k^T`` and
``(J_k Q)^T`` exist all the same; on 894a51a the kernel then refactorized ``J W`` at every later pass with that
undamped certificate, which declined again where the first pass's did, so the recursion (~49 us on Romeo) answered
those passes: the slow steps of ``romeo_obstacles_sns_tpm`` (kernel p99 681 us, 272 us now). The later passes now
take the downdated passes' certificate (the damped map), as on every other stack, and keep Algorithm 1's decisions
and command.
"""

import numpy as np
import pytest
from test_damped_certificate import DAMP, coupled_stack

from hqp_tpm.solvers import _compiled, _compiled_sns, sns_tpm_reference
from hqp_tpm.solvers.levels import stacked

pytestmark = pytest.mark.skipif(not _compiled.AVAILABLE, reason="numba is not installed")


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "python"])
def test_passes_after_a_recursive_first_pass_are_downdated(compiled, monkeypatch):
    monkeypatch.setattr(_compiled, "ENABLED", compiled)
    rng = np.random.default_rng(2929)
    solves = passes = later_recursive = 0
    for _ in range(200):
        levels, n = coupled_stack(rng)
        _, J, b, sizes, n = stacked(levels, n)
        s = np.asarray(sizes, dtype=np.int64)
        first = _compiled._past_rank_factor(J, s, n, DAMP["lambda_max"], DAMP["eps"], _compiled._UNIT,
                                            _compiled.MARGIN, _compiled.COND, False)[0]
        if first == _compiled.SOLVED:
            continue                                   # (the first pass by the shortcut: not these stacks)
        box = 0.3 * np.abs(rng.standard_normal(n)) + 0.05
        status, x, sat, scale, its, feasible, nrec = _compiled_sns.sns_tpm_loop(J, b, s, -box, box, **DAMP)
        assert status == _compiled_sns.DONE
        xr, ir = sns_tpm_reference(levels, -box, box, return_info=True, **DAMP)
        assert sat == ir.saturated and its == ir.iterations and feasible == ir.feasible
        assert abs(scale - ir.scale) <= 1e-10
        assert np.linalg.norm(x - xr) <= 1e-10 * max(1.0, np.linalg.norm(xr))
        if its >= 2:
            solves += 1
            passes += its - 1
            later_recursive += nrec - 1                # (nrec counts the first pass)
    assert solves >= 10 and passes >= 20, (solves, passes)
    # (894a51a: the recursion answered 155 of the 479 later passes, now 6; the passes that the undamped
    # certificate declined)
    assert later_recursive <= passes // 10, (later_recursive, passes)
