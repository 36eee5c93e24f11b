"""TPM of a stack that reaches full rank ``n`` before its last level: the shortcut's argument and thresholds
(private to :mod:`hqp_tpm.solvers`; its one implementation is the kernel :func:`hqp_tpm.solvers._compiled._past_rank`).

When the stacked Jacobian has more rows than columns (``m > n``), :func:`hqp_tpm.solvers.tpm.tpm` pads it
with zero columns and goes through singular pivots and an SVD of the padded ``R^T``. That is the common
case of a stack ending with a posture level (6 + 7 rows on the 7-joint arm). Its result is simpler:

* let levels ``1 .. k-1`` (``m1 <= n`` rows) have regular pivots and level ``k`` cross the rank:
  ``m1 < n <= m1 + m_k``; ``J_<k^T = Q1 R1`` (one ``dgeqrf``) and ``Z`` the orthonormal basis of its
  null space, from the same Householder reflectors (``Q = [Q1 Z]``);
* the pivot of level ``k`` in the padded factorization is ``R_kk`` with ``R_kk^T = (J_k Z) W``, ``W``
  with orthonormal rows: its singular values are those of ``A = J_k Z`` (``m_k x r``, ``r = n - m1``)
  and ``m_k - r`` zeros; so its (damped) pseudo-inverse is ``W^T A#`` with the same damping law;
* Steps 2-4 then give ``x = x1 + Z A# (b_k - J_k x1)`` with ``x1 = Q1 R1^{-T} b_<k``: the least-squares
  solution of level ``k`` in the remaining null space;
* when ``A`` has full column rank the stack has rank ``n``: every later level's pivot is zero up to
  rounding (it acts in an empty null space) and its ``b`` does not reach ``x``; ``(I - J# J) x0 = 0``.

With the damping on, a pivot of levels ``< k`` with ``sigma_min < eps`` gets its damped inverse ``D_i`` (the SVD
of its block), and Steps 2-4 become the forward substitution ``z_i = D_i^T (b_i - sum_{j<i} R_ji^T z_j)``: the
recursion on the basis ``Q1`` as long as every pivot is regular (``sigma_min`` well above its rank tolerance),
which the certificates below ensure.

The kernel returns that ``x``, or declines when it cannot certify the conditions under which the general
path would take the same decisions (a pivot of levels ``< k`` not provably regular, ``A`` without a clear full
column rank, a smallest singular value of the stack near the rank tolerance, or a solution map amplifying by
more than ``1/COND``; for a damped crossing level the damped ``A#`` counts, ``||A#_lambda||_F``): then the
recursion answers (:func:`hqp_tpm.solvers._compiled._tpm`). ``tests/test_fullrank.py`` checks it against
:func:`hqp_tpm.solvers.tpm.tpm_reference` at 1e-12.
"""

from __future__ import annotations

#: Decisions are taken here only with this margin over a tolerance (the recursion decides the rest).
MARGIN = 16.0
#: The shortcut is taken only for well-conditioned pivots: (lower bound of) ``sigma_min >= COND * ||rows||_F``
#: for the upper levels' pivots, ``A`` and the stack. Nearer to a rank loss two exact formulas differ by
#: ``cond * eps`` in rounding; the recursion (the general path's exact answer) decides there.
COND = 1e-5
