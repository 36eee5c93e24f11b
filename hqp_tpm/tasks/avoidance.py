"""Collision avoidance tasks of papers/000: 1-D relaxed (29) and 3-D (28).

The avoided pair (robot point, obstacle) changes from step to step, so the policy that owns
the distance field calls :meth:`Avoidance.assign` each step with the witness point's
Jacobian ``J_c``, its ``Jdot_c qd``, the repulsion direction ``n`` and magnitude ``r``:

* 1-D (29): ``J_n = n^T J_c``, command ``r - n^T Jdot_c qd`` (acceleration level) or ``r``
  (velocity level): push the point towards any point of a plane orthogonal to ``n``.
* 3-D (28): ``J_c``, command ``r n - Jdot_c qd`` (or ``r n``).
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.errors import ParameterError, StateError
from hqp_tpm.robot.state import State
from hqp_tpm.solvers.levels import Level
from hqp_tpm.tasks.base import Task


class Avoidance(Task):
    """Repulsion of one robot point along ``n`` (``dim=1``, eq. (29)) or in 3-D (``dim=3``, eq. (28))."""

    def __init__(self, name: str = "avoid", dim: int = 1):
        if dim not in (1, 3):
            raise ParameterError(f"avoidance dimension must be 1 (eq. (29)) or 3 (eq. (28)), got {dim!r}")
        self.dim = dim
        super().__init__(name, np.zeros(dim))
        self._J_c = None
        self._jdqd_c = None
        self.normal = np.zeros(3)
        self.magnitude = 0.0
        self.point = np.zeros(3)

    def assign(self, J_c: np.ndarray, jdot_qdot_c: np.ndarray, normal: np.ndarray, magnitude: float,
               point: np.ndarray | None = None) -> None:
        """The pair of this step: point Jacobian (3 x n), its J-dot q-dot, unit direction, magnitude."""
        self._J_c, self._jdqd_c = J_c, jdot_qdot_c
        self.normal = np.asarray(normal, dtype=float)
        self.magnitude = float(magnitude)
        if point is not None:
            self.point = np.asarray(point, dtype=float)

    def _require(self):
        if self._J_c is None:
            raise StateError(f"avoidance task {self.name!r} used before assign(): no pair for this step")

    def value(self, state: State) -> np.ndarray:
        return self.point if self.dim == 3 else np.array([self.normal.dot(self.point)])

    def jacobian(self, state: State) -> np.ndarray:
        self._require()
        return self._J_c if self.dim == 3 else self.normal.dot(self._J_c).reshape(1, -1)

    def jdot_qdot(self, state: State) -> np.ndarray:
        self._require()
        return self._jdqd_c if self.dim == 3 else np.array([self.normal.dot(self._jdqd_c)])

    def start(self, state: State) -> None:  # no target to initialise
        return None

    def error(self, state: State, x_d) -> np.ndarray:
        return np.zeros(self.dim)

    def command(self, state: State, t: float, order: int, extra=None) -> np.ndarray:
        r = self.magnitude * (self.normal if self.dim == 3 else np.ones(1))
        return r if order == 1 else r - self.jdot_qdot(state)

    def level(self, state: State, t: float, order: int, extra=None) -> Level:
        return Level(self.jacobian(state), self.command(state, t, order), name=self.name, defer_finite=True)
