"""``plot_crosscheck``: the per-step disagreement of a controller's solver and its cross-check solver."""

from __future__ import annotations

import numpy as np


def _arrays(source) -> tuple[dict, str]:
    log = getattr(source, "crosscheck_log", source)  # a Controller or its CrosscheckLog
    if hasattr(log, "arrays") and callable(log.arrays) and hasattr(log, "diff"):
        return log.arrays(), getattr(log, "solver", "")
    if isinstance(source, dict) and "crosscheck_diff" in source:  # recorded arrays (hqp-tpm run --crosscheck)
        return source, ""
    raise TypeError(f"plot_crosscheck takes a Controller, its crosscheck_log or recorded arrays with "
                    f"'crosscheck_diff', got {type(source).__name__}")


def plot_crosscheck(source, ax=None, *, tol: float | None = 1e-6, label: str | None = None):
    """Semilog plot of the largest command difference per step (steps where the two solvers solve different
    problems -- a binding box -- drawn apart). ``source``: a :class:`~hqp_tpm.control.controller.Controller`
    built with ``crosscheck=...``, its ``crosscheck_log``, or the arrays of ``hqp-tpm run --crosscheck``.
    ``tol``: a horizontal reference line (None: none). Returns the matplotlib axes."""
    import matplotlib.pyplot as plt

    arrays, other = _arrays(source)
    t = np.asarray(arrays["t"], dtype=float)
    d = np.asarray(arrays["crosscheck_diff"], dtype=float)
    if t.size != d.size:
        t = t[: d.size]
    same = np.asarray(arrays.get("crosscheck_same_problem", np.ones(d.size, dtype=bool)), dtype=bool)
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 3))
    floor = np.finfo(float).tiny
    name = label or (f"vs {other}" if other else "crosscheck")
    ax.semilogy(np.where(same, t, np.nan), np.maximum(d, floor), lw=1, label=f"{name} (same problem)")
    if (~same).any():
        ax.semilogy(np.where(~same, t, np.nan), np.maximum(d, floor), lw=1, color="0.6",
                    label=f"{name} (box binds: different problems)")
    if tol is not None:
        ax.axhline(tol, color="k", ls=":", lw=0.8, label=f"{tol:g}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("max |x - x_other|")
    ax.set_title("solver cross-check, per step")
    ax.legend(loc="best", fontsize="small")
    return ax
