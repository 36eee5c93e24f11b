"""The account of one solve: what each level asked for, what it got, and what took the rest.

Computed *after* a solve from what the step already has -- the levels, the command ``x``, the hard
box and the solver's info dict (:func:`hqp_tpm.solvers.registry.solve`) -- so it is the same for every
solver and costs nothing unless called. Arrays only: levels are named by their ``Level.name``, joints
by their column index; :mod:`hqp_tpm.app.explain` adds robot names and bound kinds.

Per level (:class:`LevelAccount`):

* ``desired`` / ``achieved``: the task-space command ``b`` and ``J x`` (equality level); for an
  inequality level ``desired = clip(J x, lower, upper)``, the nearest value the bounds admit;
* ``residual = achieved - desired`` and the **fraction met**: ``1 - ||r|| / ||b||`` clipped to
  ``[0, 1]`` (equality; for an SNS-scaled full-rank level this is the scale factor), or
  ``1 - ||violation(x)|| / ||violation(0)||`` (inequality: how much of the violation of the zero
  command was removed); a level whose reference is below the tolerance is met (1) or not (0);
* ``active_rows``: inequality rows at or beyond a bound (equality: all rows);
* ``sigma_min`` / ``damping``: the smallest singular value of the level's rows projected on the null
  space of the levels above, ``J_i P_{i-1}`` (the TPM pivot ``R_ii`` has the same singular values), and
  the ``lambda`` the damping law (:mod:`hqp_tpm.solvers.damping`) gives it (0: not damped);
  ``kept = sigma^2 / (sigma^2 + lambda^2)`` is the share of that direction the damped inverse keeps;
* ``scale``: the SNS scale factor of the level (``sns``: its own; ``sns_tpm``: the common one).

Per step (:class:`StepAccount`): the joints at a bound of the box (side +1 upper, -1 lower), the joints
beyond it (possible only for the solvers that ignore the box: ``tpm``, ``nullspace``), the solver and
the QP backend.

**Causes** (:func:`explain`): for every level not met, a minimal *blocking set*, each kind verified:

* ``higher_levels``: the level cannot be met while the levels above keep what they achieved (least
  squares on ``J_k`` restricted to ``{y : A_j y = A_j x}``); the set is irreducible (deletion filter):
  without any one of its levels the level could be met;
* ``damping``: the level's projected rows are damped (``sigma_min < eps``); the set is the minimal
  set of higher levels whose rows make ``sigma_min(J_k P) < eps`` (empty: the level's own singularity);
* ``joint_bounds``: joints at a bound without which the level would reach the residual it has with
  no box at all, verified by re-solving the stack with the same solver and settings with those bounds
  released; the set is minimal (deletion filter over the saturated joints, every candidate re-solved);
* ``unexplained``: none of the above verified (e.g. a QP backend's tolerance).

**Infeasible hard constraints** (:func:`check_feasible`): the box and the levels declared hard must be
met exactly by some command; if no command does (an LP through ``scipy.optimize.linprog``), an
:class:`hqp_tpm.errors.InfeasibleError` names an irreducible infeasible subset of the constraints
(elastic LP for a Farkas-type support, then a deletion filter), e.g. ``box upper of joint 2``,
``level 'top' row 0``. An empty box is :class:`hqp_tpm.errors.EmptyBoxError`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from hqp_tpm.errors import EmptyBoxError, InfeasibleError
from hqp_tpm.solvers.damping import matrix_tol
from hqp_tpm.solvers.levels import Level, as_levels

#: A level is met when ``||residual|| <= MET_TOL * max(1, ||reference||)``.
MET_TOL = 1e-6
#: A joint is at a bound when ``|x_j - bound_j| <= BOUND_TOL * (1 + |bound_j|)``.
BOUND_TOL = 1e-9
#: Solvers that keep the hard box (the others ignore it).
BOX_SOLVERS = ("sns_tpm", "sns", "qp")

CAUSE_KINDS = ("higher_levels", "damping", "joint_bounds", "unexplained")


@dataclass(frozen=True)
class LevelAccount:
    """One level of a :class:`StepAccount` (see the module doc for each field)."""

    index: int
    name: str
    equality: bool
    desired: np.ndarray
    achieved: np.ndarray
    residual: np.ndarray
    fraction: float
    met: bool
    active_rows: tuple[int, ...]
    sigma_min: float
    damping: float
    scale: float | None = None

    @property
    def residual_norm(self) -> float:
        return float(np.linalg.norm(self.residual))

    @property
    def kept(self) -> float:
        """Share of the weakest projected direction the damped inverse keeps (1: undamped)."""
        s2 = self.sigma_min**2
        return 1.0 if self.damping == 0.0 else float(s2 / (s2 + self.damping**2))


@dataclass(frozen=True)
class Cause:
    """Why a level was not met: ``kind`` (:data:`CAUSE_KINDS`), the blocking higher ``levels`` (indices),
    the blocking ``joints`` with their ``sides`` (+1 upper, -1 lower), and ``fraction_without``: the
    level's fraction met once the blocking set is removed (the verification; NaN if not re-solved)."""

    kind: str
    levels: tuple[int, ...] = ()
    joints: tuple[int, ...] = ()
    sides: tuple[int, ...] = ()
    fraction_without: float = float("nan")


