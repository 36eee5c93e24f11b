"""Discrete dynamic movement primitives with an obstacle-avoidance coupling term, papers/004 Sec. 6, eqs. (44)-(54).

Per degree of freedom (44)-(48), with one canonical system for all of them:

    tau zd = alpha_z (beta_z (g - y) - z) + f(x) + C_t      (44), (54)
    tau yd = z                                               (45)
    f(x) = sum_i w_i Psi_i(x) / sum_i Psi_i(x) * x,  Psi_i(x) = exp(-h_i (x - c_i)^2)     (46)-(47)
    tau xd = -alpha_x x,  x(0) = 1                           (48)

``alpha_z = 4 beta_z`` (critically damped). The weights are learned from a demonstration by locally weighted
regression (Ijspeert et al. 2013, the paper's [57]): ``f_target = tau^2 ydd - alpha_z (beta_z (g - y) - tau yd)``,
``w_i = sum Psi_i x f_target / sum Psi_i x^2``.

Coupling term (49)-(53), 3-D, for a point obstacle ``o``:

    C_t = gamma sig(||o - y||) R yd (pi - phi) exp(-beta phi),   phi = angle between o - y and yd   (49)-(50)
    sig(r) = 1 / (1 + exp(eta (r - d)))                                                             (51)
    R = exp((pi/2 - phi) n^),  n = (o - y) x yd                                                     (52)-(53)

``R`` rotates ``yd`` about ``n`` by ``pi/2 - phi``, so ``R yd`` is orthogonal to ``o - y``, in the plane of ``o - y``
and ``yd``, pointing away from the obstacle's side -- as the text says. (53) as printed divides ``n`` by
``||o - y|| ||yd||``, which leaves it of norm ``sin phi``; as the axis of the exponential (52) it must be a unit
vector for ``R yd`` to be orthogonal to ``o - y``, so it is normalised here (``n^``). ``C_t = 0`` if ``yd = 0``
or ``o - y`` and ``yd`` are parallel (no plane; ``phi = 0`` head-on or ``pi``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import NonFiniteError, ShapeError
from hqp_tpm.references.trajectories import Trajectory

_TINY = 1e-12


@dataclass(frozen=True)
class Coupling:
    """Obstacle-avoidance coupling (49)-(53): gains ``gamma``, ``beta``, ``eta`` and the influence distance ``d``."""

    gamma: float = 1000.0
    beta: float = 20.0 / math.pi
    eta: float = 50.0
    d: float = 0.15

    def __call__(self, y, yd, o) -> np.ndarray:
        """``C_t`` for position ``y``, velocity ``yd`` (3-D) and a point obstacle ``o``."""
        y, yd, o = (np.asarray(v, dtype=float) for v in (y, yd, o))
        if y.shape != (3,) or yd.shape != (3,) or o.shape != (3,):
            raise ShapeError(f"coupling term (49) is 3-D: got y {y.shape}, yd {yd.shape}, o {o.shape}")
        r = o - y
        nr, nv = float(np.linalg.norm(r)), float(np.linalg.norm(yd))
        if nr < _TINY or nv < _TINY:
            return np.zeros(3)
        phi = math.acos(max(-1.0, min(1.0, float(r @ yd) / (nr * nv))))  # (50)
        n = np.cross(r, yd)
        nn = float(np.linalg.norm(n))
        if nn < _TINY * nr * nv:
            return np.zeros(3)
        R = pin.exp3((math.pi / 2 - phi) * n / nn)  # (52), unit axis
        x = self.eta * (nr - self.d)
        sig = 0.0 if x > 700 else 1.0 / (1.0 + math.exp(x))  # (51)
        return self.gamma * sig * (R @ yd) * (math.pi - phi) * math.exp(-self.beta * phi)  # (49)


@dataclass
class DMP:
    """A discrete DMP of ``dim`` degrees of freedom with ``n_basis`` radial basis functions."""

    dim: int
    n_basis: int = 30
    alpha_z: float = 48.0
    alpha_x: float = 2.0
    tau: float = 1.0
    weights: np.ndarray = field(default=None)
    goal: np.ndarray = field(default=None)
    start: np.ndarray = field(default=None)

    def __post_init__(self):
        self.beta_z = self.alpha_z / 4.0  # critically damped
        self.centers = np.exp(-self.alpha_x * np.linspace(0, 1, self.n_basis))  # c_i along the phase
        diff = np.diff(self.centers)
        self.widths = 1.0 / np.r_[diff, diff[-1]] ** 2  # h_i
        if self.weights is None:
            self.weights = np.zeros((self.dim, self.n_basis))

    def forcing(self, x: float) -> np.ndarray:
        """``f(x)`` (46)-(47)."""
        psi = np.exp(-self.widths * (x - self.centers) ** 2)
        return self.weights @ psi / max(psi.sum(), _TINY) * x

    @classmethod
    def learn(cls, t: np.ndarray, y: np.ndarray, **kw) -> DMP:
        """Fit to a demonstration ``y`` (T x dim) sampled at times ``t`` (tau = its duration)."""
        t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
        if y.ndim != 2 or y.shape[0] != t.size or t.size < 3:
            raise ShapeError(f"demonstration: y must be (T, dim) with T = len(t) >= 3, got {y.shape} and {t.shape}")
        if not (np.isfinite(t).all() and np.isfinite(y).all()):
            raise NonFiniteError("demonstration holds non-finite values")
        dmp = cls(y.shape[1], tau=float(t[-1] - t[0]), **kw)
        dmp.start, dmp.goal = y[0].copy(), y[-1].copy()
        yd = np.gradient(y, t, axis=0)
        ydd = np.gradient(yd, t, axis=0)
        tau = dmp.tau
        x = np.exp(-dmp.alpha_x * (t - t[0]) / tau)  # solution of (48)
        f = tau**2 * ydd - dmp.alpha_z * (dmp.beta_z * (dmp.goal - y) - tau * yd)
        psi = np.exp(-dmp.widths[None, :] * (x[:, None] - dmp.centers[None, :]) ** 2)  # (T, N)
        for k in range(dmp.dim):  # locally weighted regression per basis function
            dmp.weights[k] = (psi * (x * f[:, k])[:, None]).sum(0) / np.maximum((psi * (x**2)[:, None]).sum(0), _TINY)
        return dmp

    def rollout(self, dt: float, duration: float | None = None, obstacles=(), coupling: Coupling | None = None,
                goal=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Euler integration of (44)/(54), (45), (48); returns ``(t, y, yd, C_t)`` (C_t summed over the obstacles)."""
        g = self.goal if goal is None else np.asarray(goal, dtype=float)
        steps = int(round((duration if duration is not None else 1.5 * self.tau) / dt)) + 1
        y, z, x = self.start.astype(float).copy(), np.zeros(self.dim), 1.0
        T = np.zeros(steps)
        Y, V, C = (np.zeros((steps, self.dim)) for _ in range(3))
        for k in range(steps):
            yd = z / self.tau
            c = np.zeros(self.dim)
            if coupling is not None:
                for o in obstacles:
                    c = c + coupling(y, yd, o)
            T[k], Y[k], V[k], C[k] = k * dt, y, yd, c
            zd = (self.alpha_z * (self.beta_z * (g - y) - z) + self.forcing(x) + c) / self.tau  # (54)
            y = y + yd * dt
            z = z + zd * dt
            x = x - self.alpha_x * x / self.tau * dt  # (48)
        return T, Y, V, C


