"""Repulsive vectors of the relaxed collision-avoidance task, papers/000 Sec. III-B, eqs. (23)-(27).

Magnitude (authors' code form of (23)): ``r(d) = v_max / (1 + exp(gamma (d c / rho - 1)))``.
The paper prints (23) as ``exp((D/(2/rho) - 1) gamma)``; its limits (24) (``r -> r_max`` at ``D = 0``,
``r -> 0`` at ``D = rho`` for ``gamma -> inf``) only hold for ``D/(rho/2)``, i.e. ``c = 2`` here.

Direction: the unit normal (obstacle -> element) of the nearest obstacle in the surveillance area
(``"nearest"``, the authors' code), or the normalised mean of the unit normals of all obstacles in
the surveillance area, eqs. (25)-(26) (``"mean"``). The vector is ``r * r_hat``, eq. (27).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hqp_tpm.errors import NonFiniteError, ShapeError, unknown_name
from hqp_tpm.geometry.obstacles import checked_scalar

__all__ = ["DIRECTIONS", "Repulsion", "nearest_element", "repulsion_direction", "repulsion_magnitude"]

#: Valid values of ``direction``.
DIRECTIONS = ("nearest", "mean")

#: Below this norm the mean direction (25) is treated as cancelled and the nearest one is used.
MEAN_TOL = 1e-9

#: Largest argument of ``exp`` with a finite result; above it ``exp`` overflows to ``+inf`` (and r = 0).
_EXP_MAX = float(np.log(np.finfo(float).max))


def repulsion_magnitude(d, v_max: float, rho: float, gamma: float, c: float = 2.0) -> np.ndarray:
    """Eq. (23) with factor ``c`` (``c = 2``: the paper): ``v_max / (1 + exp(gamma (d c / rho - 1)))``.

    Vectorised over ``d``; ``d = +inf`` gives 0, negative ``d`` (penetration) tends to ``v_max``.
    """
    if isinstance(d, float):  # one distance (Algorithm 1): the same operations on floats
        x = gamma * (d * (c / rho) - 1.0)
        return 0.0 if x > _EXP_MAX else v_max / (1.0 + float(np.exp(x)))
    x = gamma * (np.asarray(d, dtype=float) * (c / rho) - 1.0)
    return v_max / (1.0 + np.exp(np.where(x > _EXP_MAX, np.inf, x)))  # exp(inf) = inf, no overflow warning


def _check_pairs(distance, normal, in_range):
    D = np.asarray(distance, dtype=float)
    N = np.asarray(normal, dtype=float)
    if D.ndim != 2 or N.shape != D.shape + (3,):
        raise ShapeError(f"distance must be (M, H) and normal (M, H, 3), got {D.shape} and {N.shape}")
    mask = np.isfinite(D) if in_range is None else np.asarray(in_range, dtype=bool)
    if mask.shape != D.shape:
        raise ShapeError(f"in_range must have the shape of distance {D.shape}, got {mask.shape}")
    if np.isnan(D[mask]).any():
        raise NonFiniteError("distance holds NaN for pairs in range")
    return D, N, mask


def repulsion_direction(distance, normal, in_range=None, direction: str = "nearest",
                        surveillance: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit repulsion directions per element over the obstacles in range.

    ``distance`` (M, H), ``normal`` (M, H, 3) unit vectors obstacle -> element, ``in_range`` (M, H)
    mask (default: finite distances), further restricted to ``distance <= surveillance`` if given.
    Returns ``(d_min, nearest, r_hat)``: D_min per element (22) (inf if none in range), index of the
    nearest obstacle (-1 if none) and the unit direction (M, 3) — the nearest normal, or (25)-(26) for
    ``"mean"`` (falling back to the nearest normal if the mean cancels) — zero where nothing is in range.
    """
    if direction not in DIRECTIONS:
        raise unknown_name("direction", direction, DIRECTIONS)
    D, N, mask = _check_pairs(distance, normal, in_range)
    if surveillance is not None:
        mask = mask & (D <= surveillance)
    M, H = D.shape
    Dm = np.where(mask, D, np.inf)
    if H == 0:
        return np.full(M, np.inf), np.full(M, -1, dtype=int), np.zeros((M, 3))
    nearest = np.argmin(Dm, axis=1)
    rows = np.arange(M)
    d_min = Dm[rows, nearest]
    has = np.isfinite(d_min)
    nearest = np.where(has, nearest, -1)
    r_hat = np.where(has[:, None], N[rows, np.maximum(nearest, 0)], 0.0)
    if direction == "mean":
        count = mask.sum(axis=1)
        r_mean = np.where(mask[..., None], N, 0.0).sum(axis=1) / np.maximum(count, 1)[:, None]  # (25)
        norm = np.linalg.norm(r_mean, axis=1)
        use = has & (norm > MEAN_TOL)
        r_hat = np.where(use[:, None], r_mean / np.where(use, norm, 1.0)[:, None], r_hat)  # (26)
    return d_min, nearest, r_hat