@dataclass(frozen=True)
class StepAccount:
    """The account of one solve (module doc). ``causes[k]``: the :class:`Cause` s of level ``k`` (empty
    when met), filled by :func:`explain`; ``None`` when only :func:`account` was asked for."""

    levels: tuple[LevelAccount, ...]
    x: np.ndarray
    solver: str = ""
    backend: str | None = None
    box: tuple[np.ndarray, np.ndarray] | None = None
    box_kept: bool = False
    at_bound: tuple[int, ...] = ()
    sides: tuple[int, ...] = ()
    beyond: tuple[int, ...] = ()
    solver_saturated: tuple[int, ...] = ()
    scale: float | None = None
    causes: tuple[tuple[Cause, ...], ...] | None = None
    extra: dict = field(default_factory=dict)

    def level(self, name: str) -> LevelAccount:
        for lv in self.levels:
            if lv.name == name:
                return lv
        raise KeyError(name)


# ----------------------------------------------------------------------------------------------
# The account.
# ----------------------------------------------------------------------------------------------
def _violation(Jx: np.ndarray, lo: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Signed bound violation: ``> 0`` above ``upper``, ``< 0`` below ``lower``, 0 inside."""
    return np.where(Jx > up, Jx - up, np.where(Jx < lo, Jx - lo, 0.0))


def _fraction(r: float, ref: float, tol: float) -> float:
    if ref <= tol:
        return 1.0 if r <= tol else 0.0
    return float(min(1.0, max(0.0, 1.0 - r / ref)))


def damping_lambda(smin: float, lambda_max: float, eps: float) -> float:
    """``lambda`` of the damping law for a block whose smallest singular value is ``smin``."""
    if lambda_max > 0.0 and smin < eps:
        return float(np.sqrt(max(0.0, 1.0 - (smin / eps) ** 2)) * lambda_max)
    return 0.0


def _kept_rows(level: Level, x: np.ndarray, qp: bool) -> np.ndarray:
    """Rows the solver treats as constraints: all of an equality; of an inequality the analytic
    solvers' active rows, or (QP) the rows at or beyond a bound."""
    if level.is_equality:
        return np.ones(level.m, dtype=bool)
    if not qp:
        return level.active_rows()
    Jx = level.J @ x
    tol = BOUND_TOL * 1e3 * (1.0 + np.abs(Jx))
    return (Jx >= level.upper - tol) | (Jx <= level.lower + tol)


def _projector_step(P: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """``A P``'s singular values' minimum and the next projector ``P - (A P)^+ A P``."""
    if A.shape[0] == 0:
        return P, np.inf, np.zeros(0)
    AP = A @ P
    U, s, Vt = np.linalg.svd(AP, full_matrices=False)
    r = int((s > matrix_tol(A)).sum())
    V = Vt[:r]
    smin = float(s.min()) if s.size and A.shape[0] <= P.shape[0] else 0.0
    return P - V.T @ V, smin, s


def account(levels, x, *, box=None, info: dict | None = None, solver: str = "", lambda_max: float = 0.0,
            eps: float = 0.0) -> StepAccount:
    """The :class:`StepAccount` of command ``x`` for ``levels`` (module doc); no causes (see :func:`explain`).

    ``box = (lower, upper)`` is the hard box of the step (``None``: none), ``info`` the dict returned by
    :func:`hqp_tpm.solvers.registry.solve`, ``solver`` its name, ``lambda_max`` / ``eps`` its damping.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    lv = as_levels(levels, n) if levels else ()
    info = info or {}
    qp = solver.startswith("qp")
    scales = info.get("scales")
    common = info.get("scale")
    P = np.eye(n)
    out = []
    for i, level in enumerate(lv):
        Jx = level.J @ x
        if level.is_equality:
            desired = level.b
            residual = Jx - desired
            ref = float(np.linalg.norm(desired))
        else:
            desired = np.clip(Jx, level.lower, level.upper)
            residual = _violation(Jx, level.lower, level.upper)
            ref = float(np.linalg.norm(_violation(np.zeros(level.m), level.lower, level.upper)))
        r = float(np.linalg.norm(residual))
        tol = MET_TOL * max(1.0, ref)
        kept = _kept_rows(level, x, qp)
        P, smin, _ = _projector_step(P, level.J[kept])
        if level.is_equality:
            active = tuple(range(level.m))
        else:
            at = (Jx >= level.upper - 1e-9 * (1 + np.abs(Jx))) | (Jx <= level.lower + 1e-9 * (1 + np.abs(Jx)))
            active = tuple(int(k) for k in np.flatnonzero(at | kept))
        scale = None
        if scales is not None and i < len(scales):
            scale = float(scales[i])
        elif common is not None:
            scale = float(common)
        out.append(LevelAccount(i, level.name or str(i), level.is_equality, np.array(desired, dtype=float), Jx,
                                residual, _fraction(r, ref, tol), r <= tol, active, smin,
                                damping_lambda(smin, lambda_max, eps) if np.isfinite(smin) else 0.0, scale))
    at_bound, sides, beyond = (), (), ()
    if box is not None:
        lo, up = (np.asarray(b, dtype=float) for b in box)
        fin_lo, fin_up = np.isfinite(lo), np.isfinite(up)
        lo0, up0 = np.where(fin_lo, lo, 0.0), np.where(fin_up, up, 0.0)
        tlo, tup = BOUND_TOL * (1.0 + np.abs(lo0)), BOUND_TOL * (1.0 + np.abs(up0))
        hi = fin_up & (np.abs(x - up0) <= tup)
        low = fin_lo & (np.abs(x - lo0) <= tlo) & ~hi
        idx = np.flatnonzero(hi | low)
        at_bound = tuple(int(j) for j in idx)
        sides = tuple(1 if hi[j] else -1 for j in idx)
        beyond = tuple(int(j) for j in np.flatnonzero((fin_up & (x > up0 + tup)) | (fin_lo & (x < lo0 - tlo))))
        box = (lo, up)
    backend = info.get("solver") if qp else None
    return StepAccount(tuple(out), x, solver, backend, box, solver in BOX_SOLVERS or qp, at_bound, sides, beyond,
                       tuple(int(j) for j in info.get("saturated", ())), None if common is None else float(common))


# ----------------------------------------------------------------------------------------------
# Causes.
# ----------------------------------------------------------------------------------------------
def _constrained_residual(Jk: np.ndarray, bk: np.ndarray, A: np.ndarray, a: np.ndarray) -> float:
    """``min ||J_k y - b_k||`` over ``{y : A y = a}`` (``a`` consistent: it is ``A x``)."""
    if A.shape[0] == 0:
        y0, N = np.zeros(Jk.shape[1]), np.eye(Jk.shape[1])
    else:
        y0 = np.linalg.lstsq(A, a, rcond=None)[0]
        _, s, Vt = np.linalg.svd(A, full_matrices=True)
        N = Vt[int((s > matrix_tol(A)).sum()):].T
    target = bk - Jk @ y0
    if N.shape[1] == 0:
        return float(np.linalg.norm(target))
    M = Jk @ N
    z = np.linalg.lstsq(M, target, rcond=None)[0]
    return float(np.linalg.norm(M @ z - target))


def deletion_filter(items: Sequence, still_blocked: Callable[[list], bool]) -> list:
    """Irreducible subset of ``items`` that keeps ``still_blocked`` true (``still_blocked(items)`` must be).

    Each item is dropped in turn, the last first, if the property holds without it: the result loses
    the property without any one of its items (the classic IIS deletion filter). Trying the last items
    first keeps the first ones when several subsets qualify: the highest levels, the joints saturated
    in the solution itself rather than those only a re-solve saturates.
    """
    keep = list(items)
    for item in reversed(list(items)):
        trial = [k for k in keep if k != item]
        if still_blocked(trial):
            keep = trial
    return keep


def _level_target(level: Level, la: LevelAccount) -> tuple[np.ndarray, np.ndarray]:
    """The rows and values level ``k`` needs: all of an equality; the violated rows of an inequality."""
    if level.is_equality:
        return level.J, level.b
    bad = la.residual != 0.0
    return level.J[bad], la.desired[bad]


class _Resolver:
    """Re-solves the step with some joint bounds released (cached by the released set)."""

    def __init__(self, levels, acc: StepAccount, solve: Callable, budget: int):
        self.levels, self.acc, self.solve = levels, acc, solve
        self.cache: dict = {}
        self.budget = budget  # re-solves left for this step
        self.found: list[tuple[int, ...]] = []  # blocking sets found for the levels explained so far
        self.side = dict(zip(acc.at_bound, acc.sides, strict=True))  # grows with joints saturated after a release

    def released(self, joints: frozenset) -> _Outcome:
        """The outcome of the solve with the bounds of ``joints`` released (-1: the whole box) on the side
        in ``self.side`` (+1 upper, -1 lower, 0 both)."""
        key = frozenset((j, self.side.get(j)) for j in joints)
        if key not in self.cache:
            if self.budget <= 0:
                raise _OverBudget
            self.budget -= 1
            lo, up = (b.copy() for b in self.acc.box)
            for j in joints:
                if j == -1:  # the whole box
                    lo[:], up[:] = -np.inf, np.inf
                    continue
                if self.side[j] >= 0:
                    up[j] = np.inf
                if self.side[j] <= 0:
                    lo[j] = -np.inf
            x, _ = self.solve(self.levels, (lo, up))
            self.cache[key] = _outcome(self.levels, x, lo, up)
        return self.cache[key]


class _OverBudget(Exception):
    """The step's re-solves are used up: the joint cause of this level is left unverified."""


@dataclass(frozen=True)
class _Outcome:
    """What a re-solve is checked on: each level's residual norm and fraction met, the joints at a bound."""

    residual: tuple[float, ...]
    fraction: tuple[float, ...]
    at_bound: tuple[int, ...]
    sides: tuple[int, ...]


def _outcome(levels, x, lo, up) -> _Outcome:
    res, frac = [], []
    for level in levels:
        Jx = level.J @ x
        if level.is_equality:
            r, ref = np.linalg.norm(Jx - level.b), np.linalg.norm(level.b)
        else:
            r = np.linalg.norm(_violation(Jx, level.lower, level.upper))
            ref = np.linalg.norm(_violation(np.zeros(level.m), level.lower, level.upper))
        res.append(float(r))
        frac.append(_fraction(float(r), float(ref), MET_TOL * max(1.0, float(ref))))
    fin_lo, fin_up = np.isfinite(lo), np.isfinite(up)
    lo0, up0 = np.where(fin_lo, lo, 0.0), np.where(fin_up, up, 0.0)
    hi = fin_up & (np.abs(x - up0) <= BOUND_TOL * (1.0 + np.abs(up0)))
    low = fin_lo & (np.abs(x - lo0) <= BOUND_TOL * (1.0 + np.abs(lo0))) & ~hi
    idx = np.flatnonzero(hi | low)
    return _Outcome(tuple(res), tuple(frac), tuple(int(j) for j in idx), tuple(1 if hi[j] else -1 for j in idx))


def explain(levels, x, *, box=None, info: dict | None = None, solver: str = "", lambda_max: float = 0.0,
            eps: float = 0.0, x0=None, solve: Callable | None = None, acc: StepAccount | None = None,
            hints: dict | None = None, hard: Sequence[int] | int = (), max_resolves: int = 60) -> StepAccount:
    """:func:`account` with the causes of every level not met (module doc).

    ``solve(levels, box) -> (x, info)`` re-solves the step with another box; by default
    :func:`hqp_tpm.solvers.registry.solve` with ``solver``, ``x0``, ``lambda_max``, ``eps``.
    ``acc``: an account already computed for these arguments. ``hints``: by level name, the joint
    blocking set ``((joint, side), ...)`` of an earlier step, kept if one re-solve confirms it (a run
    explains every step for the cost of about two re-solves while the saturations stay the same).
    ``max_resolves``: re-solves allowed for the step (a level whose joint cause needs more is
    ``unexplained`` unless another cause holds). ``hard``: levels that must be met (indices, or an int
    ``h``: the top ``h``); if one is not, and no command meets them with the box,
    :class:`hqp_tpm.errors.InfeasibleError` names the conflict.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    lv = as_levels(levels, n) if levels else ()
    acc = acc or account(lv, x, box=box, info=info, solver=solver, lambda_max=lambda_max, eps=eps)
    if solve is None and acc.box_kept and acc.box is not None:
        from hqp_tpm.solvers.registry import solve as registry_solve

        def solve(levels_, box_):
            return registry_solve(solver, levels_, n, x0=x0, box=box_, lambda_max=lambda_max, eps=eps)
    hard = list(range(min(hard, len(lv)))) if isinstance(hard, int) else list(hard)
    if any(not acc.levels[i].met for i in hard):
        check_feasible(lv, acc.box, hard=hard)
    qp = solver.startswith("qp")
    resolver = None
    if solve is not None and acc.box is not None and acc.box_kept:
        resolver = _Resolver(lv, acc, solve, max_resolves)
    kept = [_kept_rows(level, x, qp) for level in lv]
    rows = [level.J[k] for level, k in zip(lv, kept, strict=True)]
    causes = []
    for k, (level, la) in enumerate(zip(lv, acc.levels, strict=True)):
        if la.met:
            causes.append(())
            continue
        found: list[Cause] = []
        Jk, bk = _level_target(level, la)
        tol = MET_TOL * max(1.0, float(np.linalg.norm(bk)))
        higher = [j for j in range(k) if rows[j].shape[0]]

        def blocked(subset, Jk=Jk, bk=bk, tol=tol):
            A = np.vstack([rows[j] for j in subset]) if subset else np.zeros((0, n))
            return _constrained_residual(Jk, bk, A, A @ x) > tol

        if higher and blocked(higher):
            found.append(Cause("higher_levels", tuple(deletion_filter(higher, blocked))))
        if la.damping > 0.0:
            def damped(subset, Jk=level.J[kept[k]]):
                P = np.eye(n)
                for j in subset:
                    P, _, _ = _projector_step(P, rows[j])
                return _projector_step(P, Jk)[1] < eps
            found.append(Cause("damping", tuple(deletion_filter(higher, damped))))
        if resolver is not None and acc.at_bound:
            try:
                found.extend(_joint_cause(resolver, acc, k, (hints or {}).get(la.name)))
            except _OverBudget:
                pass
        if not found:
            found.append(Cause("unexplained"))
        causes.append(tuple(found))
    return StepAccount(**{**acc.__dict__, "causes": tuple(causes)})


def _joint_cause(resolver: _Resolver, acc: StepAccount, k: int, hint=None) -> list[Cause]:
    """Saturated joints without which level ``k`` reaches the residual it has with no box (re-solved).

    ``hint``: a blocking set found at an earlier step; if its joints are at the same bounds and releasing
    them is enough here too (one re-solve), it is kept without re-running the deletion filter.
    """
    free = resolver.released(frozenset([-1])).residual[k]
    r_now = acc.levels[k].residual_norm
    tol = MET_TOL * max(1.0, float(np.linalg.norm(acc.levels[k].desired)))
    if r_now <= free + tol:   # the box costs this level nothing
        return []
    target = free + max(tol, 1e-3 * (r_now - free))

    def reached(subset) -> bool:
        return resolver.released(frozenset(subset)).residual[k] <= target

    for j, s in hint or ():
        resolver.side.setdefault(j, s)   # a joint a re-solve saturated at the earlier step: release that side
        if s == 0:
            resolver.side[j] = 0         # both sides released then: both again (a superset of one side)
    if hint and all(resolver.side[j] == s for j, s in hint) and reached([j for j, _ in hint]):
        joints = [j for j, _ in hint]
        frac = resolver.released(frozenset(joints)).fraction[k]
        return [Cause("joint_bounds", (), tuple(joints), tuple(resolver.side[j] for j in joints), frac)]
    for known in sorted(resolver.found, key=len):  # a set found for a higher level of this step often suffices:
        if reached(known):                        # the filter then starts from it (fewer, mostly cached, solves)
            joints = deletion_filter(list(known), reached)
            resolver.found.append(tuple(joints))
            frac = resolver.released(frozenset(joints)).fraction[k]
            return [Cause("joint_bounds", (), tuple(joints), tuple(resolver.side[j] for j in joints), frac)]

    start = list(acc.at_bound)
    n = acc.x.shape[0]
    for _ in range(n):                      # releasing some bounds can saturate others: add them
        if reached(start):
            break
        again = resolver.released(frozenset(start))
        more = False
        for j, s in zip(again.at_bound, again.sides, strict=True):
            if j not in start:
                resolver.side[j] = s
                start.append(j)
                more = True
            elif resolver.side[j] not in (0, s):   # now at its other bound: release both sides
                resolver.side[j] = 0
                more = True
        if not more:
            return []
    else:
        return []
    joints = deletion_filter(start, reached)
    resolver.found.append(tuple(joints))
    frac = resolver.released(frozenset(joints)).fraction[k]
    return [Cause("joint_bounds", (), tuple(joints), tuple(resolver.side[j] for j in joints), frac)]


# ----------------------------------------------------------------------------------------------
# Infeasible hard constraints.
# ----------------------------------------------------------------------------------------------
def _constraints(levels, box, hard):
    """Hard constraints as rows ``(a, lower, upper, label)`` of ``lower <= a x <= upper``."""
    rows = []
    if box is not None:
        lo, up = box
        n = lo.shape[0]
        for j in range(n):
            e = np.zeros(n)
            e[j] = 1.0
            if np.isfinite(lo[j]):
                rows.append((e, lo[j], np.inf, f"box lower of joint {j} ({lo[j]:.6g})"))
            if np.isfinite(up[j]):
                rows.append((e, -np.inf, up[j], f"box upper of joint {j} ({up[j]:.6g})"))
    for i in hard:
        level = levels[i]
        for r in range(level.m):
            if level.is_equality:
                rows.append((level.J[r], level.b[r], level.b[r], f"level {level.name!r} row {r} (= {level.b[r]:.6g})"))
            else:
                lo, up = level.lower[r], level.upper[r]
                if np.isfinite(lo):
                    rows.append((level.J[r], lo, np.inf, f"level {level.name!r} row {r} lower ({lo:.6g})"))
                if np.isfinite(up):
                    rows.append((level.J[r], -np.inf, up, f"level {level.name!r} row {r} upper ({up:.6g})"))
    return rows


def _elastic(rows, n, tol):
    """Elastic LP ``min sum(s)`` with ``lower - s <= a x <= upper + s``: total violation and the rows with a
    positive multiplier (a Farkas-type support of the infeasibility) or None when feasible."""
    from scipy.optimize import linprog

    if not rows:
        return None
    m = len(rows)
    A_ub, b_ub = [], []
    for k, (a, lo, up, _) in enumerate(rows):
        s = np.zeros(m)
        s[k] = -1.0
        if np.isfinite(up):
            A_ub.append(np.concatenate([a, s]))
            b_ub.append(up)
        if np.isfinite(lo):
            A_ub.append(np.concatenate([-a, s]))
            b_ub.append(-lo)
    c = np.concatenate([np.zeros(n), np.ones(m)])
    res = linprog(c, A_ub=np.array(A_ub), b_ub=np.array(b_ub),
                  bounds=[(None, None)] * n + [(0, None)] * m, method="highs")
    if res.status != 0 or res.fun <= tol:
        return None
    return [k for k in range(m) if res.x[n + k] > tol or _touches(res, k, rows)]


def _touches(res, k, rows) -> bool:
    """Row ``k`` has a nonzero multiplier in the elastic LP (it takes part in the certificate)."""
    marg = np.abs(res.ineqlin.marginals)
    pos = 0
    for i, (_, lo, up, _) in enumerate(rows):
        cnt = int(np.isfinite(up)) + int(np.isfinite(lo))
        if i == k:
            return bool(marg[pos:pos + cnt].max(initial=0.0) > 1e-9)
        pos += cnt
    return False


def _feasible(rows, n, tol) -> bool:
    return _elastic(rows, n, tol) is None


def check_feasible(levels, box=None, *, hard: Sequence[int] | int = 1, tol: float = 1e-9) -> None:
    """Raise :class:`hqp_tpm.errors.InfeasibleError` if no command meets the box and the ``hard`` levels.

    ``hard``: the indices of the levels that must hold exactly (an int ``h``: the top ``h`` levels).
    The error's ``conflict`` lists the labels of an irreducible infeasible subset of the constraints
    and its message names them; an empty box (some ``lower > upper``) raises :class:`EmptyBoxError`.
    """
    lv = as_levels(levels) if levels else ()
    n = lv[0].n if lv else (0 if box is None else np.size(box[0]))
    if box is not None:
        lo, up = (np.asarray(b, dtype=float) for b in box)
        empty = np.flatnonzero(lo > up)
        if empty.size:
            names = [f"box lower of joint {j} ({lo[j]:.6g})" for j in empty[:1]] + \
                    [f"box upper of joint {j} ({up[j]:.6g})" for j in empty[:1]]
            raise EmptyBoxError(f"the box is empty at joint(s) {empty.tolist()}: lower > upper; conflicting "
                                f"constraints: {', '.join(names)}", names)
        box = (lo, up)
    hard = list(range(min(hard, len(lv)))) if isinstance(hard, int) else list(hard)
    rows = _constraints(lv, box, hard)
    support = _elastic(rows, n, tol)
    if support is None:
        return
    if _feasible([rows[k] for k in support], n, tol):  # the support is a heuristic: fall back to all rows
        support = list(range(len(rows)))
    iis = deletion_filter(support, lambda sub: not _feasible([rows[k] for k in sub], n, tol))
    names = [rows[k][3] for k in iis]
    raise InfeasibleError(f"no command meets the hard constraints; an irreducible conflicting set: "
                          f"{'; '.join(names)}", names)
