"""Probes that record task quantities, and the run's files: ``trajectory.npz`` and ``metrics.json``."""

from __future__ import annotations

import ctypes
import errno
import functools
import json
import math
import os
import shutil
import stat as _stat
import sys
import tempfile
import time
import uuid
import zipfile
from collections import Counter
from pathlib import Path

import numpy as np

from hqp_tpm.errors import OutputError
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

#: The schema of ``metrics.json``: every key a run may write, once, with its unit and meaning. ``{task}`` stands
#: for a task name, ``{part}`` for ``position``/``orientation`` (a pose task's two halves); the unit of
#: ``error_{task}_*`` is the task's own (:func:`task_unit`). ``docs/metrics.md`` is generated from this table.
METRICS: dict[str, tuple[str, str]] = {
    "scenario": ("-", "scenario name"),
    "solver": ("-", "solver of the run (``tpm``, ``sns_tpm``, ``qp:daqp``, ...)"),
    "level": ("-", "``velocity`` or ``acceleration``"),
    "crosscheck_solver": ("-", "the second solver of ``--crosscheck`` (null without it)"),
    "steps": ("1", "control steps run"),
    "steps_requested": ("1", "control steps asked for (more than ``steps`` in a partial run)"),
    "status": ("-", "``complete``, or ``partial`` when the run was stopped (signal) or a step failed"),
    "{metric}_reason": ("-", "why ``{metric}`` is null: it was not finite (NaN or inf); metrics.json is strict JSON"),
    "wall_time_s": ("s", "wall-clock time of the whole loop (recording included, compiling kernels left out)"),
    "mean_step_us": ("µs", "mean time of one control step (state update, policy, solve, integration; compiling "
                     "kernels left out: ``compile_s``)"),
    "compile_s": ("s", "time spent making the compiled kernels during the run: compiling them (the first run on a "
                  "machine) or loading them from the cache; left out of ``wall_time_s`` and ``mean_step_us``"),
    "lean": ("1", "1 if ctrl.step() ran its planned step (the readable step's numbers in fewer calls; compiled by "
                  "numba unless HQP_TPM_COMPILED=0), else 0"),
    "max_dq_jump": ("rad/s", "largest change of any joint velocity between two consecutive steps"),
    "max_dq_jump_step": ("1", "step at which ``max_dq_jump`` happens"),
    "max_abs_dq": ("rad/s", "largest joint velocity (absolute value) of the run"),
    "chatter": ("1/s", "largest over the joints of the sign changes per second of the command's rate (the change "
                "of a joint velocity between two steps; changes of at most ``CHATTER_DEADBAND`` rad/s count as none)"),
    "chatter_mean": ("1/s", "``chatter`` averaged over the joints"),
    "error_{task}_max": ("task unit", "largest norm of the task error ``x_d - x`` over the run"),
    "error_{task}_rms": ("task unit", "RMS over the run of the task error norm"),
    "error_{task}_{part}_max": ("m or rad", "a pose task: largest norm of its position (m) or orientation (rad) "
                                "error"),
    "error_{task}_{part}_rms": ("m or rad", "a pose task: RMS of its position (m) or orientation (rad) error norm"),
    "ee_error_max": ("m", "the EE task (named ``ee``): largest position error"),
    "ee_error_rms": ("m", "the EE task: RMS position error"),
    "ee_error_max_settled": ("m", "the EE task: largest position error from t = 2 s on"),
    "ee_error_rms_settled": ("m", "the EE task: RMS position error from t = 2 s on"),
    "pointing_violation_max_deg": ("deg", "largest angle by which the pointing axis left its cone"),
    "pointing_violation_max_deg_settled": ("deg", "the same from t = 2 s on"),
    "d_minimal_min": ("m", "smallest control-point distance ``D_minimal`` (papers/000)"),
    "d_ee_min": ("m", "smallest EE-obstacle distance ``D_ee`` (papers/000)"),
    "d_obstacle_min": ("m", "smallest robot-obstacle distance"),
    "d_self_min": ("m", "smallest distance between checked self-collision pairs"),
    "crosscheck_max_diff": ("rad/s or rad/s²", "largest difference of the command between the run's solver and the "
                            "crosscheck solver on the same levels (rad/s at velocity level, rad/s² at acceleration "
                            "level)"),
    "crosscheck_max_diff_same_problem": ("rad/s or rad/s²", "``crosscheck_max_diff`` over the steps where the two "
                                         "solvers solve the same problem (no box binds that one of them ignores "
                                         "or scales differently); null, with a ``_reason``, when there is no such "
                                         "step"),
    "crosscheck_steps_different_problems": ("1", "steps where a binding box makes the two solvers solve different "
                                            "problems (SNS-TPM's uniform scale vs the lexicographic QP, TPM vs a "
                                            "boxed solver)"),
    "scale_min": ("1", "smallest SNS task scale factor s"),
    "steps_scaled": ("1", "steps with s < 1"),
    "time_in_stack_s": ("s", "time spent in each stack (stack label -> seconds)"),
    "stack_changes": ("1", "number of steps at which the stack differs from the previous step's"),
    "units": ("-", "the unit of every numeric metric of this file (metric -> unit)"),
    "explain": ("s", "with ``--explain``: seconds each task was degraded, by cause, by blocking joint bound and by "
                "blocking higher task; ``fraction_met_min``: smallest fraction of a task met (1)"),
    # the plant ([plant] section, hqp_tpm.plants; docs/plant.md)
    "plant": ("-", "what the command drove: ``kinematic`` (the controller's own perfect integration) or ``mujoco``"),
    "plant_integrator": ("-", "MuJoCo's integrator (``euler``, ``implicitfast``, ...)"),
    "plant_timestep_s": ("s", "MuJoCo's timestep (it divides the control period)"),
    "plant_unmodelled": ("-", "the effects the plant simulated and the controller did not model (option -> value)"),
    "tau_max": ("N m", "largest applied joint torque (absolute value)"),
    "distance_crosscheck_max": ("m", "largest difference between the run's distances (coal or closed form) and "
                                "MuJoCo's ``mj_geomDistance`` on the plant's geometry, over the pairs computed"),
    "distance_crosscheck_steps": ("1", "steps at which ``distance_crosscheck_max`` compared at least one pair"),
    # policy summaries: the co-manipulation hierarchy and admittance (papers/003)
    "sigma_m_min": ("1", "smallest manipulability index sigma_m (14)"),
    "sigma_m_mean": ("1", "mean manipulability index"),
    "sigma_m_below_threshold_s": ("s", "time with sigma_m below its threshold"),
    "sigma_l_max": ("1", "largest joint-limit index sigma_l (11)"),
    "joint_deviation_max": ("rad", "largest |q_i - q_i*| (distance of a joint from the middle of its range)"),
    "joint_limit_margin_min": ("rad", "smallest distance of a joint to its limit (negative: past it)"),
    "operator_force_max": ("N", "largest operator force"),
    "markers_reached": ("-", "indices of the markers the operator reached"),
    "markers_reached_t": ("s", "times at which they were reached"),
    "markers_skipped": ("-", "indices of the markers the operator gave up"),
    "time_in_named_stack_s": ("s", "time in each stack of Fig. 3 of papers/003 (name -> seconds)"),
    "admittance_lag_max": ("m", "largest distance between the admittance reference and the flange"),
    # policy summaries: planar avoidance (papers/004)
    "d_m": ("m", "the policy's minimal distance d_m"),
    "d_i": ("m", "the policy's influence distance d_i"),
    "scheme": ("-", "avoidance scheme (``exact``, ``approximate``, ...)"),
    "secondary": ("-", "how the secondary task is handled"),
    "time_below_d_m_s": ("s", "time with a link closer than d_m to an obstacle"),
    "time_avoidance_primary_s": ("s", "time with the avoidance as the primary task"),
    "time_avoidance_secondary_s": ("s", "time with the avoidance as a secondary task"),
    # plant summaries: a floating base standing on MuJoCo (hqp_tpm.plants.floating_base)
    "base_height_max_change_m": ("m", "largest change of the base height from its start"),
    "foot_slip_max_m": ("m", "largest horizontal displacement of a sole on the ground from its start"),
    "cone_margin_min_N": ("N", "smallest mu f_z - |f_t| of the contact QP's corner forces (>= 0: inside the cones)"),
    "normal_force_min_N": ("N", "smallest normal force of a sole corner in the contact QP"),
    "sim_cone_margin_min_N": ("N", "smallest mu f_n - |f_t| of MuJoCo's contact forces with the controller's mu"),
    "tau_ratio_max": ("1", "largest |tau_i| / effort limit_i"),
    "qp_deviation_max": ("rad/s^2", "largest |a - a*|: the contact QP's change of the stack's acceleration"),
}

