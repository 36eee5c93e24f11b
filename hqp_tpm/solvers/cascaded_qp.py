"""Cascaded QP: the lexicographic reference solution, one QP per level through qpsolvers.

Level ``k`` minimizes its error (``||J_k x - b_k||^2``, or the squared violation of
``lower_k <= J_k x <= upper_k`` through slack variables) while every higher level keeps the
optimum it reached: ``J_j x`` at the value reached (equality level), the bounds relaxed by the
violation left (inequality level). An optional hard box ``lower <= x <= upper`` (the joint
limits) is kept in every QP. A last level picks the point nearest to ``x0`` (0 if not given),
so on feasible equality stacks the answer is :func:`hqp_tpm.solvers.tpm` ``(levels, x0=x0)``.

Numerical care, because the stacked "keep the optimum" constraints are often dependent:

* kept equalities are never handed to a backend: ``x = x_p + N z`` with ``N`` an orthonormal
  basis of their common null space (SVD, TPM rank tolerance), so each QP is in ``z`` only;
* a level's variables are split along the SVD of ``J N``: the objective is ``||u - target||^2``
  (or ``||w||^2``) and the directions ``t`` it cannot see get a Hessian weight only for the
  backends that need a positive-definite one (:data:`FREE_WEIGHT`);
* the current point is always feasible (kept bounds are relaxed to it), so ``z = 0`` is a
  feasible start; bounds that meet (``lower == upper``) and kept bounds with a positive
  multiplier (active at every optimum of their level) become equalities;
* each QP is handed to the backend in units where it is of order 1 (:func:`normalized`), so that the
  backends' absolute tolerances mean the same whatever the units of ``J``, ``b`` and the box;
* a backend that returns no solution is retried with :data:`RETRY_OPTIONS`; ProxQP last through
  ProxSuite itself (:data:`LAST_RESORT`), whose infeasibility tests qpsolvers cannot switch off; then
  the :data:`FALLBACK` backends, reported in :attr:`CascadeInfo.fallbacks`;
* a level has :data:`TIME_BUDGET` CPU seconds, all attempts included; OSQP and DAQP get the rest of it
  as their own time limit, the others are checked after each call;
* ProxQP runs its sparse backend (:data:`SPARSE_CALL`): the same inputs give the same bits in any
  process, whatever ran before (tests/test_reproducible.py).
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from hqp_tpm.errors import (
    BoxError,
    SolverBudgetError,
    SolverFailedError,
    SolverNotAvailableError,
    unknown_name,
)
from hqp_tpm.solvers.damping import check_damping, check_x0, matrix_tol, rank_tol
from hqp_tpm.solvers.levels import as_levels

if TYPE_CHECKING:  # qpsolvers is imported on first use (it takes ~1 s to import)
    import qpsolvers

#: pip package that provides each qpsolvers backend (name not listed: ``pip install qpsolvers[<name>]``).
PIP_PACKAGE = {
    "clarabel": "clarabel", "copt": "coptpy", "cvxopt": "cvxopt", "daqp": "daqp", "ecos": "ecos",
    "gurobi": "gurobipy", "highs": "highspy", "hpipm": "hpipm_python", "jaxopt_osqp": "jaxopt",
    "kvxopt": "kvxopt", "mosek": "mosek", "osqp": "osqp", "piqp": "piqp", "proxqp": "proxsuite",
    "pyqpmad": "pyqpmad", "qpalm": "qpalm", "qpax": "qpax", "qpoases": "qpoases", "qpswift": "qpSWIFT",
    "qtqp": "qtqp", "quadprog": "quadprog", "scs": "scs", "sip": "sip-qp-python",
}


def _osqp_polish_key() -> str:
    """OSQP 1.0 renamed its ``polish`` setting ``polishing`` (version read from metadata: importing osqp is slow)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        major = int(version("osqp").split(".")[0])
    except (PackageNotFoundError, ValueError):
        return "polish"
    return "polishing" if major >= 1 else "polish"


POLISH = _osqp_polish_key()

#: ProxQP's tolerances: its residuals at 1e-11 leave an active bound up to ~1e-9 short (the sparse backend),
#: so its duality gap is checked too (then bounds are met to ~3e-11).
_PROXQP = {"eps_abs": 1e-11, "eps_rel": 0.0, "check_duality_gap": True, "eps_duality_gap_abs": 1e-11,
           "eps_duality_gap_rel": 0.0}

