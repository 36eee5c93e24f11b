"""Replay recorded torques on a run's ``plant.xml`` with MuJoCo alone (no hqp-tpm, no pinocchio in the loop)."""

from __future__ import annotations

import numpy as np

from hqp_tpm.plants.mjcf import compile_xml, mujoco_module


def replay_torques(xml: str, qpos0, qvel0, ctrl, period: float) -> np.ndarray:
    """``qpos`` at the start of every period when the motor commands ``ctrl`` (steps x motors, the recorded
    ``tau`` at the actuated columns) are applied from ``(qpos0, qvel0)`` (MuJoCo's conventions). The model's
    timestep divides ``period``; the result's row ``i`` is the state the ``i``-th torque was applied from."""
    mujoco = mujoco_module()
    model = compile_xml(xml)
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = qpos0, qvel0
    substeps = max(1, round(period / model.opt.timestep))
    ctrl = np.asarray(ctrl, dtype=float)
    out = np.empty((ctrl.shape[0], model.nq))
    for i, u in enumerate(ctrl):
        out[i] = data.qpos
        data.ctrl[:] = u
        for _ in range(substeps):
            mujoco.mj_step(model, data)
    return out