#: Units of task errors by task type (a pose task is split into position and orientation).
TASK_UNITS = {"FramePosition": "m", "CenterOfMass": "m", "FrameOrientation": "rad", "Posture": "rad", "Force": "N",
              "Pointing": "1", "QuaternionOrientation": "1", "Manipulability": "1", "JointLimit": "1"}


def task_unit(task: Task) -> str:
    """The unit of a task's error (``"1"``: dimensionless; unknown task types: ``"task unit"``)."""
    return TASK_UNITS.get(type(task).__name__, "task unit")


def schema_key(key: str, tasks=()) -> str | None:
    """The :data:`METRICS` entry ``key`` belongs to (None if none)."""
    if key in METRICS:
        return key
    if key.endswith("_reason") and schema_key(key[: -len("_reason")], tasks) is not None:
        return "{metric}_reason"
    for name in sorted(tasks, key=len, reverse=True):
        for part in ("position", "orientation"):
            for stat in ("max", "rms"):
                if key == f"error_{name}_{part}_{stat}":
                    return f"error_{{task}}_{{part}}_{stat}"
        for stat in ("max", "rms"):
            if key == f"error_{name}_{stat}":
                return f"error_{{task}}_{stat}"
    return None


def _norm(e: np.ndarray) -> np.ndarray:
    return np.abs(e) if e.ndim == 1 else np.linalg.norm(e, axis=1)


