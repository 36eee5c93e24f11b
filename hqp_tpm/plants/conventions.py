"""The free-joint conventions of pinocchio and MuJoCo, converted here and nowhere else.

A floating base (pinocchio's ``JointModelFreeFlyer``, MuJoCo's ``free`` joint) is stored differently:

============  =====================================  ==============================================
quantity      pinocchio                              MuJoCo
============  =====================================  ==============================================
position      ``x y z  qx qy qz qw``                 ``x y z  qw qx qy qz``
velocity      ``v`` (body frame), ``w`` (body frame)  ``v`` (world frame), ``w`` (body frame)
force         ``f`` (body frame), ``n`` (body frame)  ``f`` (world frame), ``n`` (body frame)
============  =====================================  ==============================================

With ``R`` the base orientation, ``v_mj = R v_pin`` and, by duality (the power ``f . v`` is the same in
both), ``f_mj = R f_pin``. The acceleration follows from the velocity: ``d/dt (R v) = R (a + w x v)``.
"""

from __future__ import annotations

import numpy as np


def quat_xyzw_to_wxyz(q: np.ndarray) -> np.ndarray:
    return np.array([q[3], q[0], q[1], q[2]])


def quat_wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    return np.array([q[1], q[2], q[3], q[0]])


def rotation_xyzw(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``x, y, z, w`` (normalized first)."""
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def free_position_to_mujoco(q7: np.ndarray) -> np.ndarray:
    """pinocchio ``x y z qx qy qz qw`` -> MuJoCo ``x y z qw qx qy qz``."""
    return np.concatenate([q7[:3], quat_xyzw_to_wxyz(q7[3:7])])


def free_position_from_mujoco(qpos7: np.ndarray) -> np.ndarray:
    """MuJoCo ``x y z qw qx qy qz`` -> pinocchio ``x y z qx qy qz qw``."""
    return np.concatenate([qpos7[:3], quat_wxyz_to_xyzw(qpos7[3:7])])


def free_motion_to_mujoco(q7: np.ndarray, v6: np.ndarray) -> np.ndarray:
    """A pinocchio free-joint velocity (or force) at pinocchio position ``q7`` -> MuJoCo's: linear part to world."""
    return np.concatenate([rotation_xyzw(q7[3:7]) @ v6[:3], v6[3:6]])


def free_motion_from_mujoco(q7: np.ndarray, v6: np.ndarray) -> np.ndarray:
    """A MuJoCo free-joint velocity (or force) at pinocchio position ``q7`` -> pinocchio's: linear part to body."""
    return np.concatenate([rotation_xyzw(q7[3:7]).T @ v6[:3], v6[3:6]])


def free_acceleration_to_mujoco(q7: np.ndarray, v6: np.ndarray, a6: np.ndarray) -> np.ndarray:
    """pinocchio's ``a = dv/dt`` (body frame) -> MuJoCo's ``qacc``: ``d/dt (R v) = R (a + w x v)``."""
    return np.concatenate([rotation_xyzw(q7[3:7]) @ (a6[:3] + np.cross(v6[3:6], v6[:3])), a6[3:6]])
