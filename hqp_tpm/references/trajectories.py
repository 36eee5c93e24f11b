"""Desired task trajectories: ``reference(t) -> (x_d, xd_d, xdd_d)``.

A trajectory may be *relative*: its offset is the task value at the start of the run
(``start(x0)``), as the Romeo hand circles and the 'hold where you are' targets need.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from hqp_tpm.errors import NonFiniteError, ShapeError, StateError, shown
from hqp_tpm.robot import _compiled


def _frozen(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """The arrays made read-only: a constant reference is computed once and shared by every step."""
    for a in arrays:
        a.flags.writeable = False
    return arrays


def _finite(x, what: str) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(x, dtype=float))
    if not np.isfinite(arr).all():
        raise NonFiniteError(f"{what} holds non-finite values: {arr}")
    return arr


_FLOAT64 = np.dtype(np.float64)


def _copy_finite(x: np.ndarray, out: np.ndarray) -> bool:
    """:func:`~hqp_tpm.robot._compiled.copy_finite` typed at its first call (:func:`~hqp_tpm.robot._compiled.typed`)."""
    global _copy_finite
    if not _compiled.ENABLED:  # (numpy's check and copy)
        ok = x.shape == out.shape and bool(np.isfinite(x).all())
        if ok:
            out[...] = x
        return ok
    _copy_finite = kernel = _compiled.typed(_compiled.copy_finite, x, out)
    return kernel(x, out)


@dataclass
class Trajectory:
    """Base: a constant zero-dimensional placeholder; subclasses give ``reference``.

    The numbers of the fields in ``FROZEN_FIELDS`` are stored as read-only copies: to change them, assign new
    ones (``traj.center = [...]``; ``traj.center[0] = ...`` raises). A change is then a new object, which the
    cached constant references and the compiled row writers and programs (they compare identities) see; an
    assignment also drops the cached reference.
    """

    #: the array fields kept as read-only copies (see the class doc)
    FROZEN_FIELDS: ClassVar[tuple[str, ...]] = ("origin",)
    #: ``reference(t)`` depends on ``t`` (False: constant between assignments and starts)
    time_varying: ClassVar[bool] = True
    #: ``x_d`` as one array written in place while the reference stays constant (:class:`Constant`, :class:`Hold` once
    #: started; its derivatives are zero), which the compiled steps read where it is (None: no such array)
    live: ClassVar[np.ndarray | None] = None
    #: the name of the task it was made or assigned for, which its errors name (None: not assigned through a task)
    task: ClassVar[str | None] = None

    relative: bool = False
    origin: np.ndarray | None = field(default=None, repr=False)

    def __setattr__(self, name: str, value) -> None:
        if name in self.FROZEN_FIELDS:
            if value is not None:
                value = np.array(value, dtype=float)  # a copy: the caller's array stays theirs
                value.flags.writeable = False
            object.__setattr__(self, "_ref", None)
        object.__setattr__(self, name, value)

    def start(self, x0: np.ndarray) -> None:
        """Called once with the task value at the start; fixes the offset of relative trajectories."""
        self.origin = np.array(x0, dtype=float) if self.relative else None

    def offset(self, dim: int) -> np.ndarray:
        """The origin (the start value) of a relative trajectory, zeros for an absolute one."""
        if self.origin is None and self.relative:
            raise self.unstarted()
        return self.origin if self.origin is not None else np.zeros(dim)

    def size(self) -> int | None:
        """How many values ``x_d`` has, where the trajectory says (None: it takes its task's)."""
        return None

    def unstarted(self) -> StateError:
        """The error of a relative trajectory used before :meth:`start`: never evaluated with a zero origin."""
        where = "" if self.task is None else f"task {self.task!r}: "
        return StateError(f"{where}relative {type(self).__name__} target used before start(): its origin, the task's "
                          "value at the start, is not set (a target assigned, or a task added, after the run started "
                          "is not started): call ctrl.start([task]) after assigning it, or assign it before the first "
                          "step")

    def reference(self, t: float):  # pragma: no cover - abstract
        raise NotImplementedError


@dataclass
class Constant(Trajectory):
    """``x_d = value`` (plus the start value when relative), zero derivatives; ``x_d`` also in :attr:`live`."""

    FROZEN_FIELDS: ClassVar[tuple[str, ...]] = ("origin", "value")
    time_varying: ClassVar[bool] = False

    value: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self):
        self.value = _finite(self.value, "target")

    def size(self) -> int | None:
        return self.value.size or None

    def __setattr__(self, name: str, value) -> None:
        super().__setattr__(name, value)
        d = self.__dict__
        if name == "value" or (name == "origin" and "live" in d):  # x_d anew, into live in place (shape kept)
            o = self.origin  # (None: absolute, or relative and not started: then reference refuses it)
            if o is None:
                x = self.value.copy()
            else:  # (an empty relative value: the origin itself)
                x = self.value + o if self.value.size else o.copy()
            if "live" in d and d["live"].shape == x.shape:
                d["live"][...] = x
            else:
                d["live"] = x

    def __getattr__(self, name: str):  # (``value`` after assign: a read-only copy of live, made when read)
        d = self.__dict__
        if name != "value" or "live" not in d:
            raise AttributeError(name)
        value = d["value"] = d["live"].copy()
        value.flags.writeable = False
        return value

    def __copy__(self) -> Constant:  # (a shallow copy owns its live array: an assignment to one leaves the other)
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__, live=self.live.copy())
        return new

    def assign(self, x) -> bool:
        """``value = x`` if ``x`` is a contiguous float64 vector of the value's size, finite, and this constant has no
        origin: checked and written into :attr:`live` in one compiled call (``value`` and the reference, read-only
        copies, are made when next read: arrays returned before are not changed); False (nothing changed) else."""
        d = self.__dict__
        if type(x) is not np.ndarray or x.dtype is not _FLOAT64 or x.strides != (8,) or d["origin"] is not None \
                or not _copy_finite(x, d["live"]):
            return False
        d["_ref"] = None
        d.pop("value", None)
        return True

    def reference(self, t: float):
        if self._ref is None:  # constant between assignments and starts: computed once, read-only
            if self.relative and self.origin is None:
                raise self.unstarted()
            x = self.live.copy()
            z = np.zeros_like(x)
            self._ref = _frozen(x, z) + (z,)
        return self._ref


