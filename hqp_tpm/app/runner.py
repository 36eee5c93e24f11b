"""Run a controller for a number of steps and record what happened, step by step."""

from __future__ import annotations

import os
import shutil
import struct
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hqp_tpm import _jit
from hqp_tpm.app.results import blocks
from hqp_tpm.control.controller import Controller
from hqp_tpm.errors import DivergedError, ShapeError, StateError
from hqp_tpm.solvers.registry import check_solver_name

#: Rows a column keeps in memory before they are appended to its file (a chunk).
CHUNK_ROWS = 4096
#: Bytes reserved for the header of a column's ``.npy`` file (rewritten with the final shape on close).
_HEADER_BYTES = 256


def _npy_header(dtype: np.dtype, shape: tuple) -> bytes:
    """A version-1.0 ``.npy`` header padded to :data:`_HEADER_BYTES` (so the shape can grow in place)."""
    text = repr({"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": tuple(shape)})
    body = text.encode("latin1")
    pad = _HEADER_BYTES - 10 - len(body) - 1
    if pad < 0:
        raise ShapeError(f"npy header too long for shape {shape}")
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", _HEADER_BYTES - 10) + body + b" " * pad + b"\n"


class _Column:
    """One recorded quantity: rows buffered in memory, then appended to ``<folder>/<key>.npy``."""

    def __init__(self, path: Path, first) -> None:
        self.path = path
        arr = np.asarray(first, dtype=float)
        self.tail = arr.shape
        self.dtype = np.dtype(float)
        self.rows = 0
        self.buf: list = []
        self.fh = open(path, "wb")  # noqa: SIM115 - closed by close()
        self.fh.write(_npy_header(self.dtype, (0, *self.tail)))

    def add(self, value) -> None:
        self.buf.append(value)
        if len(self.buf) >= CHUNK_ROWS:
            self.flush()

    def flush(self) -> None:
        if not self.buf:
            return
        block = np.asarray(self.buf, dtype=self.dtype)
        if block.shape[1:] != self.tail:
            raise ShapeError(f"recorded value {self.path.stem!r} changed shape from {self.tail} to {block.shape[1:]}")
        self.fh.write(np.ascontiguousarray(block).tobytes())
        self.rows += block.shape[0]
        self.buf = []

    def close(self) -> None:
        self.flush()
        self.fh.seek(0)
        self.fh.write(_npy_header(self.dtype, (self.rows, *self.tail)))
        self.fh.close()


class Recording:
    """Per-step values of a run (``t, q, dq, ddq, stack`` and any probe values), streamed to disk.

    Each quantity is buffered for :data:`CHUNK_ROWS` steps and then appended to its own ``.npy`` file in
    ``folder`` (a fresh temporary folder when none is given), so memory does not grow with the number of
    steps. :meth:`close` finishes the files; :meth:`load` opens them memory-mapped (``np.load(path,
    mmap_mode="r")`` works as well); :meth:`arrays` returns them in memory, as before. The stack label
    (``stack``) is stored as an integer code per step plus the list of labels, and becomes a string
    column on close.
    """

    def __init__(self, joint_names, folder: str | os.PathLike | None = None) -> None:
        self.joint_names = list(joint_names)
        self._own = folder is None
        self.folder = Path(tempfile.mkdtemp(prefix="hqp-tpm-rec-")) if folder is None else Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.columns: dict[str, _Column] = {}
        self.labels: dict[str, int] = {}
        self.closed = False

    def __len__(self) -> int:
        col = self.columns.get("t")
        return 0 if col is None else col.rows + len(col.buf)

    def __repr__(self) -> str:
        cols = ", ".join("stack" if k == "stack_code" else k for k in self.columns)
        return f"Recording({len(self)} steps, {len(self.joint_names)} joints, columns: {cols})"

    def add(self, **values) -> None:
        if self.closed:
            raise StateError("the recording is closed")
        for k, v in values.items():
            if k == "stack":
                v = self.labels.setdefault(v, len(self.labels))
                k = "stack_code"
            col = self.columns.get(k)
            if col is None:
                col = self.columns[k] = _Column(self.folder / f"{k}.npy", v)
            col.add(v)

    def close(self) -> None:
        """Write the buffered rows and the final headers; add ``stack.npy`` (labels) and ``joint_names.npy``."""
        if self.closed:
            return
        for col in self.columns.values():
            col.close()
        self.closed = True
        names = list(self.labels)
        codes = self.columns.get("stack_code")
        if codes is not None:
            width = max((len(s) for s in names), default=1) or 1
            dtype = np.dtype(f"<U{width}")
            lookup = np.array(names, dtype=dtype)
            src = np.load(codes.path, mmap_mode="r")
            with open(self.folder / "stack.npy", "wb") as fh:
                fh.write(_npy_header(dtype, (src.shape[0],)))
                for _, block in blocks(src, rows=4 * CHUNK_ROWS):  # memory does not grow with the run
                    fh.write(lookup[np.asarray(block, dtype=int)].tobytes())
            del src
            codes.path.unlink()
        np.save(self.folder / "joint_names.npy", np.array(self.joint_names, dtype=str))

    def files(self) -> dict[str, Path]:
        """Key -> ``.npy`` file of the closed recording."""
        self.close()
        return {p.stem: p for p in sorted(self.folder.glob("*.npy"))}

    def load(self) -> dict[str, np.ndarray]:
        """The closed recording's arrays, memory-mapped (read only)."""
        return {k: np.load(p, mmap_mode="r") for k, p in self.files().items()}

    def arrays(self) -> dict[str, np.ndarray]:
        """The recording's arrays in memory (for short runs and tests)."""
        return {k: np.array(v) for k, v in self.load().items()}

    def discard(self) -> None:
        """Remove the files of a recording made in its own temporary folder."""
        self.close()
        if self._own:
            shutil.rmtree(self.folder, ignore_errors=True)


