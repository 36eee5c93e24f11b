"""Cross-checking a controller's solver with another one, step by step, like for like.

``Controller(..., crosscheck="qp:daqp")`` solves every step again with the other solver through the command's path:
the same levels (active inequality rows as equalities), ``x0``, box, damping and blend (eq. (8) of papers/003, from
the same policy state). The records (:class:`CrosscheckLog`): docs/cli.md, "Crosscheck".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from hqp_tpm.solvers.levels import Level
from hqp_tpm.solvers.registry import ANALYTIC, BOXED, solve


def _kind(name: str) -> str:
    return "analytic" if name in ANALYTIC else "sns" if name in BOXED else "qp"


def same_levels(levels) -> list[Level]:
    """The levels as the analytic solvers see them: active rows as equalities, empty levels dropped."""
    out = []
    for lv in levels:
        J, b = lv.as_equality()
        if J.shape[0]:
            out.append(Level(J, b, name=lv.name))
    return out


def crosscheck_step(ctrl, state, stack, levels, x0, box, x_main) -> Callable[[np.ndarray], dict]:
    """Solve the step with ``ctrl.crosscheck`` through the controller's path (module doc); call before the
    controller's own blend. ``x_main``: the controller's unblended solution. Returns ``compare(x)``: the step's
    record (:meth:`CrosscheckLog.append`) against the controller's final command ``x``."""
    other = ctrl.crosscheck
    n = ctrl.robot.nv
    same = same_levels(levels)
    kw = {"x0": x0, "box": box, "lambda_max": ctrl.lambda_max, "eps": ctrl.eps}
    x = solve(other, same, n, **kw)[0]
    policy = ctrl.policy
    if policy.blends:
        def resolve(s):
            return solve(other, s.to_levels(state, ctrl.t, ctrl.order), n, **kw)[0]

        saved = policy.snapshot()
        try:
            x = policy.blend(state, ctrl.t, stack, x, resolve)
        finally:
            policy.restore(saved)
        if box is not None and other not in ANALYTIC:
            x = np.minimum(np.maximum(x, box[0]), box[1])
    same_problem = True
    ka, kb = _kind(ctrl.solver), _kind(other)
    if box is not None and not (ka == kb and ka in ("analytic", "qp")):
        free = x_main if ka == "analytic" else x if kb == "analytic" else solve("tpm", same, n, **kw)[0]
        unit = 1.0 + np.maximum(np.abs(np.nan_to_num(box[0], neginf=0.0)), np.abs(np.nan_to_num(box[1], posinf=0.0)))
        same_problem = bool((np.maximum(0.0, np.maximum(box[0] - free, free - box[1])) <= 1e-9 * unit).all())
    command = np.asarray(x, dtype=float)

    def compare(x: np.ndarray) -> dict:
        d = np.abs(command - x)
        j = int(np.argmax(d)) if d.size else 0
        return {"solver": other, "diff": float(d[j]) if d.size else 0.0, "joint": j,
                "rel": float(np.linalg.norm(command - x) / max(1.0, np.linalg.norm(x))), "same_problem": same_problem,
                # every Policy can snapshot and restore its state, so the blend is always replayed: like for like
                "like_for_like": True, "command": command}
    return compare


@dataclass
class CrosscheckLog:
    """Per successful step: time, largest command difference, its joint, relative difference, flags."""

    solver: str = ""
    t: list = field(default_factory=list)
    diff: list = field(default_factory=list)
    joint: list = field(default_factory=list)
    rel: list = field(default_factory=list)
    same_problem: list = field(default_factory=list)
    like_for_like: list = field(default_factory=list)

    def append(self, t: float, rec: dict) -> None:
        self.solver = rec["solver"]
        self.t.append(float(t))
        self.diff.append(rec["diff"])
        self.joint.append(rec["joint"])
        self.rel.append(rec["rel"])
        self.same_problem.append(rec["same_problem"])
        self.like_for_like.append(rec["like_for_like"])

    def __len__(self) -> int:
        return len(self.t)

    def arrays(self) -> dict[str, np.ndarray]:
        return {"t": np.asarray(self.t), "crosscheck_diff": np.asarray(self.diff),
                "crosscheck_joint": np.asarray(self.joint), "crosscheck_rel": np.asarray(self.rel),
                "crosscheck_same_problem": np.asarray(self.same_problem, dtype=bool),
                "crosscheck_like_for_like": np.asarray(self.like_for_like, dtype=bool)}

    def max_diff(self, *, same_problem_only: bool = True) -> float:
        """Largest difference over the steps (by default over the steps where the problems are the same)."""
        d = np.asarray(self.diff)
        if same_problem_only:
            d = d[np.asarray(self.same_problem, dtype=bool)] if d.size else d
        return float(d.max()) if d.size else 0.0
