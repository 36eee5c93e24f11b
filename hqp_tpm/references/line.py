"""A straight line from ``start`` to ``end`` with a trapezoidal velocity profile (papers/004, Sec. 4.3).

The planar examples of papers/004 move the end effector "along a straight line from P_1 to P_2" with "a
trapezoid velocity profile with an acceleration of 4 m s^-2 and a max. velocity of 0.4 m s^-1". The path
parameter ``s(t)`` (arc length) accelerates at ``a_max`` up to ``v_max``, cruises and brakes at ``a_max``
(a triangle when the line is too short to reach ``v_max``); before ``t_start`` and after the end the
reference holds still.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hqp_tpm.errors import ParameterError, ShapeError
from hqp_tpm.references.trajectories import Trajectory, _finite


@dataclass
class Line(Trajectory):
    """``x_d(t) = start + s(t) u`` (``u`` the unit direction), ``s`` trapezoidal in time."""

    start_point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    end_point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    v_max: float = 0.4
    a_max: float = 4.0
    t_start: float = 0.0

    def __post_init__(self):
        self.start_point = _finite(self.start_point, "line start")
        self.end_point = _finite(self.end_point, "line end")
        if self.start_point.shape != self.end_point.shape:
            raise ShapeError(f"line start and end must have one shape, got {self.start_point.shape} and "
                             f"{self.end_point.shape}")
        _finite([self.v_max, self.a_max, self.t_start], "v_max/a_max/t_start")
        if self.v_max <= 0 or self.a_max <= 0:
            raise ParameterError(f"line: v_max = {self.v_max!r} and a_max = {self.a_max!r} must be > 0")
        delta = self.end_point - self.start_point
        self.length = float(np.linalg.norm(delta))
        self.direction = delta / self.length if self.length > 0 else np.zeros_like(delta)
        v = min(self.v_max, math.sqrt(self.length * self.a_max))  # peak velocity (triangle if < v_max)
        self.v_peak = v
        self.t_acc = v / self.a_max
        self.t_cruise = (self.length - v * self.t_acc) / v if v > 0 else 0.0
        self.duration = 2 * self.t_acc + self.t_cruise

    def size(self) -> int | None:
        return self.start_point.size

    def profile(self, t: float) -> tuple[float, float, float]:
        """``(s, s_dot, s_ddot)`` at time ``t``."""
        a, v, ta, tc = self.a_max, self.v_peak, self.t_acc, self.t_cruise
        tau = t - self.t_start
        if tau <= 0 or self.length == 0:
            return 0.0, 0.0, 0.0
        if tau < ta:
            return 0.5 * a * tau * tau, a * tau, a
        if tau < ta + tc:
            return 0.5 * a * ta * ta + v * (tau - ta), v, 0.0
        if tau < self.duration:
            r = self.duration - tau
            return self.length - 0.5 * a * r * r, a * r, -a
        return self.length, 0.0, 0.0

    def reference(self, t: float):
        s, sd, sdd = self.profile(t)
        x = self.start_point + s * self.direction + self.offset(self.start_point.size)
        return x, sd * self.direction, sdd * self.direction
