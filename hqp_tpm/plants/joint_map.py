"""Which MuJoCo coordinates hold which pinocchio joint: joints matched by name, fixed or floating base.

pinocchio orders joints depth-first from the URDF; MuJoCo may order them differently (and puts a free joint
first). :class:`JointMap` matches every joint of the pinocchio model to the MuJoCo joint of the same name and
converts whole vectors both ways: positions, velocities, accelerations and generalized forces, in pinocchio's
order on one side and MuJoCo's ``qpos``/``qvel`` order on the other. The free joint's conventions are
:mod:`hqp_tpm.plants.conventions`' (the one place they are converted). Continuous joints (pinocchio's
``cos, sin`` pair) map to a hinge angle.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hqp_tpm.errors import PlantError
from hqp_tpm.plants import conventions as cv

#: MuJoCo joint types (``mjtJoint``): free, ball, slide, hinge.
_FREE, _BALL, _SLIDE, _HINGE = 0, 1, 2, 3


class JointMap:
    """Index maps between a pinocchio model and a compiled MuJoCo model (``mujoco.MjModel``) of the same robot.

    ``free``: (pinocchio q index, v index, MuJoCo qpos address, dof address) of the floating base, or None;
    ``actuated``: pinocchio velocity columns of the 1-DOF joints (the ones a motor drives), in pinocchio order.
    """

    def __init__(self, model: pin.Model, mj_model) -> None:
        self.nq, self.nv = model.nq, model.nv
        self.mj_nq, self.mj_nv = mj_model.nq, mj_model.nv
        self.free = None
        q_pin, q_mj, v_pin, v_mj, cont = [], [], [], [], []
        for jid in range(1, model.njoints):
            name, joint = model.names[jid], model.joints[jid]
            try:
                mj = mj_model.joint(name)
            except KeyError:
                raise PlantError(f"joint {name!r} of the pinocchio model has no MuJoCo joint of that name") from None
            kind, qa, da = int(mj.type[0]), int(mj.qposadr[0]), int(mj.dofadr[0])
            if joint.nv == 6 and joint.nq == 7 and kind == _FREE:
                self.free = (joint.idx_q, joint.idx_v, qa, da)
            elif joint.nv == 1 and joint.nq == 1 and kind in (_HINGE, _SLIDE):
                q_pin.append(joint.idx_q), q_mj.append(qa)
                v_pin.append(joint.idx_v), v_mj.append(da)
            elif joint.nv == 1 and joint.nq == 2 and kind == _HINGE:  # continuous: (cos, sin) <-> angle
                cont.append((joint.idx_q, qa))
                v_pin.append(joint.idx_v), v_mj.append(da)
            else:
                raise PlantError(f"joint {name!r}: pinocchio nq={joint.nq}, nv={joint.nv} and MuJoCo type {kind} "
                                 "do not match (supported: free-flyer, revolute, prismatic, continuous)")
        n_mapped = len(v_pin) + (6 if self.free else 0)
        if n_mapped != mj_model.nv:
            raise PlantError(f"the MuJoCo model has {mj_model.nv} degrees of freedom, the pinocchio model {n_mapped}")
        self.q_pin, self.q_mj = np.array(q_pin, dtype=int), np.array(q_mj, dtype=int)
        self.v_pin, self.v_mj = np.array(v_pin, dtype=int), np.array(v_mj, dtype=int)
        self.continuous = cont
        self.actuated = np.array(sorted(v_pin), dtype=int)
        #: the velocity permutation: ``v_mj[perm] = v_pin`` (the free block aside)
        self.identity = (self.free is None and not cont and np.array_equal(self.q_pin, self.q_mj)
                         and np.array_equal(self.v_pin, self.v_mj))

    # -- positions ---------------------------------------------------------------------------------
    def q_to_mujoco(self, q: np.ndarray) -> np.ndarray:
        if self.identity:
            return np.array(q, dtype=float)
        out = np.zeros(self.mj_nq)
        out[self.q_mj] = q[self.q_pin]
        for iq, qa in self.continuous:
            out[qa] = np.arctan2(q[iq + 1], q[iq])
        if self.free is not None:
            iq, _, qa, _ = self.free
            out[qa:qa + 7] = cv.free_position_to_mujoco(q[iq:iq + 7])
        return out

    def q_from_mujoco(self, qpos: np.ndarray) -> np.ndarray:
        if self.identity:
            return np.array(qpos, dtype=float)
        out = np.zeros(self.nq)
        out[self.q_pin] = qpos[self.q_mj]
        for iq, qa in self.continuous:
            out[iq], out[iq + 1] = np.cos(qpos[qa]), np.sin(qpos[qa])
        if self.free is not None:
            iq, _, qa, _ = self.free
            out[iq:iq + 7] = cv.free_position_from_mujoco(qpos[qa:qa + 7])
        return out

    # -- velocities, accelerations, forces ---------------------------------------------------------
    def _base_q(self, q: np.ndarray) -> np.ndarray:
        return q[self.free[0]:self.free[0] + 7]

    def v_to_mujoco(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """A velocity (or generalized force: the same rule) at pinocchio position ``q``, in MuJoCo's order."""
        if self.identity:
            return np.array(v, dtype=float)
        out = np.zeros(self.mj_nv)
        out[self.v_mj] = v[self.v_pin]
        if self.free is not None:
            _, iv, _, da = self.free
            out[da:da + 6] = cv.free_motion_to_mujoco(self._base_q(q), v[iv:iv + 6])
        return out

    def v_from_mujoco(self, q: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """A MuJoCo velocity (or generalized force) at pinocchio position ``q``, in pinocchio's order."""
        if self.identity:
            return np.array(qvel, dtype=float)
        out = np.zeros(self.nv)
        out[self.v_pin] = qvel[self.v_mj]
        if self.free is not None:
            _, iv, _, da = self.free
            out[iv:iv + 6] = cv.free_motion_from_mujoco(self._base_q(q), qvel[da:da + 6])
        return out

    force_to_mujoco = v_to_mujoco
    force_from_mujoco = v_from_mujoco

    def a_to_mujoco(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """pinocchio's acceleration ``dv/dt`` at ``(q, v)`` as MuJoCo's ``qacc``."""
        if self.identity:
            return np.array(a, dtype=float)
        out = np.zeros(self.mj_nv)
        out[self.v_mj] = a[self.v_pin]
        if self.free is not None:
            _, iv, _, da = self.free
            out[da:da + 6] = cv.free_acceleration_to_mujoco(self._base_q(q), v[iv:iv + 6], a[iv:iv + 6])
        return out

    def velocity_matrix(self, q: np.ndarray) -> np.ndarray:
        """``T`` with ``v_mj = T v_pin`` at ``q`` (for comparing matrices: ``M_pin = T^T M_mj T``)."""
        return np.column_stack([self.v_to_mujoco(q, e) for e in np.eye(self.nv)])
