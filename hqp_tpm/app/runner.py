"""Run a controller for a number of steps and record what happened, step by step."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from hqp_tpm.control.controller import Controller
from hqp_tpm.solvers.levels import Level
from hqp_tpm.solvers.registry import solve


@dataclass
class Recording:
    """Per-step arrays of a run (``t, q, dq, ddq, stack`` and any probe values)."""

    joint_names: list[str]
    columns: dict[str, list] = field(default_factory=dict)

    def __repr__(self) -> str:
        n = len(self.columns.get("t", ()))
        return f"Recording({n} steps, {len(self.joint_names)} joints, columns: {', '.join(self.columns)})"

    def add(self, **values) -> None:
        for k, v in values.items():
            self.columns.setdefault(k, []).append(v)

    def arrays(self) -> dict[str, np.ndarray]:
        out = {}
        for k, v in self.columns.items():
            if k == "stack":
                out[k] = np.array(v, dtype=str)
            else:
                out[k] = np.asarray(v, dtype=float)
        out["joint_names"] = np.array(self.joint_names, dtype=str)
        return out


def run(ctrl: Controller, steps: int, *, progress: bool = False, crosscheck: str | None = None,
        probes=(), label: str = "run") -> tuple[Recording, dict]:
    """Step ``ctrl`` ``steps`` times, recording the state at each sample time and the command.

    ``dq`` is the joint velocity applied during the step (the command at velocity level, the
    state velocity at acceleration level); ``ddq`` the acceleration command (acceleration
    level) or the finite difference of ``dq`` (velocity level). ``crosscheck`` names a second
    solver that solves every step's same levels; the largest command difference is recorded.
    ``probes``: callables ``probe(ctrl, result) -> dict`` adding per-step values.
    """
    rec = Recording(list(ctrl.robot.joint_names))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=steps, desc=label, unit="step", mininterval=0.5)
    prev_dq = None
    solve_time = 0.0
    t_start = time.perf_counter()
    for _ in range(steps):
        q, v, t = ctrl.q.copy(), ctrl.v.copy(), ctrl.t
        t0 = time.perf_counter()
        res = ctrl.step()
        solve_time += time.perf_counter() - t0
        dq = res.command if ctrl.order == 1 else v
        if ctrl.order == 2:
            ddq = res.command
        else:
            ddq = np.zeros_like(dq) if prev_dq is None else (dq - prev_dq) / ctrl.dt
        prev_dq = dq
        row = {"t": t, "q": q, "dq": dq, "ddq": ddq, "stack": res.stack.label()}
        for key in ("scale", "iterations"):
            if key in res.info and np.isscalar(res.info[key]):
                row[key] = float(res.info[key])
        if "saturated" in res.info:
            sat = np.zeros(ctrl.robot.nv)
            sat[np.asarray(res.info["saturated"], dtype=int)] = 1.0
            row["saturated"] = sat
        if crosscheck:
            x0 = -ctrl.nullspace_damping * v if (ctrl.order == 2 and ctrl.nullspace_damping) else None
            box = ctrl.box(ctrl.state, t) if ctrl.box is not None else None
            # the same stack: inequality rows as the analytic solver used them (active ones, as equalities)
            same = [Level(J, b, name=lv.name) for lv, (J, b) in zip(res.levels, (lv.as_equality() for lv in
                                                                             res.levels), strict=True)
                    if J.shape[0]]
            other, _ = solve(crosscheck, same, ctrl.robot.nv, x0=x0, box=box,
                             lambda_max=ctrl.lambda_max, eps=ctrl.eps)
            row["crosscheck_diff"] = float(np.max(np.abs(other - res.command)))
        for probe in probes:
            row.update(probe(ctrl, res))
        rec.add(**row)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    wall = time.perf_counter() - t_start
    timing = {"wall_time_s": wall, "steps": steps, "mean_step_us": 1e6 * solve_time / max(steps, 1)}
    return rec, timing
