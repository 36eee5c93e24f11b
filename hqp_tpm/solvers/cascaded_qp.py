"""Cascaded QP: the lexicographic reference solution, one QP per level through qpsolvers.

Level ``k`` minimizes its error (``||J_k x - b_k||^2``, or the squared violation of
``lower_k <= J_k x <= upper_k`` through slack variables) while every higher level keeps the
optimum it reached; an optional hard box ``lower <= x <= upper`` (the joint limits) is kept
in every QP. A last level picks the point nearest to ``x0`` (0 if not given), so on feasible
equality stacks the answer is :func:`hqp_tpm.solvers.tpm` ``(levels, x0=x0)``.

Kept equalities are never handed to a backend: the cascade parametrizes
``x = x_p + N z`` with ``N`` an orthonormal basis of their common null space (SVD with the
rank tolerance of the TPM code), so dependent or conflicting levels cannot make a QP
degenerate, and every QP has only inequality constraints. The current point ``x_p`` is
always feasible (kept bounds are relaxed to it), so ``z = 0`` is a feasible start.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import qpsolvers
from scipy import sparse

from hqp_tpm.errors import BoxError, SolverFailedError, SolverNotAvailableError, unknown_name
from hqp_tpm.solvers.damping import RANK_TOL
from hqp_tpm.solvers.levels import Level, as_levels

#: pip package that provides each qpsolvers backend (name not listed: ``pip install qpsolvers[<name>]``).
PIP_PACKAGE = {
    "clarabel": "clarabel", "copt": "coptpy", "cvxopt": "cvxopt", "daqp": "daqp", "ecos": "ecos",
    "gurobi": "gurobipy", "highs": "highspy", "hpipm": "hpipm_python", "jaxopt_osqp": "jaxopt",
    "kvxopt": "kvxopt", "mosek": "mosek", "osqp": "osqp", "piqp": "piqp", "proxqp": "proxsuite",
    "pyqpmad": "pyqpmad", "qpalm": "qpalm", "qpax": "qpax", "qpoases": "qpoases", "qpswift": "qpSWIFT",
    "qtqp": "qtqp", "quadprog": "quadprog", "scs": "scs", "sip": "sip-qp-python",
}

#: Tight default settings per backend (any ``**solver_options`` of the call override them).
DEFAULT_OPTIONS = {
    "proxqp": {"eps_abs": 1e-12, "eps_rel": 0.0, "max_iter": 10_000},
    "osqp": {"eps_abs": 1e-9, "eps_rel": 1e-9, "polish": True, "max_iter": 100_000},
    "daqp": {"primal_tol": 1e-12, "dual_tol": 1e-12},
    "clarabel": {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10},
    "piqp": {"eps_abs": 1e-10, "eps_rel": 1e-10},
}

#: Hessian weight of the directions a level's objective does not see (quadprog and daqp need a
#: positive-definite Hessian); it is exact when no inequality couples them to the objective.
FREE_WEIGHT = float(__import__("os").environ.get("FW", "1e-10"))

#: A kept bound whose multiplier exceeds this (relative to the largest one) is active at every
#: optimum of its level, and is kept as an equality by the levels below.
PIN_TOL = 1e-7


@dataclass(frozen=True)
class CascadeInfo:
    """What :func:`cascaded_qp` reports with ``return_info=True``.

    ``residuals[k]``: ``||J_k x - b_k||`` of an equality level, the norm of the bound
    violation of an inequality level. ``qp_count``: QPs actually solved (a level already
    decided by the higher ones needs none).
    """

    residuals: np.ndarray
    solver: str
    qp_count: int


@dataclass
class _Cascade:
    """State between levels: ``x + N z`` keeps all equalities, ``G x <= h`` all inequalities."""

    x: np.ndarray
    N: np.ndarray
    G: np.ndarray
    h: np.ndarray
    solver: str
    options: dict
    qp_count: int = field(default=0)

    def move(self, z: np.ndarray) -> None:
        """Go to ``x + N z`` and relax the kept bounds by what the backend's tolerance left violated."""
        self.x = self.x + self.N @ z
        self.h = np.maximum(self.h, self.G @ self.x)

    def restrict(self, A: np.ndarray) -> None:
        """Keep ``A x`` at its current value: ``N <- N null(A N)``."""
        if A.shape[0] and self.N.shape[1]:
            self.N = self.N @ null_space_basis(A @ self.N)

    def keep_bounds(self, J: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """Add ``lower <= J x <= upper`` (finite sides only), relaxed to the current point; return the rows."""
        up, lo = np.isfinite(upper), np.isfinite(lower)
        G = np.vstack([J[up], -J[lo]])
        h = np.concatenate([upper[up], -lower[lo]])
        self.G = np.vstack([self.G, G])
        self.h = np.concatenate([self.h, np.maximum(h, G @ self.x)])
        return G

    def qp(self, P, q, T, where: str, G_own=None, h_own=None) -> tuple[np.ndarray, np.ndarray]:
        """Solve ``min 1/2 v'Pv + q'v`` s.t. ``G_own v <= h_own`` and the kept bounds at ``z = T v``; move there.

        Kept bounds whose multiplier is positive stay active at every optimum of this level, so
        they are kept as equalities from now on. Returns ``v`` and the multipliers of ``G_own``.
        """
        G_own = np.zeros((0, P.shape[0])) if G_own is None else G_own
        h_own = np.zeros(0) if h_own is None else h_own
        Gz = self.G @ self.N
        rows = np.flatnonzero(np.linalg.norm(Gz, axis=1) > RANK_TOL)  # the others are constant: met at z = 0
        G = np.vstack([G_own, Gz[rows] @ T])
        h = np.concatenate([h_own, (self.h - self.G @ self.x)[rows]])
        v, mult = self.solve(P, q, G, h, where)
        self.move(T @ v)
        mult_own, mult_kept = mult[: G_own.shape[0]], mult[G_own.shape[0]:]
        self.restrict(self.G[rows[mult_kept > PIN_TOL * max(1.0, mult.max(initial=0.0))]])
        return v, mult_own

    def solve(self, P, q, G, h, where: str) -> tuple[np.ndarray, np.ndarray]:
        """One QP ``min 1/2 v'Pv + q'v  s.t.  G v <= h`` through qpsolvers: solution and multipliers."""
        options = dict(self.options)
        m = G.shape[0]
        if m == 0:
            G, h = None, None
            options.pop("polish", None)  # nothing to polish; OSQP would print that it skipped it
        if self.solver not in qpsolvers.dense_solvers:
            P, G = sparse.csc_matrix(P), None if G is None else sparse.csc_matrix(G)
        self.qp_count += 1
        try:
            sol = qpsolvers.solve_problem(qpsolvers.Problem(P, q, G, h), self.solver, **options)
        except Exception as exc:  # backends raise their own types on numerical trouble
            raise SolverFailedError(f"{where}: backend {self.solver!r} failed: {exc}") from exc
        if not sol.found or sol.x is None or not np.isfinite(sol.x).all():
            raise SolverFailedError(f"{where}: backend {self.solver!r} returned no solution")
        mult = np.zeros(m) if sol.z is None or m == 0 else np.asarray(sol.z, dtype=float).reshape(m)
        return sol.x, mult


def null_space_basis(A: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the null space of ``A`` (singular values above the TPM rank tolerance count)."""
    _, s, Vt = np.linalg.svd(A, full_matrices=True)
    return Vt[int((s > RANK_TOL).sum()):].T


def check_solver(solver: str) -> str:
    """Return ``solver`` if qpsolvers can use it, else raise :class:`SolverNotAvailableError`."""
    installed = list(qpsolvers.available_solvers)
    if isinstance(solver, str) and solver in installed:
        return solver
    known = sorted(name[: -len("_solve_qp")] for name in dir(qpsolvers.solvers) if name.endswith("_solve_qp"))
    if isinstance(solver, str) and solver in known:
        return _raise_not_installed(solver, installed)
    hints = ", ".join(f"'{k}' -> {PIP_PACKAGE[k]}" for k in ("proxqp", "osqp", "daqp", "quadprog", "clarabel"))
    err = unknown_name("QP backend", solver, installed, SolverNotAvailableError)
    raise SolverNotAvailableError(f"{err} (installed); qpsolvers also knows {', '.join(known)}, "
                                  f"installed with pip (e.g. {hints})")


def _raise_not_installed(solver: str, installed: list[str]):
    package = PIP_PACKAGE.get(solver, f"qpsolvers[{solver}]")
    raise SolverNotAvailableError(f"QP backend {solver!r} is not installed: `pip install {package}`; "
                                  f"installed backends are: {', '.join(sorted(installed))}")


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


def _options(solver: str, solver_options: dict) -> dict:
    return {**DEFAULT_OPTIONS.get(solver, {}), **solver_options}


def _equality_level(c: _Cascade, J: np.ndarray, b: np.ndarray, k: int) -> None:
    """Minimize ``||J x - b||^2``, then keep ``J x`` at the value reached."""
    r = c.N.shape[1]
    U, s, Vt = np.linalg.svd(J @ c.N, full_matrices=True)
    rank = int((s > RANK_TOL).sum())
    if rank == 0:  # the level is decided by the higher ones (or nothing is left free)
        return
    # z = V1 diag(1/s1) u + V2 t: the objective is ||u - target||^2; t is weighted only for a PD Hessian
    V1, V2, s1 = Vt[:rank].T, Vt[rank:].T, s[:rank]
    target = U[:, :rank].T @ (b - J @ c.x)
    P = np.diag(np.concatenate([np.ones(rank), np.full(r - rank, FREE_WEIGHT)]))
    q = np.concatenate([-target, np.zeros(r - rank)])
    c.qp(P, q, np.hstack([V1 / s1, V2]), f"level {k}")
    c.restrict(J)


def _inequality_level(c: _Cascade, J: np.ndarray, lower: np.ndarray, upper: np.ndarray, k: int) -> None:
    """Minimize the squared violation of ``lower <= J x <= upper``, then keep the bounds relaxed by it."""
    rows = np.isfinite(lower) | np.isfinite(upper)
    J, lower, upper = J[rows], lower[rows], upper[rows]
    Jx = J @ c.x
    r, m = c.N.shape[1], J.shape[0]
    if r == 0 or not ((Jx < lower) | (Jx > upper)).any():  # met already: nothing to minimize
        c.keep_bounds(J, lower, upper)
        return
    # variables v = (z, w): lower <= J (x + N z) - w <= upper, minimize ||w||^2
    A, I = J @ c.N, np.eye(m)
    up, lo = np.isfinite(upper), np.isfinite(lower)
    G = np.vstack([np.hstack([A[up], -I[up]]), np.hstack([-A[lo], I[lo]])])
    h = np.concatenate([(upper - Jx)[up], (Jx - lower)[lo]])
    P = np.diag(np.concatenate([np.full(r, FREE_WEIGHT), np.ones(m)]))
    _, mult = c.qp(P, np.zeros(r + m), np.eye(r, r + m), f"level {k}", G, h)
    kept = c.keep_bounds(J, lower, upper)
    c.restrict(kept[mult > PIN_TOL * max(1.0, mult.max(initial=0.0))])


def _nearest_point(c: _Cascade, x0: np.ndarray, k: int) -> None:
    """Last level: minimize ``||x - x0||^2`` with every level kept."""
    r = c.N.shape[1]
    if r:
        c.qp(np.eye(r), c.N.T @ (c.x - x0), np.eye(r), f"level {k} (minimum norm)")


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
                **solver_options):
    """Solve a prioritized stack lexicographically, one QP per level (see module doc).

    ``levels``: highest priority first, ``(J, b)`` pairs or :class:`Level` (inequality
    bounds are true inequalities here, ``active`` is ignored). ``solver``: any backend in
    ``qpsolvers.available_solvers``. ``lower``/``upper``: hard box on ``x``, kept in every
    QP. ``x0``: the last level minimizes ``||x - x0||^2``. ``n`` is needed only for an
    empty stack. ``solver_options`` override :data:`DEFAULT_OPTIONS`.
    Returns ``x``, or ``(x, CascadeInfo)`` with ``return_info=True``.
    """
    solver = check_solver(solver)
    lv = as_levels(levels, n)
    n = lv[0].n if lv else n
    box_lo, box_up = check_box(lower, upper, n)
    x0 = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).reshape(n)
    c = _Cascade(np.clip(np.zeros(n), box_lo, box_up), np.eye(n), np.zeros((0, n)), np.zeros(0),
                 solver, _options(solver, solver_options))
    c.keep_bounds(np.eye(n), box_lo, box_up)
    for k, level in enumerate(lv):
        _solve_level(c, level, k)
    _nearest_point(c, x0, len(lv))
    x = np.clip(c.x, box_lo, box_up)
    if not return_info:
        return x
    return x, CascadeInfo(residuals(lv, x), solver, c.qp_count)


def _solve_level(c: _Cascade, level: Level, k: int) -> None:
    if level.is_equality:
        _equality_level(c, level.J, level.b, k)
    else:
        _inequality_level(c, level.J, level.lower, level.upper, k)
