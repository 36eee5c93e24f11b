"""Small 3-D vector helpers on Python floats: numpy's IEEE products and sums without its per-call overhead (numpy's
general versions cost ~10x more at this size). Details: docs/internals.md#spatial."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

_EZ = np.array([0.0, 0.0, 1.0])
_HALF_TURN_X = np.array([1.0, -1.0, -1.0])  # columns of R @ diag(1, -1, -1)


def cross3(a, b) -> tuple[float, float, float]:
    """Cross product of two 3-sequences of floats."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors."""
    return np.array(cross3(a.tolist(), b.tolist()))


def rotation_z_to(axis) -> np.ndarray:
    """A rotation whose z column is ``axis/|axis|`` (``pin.Quaternion.FromTwoVectors``; an axis pointing down as the
    rotation to ``-axis`` and a half turn about x: ``FromTwoVectors`` loses accuracy near opposite vectors)."""
    a = np.asarray(axis, dtype=float)
    if a[2] >= 0.0:
        return pin.Quaternion.FromTwoVectors(_EZ, a).matrix()
    return pin.Quaternion.FromTwoVectors(_EZ, -a).matrix() * _HALF_TURN_X