#: Rows of a recorded column that :func:`metrics` holds in memory at a time.
BLOCK_ROWS = 16384


def blocks(a: np.ndarray, rows: int | None = None, overlap: int = 0):
    """``(start, block)`` for row blocks ``a[start - overlap : start + rows]`` (clipped at 0) as in-memory arrays
    (``rows``: :data:`BLOCK_ROWS`).

    A whole memory-mapped column (``np.memmap``, e.g. from :meth:`Recording.load`) is mapped again for each
    block and unmapped after it: its file pages do not accumulate in the process's memory, so the peak memory of
    the metrics does not grow with the number of steps (``benchmarks/peak_rss.py``).
    """
    n, rows = a.shape[0], BLOCK_ROWS if rows is None else rows
    whole = None
    if isinstance(a, np.memmap) and a.filename is not None:
        m = np.load(a.filename, mmap_mode="r")
        if m.shape == a.shape and m.strides == a.strides and m.dtype == a.dtype:
            whole = a.filename  # the column itself (a view of the same shape and strides is the whole file)
        del m
    for i in range(0, n, rows):
        lo = max(i - overlap, 0)
        if whole is None:
            yield i, np.asarray(a[lo:i + rows])
        else:
            m = np.load(whole, mmap_mode="r")
            block = np.array(m[lo:i + rows])
            del m
            yield i, block


class _Stat:
    """Maximum, sum of squares and count of a per-step norm over row blocks (``rms = sqrt(sum / count)``: for one
    block exactly ``np.sqrt(np.mean(x**2))``; over several, the same up to the summation order)."""

    __slots__ = ("max", "sq", "count")

    def __init__(self):
        self.max, self.sq, self.count = -np.inf, 0.0, 0

    def add(self, x: np.ndarray) -> None:
        if x.size:
            self.max = _top(self.max, float(x.max()))
            self.sq += np.sum(x**2)
            self.count += x.size

    def rms(self) -> float:
        return float(np.sqrt(self.sq / self.count))


def _top(a: float, b: float) -> float:
    """``max(a, b)`` that keeps a NaN (as ``ndarray.max`` over the whole column would)."""
    return a if (a != a or a >= b) else b


def _pointing_task(tasks) -> Pointing | None:
    return next((task for task in tasks.values() if isinstance(task, Pointing)), None)


