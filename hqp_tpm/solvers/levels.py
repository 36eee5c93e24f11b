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

import math
from collections.abc import Iterable, Sequence

import numpy as np
from scipy.linalg.blas import ddot as _ddot

from hqp_tpm.errors import BoxError, MagnitudeError, NonFiniteError, ParameterError, ShapeError

#: The largest sum of squares of a level's ``J`` (or ``b``) the solvers take: their norms (rank tolerances,
#: certificates) must not overflow float64, also summed over a stack (entries up to about 1e152; beyond, a
#: :class:`~hqp_tpm.errors.MagnitudeError`). The same test finds NaN and inf: ``NaN <= x`` is False.
MAX_SUMSQ = 1e304

#: The smallest nonzero sum of squares of a level's ``J`` the solvers take: below it (entries under about 1e-146)
#: the norms behind the rank tolerances underflow and a solve would divide by zero; a
#: :class:`~hqp_tpm.errors.MagnitudeError` asks to scale the level up instead.
MIN_SUMSQ = 1e-292

_SCALE_DOWN = ("beyond what the solvers' norms (rank tolerances, certificates) and finiteness tests hold; scale the "
               "level down (J and b by one factor: the same equations)")


def sumsq(a: np.ndarray) -> float:
    """``sum a_i^2`` over an array's entries by BLAS ``ddot``: a quarter of ``a @ a``'s time at a stack's sizes (no
    ufunc machinery) and no overflow warning; NaN and inf propagate, an overflow gives inf."""
    f = a.ravel()
    return _ddot(f, f) if f.size else 0.0


def all_finite(a: np.ndarray) -> bool:
    """Are all entries finite? One sum of squares; only when it overflows are the entries tested one by one."""
    return math.isfinite(sumsq(a)) or bool(np.isfinite(a).all())


def _vector(x, m: int, what: str, *, allow_inf: bool = False, check: bool = True) -> np.ndarray:
    if type(x) is np.ndarray and x.dtype == np.float64 and x.shape == (m,):  # the common case, checked cheaply
        arr = x
    else:
        arr = _real(x, what)
        if arr.ndim == 0:
            arr = np.full(m, float(arr))
        arr = arr.reshape(-1) if arr.ndim == 2 and 1 in arr.shape else arr
        if arr.shape != (m,):
            raise ShapeError(f"{what} has shape {np.shape(x)}, expected ({m},) to match J's {m} rows")
    if check:
        _check_vector(arr, what, allow_inf)
    return arr


def _check_vector(arr: np.ndarray, what: str, allow_inf: bool) -> None:
    if allow_inf:
        if np.isnan(arr).any():
            raise NonFiniteError(f"{what} holds NaN at rows {np.flatnonzero(np.isnan(arr)).tolist()}: {arr}")
    elif not sumsq(arr) <= MAX_SUMSQ:            # (one sum: NaN, inf and overflow all fail it)
        if not np.isfinite(arr).all():
            bad = np.flatnonzero(~np.isfinite(arr)).tolist()
            raise NonFiniteError(f"{what} holds non-finite values at rows {bad}: {arr}")
        raise MagnitudeError(f"{what} reaches {np.abs(arr).max():.3g}: its sum of squares exceeds "
                             f"{MAX_SUMSQ:.0e}, {_SCALE_DOWN}")


def _real(x, what: str) -> np.ndarray:
    """``x`` as a float array; a complex one is refused (``np.asarray(x, float)`` would drop its imaginary part)."""
    if np.iscomplexobj(x):
        raise ParameterError(f"{what} is complex; the solvers take real arrays only")
    return np.asarray(x, dtype=float)