@dataclass
class Hold(Trajectory):
    """Hold the value the task had at the start (``relative`` by construction)."""

    time_varying: ClassVar[bool] = False
    relative: bool = True

    def __post_init__(self):
        self._ref = None

    def __setattr__(self, name: str, value) -> None:
        super().__setattr__(name, value)
        if name == "origin":  # (live: x_d, the origin, once started)
            self.__dict__["live"] = None if value is None else self.origin.copy()

    def reference(self, t: float):
        if self.origin is None:
            raise self.unstarted()
        if self._ref is None:  # constant between starts: computed once, read-only
            x = self.origin.copy()
            z = np.zeros_like(x)
            self._ref = _frozen(x, z) + (z,)
        return self._ref


def harmonic_point(base: float, a: float, b: float, w: float, c: float, s: float) -> tuple[float, float, float]:
    """One entry of :meth:`Harmonic.reference` with ``c, s = cos(w t + phase), sin(w t + phase)``: ``x = base + a c +
    b s``, ``xd = w (-a s + b c)``, ``xdd = -w^2 (a c + b s)`` (also compiled into the planned steps' kernel,
    :mod:`hqp_tpm.control._compiled_step`: the same operations)."""
    return base + a * c + b * s, w * (-a * s + b * c), (-w * w) * (a * c + b * s)


