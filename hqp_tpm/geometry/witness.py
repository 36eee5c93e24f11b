"""Witness-point kinematics, papers/000 eqs. (28)-(29): ``J_c`` and ``J̇_c q̇`` of a point rigidly attached to a joint.

The avoidance rows use them at the robot witness point of a pair (:class:`~hqp_tpm.geometry.distances.DistanceField`
gives the point, the joint is the element's parent joint).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.robot.spatial import cross, cross3

__all__ = ["point_jacobian", "point_jdot_qdot"]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def point_jacobian(model: pin.Model, data: pin.Data, joint_id: int, p_world) -> np.ndarray:
    """3 x nv world-aligned Jacobian ``J_c`` (28) of the point currently at ``p_world``, fixed to ``joint_id``.

    Needs ``data.J`` and ``data.oMi``: run ``pin.computeJointJacobians(model, data, q)`` first.
    ``J_c = J_v - [r]x J_w`` with ``r = p_world - o_joint`` and ``J`` the joint's LOCAL_WORLD_ALIGNED Jacobian.
    """
    J = pin.getJointJacobian(model, data, int(joint_id), _LWA)
    r = np.asarray(p_world, dtype=float) - data.oMi[int(joint_id)].translation
    return J[:3] - pin.skew(r).dot(J[3:])


def point_jdot_qdot(model: pin.Model, data: pin.Data, joint_id: int, p_world) -> np.ndarray:
    """``J̇_c q̇`` (world frame) of the point currently at ``p_world``, fixed to ``joint_id`` (used in (29)).

    It is the classical acceleration of that point at zero joint acceleration. Needs ``data.oMi``,
    ``data.v`` and ``data.a`` from ``pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))``
    (``data.a`` must come from a zero ``q̈``; algorithms that overwrite ``data.a`` afterwards break this).
    """
    jid = int(joint_id)
    M = data.oMi[jid]
    R = M.rotation
    v = data.v[jid].vector  # local (linear, angular)
    a = data.a[jid].vector
    w_l = v[3:]
    a_o = R.dot(a[:3] + cross(w_l, v[:3])).tolist()  # classical acceleration of the joint origin
    alpha = R.dot(a[3:]).tolist()
    w = R.dot(w_l).tolist()
    r = (np.asarray(p_world, dtype=float) - M.translation).tolist()
    c1, c2 = cross3(alpha, r), cross3(w, cross3(w, r))
    return np.array([a_o[0] + c1[0] + c2[0], a_o[1] + c1[1] + c2[1], a_o[2] + c1[2] + c2[2]])
