"""What a distance-field update records: per pair distance, witness points, normal, in range, computed.

Preallocated once (the field's update writes into them in place); ``clear`` resets the entries of
pairs that an update may not reach (culled by the broad phase): ``+inf`` distance, NaN points, zero normal.
``last_normal`` keeps the previous normal of every pair (fallback for coinciding witness points).
"""

from __future__ import annotations

import numpy as np

__all__ = ["PairRecord", "SelfPairRecord"]


class PairRecord:
    """Robot element x obstacle results: arrays of shape (M, H) or (M, H, 3)."""

    __slots__ = ("distance", "p_robot", "p_obstacle", "normal", "in_range", "computed", "last_normal")

    def __init__(self, n_elements: int, n_obstacles: int):
        M, H = n_elements, n_obstacles
        self.distance = np.full((M, H), np.inf)
        self.p_robot = np.full((M, H, 3), np.nan)
        self.p_obstacle = np.full((M, H, 3), np.nan)
        self.normal = np.zeros((M, H, 3))
        self.in_range = np.zeros((M, H), dtype=bool)
        self.computed = np.zeros((M, H), dtype=bool)
        self.last_normal = np.zeros((M, H, 3))

    def clear(self) -> None:
        self.distance.fill(np.inf)
        self.p_robot.fill(np.nan)
        self.p_obstacle.fill(np.nan)
        self.normal.fill(0.0)
        self.computed.fill(False)


class SelfPairRecord:
    """Self-pair results: arrays of shape (S,) or (S, 3); ``p1``/``p2`` on the first/second geometry."""

    __slots__ = ("distance", "p1", "p2", "normal", "in_range", "computed", "last_normal")

    def __init__(self, n_pairs: int):
        S = n_pairs
        self.distance = np.full(S, np.inf)
        self.p1 = np.full((S, 3), np.nan)
        self.p2 = np.full((S, 3), np.nan)
        self.normal = np.zeros((S, 3))
        self.in_range = np.zeros(S, dtype=bool)
        self.computed = np.zeros(S, dtype=bool)
        self.last_normal = np.zeros((S, 3))

    def clear(self) -> None:
        self.distance.fill(np.inf)
        self.p1.fill(np.nan)
        self.p2.fill(np.nan)
        self.normal.fill(0.0)
        self.computed.fill(False)