def check_velocity(ctrl: Controller, bound: np.ndarray, step: int,
                   source: str = "the scenario's velocity_bound") -> None:
    """Raise :class:`~hqp_tpm.errors.DivergedError` if a joint velocity of ``ctrl`` (the state after ``step``, the
    run's step index from 0) exceeds ``bound`` (or is not finite), naming the step, the joint and the value (and
    ``source``, where the bound comes from)."""
    v = ctrl.v
    over = ~(np.abs(v) <= bound)
    if over.any():
        j = int(np.argmax(np.where(over, np.abs(np.nan_to_num(v, nan=np.inf)) / bound, -1.0)))
        name = ctrl.robot.joint_names[j]  # (one name per velocity column)
        raise DivergedError(f"the run diverged: at step {step + 1} (t = {ctrl.t - ctrl.dt:.6f} s) the velocity of "
                            f"joint {name} is {v[j]:.6g} rad/s, beyond {source} "
                            f"({bound[j]:.6g} rad/s); the {step} steps before it are kept")


def run(ctrl: Controller, steps: int, *, progress: bool = False, crosscheck: str | None = None,
        probes=(), label: str = "run", recording: Recording | None = None,
        stop: Callable[[], bool] | None = None, record: bool = False,
        velocity_bound: np.ndarray | None = None, bound_source: str = "the scenario's velocity_bound"
        ) -> tuple[Recording, dict]:
    """Step ``ctrl`` ``steps`` times, recording the state at each sample time and the command.

    ``dq`` is the joint velocity applied during the step (the command at velocity level, the
    state velocity at acceleration level); ``ddq`` the acceleration command (acceleration
    level) or the finite difference of ``dq`` (velocity level). ``crosscheck`` names a second
    solver the controller runs at every step like for like (``Controller(crosscheck=...)``, also used
    when the controller was built with one): ``crosscheck_diff`` (largest command difference) and
    ``crosscheck_same_problem`` (0 where a binding box makes the two solve different problems).
    ``probes``: callables ``probe(ctrl, result) -> dict`` adding per-step values.
    ``recording``: where to stream the rows (default: a new :class:`Recording` in a temporary folder);
    it is returned closed. ``stop``: checked before each step; when it returns true the run ends there
    (``timing["steps"]`` says how many steps were done, ``timing["stopped"]`` is true).
    ``record``: step with ``ctrl.step(record=True)`` (the readable path, every ``StepResult`` field computed with
    the step); else ``ctrl.step()``, compiled where the set-up has a compiled step (``timing["lean"]`` says whether
    it had), its fields computed when a probe reads them.
    ``velocity_bound``: per velocity column (rad/s); a step after which a joint velocity exceeds it raises
    :class:`~hqp_tpm.errors.DivergedError` naming the step, the joint and the value (:func:`check_velocity`), the
    rows of the steps before it recorded and ``recording`` closed (``hqp-tpm run`` writes them as a partial result).
    Compiling kernels (the first run on a machine) or loading them (:func:`hqp_tpm._jit.compile_seconds`) is kept out of
    ``wall_time_s``, ``mean_step_us`` and the progress bar's rate: ``timing["compile_s"]`` says how long it took.
    """
    rec = Recording(list(ctrl.robot.joint_names)) if recording is None else recording
    compiled_before = _jit.compile_seconds()
    bar = writer = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps, desc=label, unit="step", mininterval=0.5)
        writer = _jit.set_notice_writer(lambda line: tqdm.write(line, file=sys.stderr))
    try:
        return _run(ctrl, steps, bar, compiled_before, crosscheck, probes, rec, stop, record, velocity_bound,
                    bound_source)
    finally:
        if bar is not None:
            bar.close()
            _jit.set_notice_writer(writer)


