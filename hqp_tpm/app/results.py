"""Probes that record task quantities, and the run's files: ``trajectory.npz`` and ``metrics.json``."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np

from hqp_tpm.tasks import Pointing
from hqp_tpm.tasks.base import Task


def task_error_probe(tasks: dict[str, Task]):
    """Per step, ``error_<name>`` = ``x_d - x`` of every task (pointing: ``cos a_d - p_rp``)."""

    def probe(ctrl, res):
        st, t = ctrl.state, res.t
        out = {}
        for name, task in tasks.items():
            if isinstance(task, Pointing):
                out[f"error_{name}"] = task.pointing_error(st)
            else:
                out[f"error_{name}"] = np.array(task.error(st, task.reference(t)[0]), dtype=float)
        return out

    return probe


def standard_aliases(arrays: dict, tasks: dict[str, Task]) -> None:
    """The keys every scenario shares: ``ee_error`` (task ``ee``) and ``pointing_error`` (first pointing task)."""
    if "error_ee" in arrays:
        arrays["ee_error"] = arrays["error_ee"]
    for name, task in tasks.items():
        if isinstance(task, Pointing):
            arrays["pointing_error"] = arrays[f"error_{name}"]
            break


#: Task errors are also summarized from this time on, after the start-up transient (s).
SETTLE_S = 2.0


def metrics(arrays: dict, timing: dict, tasks: dict[str, Task]) -> dict:
    """Summary numbers of a run (all plain floats, JSON-ready); ``*_settled`` ones from ``t >= SETTLE_S``."""
    out: dict = {"steps": int(arrays["t"].size), **{k: float(v) for k, v in timing.items()}}
    dq = arrays["dq"]
    if dq.shape[0] > 1:
        jumps = np.abs(np.diff(dq, axis=0)).max(axis=1)
        out["max_dq_jump"] = float(jumps.max())
        out["max_dq_jump_step"] = int(jumps.argmax() + 1)
    out["max_abs_dq"] = float(np.abs(dq).max()) if dq.size else 0.0
    for name in tasks:
        e = arrays.get(f"error_{name}")
        if e is None:
            continue
        norm = np.abs(e) if e.ndim == 1 else np.linalg.norm(e, axis=1)
        out[f"error_{name}_max"] = float(norm.max())
        out[f"error_{name}_rms"] = float(np.sqrt(np.mean(norm**2)))
    settled = arrays["t"] >= SETTLE_S
    if "ee_error" in arrays:
        n = np.linalg.norm(arrays["ee_error"], axis=1)
        out["ee_error_max"], out["ee_error_rms"] = float(n.max()), float(np.sqrt(np.mean(n**2)))
        if settled.any():
            out["ee_error_max_settled"] = float(n[settled].max())
            out["ee_error_rms_settled"] = float(np.sqrt(np.mean(n[settled] ** 2)))
    if "pointing_error" in arrays:
        out["pointing_violation_max"] = float(max(0.0, arrays["pointing_error"].max()))
        out["pointing_violation_max_deg"] = _violation_deg(arrays, tasks, np.ones_like(settled))
        if settled.any():
            out["pointing_violation_max_deg_settled"] = _violation_deg(arrays, tasks, settled)
    for key in ("d_minimal", "d_ee", "d_obstacle", "d_self"):
        if key in arrays and np.isfinite(arrays[key]).any():
            out[f"{key}_min"] = float(np.nanmin(arrays[key]))
    if "crosscheck_diff" in arrays:
        out["crosscheck_max_diff"] = float(arrays["crosscheck_diff"].max())
    if "scale" in arrays:
        out["scale_min"] = float(arrays["scale"].min())
        out["steps_scaled"] = int((arrays["scale"] < 1 - 1e-12).sum())
    dt = float(arrays["t"][1] - arrays["t"][0]) if arrays["t"].size > 1 else 0.0
    out["time_in_stack_s"] = {k: v * dt for k, v in Counter(arrays["stack"].tolist()).items()}
    out["stack_changes"] = int((arrays["stack"][1:] != arrays["stack"][:-1]).sum())
    return out


def _violation_deg(arrays, tasks, mask) -> float:
    """Largest angle (deg) by which the pointing axis was outside its cone, over the steps in ``mask``."""
    for task in tasks.values():
        if isinstance(task, Pointing):
            p = np.clip(np.cos(task.alpha_d) - arrays["pointing_error"][mask], -1.0, 1.0)
            return float(max(0.0, np.rad2deg(np.arccos(p).max() - task.alpha_d)))
    return 0.0


def write(out_dir: Path, arrays: dict, summary: dict) -> None:
    """Write ``trajectory.npz`` and ``metrics.json`` into ``out_dir`` (created if needed)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = out_dir / "trajectory.tmp.npz"
    np.savez_compressed(tmp, **arrays)
    tmp.replace(out_dir / "trajectory.npz")  # never leave a half-written file behind
    (out_dir / "metrics.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
