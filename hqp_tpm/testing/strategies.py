"""Hypothesis strategies for random stacks, boxes and robot states (``pip install hqp-tpm[testing]``).

Only this module needs hypothesis. Each strategy draws its sizes and switches through hypothesis (so
failures shrink to fewer levels, rows and joints) and its arrays from a numpy generator seeded by a
drawn ``seed`` (kept in the case, and saved by :func:`~hqp_tpm.testing.assert_solvers_agree`)::

    from hypothesis import given
    from hqp_tpm.testing import assert_solvers_agree
    from hqp_tpm.testing.strategies import boxed_stacks, stacks

    @given(stacks(full_rank=True))
    def test_my_solver_settings(case):
        assert_solvers_agree(**case.kwargs())

    @given(boxed_stacks(stacks(), box="binds"))
    def test_boxed(case):
        assert_solvers_agree(**case.kwargs(), solvers=("sns_tpm", "qp:proxqp", "qp:daqp"))

Where each equivalence is guaranteed (the library's own tests prove these on these strategies;
:data:`hqp_tpm.testing.tolerances.GUARANTEES`):

* ``stacks(full_rank=True)`` with ``cond=None`` (Gaussian levels, ``n <= 40``, ``l <= 10``,
  ``m_i <= 6``, targets scaled 1e-2..1e2): TPM == recursive null space to 1e-9, the cascaded QP
  == TPM to 1e-8 (osqp 1e-5) for ``n <= 20``;
* ``full_rank_stacks()`` (the library's TPM draws): TPM == recursive null space to 1e-9;
  ``full_rank_stacks(max_n=20, max_levels=6, max_rows=4)``: the cascaded QP == TPM to 1e-8;
* ``dependent_stacks()`` (exactly dependent, nearly dependent at 1e-3, conflicting and singular
  levels, n = 12): TPM == recursive null space to 1e-9, exact or damped;
* ``problems`` with :func:`~hqp_tpm.testing.stacks.random_problem` (the SNS draws): the box is never left,
  SNS-TPM's fast path == Algorithm 1 as written (1e-9), the QP's first-level residual is never larger;
* ``stacks(cond=(lo, hi))``: the stacked Jacobian has condition number exactly ``c`` (log-uniform in
  ``[lo, hi]``), its small singular directions spread over the levels (nearly dependent levels).
  TPM, the recursion, the QP (no box) and SNS-TPM's two paths agree to ``max(base, 1e3 eps c)`` up to
  ``c = 1e10`` (the defaults of :func:`~hqp_tpm.testing.assert_solvers_agree`; the library proves
  ``max(1e-6, 1e3 eps c)`` against 50-digit references on
  :func:`~hqp_tpm.testing.stacks.nearly_dependent_stack`, tests/test_numerics.py; the rank tolerance is
  relative to each level's data, :func:`hqp_tpm.solvers.damping.rank_tol`). With a *binding box* on such
  stacks the QP backends are not a reference: measured on 1,200 ``nearly_dependent_stack`` draws with
  ``box_for`` boxes (400 as drawn, 800 in other units; ``benchmarks/qp_backends.py``), each backend alone
  failed on 0 (proxqp), 57 (daqp) and 219 (osqp), the cascade's fallback solved all of them, and quadprog
  differed from the others' majority (1e-6) on 141;
* ``boxed_stacks(..., box="contains")``: SNS-TPM == TPM (to 1e-12) and the QP == TPM;
  ``box="binds"`` / ``"any"``: the QP's residuals are lexicographically <= SNS-TPM's and SNS's, every
  boxed solution in the box (1e-9 relative); ``zero="excluded"``: boxes without the zero command
  (acceleration boxes, recovery) are never left.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

try:
    from hypothesis import strategies as st
except ImportError as e:  # pragma: no cover - exercised only without the extra
    raise ImportError("hqp_tpm.testing.strategies needs hypothesis: pip install 'hqp-tpm[testing]'") from e

from hqp_tpm.solvers.levels import Level
from hqp_tpm.testing.stacks import (  # noqa: F401  (the builders, re-exported: one import for a test file)
    DAMPING,
    box_for,
    box_without_zero,
    dependent_singular_stack,
    dependent_stack,
    nearly_dependent_stack,
    random_problem,
    random_stack,
)

SEEDS = st.integers(0, 2**32 - 1)
SCALES = (1e-2, 1.0, 100.0)

#: ``(seed, kind)`` for :func:`~hqp_tpm.testing.stacks.random_problem`: the SNS draws of the library's tests.
problems = st.tuples(SEEDS, st.sampled_from(["full_rank", "any", "damped"]))


@st.composite
def full_rank_stacks(draw, *, max_n: int = 40, max_levels: int = 10, max_rows: int = 6,
                     scales: Sequence[float] = SCALES):
    """``(levels, rng)``: l = 1..max_levels levels of m_i = 1..max_rows Gaussian rows, sum m_i <= n <= max_n
    (full row rank; levels dropped until they fit), targets scaled by one of ``scales``; ``rng`` continues
    the seed's stream (for an ``x0``). TPM == recursion to 1e-9 (defaults); with ``max_n=20, max_levels=6,
    max_rows=4`` the cascaded QP == TPM to 1e-8 (osqp 1e-5)."""
    seed = draw(SEEDS)
    rng = np.random.default_rng(seed)
    l = draw(st.integers(1, max_levels))
    sizes = [draw(st.integers(1, max_rows)) for _ in range(l)]
    while sum(sizes) > max_n:
        sizes.pop()
    n = draw(st.integers(max(sum(sizes), 1), max_n))
    return random_stack(rng, n, sizes, scale=draw(st.sampled_from(list(scales)))), rng


@dataclass
class StackCase:
    """A random stack: ``levels`` (highest first), its ``seed`` and how it was drawn."""

    levels: list
    n: int
    seed: int
    sizes: tuple[int, ...]
    cond: float | None = None  # the prescribed condition number of the stacked J (None: Gaussian)
    rank: int | None = None  # the prescribed rank (None: generic)
    rng: np.random.Generator | None = field(default=None, repr=False)  # continues the seed's stream

    def kwargs(self) -> dict:
        """Keyword arguments of :func:`~hqp_tpm.testing.assert_solvers_agree`."""
        return {"levels": self.levels, "seed": self.seed}


@dataclass
class BoxedCase(StackCase):
    """A random stack with a joint box ``(lower, upper)`` and the damping it was made for."""

    box: tuple[np.ndarray, np.ndarray] = (np.zeros(0), np.zeros(0))
    damping: dict = field(default_factory=dict)
    binds: bool = False

    def kwargs(self) -> dict:
        return {"levels": self.levels, "seed": self.seed, "box": self.box, "damping": self.damping or None}


def _range(v, name: str) -> tuple[int, int]:
    lo, hi = (v, v) if isinstance(v, int) else v
    if not 0 <= lo <= hi:
        raise ValueError(f"{name} = {v!r}: give an int or a pair lo <= hi")
    return int(lo), int(hi)


def prescribed_matrix(rng, m: int, n: int, singular_values: np.ndarray) -> np.ndarray:
    """``U diag(s) V^T`` (m x n) with Haar-random orthogonal ``U``, ``V`` and the given singular values."""
    k = min(m, n)
    U, _ = np.linalg.qr(rng.standard_normal((m, m)))
    V, _ = np.linalg.qr(rng.standard_normal((n, n)))
    s = np.zeros(k)
    s[: len(singular_values)] = singular_values[:k]
    return (U[:, :k] * s) @ V[:, :k].T


@st.composite
def stacks(draw, *, n=(2, 15), levels=(1, 4), rows=(1, 4), full_rank: bool = False, rank_deficient: bool = False,
           cond: tuple[float, float] | None = None, conflict: float = 0.0, inequality: float = 0.0,
           scale: Sequence[float] = SCALES, max_n: int = 40, max_cond: float | None = None):
    """Random stacks.

    ``n``, ``levels``, ``rows``: an int or a range ``(lo, hi)`` of the joints, levels, rows per level.
    ``full_rank``: levels are dropped until ``sum m_i <= n`` (and ``n`` is drawn >= the rows).
    ``rank_deficient``: the stacked J loses 1..3 of its ``min(m, n)`` singular values (exactly dependent rows).
    ``cond``: ``(lo, hi)``: the stacked J gets singular values geometric from 1 to ``1/c``, ``c``
    log-uniform in the range (nearly dependent levels). ``conflict``/``inequality``: probability of
    appending the first task again with another target / inserting an inequality level with some active
    rows. ``scale``: the targets ``b`` are scaled by one of these. ``max_cond``: Gaussian draws are redrawn
    (up to 20 times) until cond(J) <= ``max_cond`` (the library's property tests use 1e3).
    """
    seed = draw(SEEDS)
    rng = np.random.default_rng(seed)
    l = draw(st.integers(*_range(levels, "levels")))
    r_lo, r_hi = _range(rows, "rows")
    sizes = [draw(st.integers(max(r_lo, 1), max(r_hi, 1))) for _ in range(max(l, 1))]
    n_lo, n_hi = _range(n, "n")
    if full_rank:
        while len(sizes) > 1 and sum(sizes) > min(n_hi, max_n):
            sizes.pop()
        n_lo = max(n_lo, sum(sizes))
        n_hi = max(n_hi, n_lo)
    nn = draw(st.integers(n_lo, n_hi))
    m = sum(sizes)
    k = min(m, nn)
    c = None
    rank = None
    if cond is not None or rank_deficient:
        if cond is not None:
            c = float(10.0 ** draw(st.floats(np.log10(cond[0]), np.log10(cond[1]))))
            s = np.geomspace(1.0, 1.0 / c, k) if k > 1 else np.ones(1)
        else:
            s = np.exp(rng.uniform(-1.0, 1.0, k))
        if rank_deficient and k > 1:
            rank = k - draw(st.integers(1, min(3, k - 1)))
            s = np.sort(s)[::-1]
            s[rank:] = 0.0
        J = prescribed_matrix(rng, m, nn, s) * np.sqrt(nn)  # entries of order 1, like the Gaussian draws
        Js = np.split(J, np.cumsum(sizes)[:-1])
    else:
        Js = [rng.standard_normal((mi, nn)) for mi in sizes]
        for _ in range(20 if max_cond is not None else 0):
            if np.linalg.cond(np.vstack(Js)) <= max_cond:
                break
            Js = [rng.standard_normal((mi, nn)) for mi in sizes]
    sc = float(draw(st.sampled_from(list(scale))))
    out: list = [(Ji, sc * rng.standard_normal(Ji.shape[0])) for Ji in Js]
    if conflict and rng.random() < conflict:  # the same task again, another target
        J0, b0 = out[0]
        out.append((J0.copy(), b0 + sc * rng.standard_normal(b0.size)))
    if inequality and rng.random() < inequality:
        mi = int(rng.integers(1, 4))
        lo = sc * rng.standard_normal(mi)
        out.insert(int(rng.integers(0, len(out) + 1)),
                   Level(rng.standard_normal((mi, nn)), lower=lo, upper=lo + sc * np.abs(rng.standard_normal(mi))))
    return StackCase(out, nn, seed, tuple(sizes), c, rank, rng)


@st.composite
def dependent_stacks(draw, *, n=12, singular_within: bool | None = None, scale: float = 10.0):
    """:func:`~hqp_tpm.testing.stacks.dependent_stack`: tasks exactly dependent on higher ones, nearly so
    (1e-3), or in conflict (the same task again); optionally a level singular by itself. TPM == recursion to
    1e-9 at n = 12 (with fewer columns than rows, 13, they differ today: see README)."""
    seed = draw(SEEDS)
    rng = np.random.default_rng(seed)
    nn = draw(st.integers(*_range(n, "n")))
    within = draw(st.booleans()) if singular_within is None else singular_within
    lv = dependent_stack(rng, nn, within)
    if scale != 10.0:
        lv = [(J, b * (scale / 10.0)) for J, b in lv]
    return StackCase(lv, nn, seed, tuple(J.shape[0] for J, _ in lv), None, None, rng)


def _free_solution(levels, n, damping):
    from hqp_tpm.solvers import tpm

    return tpm(levels, n=n, **damping)


@st.composite
def boxed_stacks(draw, stack_strategy=None, *, box: str = "any", zero: str = "inside", damping: dict | None = None,
                 infinite: float = 0.05, locked: float = 0.03):
    """A stack from ``stack_strategy`` (default :func:`stacks`) with a joint box.

    ``box``: ``"any"`` (each side uniform in [0, 1.2] times max|x_tpm|, a few infinite sides and locked
    joints), ``"binds"`` (as ``any``, and the joint of the largest TPM command cut to half of it),
    ``"contains"`` (the TPM solution strictly inside). ``zero``: ``"inside"`` (0 in the box: a velocity
    box of a state within its limits) or ``"excluded"`` (30 % of the joints' boxes shifted: acceleration
    boxes, recovery). ``damping``: the TPM damping the box is built around (recorded in the case).
    """
    if box not in ("any", "binds", "contains") or zero not in ("inside", "excluded"):
        raise ValueError(f"box must be any/binds/contains and zero inside/excluded, got {box!r}, {zero!r}")
    case = draw(stack_strategy if stack_strategy is not None else stacks())
    rng = np.random.default_rng(case.seed + 1)
    damping = dict(damping or {})
    n = case.n
    x = _free_solution(case.levels, n, damping)
    c = float(np.abs(x).max()) + 1e-300
    if box == "contains":
        lo = np.minimum(x, 0.0) - rng.uniform(0.0, 1.0, n) * np.abs(x) - 1e-6 * max(c, 1.0)
        up = np.maximum(x, 0.0) + rng.uniform(0.0, 1.0, n) * np.abs(x) + 1e-6 * max(c, 1.0)
    else:
        lo = -rng.uniform(0.0, 1.2, n) * c
        up = rng.uniform(0.0, 1.2, n) * c
        lo[rng.random(n) < infinite] = -np.inf
        up[rng.random(n) < infinite] = np.inf
        lk = rng.random(n) < locked
        lo[lk] = up[lk] = 0.0
        if box == "binds":
            j = int(np.argmax(np.abs(x)))
            if x[j] > 0:
                up[j] = 0.5 * x[j]
            else:
                lo[j] = 0.5 * x[j]
    if zero == "excluded":
        width = np.nan_to_num(up - lo, posinf=1.0)
        shift = np.where(rng.random(n) < 0.3, rng.uniform(-0.5, 0.5, n) * width, 0.0)
        lo, up = lo + shift, up + shift
    binds = bool(((x < lo) | (x > up)).any())
    return BoxedCase(case.levels, n, case.seed, case.sizes, case.cond, case.rank, case.rng, (lo, up), damping, binds)


@st.composite
def robot_states(draw, robot, *, margin: float = 0.0, velocity: float = 1.0):
    """``(q, v)`` of ``robot`` within its limits (:mod:`hqp_tpm.testing.states`): bounded joints within their
    limits shrunk by ``margin`` of the range, other columns as tangent components, velocities within the
    velocity limits times ``velocity``."""
    from hqp_tpm.testing.states import configuration, sampling_box, velocity_box

    lo, up, _ = sampling_box(robot, margin)
    u = np.array([draw(st.floats(float(a), float(b), allow_nan=False)) for a, b in zip(lo, up, strict=True)])
    vlo, vup = velocity_box(robot, velocity)
    v = np.array([draw(st.floats(float(a), float(b), allow_nan=False)) if np.isfinite(b)
                  else draw(st.floats(-3.0 * velocity, 3.0 * velocity)) for a, b in zip(vlo, vup, strict=True)])
    return configuration(robot, u), v
