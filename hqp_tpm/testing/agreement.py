"""``assert_solvers_agree``: solve one stack with several solvers and check what the library guarantees.

What is compared, pair by pair (see :func:`relation`):

* **the same problem** -- commands must agree (:mod:`hqp_tpm.testing.tolerances`): TPM and the
  recursive null space always; the QP backends among themselves always; a boxed solver (SNS-TPM,
  multi-task SNS, the QP) and an analytic one when there is no box or the box contains the
  analytic solution (for the multi-task SNS: every partial solution, as it checks the box level by
  level); SNS-TPM and SNS under the same condition.
* **different problems by construction** -- with a box that binds, SNS-TPM scales the whole stack
  by one factor, the multi-task SNS scales each level, the cascaded QP is the lexicographic optimum
  in the box and TPM ignores the box. What the library guarantees then is the *level-by-level
  residual order*: ``tpm <=lex qp <=lex sns_tpm, sns`` (undamped; at the first level where two
  residual vectors differ by more than the tolerance, the one on the left is smaller), and every
  boxed solution inside the box. With damping no order is guaranteed, only the boxes (and two QP
  backends are not compared either: a damped level is damped around the point its backend reached, so
  the cascade is path dependent -- measured 9e-2 apart on a romeo_sns_tpm step).

Inequality levels: by default (``inequalities="active"``) every solver gets the analytic solvers'
view of the stack -- the active rows as equalities (:meth:`Level.as_equality`) -- so the commands
are comparable; ``inequalities="as_given"`` hands the QP the true inequalities, and the QP is then
compared with the analytic solvers only through the residual order.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hqp_tpm.errors import HqpTpmError, ShapeError
from hqp_tpm.solvers.levels import Level, as_levels
from hqp_tpm.testing import tolerances as T

DEFAULT_SOLVERS = ("tpm", "nullspace", "qp:proxqp", "qp:daqp")
ANALYTIC = ("tpm", "nullspace")
SNS = ("sns_tpm", "sns", "sns_tpm_reference")  # the last: Algorithm 1 of papers/002 as written (not in the registry)

#: Environment variable naming the directory failing cases are saved to (default: the temp dir).
SAVE_DIR_ENV = "HQP_TPM_TESTING_DIR"


def kind(solver: str) -> str:
    """``"analytic"``, ``"sns"`` or ``"qp"``."""
    if solver in ANALYTIC:
        return "analytic"
    if solver in SNS:
        return "sns"
    if solver == "qp" or solver.startswith("qp:"):
        return "qp"
    from hqp_tpm.solvers.registry import check_solver_name

    check_solver_name(solver)  # raises UnknownNameError listing the names
    raise AssertionError("unreachable")


@dataclass
class Comparison:
    """One check of the report: two solvers (or one and its box), the measure and its tolerance."""

    a: str
    b: str
    what: str  # "same problem", "residual order", "in box", "solved"
    value: float
    tol: float
    ok: bool
    where: str = ""
    note: str = ""


@dataclass
class Report:
    """What :func:`assert_solvers_agree` measured. ``str(report)`` is the table of its error message."""

    solvers: tuple[str, ...]
    names: tuple[str, ...]
    rows: tuple[int, ...]
    commands: dict[str, np.ndarray]
    residuals: dict[str, np.ndarray]
    errors: dict[str, str]
    comparisons: list[Comparison]
    cond: float
    level_cond: np.ndarray
    projected_cond: np.ndarray
    n: int
    box: str
    damping: dict
    seed: int | None = None
    path: Path | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.comparisons)

    def worst(self) -> Comparison | None:
        """The failed comparison furthest beyond its tolerance (None if all pass)."""
        bad = [c for c in self.comparisons if not c.ok]
        return max(bad, key=lambda c: c.value / c.tol if c.tol > 0 else np.inf, default=None)

    def table(self) -> str:
        head = (f"{'level':<16}{'rows':>5}{'cond(J_k)':>11}{'cond proj':>11}"
                + "".join(f"{s[:13]:>14}" for s in self.solvers))
        damping = ", ".join(f"{k} = {v:g}" for k, v in self.damping.items()) or "none"
        lines = [f"stack: {len(self.names)} levels, n = {self.n}, cond(J) = {self.cond:.2e}, box: {self.box}, "
                 f"damping: {damping}" + (f", seed = {self.seed}" if self.seed is not None else ""),
                 "residual per level (||J_k x - b_k||, or the bound violation):", head]
        for k, name in enumerate(self.names):
            cells = []
            for s in self.solvers:
                r = self.residuals.get(s)
                cells.append(f"{'error':>14}" if r is None else f"{r[k]:>14.3e}")
            lines.append(f"{name[:15]:<16}{self.rows[k]:>5}{self.level_cond[k]:>11.2e}{self.projected_cond[k]:>11.2e}"
                         + "".join(cells))
        lines.append("checks:")
        for c in self.comparisons:
            pair = c.a if c.what in ("in box", "solved") else f"{c.a} vs {c.b}"
            where = f" at {c.where}" if c.where else ""
            lines.append(f"  {'ok  ' if c.ok else 'FAIL'} {pair:<26} {c.what:<15} {c.value:>10.3e} "
                         f"(tol {c.tol:.1e}){where}" + (f"  {c.note}" if c.note else ""))
        lines += [f"note: {n}" for n in self.notes]
        if self.path is not None:
            path = repr(str(self.path))
            lines.append(f"reproduce: hqp_tpm.testing.assert_solvers_agree(**hqp_tpm.testing.load_case({path}))")
        return "\n".join(lines)

    __str__ = table


# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------
def residual(level: Level, x: np.ndarray) -> float:
    """``||J x - b||`` of an equality level, the norm of the bound violation of an inequality level."""
    y = level.J @ x
    if level.is_equality:
        return float(np.linalg.norm(y - level.b))
    return float(np.linalg.norm(np.maximum(0.0, np.maximum(level.lower - y, y - level.upper))))


def _rank_tol(A: np.ndarray) -> float:
    try:  # the library's own law once it has one
        from hqp_tpm.solvers.damping import matrix_tol

        return float(matrix_tol(A))
    except ImportError:
        from hqp_tpm.solvers.damping import RANK_TOL

        return RANK_TOL


def conditioning(levels: Sequence[Level]) -> tuple[float, np.ndarray, np.ndarray]:
    """``(cond_eff, cond(J_k), cond of J_k projected)`` of the active rows.

    ``cond of J_k projected``: ``||J_k|| / sigma`` with ``sigma`` the smallest singular value of
    ``J_k Z`` above the rank tolerance, ``Z`` an orthonormal basis of the null space of the levels
    above -- what the solvers invert. ``cond_eff`` is the largest of them (inf-free: rank
    decisions drop the singular values below the tolerance).
    """
    n = levels[0].n if levels else 0
    Z = np.eye(n)
    kc, pc = [], []
    for lv in levels:
        J, _ = lv.as_equality()
        if J.shape[0] == 0 or Z.shape[1] == 0:
            kc.append(1.0 if J.shape[0] == 0 else np.linalg.cond(J))
            pc.append(1.0)
            continue
        s = np.linalg.svd(J, compute_uv=False)
        kc.append(float(s[0] / s[-1]) if s[-1] > 0 else np.inf)
        JZ = J @ Z
        U, sz, Vt = np.linalg.svd(JZ, full_matrices=True)
        tol = _rank_tol(J)
        r = int((sz > tol).sum())
        pc.append(float(s[0] / sz[r - 1]) if r else 1.0)
        Z = Z @ Vt[r:].T
    pc_arr = np.asarray(pc)
    return (float(pc_arr.max()) if pc_arr.size else 1.0), np.asarray(kc), pc_arr


def _as_damping(damping) -> dict:
    if damping is None:
        return {}
    if isinstance(damping, Mapping):
        out = {k: float(v) for k, v in damping.items()}
    else:
        lam, eps = damping
        out = {"lambda_max": float(lam), "eps": float(eps)}
    unknown = set(out) - {"lambda_max", "eps"}
    if unknown:
        raise ValueError(f"damping takes lambda_max and eps, got {sorted(unknown)}")
    return out if out.get("lambda_max", 0.0) > 0.0 else {}


def _solve(solver: str, levels, n: int, x0, box, damping: dict, options: dict | None) -> np.ndarray:
    if solver == "sns_tpm_reference":  # as the registry calls sns_tpm: x0 as one more (lowest) level
        from hqp_tpm.solvers.sns import sns_tpm_reference

        lo, up = box if box is not None else (np.full(n, -np.inf), np.full(n, np.inf))
        if x0 is not None:
            levels = [*levels, (np.eye(n), x0)]
        return sns_tpm_reference(levels, lo, up, **damping)
    if kind(solver) == "qp" and options:
        from hqp_tpm.solvers.cascaded_qp import cascaded_qp

        backend = "proxqp" if solver == "qp" else solver.split(":", 1)[1]
        lo, up = box if box is not None else (None, None)
        return cascaded_qp(levels, solver=backend, x0=x0, lower=lo, upper=up, n=n, **damping, **options)
    from hqp_tpm.solvers.registry import solve

    return solve(solver, levels, n, x0=x0, box=box, **damping)[0]


def _in_box(x, lo, up) -> tuple[float, int]:
    """Largest relative violation of the box and the joint."""
    unit = 1.0 + np.maximum(np.abs(np.nan_to_num(lo, neginf=0.0)), np.abs(np.nan_to_num(up, posinf=0.0)))
    viol = np.maximum(0.0, np.maximum(lo - x, x - up)) / unit
    j = int(np.argmax(viol)) if viol.size else 0
    return (float(viol[j]) if viol.size else 0.0), j


def relation(a: str, b: str, *, boxed: bool, free_inside: bool, partial_inside: bool, damped: bool,
             true_inequalities: bool) -> tuple[str | None, str, str]:
    """How the solutions of ``a`` and ``b`` relate: ``("same", a, b)``, ``("order", lo, hi)`` (``lo <=lex hi``)
    or ``(None, a, b)`` when the library guarantees nothing between them (see the module doc)."""
    ka, kb = kind(a), kind(b)
    rank = {"analytic": 0, "qp": 1, "sns": 2}
    if rank[ka] > rank[kb]:
        a, b, ka, kb = b, a, kb, ka
    order = None if damped else "order"
    if ka == kb == "analytic":
        return "same", a, b
    if ka == kb == "qp":  # a damped cascade under a binding box depends on each backend's path: no guarantee
        return (None if damped and boxed and not free_inside else "same"), a, b
    if {a, b} == {"sns_tpm", "sns_tpm_reference"}:  # the fast path and Algorithm 1 as written: one algorithm
        return "same", a, b
    if ka == kb == "sns":
        return ("same" if not boxed or (free_inside and partial_inside) else None), a, b
    inside = not boxed or (free_inside and (b != "sns" or partial_inside))
    if ka == "analytic" and kb == "qp":
        if true_inequalities:
            return None, a, b
        return ("same" if inside else order), a, b
    if ka == "analytic":  # vs sns
        return ("same" if inside else order), a, b
    # qp vs sns: the SNS solution is a point of the box, the QP the lexicographic optimum over it
    if inside and not true_inequalities:
        return "same", a, b
    return order if boxed else None, a, b


def _lex_order(levels, x_lo, x_hi, r_lo, r_hi, rtol) -> tuple[bool, float, float, str]:
    """``r_lo <=lex r_hi`` up to the scaled tolerances: ``(ok, r_lo - r_hi at the deciding level, tol, where)``.

    At each level, ``d = r_lo - r_hi``: more than ``rtol * scale`` is a failure; below ``-EQUAL_RTOL * scale``
    (``lo`` better beyond round-off) decides in favour of ``lo`` -- a better higher level may cost the
    lower ones any amount, up to the conditioning; in between the levels count as equal and the next
    one decides. ``scale = (1 + max|J_k|) (1 + max|x|)``.
    """
    xmax = 1.0 + max(np.abs(x_lo).max(initial=0.0), np.abs(x_hi).max(initial=0.0))
    for k, lv in enumerate(levels):
        scale = (1.0 + np.abs(lv.J).max(initial=0.0)) * xmax
        tol = rtol * scale
        d = r_lo[k] - r_hi[k]
        if d > tol:
            return False, float(d), tol, f"level {k} ({lv.name})"
        if d < -T.EQUAL_RTOL * scale:
            return True, float(d), tol, f"level {k} ({lv.name}) decides"
    return True, 0.0, rtol, "all levels within tol"


# ------------------------------------------------------------------------------------------------
# saving and loading a case
# ------------------------------------------------------------------------------------------------
def save_case(path, levels, *, box=None, x0=None, damping=None, solvers=DEFAULT_SOLVERS, seed=None,
              commands: Mapping[str, np.ndarray] | None = None, inequalities: str = "active",
              solver_options: Mapping[str, dict] | None = None) -> Path:
    """Write a stack (and what was asked of it) to ``path`` (``.npz``); :func:`load_case` reads it back."""
    lv = as_levels(levels)
    arrays: dict[str, np.ndarray] = {}
    meta = {"levels": [], "solvers": list(solvers), "seed": seed, "damping": _as_damping(damping),
            "inequalities": inequalities, "n": lv[0].n if lv else None,
            "solver_options": {k: dict(v) for k, v in (solver_options or {}).items()}}
    for k, level in enumerate(lv):
        arrays[f"J{k}"] = level.J
        if level.is_equality:
            arrays[f"b{k}"] = level.b
        else:
            arrays[f"lower{k}"], arrays[f"upper{k}"] = level.lower, level.upper
            if level.active is not None:
                arrays[f"active{k}"] = level.active
        meta["levels"].append({"name": level.name, "equality": level.is_equality})
    if box is not None:
        arrays["box_lower"], arrays["box_upper"] = (np.asarray(v, dtype=float) for v in box)
    if x0 is not None:
        arrays["x0"] = np.asarray(x0, dtype=float)
    for s, x in (commands or {}).items():
        arrays[f"command:{s}"] = x
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)
    return path


def load_case(path) -> dict:
    """The keyword arguments of :func:`assert_solvers_agree` saved in ``path`` (levels, box, x0, ...)."""
    with np.load(path, allow_pickle=False) as f:
        meta = json.loads(str(f["meta"]))
        levels = []
        for k, info in enumerate(meta["levels"]):
            if info["equality"]:
                levels.append(Level(f[f"J{k}"], f[f"b{k}"], name=info["name"]))
            else:
                active = f[f"active{k}"] if f"active{k}" in f else None
                levels.append(Level(f[f"J{k}"], lower=f[f"lower{k}"], upper=f[f"upper{k}"], active=active,
                                    name=info["name"]))
        box = (f["box_lower"], f["box_upper"]) if "box_lower" in f else None
        x0 = f["x0"] if "x0" in f else None
    return {"levels": levels, "solvers": tuple(meta["solvers"]), "box": box, "x0": x0,
            "damping": meta["damping"] or None, "seed": meta["seed"], "inequalities": meta["inequalities"],
            "n": meta["n"], "solver_options": meta.get("solver_options") or None}


def _case_path(save_to, lv, box, x0) -> Path:
    h = hashlib.sha1()
    for level in lv:
        for a in (level.J, level.b, level.lower, level.upper):
            if a is not None:
                h.update(np.ascontiguousarray(a).tobytes())
    for a in (*(box or ()), x0):
        if a is not None:
            h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    name = f"hqp_tpm_case_{h.hexdigest()[:12]}.npz"
    if save_to is not None:
        p = Path(save_to)
        return p if p.suffix == ".npz" else p / name
    return Path(os.environ.get(SAVE_DIR_ENV) or Path(tempfile.gettempdir()) / "hqp_tpm_cases") / name


# ------------------------------------------------------------------------------------------------
# the assertion
# ------------------------------------------------------------------------------------------------
def check_solvers(levels, solvers: Sequence[str] = DEFAULT_SOLVERS, *, box=None, x0=None, damping=None,
                  rtol: float | None = None, atol: float | None = None, n: int | None = None,
                  inequalities: str = "active", solver_options: Mapping[str, dict] | None = None,
                  seed: int | None = None) -> Report:
    """Solve and compare like :func:`assert_solvers_agree`, without raising: the :class:`Report`."""
    if inequalities not in ("active", "as_given"):
        raise ValueError(f"inequalities must be 'active' or 'as_given', got {inequalities!r}")
    solvers = tuple(solvers)
    if len(solvers) < 1:
        raise ValueError("give at least one solver")
    for s in solvers:
        kind(s)
    damping = _as_damping(damping)
    lv = as_levels(levels, n)
    if not lv:
        raise ShapeError("the stack is empty: nothing to compare")
    n = lv[0].n
    eq_view = tuple(Level(*level.as_equality(), name=level.name or str(k)) for k, level in enumerate(lv))
    named = tuple(level if level.name else _renamed(level, str(k)) for k, level in enumerate(lv))
    has_ineq = any(not level.is_equality for level in lv)
    true_ineq = inequalities == "as_given" and has_ineq
    if box is not None:
        lo, up = (np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy() for v in box)
        if lo.shape != (n,):
            raise ShapeError(f"box has {lo.size} joints, the stack {n} columns")
        box = (lo, up)
    if x0 is not None:
        x0 = np.asarray(x0, dtype=float)
    options = dict(solver_options or {})

    def stack_for(s: str):
        return named if (true_ineq and kind(s) == "qp") else eq_view

    commands: dict[str, np.ndarray] = {}
    errors: dict[str, str] = {}
    for s in solvers:
        try:
            commands[s] = np.asarray(_solve(s, stack_for(s), n, x0, box if kind(s) != "analytic" else None,
                                            damping, options.get(s)), dtype=float)
        except HqpTpmError as e:
            errors[s] = f"{type(e).__name__}: {e}"
    # what the residual table and the orders use: the problem as the QP saw it
    problem = named if true_ineq else eq_view
    residuals = {s: np.array([residual(level, x) for level in problem]) for s, x in commands.items()}
    cond, level_cond, proj_cond = conditioning(eq_view)

    # is the box binding? (decides which pairs solve the same problem)
    free_inside = partial_inside = True
    notes = []
    if box is not None:
        from hqp_tpm.solvers import nullspace, tpm

        x_free = commands.get("tpm")
        if x_free is None:
            x_free = tpm(eq_view, x0=x0, n=n, **damping)
        free_inside = _in_box(x_free, *box)[0] <= T.BOX_RTOL
        if "sns" in solvers and free_inside:
            partial = [nullspace(eq_view[:k], n=n, **damping) for k in range(1, len(eq_view) + 1)]
            partial_inside = all(_in_box(p, *box)[0] <= T.BOX_RTOL for p in partial)
        if not free_inside:
            notes.append("the box binds: boxed and analytic solvers solve different problems; compared by the "
                         "level-by-level residual order" + (" (none guaranteed with damping)" if damping else ""))
            if damping and sum(kind(s) == "qp" for s in solvers) > 1:
                notes.append("damped cascades under a binding box are not compared across QP backends: each "
                             "level's damping acts around the point its backend reached (no guarantee)")
    if has_ineq:
        notes.append("inequality levels: " + ("the QP keeps the true inequalities" if true_ineq else
                                              "every solver gets their active rows as equalities"))

    comparisons: list[Comparison] = []
    for s, msg in errors.items():
        comparisons.append(Comparison(s, "", "solved", np.inf, 0.0, False, note=msg.splitlines()[0][:120]))
    if box is not None:
        for s, x in commands.items():
            if kind(s) != "analytic":
                v, j = _in_box(x, *box)
                comparisons.append(Comparison(s, "", "in box", v, T.BOX_RTOL, v <= T.BOX_RTOL, where=f"joint {j}"))
    names = [s for s in solvers if s in commands]
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            rel, lo_s, hi_s = relation(a, b, boxed=box is not None, free_inside=free_inside,
                                       partial_inside=partial_inside, damped=bool(damping),
                                       true_inequalities=true_ineq)
            if rel is None:
                continue
            both_qp = kind(a) == kind(b) == "qp" and box is not None and not free_inside
            r = rtol if rtol is not None else T.agreement_rtol(a, b, cond, boxed_qp=both_qp)
            if rel == "same":
                xa, xb = commands[a], commands[b]
                d = xa - xb
                tol = (r if atol is None else atol) + r * max(np.linalg.norm(xa), np.linalg.norm(xb))
                j = int(np.argmax(np.abs(d)))
                comparisons.append(Comparison(a, b, "same problem", float(np.linalg.norm(d)), float(tol),
                                              bool(np.linalg.norm(d) <= tol),
                                              where=f"joint {j} ({xa[j]:+.6g} vs {xb[j]:+.6g})"))
            else:
                ok, excess, tol, where = _lex_order(problem, commands[lo_s], commands[hi_s], residuals[lo_s],
                                                    residuals[hi_s], max(T.ORDER_RTOL, r))
                comparisons.append(Comparison(lo_s, hi_s, "residual order", excess, tol, ok, where=where,
                                              note="" if ok else f"{lo_s} must not be worse (lexicographically)"))
    box_text = "none"
    if box is not None:
        box_text = f"{n} joints, " + ("contains the analytic solution" if free_inside else "binds")
    return Report(solvers, tuple(level.name for level in problem), tuple(level.m for level in problem), commands,
                  residuals, errors, comparisons, cond, level_cond, proj_cond, n, box_text, damping, seed,
                  notes=notes)


def _renamed(level: Level, name: str) -> Level:
    if level.is_equality:
        return Level(level.J, level.b, name=name)
    return Level(level.J, lower=level.lower, upper=level.upper, active=level.active, name=name)


def assert_solvers_agree(levels, solvers: Sequence[str] = DEFAULT_SOLVERS, *, box=None, x0=None, damping=None,
                         rtol: float | None = None, atol: float | None = None, n: int | None = None,
                         inequalities: str = "active", solver_options: Mapping[str, dict] | None = None,
                         seed: int | None = None, save_to=None) -> Report:
    """Solve ``levels`` with each of ``solvers`` and check what the library guarantees between them.

    ``levels``: ``(J, b)`` pairs or :class:`~hqp_tpm.solvers.Level` (highest priority first).
    ``solvers``: registry names (``"tpm"``, ``"nullspace"``, ``"sns_tpm"``, ``"sns"``, ``"qp"``,
    ``"qp:<backend>"``) and ``"sns_tpm_reference"`` (Algorithm 1 of papers/002 as written: compared
    with ``"sns_tpm"`` as the same problem even when the box binds). ``box = (lower, upper)``: the hard
    box of the boxed solvers (the analytic ones ignore it). ``x0``: the null-space term (eq. (14)).
    ``damping``: ``{"lambda_max": ..., "eps": ...}`` or a pair. ``rtol``/``atol``: override the defaults
    of :mod:`hqp_tpm.testing.tolerances`. ``solver_options``: per solver name, options handed to the QP
    backend (e.g. ``{"qp:osqp": {"eps_abs": 1e-3}}``).
    ``seed``: recorded in the report and the saved case, to reproduce a random draw.

    Returns the :class:`Report` when every check passes. Otherwise raises ``AssertionError`` with the
    report's table (residual per level and solver, conditioning, each check with its worst
    disagreement and where) and saves the case to ``save_to`` (a ``.npz`` path or a directory;
    default: ``$HQP_TPM_TESTING_DIR`` or the temp dir), named in the message; ``load_case(path)``
    gives back the keyword arguments.
    """
    report = check_solvers(levels, solvers, box=box, x0=x0, damping=damping, rtol=rtol, atol=atol, n=n,
                           inequalities=inequalities, solver_options=solver_options, seed=seed)
    if report.ok:
        return report
    lv = as_levels(levels, n)
    path = _case_path(save_to, lv, box, x0)
    try:
        report.path = save_case(path, lv, box=box, x0=x0, damping=damping, solvers=solvers, seed=seed,
                                commands=report.commands, inequalities=inequalities, solver_options=solver_options)
    except OSError as e:  # a read-only directory must not hide the disagreement
        report.notes.append(f"could not save the case to {path}: {e}")
    worst = report.worst()
    title = "solvers disagree"
    if worst is not None and worst.what == "solved":
        title += f": {worst.a} raised {report.errors.get(worst.a, '')}".rstrip()
    elif worst is not None:
        pair = worst.a if worst.what in ("in box", "solved") else f"{worst.a} vs {worst.b}"
        title += f": {pair} ({worst.what}) {worst.value:.3e} > tol {worst.tol:.1e}"
    raise AssertionError(f"{title}\n{report.table()}")