#: First settings tried per backend, tight enough for 1e-8 agreement with TPM (``**solver_options``
#: override them; other backends run with their own defaults). ProxQP stalls at 1e-12 on degenerate
#: levels and needs a stronger proximal rho than its default on semidefinite ones; DAQP stalls at
#: 1e-12 and needs ``eps_prox`` for a semidefinite Hessian; OSQP (first order) gets 1e-9 with polishing.
DEFAULT_OPTIONS = {
    "proxqp": {**_PROXQP, "max_iter": 1000, "rho": 1e-3},
    "osqp": {"eps_abs": 1e-9, "eps_rel": 1e-9, POLISH: True, "max_iter": 100_000, "rho": 1e-3, "raise_error": False},
    "daqp": {"primal_tol": 1e-10, "dual_tol": 1e-10, "eps_prox": -1},
}

#: Settings tried in turn when a backend returns no solution (ProxQP's infeasibility test is loose,
#: 1e-4, and qpsolvers cannot tighten it: it now and then calls a feasible level infeasible). DAQP's
#: proximal setting fails on some nearly dependent levels that it solves without (benchmarks/qp_backends.py).
RETRY_OPTIONS = {
    "daqp": [{"primal_tol": 1e-10, "dual_tol": 1e-10}],
    "proxqp": [{**_PROXQP, "max_iter": 1000, "rho": 0.1},
               {**_PROXQP, "max_iter": 1000, "rho": 1e-3, "compute_preconditioner": False},
               {**_PROXQP, "max_iter": 20_000}],  # slow convergence seen on Romeo: ~1,300
    # OSQP's adaptive rho stalls (dual residual ~1e-3 after 100,000 iterations) at degenerate vertices of
    # damped boxed levels, where a fixed large rho converges: 13 of 13 such QPs (benchmarks/qp_backends.py)
    "osqp": [{"eps_abs": 1e-9, "eps_rel": 1e-9, POLISH: True, "max_iter": 100_000, "raise_error": False, **o}
             for o in ({"rho": 10.0, "adaptive_rho": False}, {"rho": 0.1}, {"rho": 1e-6})],
}

#: Hessian weight of the directions a level's objective does not see but a kept bound touches, for
#: the backends that need a positive-definite Hessian (Goldfarb-Idnani). It moves a level's optimum
#: by about this much relative and creates multipliers of about this size, so it must stay far below
#: :data:`PIN_TOL` (1e-10 already pins wrong bounds). ProxQP, DAQP and OSQP take the semidefinite one.
FREE_WEIGHT = {"quadprog": 1e-12, "pyqpmad": 1e-12}

#: CPU seconds (this process's, so that other processes' load does not count) one level of the cascade may
#: take, all its attempts: a control step cannot wait longer, and a backend that needs more is stuck on
#: that level (ProxQP was seen spending 10-40 s on a diverging one).
TIME_BUDGET = 1.0

#: The setting through which a backend stops itself after the level's remaining budget (wall seconds,
#: which are at least the CPU seconds of this single-threaded call); the others are checked between calls.
TIME_LIMIT_KEY = {"osqp": "time_limit", "daqp": "time_limit"}

#: Backends tried, in this order, on a QP that the chosen backend returned no solution for with all its
#: settings (installed ones only, with their own default and retry settings). The QP is solved, the level
#: goes on, and :attr:`CascadeInfo.fallbacks` says which backend solved it. ``fallback=()`` turns this off.
FALLBACK = ("proxqp", "daqp", "quadprog")

#: Two bounds of a row closer than this (relative to the bound) make the row an equality.
EQUAL_BOUNDS_RTOL = 1e-10

#: A kept bound whose multiplier exceeds this (relative to the largest one) is active at every
#: optimum of its level, and is kept as an equality by the levels below.
PIN_TOL = 1e-7


@dataclass(frozen=True)
class CascadeInfo:
    """What :func:`cascaded_qp` reports with ``return_info=True``.

    ``residuals[k]``: ``||J_k x - b_k||`` of an equality level, the norm of the bound
    violation of an inequality level. ``qp_count``: QPs handed to the backend, retries
    included (a level already decided or met needs none). ``fallbacks``: ``(level, backend)`` for each
    QP that ``solver`` returned no solution for and a :data:`FALLBACK` backend solved (empty: ``solver``
    solved every level).
    """

    residuals: np.ndarray
    solver: str
    qp_count: int
    fallbacks: tuple[tuple[str, str], ...] = ()


