"""Algorithm 1 of papers/000: priority assignment with thresholds eps1, eps2, eps_ee.

As coded by the authors (docs/setups.md, 'Priority assignment'):

1. Stack = [EE position], its command plus the EE repulsion (30) while ``d_ee <= eps_ee``.
2. If a critical body point exists (the nearest within ``eps2``) and ``d <= eps1``: its
   avoidance task goes above the EE task when ``d <= d_ee`` (``d_ee`` counts as
   ``d_ee_default`` = 0.11 when no obstacle is within ``eps_ee``), else right below it.
3. If the pointing task is active (equality: always; inequality (21): ``e > 0``): append it.
4. If the critical point exists and was not placed in step 2: append its task last.

The policy owns the distance field (:class:`~hqp_tpm.control.policy.DistancePolicy`: updated once per
step after the state update); ``probe`` records ``d_minimal``, ``d_ee`` and ``active_point``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hqp_tpm.control.policy import DistancePolicy, PlanningPolicy, SceneItems
from hqp_tpm.errors import ParameterError, unknown_name
from hqp_tpm.geometry import _compiled as _kernels
from hqp_tpm.geometry.distances import DistanceField
from hqp_tpm.geometry.obstacles import Obstacle
from hqp_tpm.geometry.repulsion import DIRECTIONS, Repulsion, nearest_element
from hqp_tpm.robot import _compiled
from hqp_tpm.robot.state import State
from hqp_tpm.tasks import Pointing
from hqp_tpm.tasks.avoidance import Avoidance
from hqp_tpm.tasks.base import Task


@dataclass(frozen=True)
class Thresholds:
    """Danger thresholds of Algorithm 1 (m)."""

    eps1: float = 0.05
    eps2: float = 0.15
    eps_ee: float = 0.1
    d_ee_default: float = 0.11

    def __post_init__(self):
        if not (0 < self.eps1 < self.eps2):
            raise ParameterError(f"thresholds must satisfy 0 < eps1 < eps2, got eps1={self.eps1}, eps2={self.eps2}")
        if self.eps_ee <= 0:
            raise ParameterError(f"eps_ee must be > 0, got {self.eps_ee}")


#: Reference values of the authors' code (docs/setups.md): EE and body repulsion, eq. (23) with factor c.
EE_REPULSION = Repulsion(5.0, 0.1, 10.0, 1.5)
BODY_REPULSION = Repulsion(0.15, 0.15, 2.0, 3.0)
DEFAULT_THRESHOLDS = Thresholds()


class Algorithm1(DistancePolicy, PlanningPolicy):
    """Dynamic stack of papers/000 for an EE position task, a pointing task and body avoidance."""

    channels = ("d_minimal", "d_ee", "active_point")

    def __init__(self, robot, ee_task: Task, pointing: Pointing | None, control_points: list[str], ee_frame: str,
                 obstacles: list[Obstacle], *, thresholds: Thresholds = DEFAULT_THRESHOLDS,
                 ee_repulsion: Repulsion = EE_REPULSION, body_repulsion: Repulsion = BODY_REPULSION,
                 avoidance_dim: int = 1, direction: str = "nearest", record_range: float = 0.5):
        self.robot = robot
        self.ee_task = ee_task
        self.pointing = pointing
        self.th = thresholds
        self.ee_repulsion = ee_repulsion
        self.body_repulsion = body_repulsion
        self.direction = direction
        self.obstacles = list(obstacles)
        self.control_points = list(control_points)
        self.ee_frame = ee_frame
        self.field = DistanceField(robot.model, None, [*control_points, ee_frame], self.obstacles,
                                   surveillance=max(record_range, thresholds.eps2, thresholds.eps_ee))
        if direction not in DIRECTIONS:
            raise unknown_name("direction", direction, DIRECTIONS)
        self.body = slice(0, len(control_points))  # field rows: the control points, then the EE frame
        self.ee_index = len(control_points)
        self.ee = slice(self.ee_index, self.ee_index + 1)
        self.avoid = Avoidance("avoid", avoidance_dim)
        self.thresholds = {"d_minimal": {"eps1": thresholds.eps1, "eps2": thresholds.eps2},
                           "d_ee": {"eps_ee": thresholds.eps_ee}}
        self._last: dict = {}

    # hooks ---------------------------------------------------------------------------------
    def tasks(self) -> list[Task]:
        """The EE task, the pointing task (if any) and the avoidance task: every task :meth:`plan` may stack (what
        the controller starts and ``--explain``/``hqp-tpm explain`` account for)."""
        return [t for t in (self.ee_task, self.pointing, self.avoid) if t is not None]

    def scene(self) -> SceneItems:
        return SceneItems(self.obstacles, self.control_points, self.ee_frame, self.ee_task, self.pointing, self.field)

    # the algorithm -------------------------------------------------------------------------
    def plan(self, state: State, t: float) -> tuple[tuple[Task, ...], dict[str, np.ndarray]]:
        """This step's stack as its tasks, one per level (highest first), and the extra commands by task
        name: what ``__call__`` wraps in a :class:`Stack` and the lean step (:mod:`~hqp_tpm.control._planned_step`)
        writes as rows."""
        f, th = self.field, self.th
        # EE control point: repulsion added to the EE command (30) while d_ee <= eps_ee; the obstacle of
        # largest magnitude is the nearest, direction (p_ee - o)/||p_ee - o||
        # critical body point: largest repulsion magnitude = nearest within eps2 (31)
        _, d_ee, n_ee, k, j, d_minimal, r_hat = self._nearest()
        extras = {}
        if d_ee <= th.eps_ee:
            extras[self.ee_task.name] = self.ee_repulsion.magnitude(d_ee) * n_ee
        critical = k >= 0
        levels: list[Task] = [self.ee_task]
        placed = False
        if critical:
            self.avoid.assign_pair(f, state.data, k, j, r_hat, self.body_repulsion.magnitude(d_minimal))
            if d_minimal <= th.eps1:
                d_ee_eff = d_ee if d_ee <= th.eps_ee else th.d_ee_default
                levels.insert(0 if d_minimal <= d_ee_eff else 1, self.avoid)
                placed = True
        if self.pointing is not None and self.pointing.is_active(state):
            levels.append(self.pointing)
        if critical and not placed:
            levels.append(self.avoid)
        self._last = {"d_minimal": d_minimal, "d_ee": d_ee, "active_point": k}
        return tuple(levels), extras

    def _nearest(self):
        """``(j_ee, d_ee, n_ee, k, j, d_minimal, r_hat)``: :func:`nearest_element` of the EE row and of the body rows
        (within eps2), from one masked copy of the distances for the ``"nearest"`` direction (same choices:
        the first minimum in row-major order, tests/test_algorithm1.py)."""
        f, th = self.field, self.th
        if self.direction != "nearest" or f.distance.shape[1] == 0:
            j_ee, _, d_ee, n_ee = nearest_element(f.distance[self.ee], f.normal[self.ee], f.in_range[self.ee])
            k, j, d_minimal, r_hat = nearest_element(f.distance[self.body], f.normal[self.body],
                                                     f.in_range[self.body], self.direction, th.eps2)
            return j_ee, d_ee, n_ee, k, j, d_minimal, r_hat
        if _compiled.ENABLED:  # one compiled call, the same choices
            j_ee, d_ee, k, j, d_minimal = _kernels.nearest_pairs(f.distance, f.in_range, self.ee_index, th.eps2)
            n_ee = None if j_ee < 0 else f.normal[self.ee_index, j_ee].copy()
            r_hat = None if k < 0 else f.normal[k, j].copy()
            return j_ee, d_ee, n_ee, k, j, d_minimal, r_hat
        H = f.distance.shape[1]
        Dm = np.where(f.in_range, f.distance, np.inf)
        row = Dm[self.ee_index]
        j_ee = int(row.argmin())
        d_ee = float(row[j_ee])
        if d_ee == np.inf:
            j_ee, d_ee, n_ee = -1, np.inf, None
        else:
            n_ee = f.normal[self.ee_index, j_ee].copy()
        k, j, d_minimal, r_hat = -1, -1, np.inf, None
        if self.ee_index:
            k, j = divmod(int(Dm[: self.ee_index].argmin()), H)
            d_minimal = float(Dm[k, j])
            if d_minimal > th.eps2:  # also +inf: nothing in range
                k, j, d_minimal = -1, -1, np.inf
            else:
                r_hat = f.normal[k, j].copy()
        return j_ee, d_ee, n_ee, k, j, d_minimal, r_hat

    def probe(self, ctrl, res) -> dict:
        """Per-step record: D_minimal (31) and D_min(p_ee) (NaN when nothing in range), critical point."""
        f = self.field
        body = np.where(f.in_range[self.body], f.distance[self.body], np.inf)
        d_min_body = float(body.min()) if body.size else np.inf
        ee = np.where(f.in_range[self.ee_index], f.distance[self.ee_index], np.inf)
        d_ee = float(ee.min()) if ee.size else np.inf
        return {"d_minimal": d_min_body if np.isfinite(d_min_body) else np.nan,
                "d_ee": d_ee if np.isfinite(d_ee) else np.nan,
                "active_point": float(self._last.get("active_point", -1))}