def _matrix(J, name: str, check: bool = True) -> np.ndarray:
    if not (type(J) is np.ndarray and J.dtype == np.float64 and J.ndim == 2):
        J = _real(J, f"level {name!r}: J")
        if J.ndim == 1:
            J = J.reshape(1, -1)
        if J.ndim != 2:
            raise ShapeError(f"level {name!r}: J must be 2-D (m x n), got shape {np.shape(J)}")
    if check:
        if not sumsq(J) <= MAX_SUMSQ:            # (one sum: NaN, inf and overflow all fail it)
            if not np.isfinite(J).all():
                raise NonFiniteError(f"level {name!r}: J holds NaN or inf at {np.argwhere(~np.isfinite(J)).tolist()}")
            raise MagnitudeError(f"level {name!r}: J reaches {np.abs(J).max():.3g}: its sum of squares exceeds "
                                 f"{MAX_SUMSQ:.0e}, {_SCALE_DOWN}")
        _check_not_tiny(J, name)
    return J


def _check_not_tiny(J: np.ndarray, name: str) -> None:
    """A nonzero ``J`` whose sum of squares is below :data:`MIN_SUMSQ` (or underflows to 0): a MagnitudeError."""
    sq = sumsq(J)
    if sq < MIN_SUMSQ and (sq > 0.0 or J.any()):
        raise MagnitudeError(f"level {name!r}: J is at most {np.abs(J).max():.3g}: its sum of squares is below "
                             f"{MIN_SUMSQ:.0e}, where the solvers' norms underflow; scale the level up (J and b by "
                             "one factor: the same equations)")


class Level:
    """One priority level: ``J x = b`` or ``lower <= J x <= upper`` (row-wise), validated once.

    Exactly one of ``b`` (equality) or ``lower``/``upper`` (inequality) is given.
    ``active`` optionally fixes which inequality rows the analytic solvers keep.
    The arrays are the caller's (not copied) and must not be changed afterwards.

    ``defer_finite=True`` (used by the tasks, every control step) checks shapes now and leaves the
    NaN/inf checks to the solver, which checks the stacked rows of such levels once per solve
    (:func:`stacked`; the other solvers through :func:`as_levels`) and then names the level at fault.
    """

    __slots__ = ("J", "b", "lower", "upper", "active", "name", "checked")

    def __init__(self, J, b=None, lower=None, upper=None, active=None, name: str = "", *,
                 defer_finite: bool = False):
        self.name = name
        check = not defer_finite
        self.checked = check
        J = _matrix(J, name, check)
        m = J.shape[0]
        self.J = J
        is_eq = b is not None
        if is_eq == (lower is not None or upper is not None):
            raise ShapeError(f"level {name!r}: give either b (equality) or lower/upper (inequality), not "
                             f"{'both' if is_eq else 'neither'}")
        self.active = None
        if is_eq:
            self.b = _vector(b, m, f"level {name!r}: b", check=check)
            self.lower = self.upper = None
            return
        self.b = None
        lo = _vector(-np.inf if lower is None else lower, m, f"level {name!r}: lower", allow_inf=True, check=check)
        up = _vector(np.inf if upper is None else upper, m, f"level {name!r}: upper", allow_inf=True, check=check)
        if (lo > up).any():
            i = int(np.flatnonzero(lo > up)[0])
            raise BoxError(f"level {name!r}: lower[{i}] = {lo[i]} > upper[{i}] = {up[i]}")
        self.lower, self.upper = lo, up
        if active is not None:
            act = np.asarray(active, dtype=bool).reshape(-1)
            if act.shape != (m,):
                raise ShapeError(f"level {name!r}: active has shape {np.shape(active)}, expected ({m},)")
            self.active = act

    def check_finite(self) -> Level:
        """The NaN/inf checks a ``defer_finite`` level skipped (typed errors naming the level)."""
        if not self.checked:
            _matrix(self.J, self.name)
            if self.b is not None:
                _check_vector(self.b, f"level {self.name!r}: b", False)
            else:
                _check_vector(self.lower, f"level {self.name!r}: lower", True)
                _check_vector(self.upper, f"level {self.name!r}: upper", True)
            self.checked = True
        return self

    def __repr__(self) -> str:
        kind = "J x = b" if self.b is not None else "lower <= J x <= upper"
        return f"Level({self.name!r}, {self.m}x{self.n}, {kind})"

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
        rows = self.active_rows()
        return row_targets(self.lower[rows], self.upper[rows])

    def as_equality(self) -> tuple[np.ndarray, np.ndarray]:
        """``(J_active, target)``: the level as the analytic solvers see it (may have 0 rows)."""
        if self.b is not None:
            return self.J, self.b
        rows = self.active_rows()
        return self.J[rows], row_targets(self.lower[rows], self.upper[rows])