def _reduce(fn, values) -> float:
    """``fn`` (np.max, np.min) of per-block results, NaN kept."""
    return float(fn(np.array(list(values), dtype=float)))


#: A change of a joint velocity between two steps of at most this (rad/s) has no sign for ``chatter``.
CHATTER_DEADBAND = 1e-6


def chatter(dq: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Per joint: sign changes per second of the command's rate ``dq[k] - dq[k-1]`` (changes of at most
    :data:`CHATTER_DEADBAND` are skipped: a sign is compared with the last one that counted), over ``t``'s span.
    A smooth command changes sign a few times per motion; one that flips between its box's sides every step
    (saturations switching, issue 31) about once per step."""
    n, joints = dq.shape[0], dq.shape[1] if dq.ndim == 2 else 0
    changes, last = np.zeros(joints), np.zeros(joints)
    for _, b in blocks(dq, overlap=1):
        r = np.diff(b, axis=0)
        sign = np.where(r > CHATTER_DEADBAND, 1.0, np.where(r < -CHATTER_DEADBAND, -1.0, 0.0))
        for j in range(joints):
            seq = sign[:, j][sign[:, j] != 0.0]
            if seq.size:
                changes[j] += np.count_nonzero(seq[1:] != seq[:-1]) + (last[j] != 0.0 and seq[0] != last[j])
                last[j] = seq[-1]
    span = float(t[-1] - t[0]) if n > 1 else 0.0
    return changes / span if span > 0 else changes


def metrics(arrays: dict, timing: dict, tasks: dict[str, Task]) -> dict:
    """Summary numbers of a run (plain floats, JSON-ready), each metric once (:data:`METRICS`); ``*_settled`` ones
    from ``t >= SETTLE_S``; ``units`` gives the unit of every numeric entry.

    The columns are read in blocks of :data:`BLOCK_ROWS` rows (:func:`blocks`): memory does not grow with the run.
    """
    t = arrays["t"]
    n = int(t.size)
    out: dict = {"steps": n, **{k: float(v) for k, v in timing.items() if k != "steps"}}
    units: dict = {}
    dq = arrays["dq"]
    if dq.shape[0] > 1:
        best, where = -np.inf, 0
        for i, b in blocks(dq, overlap=1):
            lo = max(i - 1, 0)
            jumps = np.abs(np.diff(b, axis=0)).max(axis=1)
            k = int(jumps.argmax())
            if best == best and not jumps[k] <= best:  # the first largest (or NaN) jump, as argmax over the run
                best, where = float(jumps[k]), lo + k + 1
        out["max_dq_jump"] = best
        out["max_dq_jump_step"] = where
    if dq.shape[0] > 2 and dq.ndim == 2 and dq.shape[1]:
        per_joint = chatter(dq, t)
        out["chatter"], out["chatter_mean"] = float(per_joint.max()), float(per_joint.mean())
    out["max_abs_dq"] = _reduce(np.max, (np.abs(b).max() for _, b in blocks(dq))) if dq.size else 0.0
    for name, task in tasks.items():
        e = arrays.get(f"error_{name}")
        if e is None or (name == "ee" and "ee_error" in arrays) or isinstance(task, Pointing):
            continue  # the EE task is summarized as ee_error_*, a pointing task in degrees below
        if type(task).__name__ == "FramePose" and e.ndim == 2 and e.shape[1] == 6:
            for part, cols, unit in (("position", slice(0, 3), "m"), ("orientation", slice(3, 6), "rad")):
                st = _Stat()
                for _, b in blocks(e):
                    st.add(np.linalg.norm(b[:, cols], axis=1))
                out[f"error_{name}_{part}_max"] = st.max
                out[f"error_{name}_{part}_rms"] = st.rms()
                units[f"error_{name}_{part}_max"] = units[f"error_{name}_{part}_rms"] = unit
            continue
        st = _Stat()
        for _, b in blocks(e):
            st.add(_norm(b))
        out[f"error_{name}_max"] = st.max
        out[f"error_{name}_rms"] = st.rms()
        units[f"error_{name}_max"] = units[f"error_{name}_rms"] = task_unit(task)
    any_settled = any(bool((b >= SETTLE_S).any()) for _, b in blocks(t))
    if "ee_error" in arrays:
        whole, settled = _Stat(), _Stat()
        for (_, b), (_, bt) in zip(blocks(arrays["ee_error"]), blocks(t), strict=True):
            nb = _norm(b)
            whole.add(nb)
            settled.add(nb[bt >= SETTLE_S])
        out["ee_error_max"], out["ee_error_rms"] = whole.max, whole.rms()
        if any_settled:
            out["ee_error_max_settled"] = settled.max
            out["ee_error_rms_settled"] = settled.rms()
    pointing = _pointing_task(tasks)
    if "pointing_error" in arrays:
        out["pointing_violation_max_deg"] = _violation_deg(arrays["pointing_error"], pointing, None)
        if any_settled:
            out["pointing_violation_max_deg_settled"] = _violation_deg(arrays["pointing_error"], pointing, t)
    for key in ("d_minimal", "d_ee", "d_obstacle", "d_self"):
        if key in arrays:
            lows = [float(np.nanmin(b)) for _, b in blocks(arrays[key]) if np.isfinite(b).any()]
            if lows:
                out[f"{key}_min"] = min(lows)
    if "crosscheck_diff" in arrays:
        diff = arrays["crosscheck_diff"]
        out["crosscheck_max_diff"] = _reduce(np.max, (b.max() for _, b in blocks(diff)))
        if "crosscheck_same_problem" in arrays:
            top, different, checked = 0.0, 0, 0
            for (_, d), (_, s) in zip(blocks(diff), blocks(arrays["crosscheck_same_problem"]), strict=True):
                same = s > 0.5
                top = _top(top, float(d[same].max(initial=0.0)))
                different += int((~same).sum())
                checked += same.size
            if different < checked:
                out["crosscheck_max_diff_same_problem"] = top
            else:  # (a maximum over no step is no agreement: 0.0 here read as one)
                out["crosscheck_max_diff_same_problem"] = None
                out["crosscheck_max_diff_same_problem_reason"] = ("no step where both solvers solved the same "
                                                                  "problem (a binding box one of them ignores)")
            out["crosscheck_steps_different_problems"] = different
    if "scale" in arrays:
        out["scale_min"] = _reduce(np.min, (b.min() for _, b in blocks(arrays["scale"])))
        out["steps_scaled"] = sum(int((b < 1 - 1e-12).sum()) for _, b in blocks(arrays["scale"]))
    dt = float(t[1] - t[0]) if n > 1 else 0.0
    counts: Counter = Counter()
    changes = 0
    for i, block in blocks(arrays["stack"], overlap=1):
        counts.update(block[1:].tolist() if i else block.tolist())
        changes += int((block[1:] != block[:-1]).sum())
    out["time_in_stack_s"] = {k: v * dt for k, v in counts.items()}
    out["stack_changes"] = changes
    out["units"] = units
    return out


def finish_units(summary: dict, tasks=()) -> dict:
    """Fill ``summary["units"]`` for every numeric entry from :data:`METRICS` (after policy summaries were added)."""
    units = summary.setdefault("units", {})
    for key, value in summary.items():
        if key == "units" or key in units or isinstance(value, str) or value is None:
            continue
        entry = schema_key(key, tasks)
        if entry is not None and METRICS[entry][0] not in ("-", "task unit"):
            units[key] = METRICS[entry][0]
    summary["units"] = dict(sorted(units.items()))
    return summary


def metrics_doc() -> str:
    """``docs/metrics.md``: the schema of ``metrics.json`` as a Markdown table (generated from :data:`METRICS`)."""
    lines = ["# `metrics.json`", "",
             "<!-- generated by `python -m hqp_tpm.app.results > docs/metrics.md` from `METRICS` in "
             "`hqp_tpm/app/results.py`; a test checks that this file is current -->", "",
             "`hqp-tpm run` writes one `metrics.json` per run: every metric below at most once (those that apply to "
             "the run), plain JSON numbers, strings, lists or tables. `units` repeats the unit of every numeric entry "
             f"of the file. `*_settled` metrics are taken from t = {SETTLE_S:g} s on. `{{task}}` is a task name of the "
             "scenario; a task's error has the task's unit: " + ", ".join(f"{k} {v}" for k, v in TASK_UNITS.items())
             + " (`1`: dimensionless).", "",
             "| metric | unit | meaning |", "|---|---|---|"]
    for key, (unit, meaning) in METRICS.items():
        lines.append(f"| `{key}` | {unit} | {meaning.replace('``', '`')} |")
    return "\n".join(lines) + "\n"


def _violation_deg(pointing_error: np.ndarray, task: Pointing | None, t: np.ndarray | None) -> float:
    """Largest angle (deg) by which the pointing axis was outside its cone, over all steps (``t`` None) or the
    steps with ``t >= SETTLE_S``."""
    if task is None:
        return 0.0
    top = -np.inf
    times = blocks(t) if t is not None else None
    for _, b in blocks(pointing_error):
        if times is not None:
            b = b[next(times)[1] >= SETTLE_S]
        if b.size:
            p = np.clip(np.cos(task.alpha_d) - b, -1.0, 1.0)
            top = _top(top, float(np.arccos(p).max()))
    return float(max(0.0, np.rad2deg(top - task.alpha_d)))


def strict(value, reasons: dict | None = None, key: str = ""):
    """``value`` made strict JSON: a non-finite float becomes ``None`` and ``<key>_reason`` says why."""
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            extra: dict = {}
            out[k] = strict(v, extra, str(k))
            out.update({rk: rv for rk, rv in extra.items() if rk not in value})
        return out
    if isinstance(value, (list, tuple)):
        return [strict(v) for v in value]
    if isinstance(value, (float, np.floating)) and not math.isfinite(value):
        if reasons is not None and key:
            reasons[f"{key}_reason"] = f"not finite ({float(value)!r}): the run produced NaN or inf"
        return None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


def dumps(summary: dict) -> str:
    """Strict JSON text of a summary (``allow_nan=False``: no ``NaN``/``Infinity`` tokens)."""
    return json.dumps(strict(summary), indent=2, sort_keys=True, allow_nan=False) + "\n"


def write_npz(path: Path, files: dict[str, Path]) -> None:
    """``trajectory.npz`` from ``.npy`` files, streamed (compressed like ``np.savez_compressed``)."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
        for key, f in files.items():
            zf.write(f, arcname=f"{key}.npy")