def nearest_element(distance: np.ndarray, normal: np.ndarray, in_range: np.ndarray, direction: str = "nearest",
                    surveillance: float | None = None) -> tuple[int, int, float, np.ndarray | None]:
    """The element nearest to an obstacle in range, D_minimal (31), and its unit repulsion direction.

    Row ``k`` of :func:`repulsion_direction` for the element ``k`` of smallest ``d_min`` (the first one
    on ties), computed for that element only and without validation: for the arrays of a
    :class:`~hqp_tpm.geometry.distances.DistanceField` (finite or ``+inf`` distances). Returns
    ``(k, j, d, r_hat)`` with ``j`` its nearest obstacle, or ``(-1, -1, inf, None)`` if no pair is in range.
    """
    mask = in_range if surveillance is None else in_range & (distance <= surveillance)
    Dm = np.where(mask, distance, np.inf)
    if Dm.size == 0:
        return -1, -1, np.inf, None
    k, j = divmod(int(Dm.argmin()), Dm.shape[1])  # row-major: the first minimal element, then obstacle
    d = float(Dm[k, j])
    if d == np.inf:
        return -1, -1, np.inf, None
    if direction == "mean":
        row = mask[k]
        r_mean = np.where(row[:, None], normal[k], 0.0).sum(axis=0) / max(int(row.sum()), 1)  # (25)
        norm = np.sqrt((r_mean * r_mean).sum())
        if norm > MEAN_TOL:
            return k, j, d, r_mean / norm  # (26)
    return k, j, d, normal[k, j].copy()


@dataclass(frozen=True)
class Repulsion:
    """Parameters of the sigmoid repulsion (23): maximum ``v_max``, range ``rho``, shape ``gamma``, factor ``c``.

    Reference values (lwr_relaxed): EE ``Repulsion(5.0, 0.1, 10.0, 1.5)``, body ``Repulsion(0.15, 0.15, 2.0, 3.0)``.
    """

    v_max: float
    rho: float
    gamma: float
    c: float = 2.0

    def __post_init__(self):
        for name in ("v_max", "rho", "gamma", "c"):
            x = checked_scalar(f"Repulsion.{name}", getattr(self, name), strict=name != "v_max")
            object.__setattr__(self, name, x)

    def magnitude(self, d) -> np.ndarray:
        """Eq. (23) (with factor ``c``), vectorised over ``d``."""
        return repulsion_magnitude(d, self.v_max, self.rho, self.gamma, self.c)

    def vectors(self, distance, normal, in_range=None, direction: str = "nearest",
                surveillance: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Repulsive vectors (27) per element from (M, H) pair arrays (e.g. a DistanceField's).

        Returns ``(magnitude (M,), r_hat (M, 3), d_min (M,), nearest (M,))``; the magnitude uses the
        nearest obstacle's distance (22), the direction follows ``direction`` (see
        :func:`repulsion_direction`); both are zero for elements with no obstacle in range.
        The vector of element ``k`` is ``magnitude[k] * r_hat[k]``.
        """
        d_min, nearest, r_hat = repulsion_direction(distance, normal, in_range, direction, surveillance)
        mag = np.where(np.isfinite(d_min), self.magnitude(np.where(np.isfinite(d_min), d_min, 0.0)), 0.0)
        return mag, r_hat, d_min, nearest
