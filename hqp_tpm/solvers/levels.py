"""Priority levels as plain arrays: what every solver consumes.

A stack is an ordered sequence of levels, highest priority first. A level is either a
pair ``(J, b)`` asking for ``J x = b`` or a :class:`Level`, which may instead carry
inequality bounds ``lower <= J x <= upper`` (use ``-inf``/``+inf`` for a missing side).

Inequality rows in the analytic solvers (TPM, SNS-TPM, recursive null space) follow the
rule papers/000 uses for the pointing cone (21): a row is *active* -- it enters the stack
as an equality whose target is the violated bound -- while its bound is violated, and is
left out otherwise. Without further information "violated" means violated by the zero
command ``x = 0`` (``lower > 0`` or ``upper < 0``): at velocity level with bounds built
from the task value, e.g. ``lower = k (cos a_d - p_rp)``, this is exactly the paper's
``e > 0``. A task that knows better (e.g. the acceleration-level cone, active while the
*position* error ``e > 0``) passes an explicit ``active`` mask; an active row's target is
then the bound violated at zero, or else its finite bound nearest to zero. The cascaded QP
ignores ``active`` and treats the bounds as true inequalities.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from hqp_tpm.errors import BoxError, NonFiniteError, ShapeError


def _vector(x, m: int, what: str, *, allow_inf: bool = False) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 0:
        arr = np.full(m, float(arr))
    arr = arr.reshape(-1) if arr.ndim == 2 and 1 in arr.shape else arr
    if arr.shape != (m,):
        raise ShapeError(f"{what} has shape {np.shape(x)}, expected ({m},) to match J's {m} rows")
    bad = np.isnan(arr) if allow_inf else ~np.isfinite(arr)
    if bad.any():
        raise NonFiniteError(f"{what} holds non-finite values at rows {np.flatnonzero(bad).tolist()}: {arr}")
    return np.ascontiguousarray(arr)


@dataclass(frozen=True, eq=False)
class Level:
    """One priority level: ``J x = b`` or ``lower <= J x <= upper`` (row-wise).

    Exactly one of ``b`` (equality) or ``lower``/``upper`` (inequality) is given.
    ``active`` optionally fixes which inequality rows the analytic solvers keep.
    """

    J: np.ndarray
    b: np.ndarray | None = None
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    active: np.ndarray | None = None
    name: str = ""

    def __post_init__(self) -> None:
        J = np.asarray(self.J, dtype=float)
        if J.ndim == 1:
            J = J.reshape(1, -1)
        if J.ndim != 2:
            raise ShapeError(f"level {self.name!r}: J must be 2-D (m x n), got shape {np.shape(self.J)}")
        if not np.isfinite(J).all():
            raise NonFiniteError(f"level {self.name!r}: J holds NaN or inf at {np.argwhere(~np.isfinite(J)).tolist()}")
        m = J.shape[0]
        object.__setattr__(self, "J", np.ascontiguousarray(J))
        is_eq = self.b is not None
        is_ineq = self.lower is not None or self.upper is not None
        if is_eq == is_ineq:
            raise ShapeError(f"level {self.name!r}: give either b (equality) or lower/upper (inequality), not "
                             f"{'both' if is_eq else 'neither'}")
        if is_eq:
            object.__setattr__(self, "b", _vector(self.b, m, f"level {self.name!r}: b"))
            return
        lo = _vector(-np.inf if self.lower is None else self.lower, m, f"level {self.name!r}: lower", allow_inf=True)
        up = _vector(np.inf if self.upper is None else self.upper, m, f"level {self.name!r}: upper", allow_inf=True)
        if (lo > up).any():
            i = int(np.flatnonzero(lo > up)[0])
            raise BoxError(f"level {self.name!r}: lower[{i}] = {lo[i]} > upper[{i}] = {up[i]}")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", up)
        if self.active is not None:
            act = np.asarray(self.active, dtype=bool).reshape(-1)
            if act.shape != (m,):
                raise ShapeError(f"level {self.name!r}: active has shape {np.shape(self.active)}, expected ({m},)")
            object.__setattr__(self, "active", act)

    @property
    def m(self) -> int:
        return self.J.shape[0]

    @property
    def n(self) -> int:
        return self.J.shape[1]

    @property
    def is_equality(self) -> bool:
        return self.b is not None

    def active_rows(self) -> np.ndarray:
        """Boolean mask of the rows the analytic solvers keep (all rows of an equality)."""
        if self.b is not None:
            return np.ones(self.m, dtype=bool)
        if self.active is not None:
            return self.active
        return (self.lower > 0.0) | (self.upper < 0.0)

    def target(self) -> np.ndarray:
        """Per-row target of the active rows, as an equality right-hand side (see module doc)."""
        if self.b is not None:
            return self.b
        lo, up = self.lower, self.upper
        nearest = np.where(np.isfinite(lo) & (~np.isfinite(up) | (np.abs(lo) <= np.abs(up))), lo, up)
        t = np.where(lo > 0.0, lo, np.where(up < 0.0, up, nearest))
        return t[self.active_rows()]

    def as_equality(self) -> tuple[np.ndarray, np.ndarray]:
        """``(J_active, target)``: the level as the analytic solvers see it (may have 0 rows)."""
        if self.b is not None:
            return self.J, self.b
        rows = self.active_rows()
        return self.J[rows], self.target()


LevelLike = Level | tuple | Sequence


def as_level(level, index: int = 0) -> Level:
    """Turn a ``(J, b)`` pair or a :class:`Level` into a validated :class:`Level`."""
    if isinstance(level, Level):
        return level
    try:
        J, b = level
    except (TypeError, ValueError):
        raise ShapeError(f"level {index} must be a Level or a (J, b) pair, got {type(level).__name__}") from None
    return Level(J, b, name=str(index))


def as_levels(levels: Iterable, n: int | None = None) -> tuple[Level, ...]:
    """Validate a stack: every level well formed, all with the same number of columns ``n``."""
    out = tuple(as_level(lv, i) for i, lv in enumerate(levels))
    if not out:
        if n is None:
            raise ShapeError("the stack is empty and n is not given: cannot tell the command's size")
        return out
    n0 = out[0].n if n is None else n
    for i, lv in enumerate(out):
        if lv.n != n0:
            raise ShapeError(f"level {i} ({lv.name!r}) has {lv.n} columns, expected n = {n0}")
    return out


def equality_stack(levels: Sequence[Level]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The analytic solvers' view: active rows of each level as ``(J_i, b_i)``; empty levels dropped."""
    pairs = (lv.as_equality() for lv in levels)
    return [(J, b) for J, b in pairs if J.shape[0] > 0]
