"""Small 3-D vector helpers (numpy's general versions cost ~10x more at this size).

They work on Python floats (``ndarray.tolist()``): the same IEEE products and sums as numpy's
elementwise operations, without numpy's per-call overhead on 3-vectors. For the same reason the
per-step matrix-vector products are written ``A.dot(x)``: the same BLAS call as ``A @ x`` (equal
to the last bit, tested) at about a third of its call overhead.
"""

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
    """A rotation whose z column is ``axis/|axis|`` (``pin.Quaternion.FromTwoVectors``).

    ``FromTwoVectors`` loses accuracy for nearly opposite vectors (1e-6 at 1e-5 rad from -z), so an axis
    pointing down is handled as the rotation to ``-axis`` followed by a half turn about x.
    """
    a = np.asarray(axis, dtype=float)
    if a[2] >= 0.0:
        return pin.Quaternion.FromTwoVectors(_EZ, a).matrix()
    return pin.Quaternion.FromTwoVectors(_EZ, -a).matrix() * _HALF_TURN_X
