"""Collision avoidance tasks: papers/000's 1-D relaxed (29) and 3-D (28), and the whole-body pairs' one-sided rows.

1-D (29): ``J = n^T J_c``, command ``r`` (velocity level) or ``r - n^T Jdot_c qd`` (acceleration level); 3-D (28):
``J = J_c``, command ``r n`` or ``r n - Jdot_c qd`` (``J_c``, ``n``, ``r``: :meth:`Avoidance.assign`, every step)."""

from __future__ import annotations

import math

import numpy as np

from hqp_tpm.errors import ParameterError, ScenarioError, StateError
from hqp_tpm.robot import _compiled
from hqp_tpm.robot.state import State
from hqp_tpm.solvers.levels import MAX_SUMSQ, MIN_SUMSQ, Level, sumsq
from hqp_tpm.tasks import _compiled_rows
from hqp_tpm.tasks.base import AssignedTask


class Avoidance(AssignedTask):
    """Repulsion of one robot point along ``n`` (``dim=1``, eq. (29)) or in 3-D (``dim=3``, eq. (28))."""

    def __init__(self, name: str = "avoid", dim: int = 1):
        if dim not in (1, 3):
            raise ParameterError(f"avoidance dimension must be 1 (eq. (29)) or 3 (eq. (28)), got {dim!r}")
        self.dim = dim
        super().__init__(name, np.zeros(dim))
        self.assign(None, None, np.zeros(3), 0.0, np.zeros(3))

    def assign(self, J_c: np.ndarray, jdot_qdot_c: np.ndarray, normal: np.ndarray, magnitude: float,
               point: np.ndarray | None = None) -> None:
        """The pair of this step: point Jacobian (3 x n), its J-dot q-dot, unit direction, magnitude."""
        self._J_c, self._jdqd_c, self._pair = J_c, jdot_qdot_c, None
        self.normal = np.asarray(normal, dtype=float)
        self.magnitude = float(magnitude)
        if point is not None:
            self.point = np.asarray(point, dtype=float)

    def assign_pair(self, field, data, element: int, obstacle: int, normal: np.ndarray, magnitude: float) -> None:
        """:meth:`assign` of pair (element, obstacle) of a :class:`~hqp_tpm.geometry.distances.DistanceField`
        updated on ``data`` (its ``J_c`` and ``J̇_c q̇`` computed on first use)."""
        self.assign(None, None, normal, magnitude, field.p_robot[element, obstacle])
        self._pair = (field, data, element, obstacle)

    def _require(self):
        if self._J_c is None:
            if self._pair is None:
                raise StateError(f"avoidance task {self.name!r} used before assign(): no pair for this step")
            field, data, k, j = self._pair
            self._J_c, self._jdqd_c = field.jacobian(data, k, j), field.jdot_qdot(data, k, j)

    def value(self, state: State) -> np.ndarray:
        return self.point if self.dim == 3 else np.array([self.normal.dot(self.point)])

    def jacobian(self, state: State) -> np.ndarray:
        self._require()
        return self._J_c if self.dim == 3 else self.normal.dot(self._J_c).reshape(1, -1)

    def jdot_qdot(self, state: State) -> np.ndarray:
        self._require()
        return self._jdqd_c if self.dim == 3 else np.array([self.normal.dot(self._jdqd_c)])

    def command(self, state: State, t: float, order: int, extra=None, J=None) -> np.ndarray:
        r = self.magnitude * (self.normal if self.dim == 3 else np.ones(1))
        return r if order == 1 else r - self.jdot_qdot(state)

    def row_writer(self, state: State, order: int, J: np.ndarray, b: np.ndarray):
        """The planned step's ``write(t)``: :meth:`jacobian`, :meth:`command` of the pair assigned into ``J``, ``b``."""
        def write(t: float) -> None:
            pair = self._pair
            if self.dim == 1 and _compiled.ENABLED and pair is not None and self._J_c is None:
                pair[0].avoidance_row(pair[1], pair[2], pair[3], self.normal, self.magnitude, order, J, b)
            elif self.dim == 1 and _compiled.ENABLED:
                self._require()
                _compiled_rows.avoidance_row(J, b, self.normal, self._J_c, self._jdqd_c, self.magnitude, order)
            else:
                J[...] = self.jacobian(state)
                b[...] = self.command(state, t, order)
        return write


class PairAvoidance(AssignedTask):
    """Rows ``n_k^T J_k qd >= lower_k`` (1-D avoidance per pair, a one-sided inequality level), assigned by the
    whole-body policy every step."""

    dim = 0

    def __init__(self, name: str):
        super().__init__(name, None)
        self.assign(np.zeros((0, 0)), np.zeros(0), np.zeros(0))
        self._upper = np.zeros(0)  # +inf per row, read-only: every level's upper bound (one array per row count)

    def assign(self, J: np.ndarray, lower: np.ndarray, distance: np.ndarray) -> None:
        J = J if type(J) is np.ndarray and J.ndim == 2 else np.atleast_2d(J)
        self.J, self.lower, self.distance = J, np.asarray(lower, float), np.asarray(distance, float)
        self.dim = self.lower.size

    def value(self, state: State) -> np.ndarray:
        return self.distance

    def jacobian(self, state: State) -> np.ndarray:
        return self.J

    def jdot_qdot(self, state: State) -> np.ndarray:
        raise NotImplementedError("whole_body avoidance is velocity-level only")

    def reference(self, t: float):
        return np.zeros(self.dim), np.zeros(self.dim), np.zeros(self.dim)

    def level(self, state: State, t: float, order: int, extra=None) -> Level:
        if order != 1:
            raise ScenarioError("the whole_body policy works at velocity level only")
        return self.level_of(self.J, self.lower)

    def level_of(self, J: np.ndarray, lower: np.ndarray) -> Level:
        """The level of rows ``J qd >= lower`` (these rows, e.g. kept from an earlier step)."""
        if self._upper.size != lower.size:
            self._upper = np.full(lower.size, np.inf)
            self._upper.flags.writeable = False
        return Level(J, lower=lower, upper=self._upper, name=self.name, defer_finite=True)

    def rows_from(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """``(J_a, lower_a - J_a v)``: the rows with ``lower - J v > 0`` (``shifted(level, v).as_equality()`` in fewer
        calls); None if ``J`` or ``lower`` would fail the level's checks (that path raises the error)."""
        J = self.J
        if not MIN_SUMSQ <= sumsq(J) <= MAX_SUMSQ or math.isnan(sumsq(self.lower)):
            return None
        lower = self.lower - J @ v
        if lower.size and lower.min() > 0.0:  # every row kept (the usual case): J itself (NaN: below, not kept)
            return J, lower
        keep = lower > 0.0
        return J[keep], lower[keep]