@dataclass
class Harmonic(Trajectory):
    """``x_d(t) = center + a cos(w t + phi) + b sin(w t + phi)`` with analytic derivatives.

    The LWR ellipse of papers/000 is ``center = [0, .6, 0]``, ``a = [.2, 0, .2]``,
    ``b = [0, .1, 0]``, ``w = 1``; a Romeo hand circle is relative with
    ``center = [0, 0, -r]``, ``a = [0, 0, r]``, ``b = [0, -+2r, 0]``, ``w = 2 pi / Tc``.
    """

    FROZEN_FIELDS: ClassVar[tuple[str, ...]] = ("origin", "center", "cos_amplitude", "sin_amplitude")

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    cos_amplitude: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sin_amplitude: np.ndarray = field(default_factory=lambda: np.zeros(3))
    omega: float = 1.0
    phase: float = 0.0

    def __post_init__(self):
        self.center = _finite(self.center, "center")
        self.cos_amplitude = _finite(self.cos_amplitude, "cos_amplitude")
        self.sin_amplitude = _finite(self.sin_amplitude, "sin_amplitude")
        if not (self.center.shape == self.cos_amplitude.shape == self.sin_amplitude.shape):
            raise ShapeError(f"center, cos_amplitude, sin_amplitude must have one shape, got {self.center.shape}, "
                             f"{self.cos_amplitude.shape}, {self.sin_amplitude.shape}")
        _finite([self.omega, self.phase], "omega/phase")
        self._terms = None

    def size(self) -> int | None:
        return self.center.size

    def terms(self) -> tuple[float, float, tuple[tuple[float, float, float], ...]]:
        """``(omega, phase, ((center + offset, a, b) per entry))`` as floats, what :meth:`reference` computes from
        (:func:`harmonic_point`); the same tuple while none of them changes (assigning a frozen field or starting again
        builds it anew)."""
        fields = self._ref
        if fields is None:
            offset = self.offset(self.center.size).tolist()
            fields = self._ref = tuple(zip([ci + oi for ci, oi in zip(self.center.tolist(), offset, strict=True)],
                                           self.cos_amplitude.tolist(), self.sin_amplitude.tolist(), strict=True))
        terms = self._terms
        if terms is None or terms[2] is not fields or terms[0] != self.omega or terms[1] != self.phase:
            terms = self._terms = (float(self.omega), float(self.phase), fields)
        return terms

    def reference(self, t: float):
        w, phase, fields = self.terms()
        c, s = math.cos(w * t + phase), math.sin(w * t + phase)  # equal to np.cos/np.sin (tested)
        # per entry on floats: the IEEE operations of the array expressions, without numpy's per-call overhead
        x, xd, xdd = [], [], []
        for base, ai, bi in fields:
            xi, xdi, xddi = harmonic_point(base, ai, bi, w, c, s)
            x.append(xi)
            xd.append(xdi)
            xdd.append(xddi)
        return np.array(x), np.array(xd), np.array(xdd)


def as_trajectory(target, dim: int, task: str | None = None) -> Trajectory:
    """A :class:`Trajectory` from a trajectory, ``None``/``"hold"`` (hold the start value) or a constant, for the task
    named ``task`` (its :attr:`~Trajectory.task`, which its errors name)."""
    if isinstance(target, Trajectory) or target is None or (isinstance(target, str) and target == "hold"):
        trajectory = target if isinstance(target, Trajectory) else Hold()
        if trajectory.size() not in (None, dim):
            raise ShapeError(f"target {type(trajectory).__name__} has {trajectory.size()} values, expected {dim}")
        if task is not None:
            trajectory.task = task
        return trajectory
    try:
        value = _finite(target, "target")
    except (TypeError, ValueError) as exc:
        if isinstance(exc, NonFiniteError):
            raise
        raise ShapeError(f"target {shown(target)} is not {dim} numbers; expected {dim} values, a Trajectory, or "
                         "None / 'hold' (the start value)") from None
    if value.shape != (dim,):
        raise ShapeError(f"target has shape {value.shape}, expected ({dim},)")
    return Constant(value=value)