@dataclass
class _Cascade:
    """State between levels: ``x + N z`` keeps all equalities, ``G x <= h`` all inequalities."""

    x: np.ndarray
    N: np.ndarray
    G: np.ndarray
    h: np.ndarray
    solver: str
    attempts: list[dict]
    qp_count: int = field(default=0)
    time_budget: float | None = None
    fallback: tuple[str, ...] = ()
    fallbacks: list[tuple[str, str]] = field(default_factory=list)
    level_start: float = field(default=0.0)

    def start_level(self) -> None:
        self.level_start = time.process_time()

    def check_budget(self, where: str, error: Exception | None = None) -> None:
        """Raise :class:`SolverBudgetError` if the level has used more than its time budget."""
        if self.time_budget is None:
            return
        spent = time.process_time() - self.level_start
        if spent > self.time_budget:
            raise SolverBudgetError(f"{where}: backend {self.solver!r} spent {spent:.2f} s CPU, more than the level's "
                                    f"time budget of {self.time_budget:g} s; try another backend") from error

    def move(self, z: np.ndarray) -> None:
        """Go to ``x + N z`` and relax the kept bounds by what the backend's tolerance left violated."""
        self.x = self.x + self.N @ z
        self.h = np.maximum(self.h, self.G @ self.x)

    def restrict(self, A: np.ndarray) -> None:
        """Keep ``A x`` at its current value: ``N <- N null(A N)``."""
        if A.shape[0] and self.N.shape[1]:
            self.N = self.N @ null_space_basis(A @ self.N, matrix_tol(A, max(A.shape)))

    def keep_bounds(self, J: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
        """Keep ``lower <= J x <= upper``, relaxed to the current point (rows whose bounds meet: equalities)."""
        Jx = J @ self.x
        lower, upper = np.minimum(lower, Jx), np.maximum(upper, Jx)
        eq, up, lo = bound_kinds(lower, upper)
        self.restrict(J[eq])
        self.G = np.vstack([self.G, J[up], -J[lo]])
        self.h = np.concatenate([self.h, upper[up], -lower[lo]])

    def kept_bounds_in(self, B: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The kept bounds as ``G_y y <= h_y`` in ``z = B y`` (``B`` orthonormal): rows used, ``G_y``, ``h_y``.

        Entries below the rank tolerance are rounding noise and set to zero (a backend could push a
        free direction to 1e16 to exploit them); rows left all zero are met at ``y = 0`` and dropped.
        """
        Gy = self.G @ self.N @ B
        Gy[np.abs(Gy) <= rank_tol(1.0, self.G.shape[1]) * np.linalg.norm(self.G, axis=1)[:, None]] = 0.0
        rows = np.flatnonzero(np.abs(Gy).max(axis=1, initial=0.0) > 0.0)
        return rows, Gy[rows], (self.h - self.G @ self.x)[rows]

    def qp(self, P, q, B, scale, where: str, C=None, lower=None, upper=None) -> np.ndarray:
        """Solve ``min 1/2 v'Pv + q'v`` s.t. ``lower <= C v <= upper`` and the kept bounds; move to ``x + N z``.

        ``z = B diag(scale) v[:r]``, ``B`` orthonormal (r x r); the other entries of ``v`` are the
        level's slacks. Kept bounds with a positive multiplier are active at every optimum of
        this level and become equalities. Returns the mask of the rows of ``C`` active at every optimum.
        """
        r, p = len(scale), P.shape[0]
        if C is None:
            C, lower, upper = np.zeros((0, p)), np.zeros(0), np.zeros(0)
        eq, up, lo = bound_kinds(lower, upper)
        rows, Gy, hy = self.kept_bounds_in(B)
        G = np.vstack([C[up], -C[lo], np.hstack([Gy * scale, np.zeros((rows.size, p - r))])])
        h = np.concatenate([upper[up], -lower[lo], hy])
        v, mult = self.solve(P, q, G, h, C[eq], upper[eq], where, magnitude(q, lower, upper))
        self.move(B @ (scale * v[:r]))
        n_up, n_lo = up.sum(), lo.sum()
        self.restrict(self.G[rows[positive(mult[n_up + n_lo:], mult)]])
        active = eq.copy()
        active[up] |= positive(mult[:n_up], mult)
        active[lo] |= positive(mult[n_up: n_up + n_lo], mult)
        return active

    def solve(self, P, q, G, h, A, b, where: str, size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """``min 1/2 v'Pv + q'v  s.t.  G v <= h, A v = b`` for a diagonal ``P``: solution, multipliers of G.

        A variable that neither ``q`` nor any constraint sees is decoupled: it stays 0 and is left out.
        ``size``: the expected magnitude of ``v`` (:func:`magnitude`), see :meth:`backend`.
        """
        used = (q != 0.0) | G.any(axis=0) | A.any(axis=0)
        v, mult = np.zeros(q.size), np.zeros(G.shape[0])
        if used.any():
            v[used], mult = self.backend(P[np.ix_(used, used)], q[used], G[:, used], h, A[:, used], b, where, size)
        return v, mult

    def backend(self, P, q, G, h, A, b, where: str, size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """One QP through qpsolvers: solution and multipliers of ``G``; on failure the retry settings.

        The backend gets the problem in units where it is of order 1 (:func:`normalized`: rows of ``G`` and
        ``A`` of unit norm, ``v = size w``), so that its absolute tolerances mean the same in any units;
        the multipliers returned are those of that problem (scale-free: :func:`positive` compares them
        with 1, so a level in other units pins the same bounds).
        """
        m = G.shape[0]
        arrays, d = normalized(P, q, G, h, A, b, size)
        errors: list[Exception] = []
        for solver in (self.solver, *self.fallback):
            attempts = self.attempts if solver == self.solver else _attempts(solver, {})
            found = self._attempt(solver, attempts, _problem(solver, *arrays), m, where, errors)
            if found is not None:
                if solver != self.solver:
                    self.fallbacks.append((where, solver))
                return d * found[0], found[1]
        error = errors[-1] if errors else None
        tried = f"; nor did the fallback backends {', '.join(map(repr, self.fallback))}" if self.fallback else ""
        raise SolverFailedError(f"{where}: backend {self.solver!r} returned no solution with any of its "
                                f"{len(self.attempts)} settings{f' ({error})' if error else ''}{tried}; "
                                f"try another backend") from error

    def _attempt(self, solver: str, attempts: list[dict], problem, m: int, where: str,
                 errors: list) -> tuple[np.ndarray, np.ndarray] | None:
        """Solve ``problem`` with ``solver`` and each of ``attempts`` in turn (then :data:`LAST_RESORT`)."""
        import qpsolvers

        for options in attempts:
            if problem.G is None and problem.A is None:
                options = {k: v for k, v in options.items() if k != POLISH}  # OSQP would print it skipped it
            if self.time_budget is not None and solver in TIME_LIMIT_KEY:
                left = self.time_budget - (time.process_time() - self.level_start)
                options = {**options, TIME_LIMIT_KEY[solver]: max(left, 1e-3)}
            self.qp_count += 1
            try:
                sol = qpsolvers.solve_problem(problem, solver, **options)
            except qpsolvers.SolverNotFound as exc:
                raise _not_available(solver, sorted(qpsolvers.available_solvers)) from exc
            except Exception as exc:  # backends raise their own types on numerical trouble
                errors.append(exc)
                self.check_budget(where, exc)
                continue
            self.check_budget(where)
            if sol.found and sol.x is not None and np.isfinite(sol.x).all():
                mult = np.zeros(m) if sol.z is None or m == 0 else np.asarray(sol.z, dtype=float).reshape(m)
                return sol.x, mult
        if solver in LAST_RESORT:
            self.qp_count += 1
            found = LAST_RESORT[solver](problem, attempts[0])
            self.check_budget(where)
            if found is not None:
                return found[0], np.zeros(m) if m == 0 else found[1]
        return None


#: Backends handed sparse matrices although they take dense ones. ProxQP's dense backend (AVX2 build) gives
#: results whose last bits depend on where the heap placed its work buffers (16- vs 32-byte aligned), so a
#: run would depend on what the process did before; its sparse backend returns the same bits every time.
SPARSE_CALL = frozenset({"proxqp"})


def _problem(solver: str, P, q, G, h, A, b) -> qpsolvers.Problem:
    """A qpsolvers problem without empty blocks, sparse for the backends that only take sparse matrices and
    for :data:`SPARSE_CALL`."""
    import qpsolvers

    G, h = (G, h) if G.shape[0] else (None, None)
    A, b = (A, b) if A.shape[0] else (None, None)
    if solver not in qpsolvers.dense_solvers or solver in SPARSE_CALL:
        P, G, A = (None if M is None else _csc(M) for M in (P, G, A))
    return qpsolvers.Problem(P, q, G, h, A, b)


def _csc(M: np.ndarray):
    """``M`` as a SciPy CSC matrix (its non-zeros, column by column), at half the cost of ``csc_matrix(M)``."""
    from scipy import sparse

    cols, rows = np.nonzero(M.T)
    indptr = np.zeros(M.shape[1] + 1, dtype=np.int32)
    np.cumsum(np.bincount(cols, minlength=M.shape[1]), out=indptr[1:])
    return sparse.csc_matrix((M.T[cols, rows], rows.astype(np.int32), indptr), shape=M.shape)


def _proxqp_direct(problem: qpsolvers.Problem, options: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """ProxQP called through ProxSuite itself, without the infeasibility tests qpsolvers cannot switch off.

    ProxQP's default ``eps_primal_inf`` (1e-4) now and then calls a feasible level infeasible, and so does
    its sparse backend even at 1e-12 (romeo_qp step 1,277, level 4: one variable, 18 rows, feasible on
    [-0.111, 0.097]). Every cascade QP is feasible (``z = 0`` is), so here the tests are off (tolerance 0:
    never met); a level that does not converge ends at ``max_iter`` or the time budget.
    """
    from proxsuite import proxqp

    P, q, G, h, A, b = problem.P, problem.q, problem.G, problem.h, problem.A, problem.b
    kind = proxqp.dense if isinstance(P, np.ndarray) else proxqp.sparse  # sparse: see SPARSE_CALL
    qp = kind.QP(q.size, 0 if A is None else A.shape[0], 0 if G is None else G.shape[0])
    for key in ("eps_abs", "eps_rel", "max_iter"):
        if key in options:
            setattr(qp.settings, key, options[key])
    qp.settings.eps_primal_inf = qp.settings.eps_dual_inf = 0.0
    qp.init(P, q, A, b, G, None if G is None else np.full(G.shape[0], -np.inf), h, rho=options.get("rho", 1e-6))
    qp.solve()
    if qp.results.info.status != proxqp.QPSolverOutput.PROXQP_SOLVED:
        return None
    return qp.results.x, qp.results.z


#: Called with the first settings when every qpsolvers attempt failed: ``(x, multipliers of G)`` or None.
LAST_RESORT = {"proxqp": _proxqp_direct}


def magnitude(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> float:
    """Expected size of a level QP's solution: ``max |q|`` and, per row of ``lower <= C v <= upper``, the
    distance from ``C v = 0`` to the nearest finite bound (the violation of a violated row)."""
    lo, up = np.abs(lower), np.abs(upper)
    near = np.where(np.isfinite(lo) & np.isfinite(up), np.minimum(lo, up), np.where(np.isfinite(lo), lo, up))
    near = near[np.isfinite(near)]
    return float(max(np.abs(q).max(initial=0.0), near.max(initial=0.0)))


def normalized(P, q, G, h, A, b, size: float):
    """``min 1/2 v'Pv + q'v  s.t.  G v <= h, A v = b`` in units where it is of order 1 for the backend.

    ``v = d w`` with ``d = size / sqrt(max(P_jj, 1))`` (``size``: :func:`magnitude`, 1 if zero): the
    variables in units of the solution's expected size, those a damped level weighs heavily
    (``1 + lambda^2 / s^2``) scaled to a unit Hessian; then the rows of ``G`` and ``A`` divided by their
    norms. Returns the problem in ``w`` and ``d``. Without it a level in other units (J times 1e6, or
    targets and box times 1e-6) met the backends' absolute tolerances 1e6 times too tight or loose:
    DAQP, ProxQP and OSQP failed or ran out of time on a few percent of such levels, and multipliers
    that are rounding noise pinned bounds that are not active.
    """
    size = size if np.isfinite(size) and size > 0.0 else 1.0
    p = np.diag(P)
    unit = 1.0 / np.sqrt(np.maximum(p, 1.0))  # d = size * unit; no product with size: it may be huge
    P, q, G, A = np.diag(p * unit * unit), q * unit / size, G * unit, A * unit
    g = np.linalg.norm(G, axis=1)
    g = np.where(g > 0.0, g, 1.0)
    a = np.linalg.norm(A, axis=1)
    a = np.where(a > 0.0, a, 1.0)
    return (P, q, G / g[:, None], h / g / size, A / a[:, None], b / a / size), size * unit


def bound_kinds(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masks of the rows of ``lower <= y <= upper`` that are equalities, finite upper and finite lower bounds."""
    size = np.maximum(1.0, np.abs(np.where(np.isfinite(upper), upper, 0.0)))
    eq = upper - lower <= EQUAL_BOUNDS_RTOL * size
    return eq, np.isfinite(upper) & ~eq, np.isfinite(lower) & ~eq


def positive(mult: np.ndarray, among: np.ndarray | None = None) -> np.ndarray:
    """Mask of the multipliers above :data:`PIN_TOL` relative to the largest of ``among`` (default: ``mult``)."""
    among = mult if among is None else among
    return mult > PIN_TOL * max(1.0, among.max(initial=0.0))


def null_space_basis(A: np.ndarray, tol: float) -> np.ndarray:
    """Orthonormal basis of the null space of ``A`` (singular values above ``tol`` count)."""
    _, s, Vt = np.linalg.svd(A, full_matrices=True)
    return Vt[int((s > tol).sum()):].T


@dataclass(frozen=True)
class _Split:
    """Truncated SVD ``A = U1 diag(s1) V1'`` of a level on the free space; ``B = [V1 V2]`` is orthonormal.

    The level's variables are ``z = B diag(scale) (u, t)`` with ``scale = (1/s1, 1/unit)``, so that
    ``A z = U1 u`` and ``t`` spans the directions the level cannot see. ``unit`` (the largest ``s1``)
    puts ``t`` in the level's units, as ``u``: with ``t`` in the units of ``z`` instead, a level
    whose ``J`` is 1e6 times larger handed the backend variables 1e6 apart in size.
    """

    U1: np.ndarray
    s1: np.ndarray
    B: np.ndarray
    s_all: np.ndarray

    @property
    def rank(self) -> int:
        return self.s1.size

    @property
    def unit(self) -> float:
        """``t = unit V2' z``: the size of the level's ``J`` on the free space (1 if it has rank 0)."""
        return float(self.s1[0]) if self.rank else 1.0

    @property
    def scale(self) -> np.ndarray:
        return np.concatenate([1.0 / self.s1, np.full(self.B.shape[1] - self.rank, 1.0 / self.unit)])


def split(A: np.ndarray, tol: float) -> _Split:
    """:class:`_Split` of ``A`` (m x r), singular values above ``tol`` counting (the solvers' rank law)."""
    U, s, Vt = np.linalg.svd(A, full_matrices=True)
    rank = int((s > tol).sum())
    return _Split(U[:, :rank], s[:rank], Vt.T, s)


def check_solver(solver: str) -> str:
    """Return ``solver`` if qpsolvers can use it, else raise :class:`SolverNotAvailableError`.

    Backends qpsolvers knows are the keys of :data:`PIP_PACKAGE` (with the package to install); a backend
    that goes missing later is reported the same way when qpsolvers raises ``SolverNotFound``.
    """
    import qpsolvers

    installed = sorted(qpsolvers.available_solvers)
    if solver in installed:
        return solver
    raise _not_available(solver, installed)


def _not_available(solver: str, installed: list[str]) -> SolverNotAvailableError:
    if solver in PIP_PACKAGE:
        return SolverNotAvailableError(
            f"QP backend {solver!r} is known to qpsolvers but not installed: "
            f"`pip install {PIP_PACKAGE[solver]}`; installed backends are: {', '.join(map(repr, installed))}")
    hints = ", ".join(f"`pip install {PIP_PACKAGE[k]}` for {k!r}" for k in ("proxqp", "osqp", "daqp", "quadprog",
                                                                             "clarabel", "highs", "piqp"))
    err = unknown_name("QP backend", solver, installed, SolverNotAvailableError)
    others = ", ".join(k for k in sorted(PIP_PACKAGE) if k not in installed)
    return SolverNotAvailableError(f"{err} (the installed ones); qpsolvers also knows {others}, "
                                   f"each after installing its package, e.g. {hints}")


def check_box(lower, upper, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The hard box as two length-``n`` vectors (``-inf``/``+inf`` for a missing side)."""
    def side(v, fill, what):
        arr = np.full(n, fill) if v is None else np.asarray(v, dtype=float)
        arr = np.full(n, float(arr)) if arr.ndim == 0 else arr
        if arr.shape != (n,):
            raise BoxError(f"box {what} has shape {np.shape(v)}, expected ({n},)")
        if np.isnan(arr).any():
            i = int(np.flatnonzero(np.isnan(arr))[0])
            raise BoxError(f"box {what}[{i}] is NaN")
        return arr

    lo, up = side(lower, -np.inf, "lower"), side(upper, np.inf, "upper")
    if (lo > up).any():
        i = int(np.flatnonzero(lo > up)[0])
        raise BoxError(f"box lower[{i}] = {lo[i]} > upper[{i}] = {up[i]}")
    return lo, up


def _fallback(solver: str, fallback: Iterable[str]) -> tuple[str, ...]:
    """The installed backends of ``fallback`` other than ``solver``, in order (a name qpsolvers does not know
    raises :class:`SolverNotAvailableError`; a known one that is not installed is skipped)."""
    import qpsolvers

    names = [fallback] if isinstance(fallback, str) else list(fallback)
    for name in names:
        if name not in qpsolvers.available_solvers and name not in PIP_PACKAGE:
            check_solver(name)
    return tuple(dict.fromkeys(s for s in names if s != solver and s in qpsolvers.available_solvers))


def _attempts(solver: str, solver_options: dict) -> list[dict]:
    """Settings to try in turn: the defaults, then the retry settings, each overridden by the caller's.

    A caller's ProxQP ``eps_abs`` is also its duality-gap tolerance (unless given): asked for a loose
    solution, ProxQP gives one.
    """
    tries = [DEFAULT_OPTIONS.get(solver, {}), *RETRY_OPTIONS.get(solver, [])]
    if solver == "proxqp" and "eps_abs" in solver_options:
        solver_options = {"eps_duality_gap_abs": solver_options["eps_abs"], **solver_options}
    return [{**options, **solver_options} for options in tries]


def damping_lambda2(s: np.ndarray, lambda_max: float, eps: float, rows: int | None = None) -> float:
    """``lambda^2`` of the damping law (:mod:`hqp_tpm.solvers.damping`) for singular values ``s``.

    ``s`` are those of ``J N`` (``m x r``); the law reads the ``min(m, n)`` singular values of ``J P``
    (``P = N N^T``), i.e. these and zeros when ``rows = min(m, n)`` exceeds ``s.size`` (a level with more
    rows than the directions left to it is damped by ``lambda_max``, as in TPM and the recursion).
    """
    if rows is not None and rows > s.size:
        s = np.concatenate([s, np.zeros(rows - s.size)])
    if lambda_max > 0.0 and s.size and s.min() < eps:
        return (1.0 - (s.min() / eps) ** 2) * lambda_max**2
    return 0.0


def _equality_level(c: _Cascade, J: np.ndarray, b: np.ndarray, k: int, lambda_max: float = 0.0,
                    eps: float = 0.0) -> None:
    """Minimize ``||J x - b||^2`` (+ ``lambda^2 ||x - x_prev||^2`` when damped), then keep ``J x``.

    The damping term is the one of the damped recursion (5): with ``lambda`` from the damping law on
    the singular values of ``J N`` (``N``: what the higher levels leave free, i.e. ``J_k P_{k-1}``),
    the minimizer is ``x_prev + (J_k P_{k-1})#_damped (b - J x_prev)``, exactly the recursion's step.
    """
    sp = split(J @ c.N, matrix_tol(J, max(J.shape)))
    if sp.rank == 0:  # the level is decided by the higher ones (or nothing is left free)
        return
    lam2 = damping_lambda2(sp.s_all, lambda_max, eps, min(J.shape))
    # ||J (x + N z) - b||^2 + lam2 ||z||^2 = ||u - target||^2 + lam2 (||u / s1||^2 + ||t||^2) + const
    target = sp.U1.T @ (b - J @ c.x)
    free = c.N.shape[1] - sp.rank
    weight = max(lam2 / sp.unit**2, FREE_WEIGHT.get(c.solver, 0.0))  # lam2 ||t / unit||^2 + weight (level units)
    P = np.diag(np.concatenate([1.0 + lam2 / sp.s1**2, np.full(free, weight)]))
    c.qp(P, np.concatenate([-target, np.zeros(free)]), sp.B, sp.scale, f"level {k}")
    c.restrict(J)


def _inequality_level(c: _Cascade, J: np.ndarray, lower: np.ndarray, upper: np.ndarray, k: int,
                      lambda_max: float = 0.0, eps: float = 0.0) -> None:
    """Minimize the squared violation of ``lower <= J x <= upper``, then keep the bounds relaxed by it.

    Damped (``lambda_max > 0``) as the analytic solvers damp the level's active rows: ``lambda`` from the
    damping law on the singular values of ``J_v N`` (``J_v``: the rows violated at the current point, the
    ones TPM makes active) and ``lambda^2 ||z||^2`` added to the violation, so that where TPM's step is
    bounded near a singular configuration the cascade's is too.
    """
    rows = np.isfinite(lower) | np.isfinite(upper)
    J, lower, upper = J[rows], lower[rows], upper[rows]
    Jx = J @ c.x
    violated = (Jx < lower) | (Jx > upper)
    if c.N.shape[1] == 0 or not violated.any():  # met already: nothing to minimize
        c.keep_bounds(J, lower, upper)
        return
    # variables (u, t, w): lower <= J (x + N z) - w = Jx + U1 u - w <= upper, minimize ||w||^2 (+ lam2 ||z||^2)
    tol = matrix_tol(J, max(J.shape))
    sp = split(J @ c.N, tol)
    r, m = c.N.shape[1], J.shape[0]
    lam2 = 0.0
    if lambda_max > 0.0:
        Jv = J[violated]
        lam2 = damping_lambda2(np.linalg.svd(Jv @ c.N, compute_uv=False), lambda_max, eps, min(Jv.shape))
    C = np.hstack([sp.U1, np.zeros((m, r - sp.rank)), -np.eye(m)])
    free = max(lam2 / sp.unit**2, FREE_WEIGHT.get(c.solver, 0.0))
    P = np.diag(np.concatenate([lam2 / sp.s1**2, np.full(r - sp.rank, free), np.ones(m)]))
    if lam2 == 0.0:
        P[: sp.rank, : sp.rank] = np.eye(sp.rank) * FREE_WEIGHT.get(c.solver, 0.0)
    active = c.qp(P, np.zeros(r + m), sp.B, sp.scale, f"level {k}", C, lower - Jx, upper - Jx)
    c.keep_bounds(J, lower, upper)
    c.restrict(J[active])


def _nearest_point(c: _Cascade, x0: np.ndarray, k: int) -> None:
    """Last level: minimize ``||x - x0||^2`` with every level kept."""
    r = c.N.shape[1]
    if r:
        c.qp(np.eye(r), c.N.T @ (c.x - x0), np.eye(r), np.ones(r), f"level {k} (minimum norm)")


def residuals(levels: Iterable, x: np.ndarray) -> np.ndarray:
    """Per level: ``||J x - b||`` (equality) or the norm of the bound violation (inequality)."""
    out = []
    for lv in as_levels(levels, np.size(x)):
        Jx = lv.J @ x
        err = Jx - lv.b if lv.is_equality else np.maximum(lv.lower - Jx, 0.0) + np.maximum(Jx - lv.upper, 0.0)
        out.append(float(np.linalg.norm(err)))
    return np.array(out)


def cascaded_qp(levels: Iterable, solver: str = "proxqp", *, x0: np.ndarray | None = None,
                lower=None, upper=None, n: int | None = None, return_info: bool = False,
                lambda_max: float = 0.0, eps: float = 0.0, time_budget: float | None = TIME_BUDGET,
                fallback: Iterable[str] = FALLBACK, **solver_options):
    """Solve a prioritized stack lexicographically, one QP per level (see module doc).

    ``levels``: highest priority first, ``(J, b)`` pairs or :class:`Level` (inequality
    bounds are true inequalities here, ``active`` is ignored). ``solver``: any backend in
    ``qpsolvers.available_solvers``. ``lower``/``upper``: hard box on ``x``, kept in every
    QP. ``x0``: the last level minimizes ``||x - x0||^2``. ``n`` is needed only for an
    empty stack. ``lambda_max``/``eps``: the damping law of the analytic solvers applied to
    every level's free part, equality (see :func:`_equality_level`; with it the cascade equals
    the damped recursive null-space solution) or inequality (:func:`_inequality_level`).
    ``time_budget``: CPU seconds one level may take, retries included; beyond it the cascade stops with
    :class:`~hqp_tpm.errors.SolverBudgetError` naming the level (None: no budget).
    ``fallback``: backends tried on a QP ``solver`` finds no solution for (:data:`FALLBACK`, installed
    ones; ``()``: none, the cascade stops with :class:`~hqp_tpm.errors.SolverFailedError` naming the
    level); which solved what is in ``CascadeInfo.fallbacks``.
    ``solver_options`` override :data:`DEFAULT_OPTIONS` (for ``solver`` only).
    Returns ``x``, or ``(x, CascadeInfo)`` with ``return_info=True``.
    """
    solver = check_solver(solver)
    lv = as_levels(levels, n)
    n = lv[0].n if lv else n
    box_lo, box_up = check_box(lower, upper, n)
    lambda_max, eps = check_damping(lambda_max, eps)
    x0 = np.zeros(n) if x0 is None else check_x0(x0, n)
    c = _Cascade(np.clip(np.zeros(n), box_lo, box_up), np.eye(n), np.zeros((0, n)), np.zeros(0),
                 solver, _attempts(solver, solver_options), time_budget=time_budget,
                 fallback=_fallback(solver, fallback))
    c.keep_bounds(np.eye(n), box_lo, box_up)
    for k, level in enumerate(lv):
        c.start_level()
        if level.is_equality:
            _equality_level(c, level.J, level.b, k, lambda_max, eps)
        else:
            _inequality_level(c, level.J, level.lower, level.upper, k, lambda_max, eps)
    c.start_level()
    _nearest_point(c, x0, len(lv))
    x = np.clip(c.x, box_lo, box_up)
    if not return_info:
        return x
    return x, CascadeInfo(residuals(lv, x), solver, c.qp_count, tuple(c.fallbacks))