def write(out_dir: Path, arrays: dict, summary: dict) -> None:
    """Write ``trajectory.npz`` and ``metrics.json`` into ``out_dir`` (a folder being built: see
    :class:`ResultFolder` for the crash-safe way to produce a run's folder)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = out_dir / f".trajectory.{os.getpid()}.{uuid.uuid4().hex[:8]}.npz"
    try:
        np.savez_compressed(tmp, **arrays)
        tmp.replace(out_dir / "trajectory.npz")
    finally:
        tmp.unlink(missing_ok=True)
    write_text(out_dir / "metrics.json", dumps(summary))


#: ``errno`` values of a write that failed for lack of room (a full disk or quota, a file-size limit) or a broken
#: medium: reported as :class:`~hqp_tpm.errors.OutputError` naming the output.
_EDQUOT = {name: code for code, name in errno.errorcode.items()}.get("EDQUOT", -1)  # (not on every platform)
WRITE_ERRNOS = frozenset(e for e in (errno.ENOSPC, errno.EFBIG, _EDQUOT, errno.EROFS, errno.EIO) if e != -1)


def output_error(exc: OSError, out: Path) -> OutputError:
    """The :class:`~hqp_tpm.errors.OutputError` of a failed write under ``out`` (``exc`` one of
    :data:`WRITE_ERRNOS`)."""
    why = {errno.ENOSPC: "no space left on the device", errno.EFBIG: "a file grew beyond the file-size limit "
           "(ulimit -f)", _EDQUOT: "the disk quota is exhausted"}.get(exc.errno,
                                                                                        exc.strerror or str(exc))
    file = f" (writing {Path(exc.filename).name})" if exc.filename else ""
    return OutputError(f"cannot write the result to {str(out)!r}: {why}{file}; nothing was replaced (a previous "
                       "result there is kept)")


def write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a uniquely named temporary file in the same folder (a full disk or a
    file-size limit: :class:`~hqp_tpm.errors.OutputError`, ``path`` as it was)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        with open(tmp, "x", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        if isinstance(exc, OutputError) or exc.errno not in WRITE_ERRNOS:
            raise
        raise output_error(exc, path) from exc
    finally:
        tmp.unlink(missing_ok=True)


# ------------------------------------------------------------------------------------ result folders
MANIFEST = "manifest.json"
#: Files a result folder of earlier versions (before manifests) may hold: such a folder is recognised too.
RESULT_FILES = ("trajectory.npz", "metrics.json", "replay.html", "joint_velocities.png", "task_errors.png",
                "pointing_error.png", "distances.png", "comanipulation.png")
_TMP_TAG = ".hqp-tpm-"


def read_manifest(folder: Path) -> dict | None:
    """The manifest of a result folder, or None when there is none (or it is unreadable)."""
    try:
        data = json.loads((Path(folder) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("tool") == "hqp-tpm" else None


def is_complete(folder: Path) -> bool:
    """True when ``folder`` holds a complete result of hqp-tpm (its manifest says so)."""
    m = read_manifest(folder)
    if m is None:  # a result of an earlier version (no manifest) counts as complete
        folder = Path(folder)
        return folder.is_dir() and not (folder / MANIFEST).exists() and (folder / "metrics.json").is_file() \
            and (folder / "trajectory.npz").is_file()
    return m.get("status") == "complete"


def _is_previous_result(folder: Path) -> bool:
    if read_manifest(folder) is not None:
        return True
    names = {p.name for p in folder.iterdir()}
    return bool(names) and names <= set(RESULT_FILES) and "metrics.json" in names


def _read_only(path: Path) -> bool:
    st = path.stat()
    return not os.access(path, os.W_OK) or not (st.st_mode & _stat.S_IWUSR)


def check_target(target: Path, *, force: bool = False) -> Path:
    """Check before any work that ``target`` can receive a run's results; returns it absolute.

    Refused (:class:`~hqp_tpm.errors.OutputError`): a path that is a file, a read-only folder (or parent),
    a non-empty folder that is not a previous result of hqp-tpm (unless ``force``).
    """
    target = Path(target).absolute()
    if target.is_symlink():  # followed knowingly: the result goes where the link points, the link stays
        real = Path(os.path.realpath(target))
        if real.is_symlink() or not real.exists():
            raise OutputError(f"output {str(target)!r} is a symbolic link to {str(real)!r}, which "
                              f"{'is a loop' if real.is_symlink() else 'does not exist'}; create the folder it "
                              "points to or choose another --out")
        target = real
    if target.exists():
        if not target.is_dir():
            raise OutputError(f"output {str(target)!r} is a file, not a folder; choose another --out")
        if _read_only(target):
            raise OutputError(f"output folder {str(target)!r} is read-only")
        if not force and any(target.iterdir()) and not _is_previous_result(target):
            raise OutputError(f"output folder {str(target)!r} is not empty and holds no hqp-tpm result "
                              f"(no {MANIFEST}); choose another --out, or pass --force to replace its contents")
    parent = target.parent
    existing = parent
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise OutputError(f"cannot create output folder {str(target)!r}: {str(existing)!r} is a file")
    if _read_only(existing):
        raise OutputError(f"cannot write into {str(existing)!r} (read-only), needed for output {str(target)!r}")
    return target


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap two paths (Linux ``renameat2(RENAME_EXCHANGE)``); False where that is not available."""
    fn = _renameat2()
    if fn is None:
        return False
    if fn(-100, os.fsencode(a), -100, os.fsencode(b), 2) == 0:  # AT_FDCWD, RENAME_EXCHANGE
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