def row_targets(lo: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Targets of active inequality rows: the bound violated at zero, else the finite bound nearest to zero."""
    if lo.shape[0] == 1:  # one row (a cone, a distance): the same choice on floats, far fewer calls
        a, b = float(lo[0]), float(up[0])
        if a > 0.0:
            return np.array([a])
        if b < 0.0:
            return np.array([b])
        near_lo = math.isfinite(a) and (not math.isfinite(b) or abs(a) <= abs(b))
        return np.array([a if near_lo else b])
    nearest = np.where(np.isfinite(lo) & (~np.isfinite(up) | (np.abs(lo) <= np.abs(up))), lo, up)
    return np.where(lo > 0.0, lo, np.where(up < 0.0, up, nearest))


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


def as_levels(levels: Iterable, n: int | None = None, *, check_finite: bool = True) -> tuple[Level, ...]:
    """Validate a stack: every level well formed, all with the same number of columns ``n``.

    ``check_finite=False`` leaves the NaN/inf checks of ``defer_finite`` levels to the caller.
    """
    out = []                                     # (a loop, not a generator: this runs on every solve)
    for i, lv in enumerate(levels):
        out.append(lv if type(lv) is Level else as_level(lv, i))
    out = tuple(out)
    if not out:
        if n is None:
            raise ShapeError("the stack is empty and n is not given: cannot tell the command's size")
        return out
    n0 = out[0].J.shape[1] if n is None else n
    for i, lv in enumerate(out):
        if lv.J.shape[1] != n0:
            raise ShapeError(f"level {i} ({lv.name!r}) has {lv.n} columns, expected n = {n0}")
        if check_finite and not lv.checked:
            lv.check_finite()
    return out


def equality_stack(levels: Sequence[Level]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The analytic solvers' view: active rows of each level as ``(J_i, b_i)``; empty levels dropped."""
    pairs = (lv.as_equality() for lv in levels)
    return [(J, b) for J, b in pairs if J.shape[0] > 0]


def stacked(levels: Iterable, n: int | None = None):
    """Validated levels and their active rows stacked: ``(levels, J, b, sizes, n)``.

    ``J`` (m x n) and ``b`` (m) hold the rows of :func:`equality_stack` in priority order,
    ``sizes`` the row count of each non-empty level. The ``defer_finite`` equality levels are
    checked here through the stacked arrays, once.
    """
    lv = as_levels(levels, n, check_finite=False)
    n = lv[0].J.shape[1] if lv else n
    Js, bs, sizes = [], [], []
    deferred = False
    for level in lv:
        if level.b is not None:
            J, b = level.J, level.b
            if not level.checked:
                deferred = True
        else:
            J, b = level.check_finite().as_equality()
            _check_vector(b, f"level {level.name!r}: b of its active rows (their bounds)", False)
        m = J.shape[0]
        if m:
            Js.append(J)
            bs.append(b)
            sizes.append(m)
    if not sizes:
        return lv, np.zeros((0, n)), np.zeros(0), (), n
    J, b = (Js[0], bs[0]) if len(Js) == 1 else (np.concatenate(Js), np.concatenate(bs))
    if deferred:                                 # one sum each: NaN, inf and too large entries fail it, then the
        sj, sb = sumsq(J), sumsq(b)              # levels' own checks raise naming the level
        if not (sj <= MAX_SUMSQ and sb <= MAX_SUMSQ):
            for level in lv:
                level.check_finite()
            if not (math.isfinite(sj) and math.isfinite(sb)):  # every level within bounds, their sum overflows
                raise MagnitudeError(f"the sum of squares of the {len(lv)} stacked levels overflows float64 (each "
                                     "within bounds): the solvers need its norm; scale the levels down")
    return lv, J, b, tuple(sizes), n