def _run(ctrl, steps, bar, compiled_before, crosscheck, probes, rec, stop, record, velocity_bound, bound_source):
    prev_dq = None
    solve_time = 0.0
    own_check = ctrl.crosscheck
    if crosscheck:  # solved by the controller at every step, through the same path as the command
        ctrl.crosscheck = check_solver_name(crosscheck)
    compiled_path = not record and ctrl.compiled()
    compiling = 0.0   # seconds spent making kernels inside the loop (out of the step times and the bar's rate)
    t_start = time.perf_counter()
    done = 0
    stopped = False
    for _ in range(steps):
        if stop is not None and stop():
            stopped = True
            break
        q, v, t = ctrl.q.copy(), ctrl.v.copy(), ctrl.t
        c0 = _jit.compile_seconds()
        t0 = time.perf_counter()
        res = ctrl.step(record)
        stack = res.label()
        step_time = time.perf_counter() - t0
        compiled = _jit.compile_seconds() - c0
        if compiled > 0.0:
            compiling += compiled
            step_time = max(step_time - compiled, 0.0)
            if bar is not None:  # the bar's elapsed time and rate leave the compile out
                bar.start_t += compiled
                bar.last_print_t += compiled
        solve_time += step_time
        if velocity_bound is not None:
            try:
                check_velocity(ctrl, velocity_bound, done, bound_source)
            except DivergedError:
                rec.close()
                raise
        dq = res.command if ctrl.order == 1 else v
        if ctrl.order == 2:
            ddq = res.command
        else:
            ddq = np.zeros_like(dq) if prev_dq is None else (dq - prev_dq) / ctrl.dt
        prev_dq = dq
        row = {"t": t, "q": q, "dq": dq, "ddq": ddq, "stack": stack}
        for key in ("scale", "iterations"):
            if key in res.info and np.isscalar(res.info[key]):
                row[key] = float(res.info[key])
        if "saturated" in res.info:
            sat = np.zeros(ctrl.robot.nv)
            sat[np.asarray(res.info["saturated"], dtype=int)] = 1.0
            row["saturated"] = sat
        if "crosscheck" in res.info:  # the controller's like-for-like check (hqp_tpm.control.crosscheck)
            check = res.info["crosscheck"]
            row["crosscheck_diff"] = check["diff"]
            row["crosscheck_same_problem"] = float(check["same_problem"])
        for probe in probes:
            row.update(probe(ctrl, res))
        rec.add(**row)
        done += 1
        if bar is not None:
            bar.update(1)
    ctrl.crosscheck = own_check
    wall = time.perf_counter() - t_start - compiling
    rec.close()
    timing = {"wall_time_s": wall, "steps": done, "mean_step_us": 1e6 * solve_time / max(done, 1),
              "lean": compiled_path, "compile_s": _jit.compile_seconds() - compiled_before}
    if stopped:
        timing["stopped"] = True
    return rec, timing