@functools.lru_cache(maxsize=1)
def _renameat2():
    if sys.platform != "linux":
        return None
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    return fn


def pid_alive(pid: int) -> bool:
    """Is process ``pid`` running (one we may not signal counts as running)?"""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale(parent: Path, name: str) -> None:
    """Remove the ``.<name>.hqp-tpm-<pid>-...`` entries in ``parent`` of processes that are gone (a killed run's
    temporary folder; a symbolic link among them, left by an earlier version that swapped a linked ``--out``
    away: only the link is removed)."""
    prefix = f".{name}{_TMP_TAG}"
    for p in parent.glob(f"{prefix}*"):
        try:
            pid = int(p.name[len(prefix):].split("-", 1)[0])
        except ValueError:
            continue
        if pid != os.getpid() and not pid_alive(pid):
            if p.is_symlink():
                p.unlink(missing_ok=True)
            else:
                shutil.rmtree(p, ignore_errors=True)


class ResultFolder:
    """A run's output folder, built in a fresh temporary folder next to ``target`` and swapped in at the end.

    ``ResultFolder(target)`` checks the target (:func:`check_target`) and creates the temporary folder
    (``.<name>.hqp-tpm-<pid>-<random>``: concurrent runs never share a name); write the files into
    :attr:`path`, then :meth:`commit` writes ``manifest.json`` and replaces ``target`` by the new folder
    in one atomic step (the previous folder, if any, is then removed); :meth:`abort` removes the
    temporary folder and leaves ``target`` as it was. A partial result (``status = "partial"``) never
    replaces a complete one: it goes to ``<target>.partial`` instead (see :meth:`destination`).
    Temporary folders left by killed processes (their pid is gone) are removed on the way.
    """

    def __init__(self, target: Path, *, force: bool = False) -> None:
        self.target = check_target(target, force=force)  # a symbolic link: the folder it points to
        self.force = force
        parent = self.target.parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
            remove_stale(parent, self.target.name)
            given = Path(target).absolute()
            if given != self.target and given.parent.is_dir():  # a link's own folder: the earlier versions' leftovers
                remove_stale(given.parent, given.name)
            self.path = Path(tempfile.mkdtemp(prefix=f".{self.target.name}{_TMP_TAG}{os.getpid()}-", dir=parent))
            umask = os.umask(0)
            os.umask(umask)
            self.path.chmod(0o777 & ~umask)  # a normal folder (mkdtemp's is private)
        except OSError as exc:
            raise OutputError(f"cannot create a folder next to {str(self.target)!r}: {exc.strerror or exc}") from None
        self.done = False

    def destination(self, status: str) -> Path:
        """Where a result of this ``status`` goes: the target, or ``<target>.partial`` for a partial run
        when the target holds a complete result."""
        if status != "complete" and is_complete(self.target):
            return self.target.with_name(self.target.name + ".partial")
        return self.target

    def commit(self, manifest: dict) -> Path:
        """Write the manifest, then swap the folder in; returns where it went."""
        from hqp_tpm import __version__

        status = manifest.get("status", "complete")
        files = sorted(p.name for p in self.path.iterdir() if p.name != MANIFEST)
        full = {"tool": "hqp-tpm", "version": __version__, "status": status,
                "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **manifest, "files": files}
        write_text(self.path / MANIFEST, json.dumps(strict(full), indent=2, sort_keys=True, allow_nan=False) + "\n")
        dest = self.destination(status)
        for _ in range(8):  # another run may create or replace the target meanwhile: try again
            if dest.exists():
                if _exchange(self.path, dest):
                    shutil.rmtree(self.path, ignore_errors=True)  # now holds the previous folder
                    break
                old = dest.with_name(f".{dest.name}{_TMP_TAG}{os.getpid()}-old-{uuid.uuid4().hex[:8]}")
                try:
                    os.rename(dest, old)
                except FileNotFoundError:
                    continue
                try:
                    os.rename(self.path, dest)
                except OSError:
                    os.rename(old, dest)  # put the previous result back
                    raise
                shutil.rmtree(old, ignore_errors=True)
                break
            try:
                os.rename(self.path, dest)
                break
            except OSError as exc:
                if exc.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                    raise
        else:
            raise OutputError(f"could not replace {str(dest)!r}: it kept changing")
        self.done = True
        return dest

    def abort(self) -> None:
        """Remove the temporary folder; the target is left as it was."""
        if not self.done:
            shutil.rmtree(self.path, ignore_errors=True)
            self.done = True


if __name__ == "__main__":
    print(metrics_doc(), end="")