class DmpTrajectory(Trajectory):
    """A task target generated by a DMP (Sec. 6.3): a minimum-jerk demonstration from the start value to ``end``
    (relative to it) in ``tau`` seconds, learned (44)-(48), rolled out with the coupling (54) to point obstacles
    ``obstacles`` (3-D; a 2-D task is the x-y plane); ``reference(t)`` interpolates the rollout (step ``dt``).
    The DMP runs open loop on its own state (no feedback from the robot)."""

    def __init__(self, end, tau: float, obstacles=(), coupling: Coupling | None = None, dt: float = 0.001,
                 horizon: float | None = None):
        super().__init__(relative=True)
        self.end = np.atleast_1d(np.asarray(end, dtype=float))
        if self.end.size not in (2, 3) or not np.isfinite(self.end).all():
            raise ShapeError(f"dmp target: end must be 2 or 3 finite numbers, got {self.end.tolist()}")
        if not (np.isfinite(tau) and tau > 0 and np.isfinite(dt) and dt > 0):
            raise NonFiniteError(f"dmp target: tau = {tau!r} and dt = {dt!r} must be finite and > 0")
        self.tau, self.dt = float(tau), float(dt)
        self.horizon = float(horizon) if horizon is not None else 3.0 * self.tau
        self.obstacles = [np.asarray(o, dtype=float) for o in obstacles]
        if any(o.shape != (3,) for o in self.obstacles):
            raise ShapeError("dmp target: obstacles are 3-D points")
        self.coupling = coupling
        self._roll = None

    def size(self) -> int | None:
        return self.end.size

    def start(self, x0: np.ndarray) -> None:
        super().start(x0)
        dim = self.end.size
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (dim,):
            raise ShapeError(f"dmp target: the task value has shape {x0.shape}, end has {dim} entries")
        t = np.linspace(0.0, self.tau, int(round(self.tau / self.dt)) + 1)
        s = t / self.tau
        s = 10 * s**3 - 15 * s**4 + 6 * s**5
        p0 = np.r_[x0, np.zeros(3 - dim)]
        demo = p0 + s[:, None] * np.r_[self.end, np.zeros(3 - dim)][None, :]
        self.dmp = DMP.learn(t, demo)
        T, Y, V, C = self.dmp.rollout(self.dt, self.horizon, self.obstacles, self.coupling)
        A = np.gradient(V, self.dt, axis=0)
        self._roll = (T, Y[:, :dim], V[:, :dim], A[:, :dim], C[:, :dim])

    def reference(self, t: float):
        if self._roll is None:
            raise self.unstarted()
        T, Y, V, A, _ = self._roll
        k = min(max(t / self.dt, 0.0), T.size - 1.0)
        i = min(int(k), T.size - 2)
        a = k - i
        return tuple((1 - a) * M[i] + a * M[i + 1] for M in (Y, V, A))
