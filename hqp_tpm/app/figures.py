"""Matplotlib figures of a run, in the style of the papers' figures (PNG files)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _save(fig, path: Path) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def joint_velocities(path: Path, arrays: dict, limits=None, title: str = "") -> None:
    """Joint velocities over time (Fig. 4 of papers/000; with limits, Fig. 3 of papers/002)."""
    t, dq, names = arrays["t"], arrays["dq"], arrays["joint_names"]
    cols = [i for i in range(dq.shape[1]) if np.ptp(dq[:, i]) > 0 or limits is not None]
    if limits is not None:
        n = len(cols)
        ncol = 4
        fig, axes = plt.subplots(int(np.ceil(n / ncol)), ncol, figsize=(12, 1.8 * np.ceil(n / ncol)), sharex=True)
        for ax, i in zip(np.ravel(axes), cols, strict=False):
            ax.plot(t, dq[:, i], "b", lw=0.8)
            ax.axhline(limits[i], color="r", lw=0.8)
            ax.axhline(-limits[i], color="r", lw=0.8)
            ax.set_title(str(names[i]), fontsize=8)
        for ax in np.ravel(axes)[n:]:
            ax.axis("off")
    else:
        fig, ax = plt.subplots(figsize=(8, 3.5))
        for i in cols:
            ax.plot(t, dq[:, i], lw=0.8, label=str(names[i]))
        ax.set_xlabel("t [s]")
        ax.set_ylabel("joint velocity [rad/s]")
        ax.legend(fontsize=7, ncol=4)
    fig.suptitle(title)
    _save(fig, path)


def task_errors(path: Path, arrays: dict, tasks: dict, title: str = "") -> None:
    """Norm of each task's error over time, with the scale factor when there is one (Fig. 2 of papers/002)."""
    t = arrays["t"]
    rows = 2 if "scale" in arrays else 1
    fig, axes = plt.subplots(rows, 1, figsize=(8, 2.5 + 1.5 * rows), sharex=True, squeeze=False)
    ax = axes[0, 0]
    for name in tasks:
        e = arrays.get(f"error_{name}")
        if e is None:
            continue
        ax.plot(t, np.abs(e) if e.ndim == 1 else np.linalg.norm(e, axis=1), lw=0.9, label=name)
    ax.set_yscale("log")
    ax.set_ylabel("task error")
    ax.legend(fontsize=8)
    if "scale" in arrays:
        axes[1, 0].plot(t, arrays["scale"], "k", lw=0.9)
        axes[1, 0].set_ylabel("scale factor s")
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(title)
    _save(fig, path)


def pointing_error(path: Path, arrays: dict, title: str = "") -> None:
    """Pointing error ``cos a_d - p_rp`` with the steps where the task is in the stack in red (Fig. 7)."""
    t, e, stack = arrays["t"], arrays["pointing_error"], arrays["stack"]
    active = np.array(["pointing" in s for s in stack])
    fig, ax = plt.subplots(figsize=(8, 3))
    ax.plot(t, e, "b", lw=0.8, label="cos a_d - p_rp")
    ax.plot(t[active], e[active], "r.", ms=1.5, label="in the stack")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("t [s]")
    ax.legend(fontsize=8)
    fig.suptitle(title)
    _save(fig, path)


def distances(path: Path, arrays: dict, thresholds: dict, title: str = "") -> None:
    """Closest distances over time with their thresholds (Figs. 5-6 of papers/000)."""
    keys = [k for k in ("d_ee", "d_minimal", "d_obstacle", "d_self") if k in arrays]
    extra = "active_point" in arrays
    fig, axes = plt.subplots(len(keys) + extra, 1, figsize=(8, 2.2 * (len(keys) + extra)), sharex=True,
                             squeeze=False)
    t = arrays["t"]
    for ax, k in zip(axes[:, 0], keys, strict=False):
        ax.plot(t, arrays[k], lw=0.9)
        for name, val in thresholds.get(k, {}).items():
            ax.axhline(val, ls="--", lw=0.7, color="r" if "1" in name or "safe" in name else "g", label=name)
        ax.set_ylabel(k + " [m]")
        if thresholds.get(k):
            ax.legend(fontsize=7)
    if extra:
        ax = axes[-1, 0]
        ax.plot(t, arrays["active_point"] + 1, "k.", ms=1)
        ax.set_ylabel("active point")
        ax.set_ylim(-0.5, np.nanmax(arrays["active_point"]) + 1.5)
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(title)
    _save(fig, path)


def comanipulation(path: Path, runs: dict, sigma_m_bar: float = 1.5, sigma_l_bar: float = 2.0,
                   title: str = "") -> None:
    """Co-manipulation indices over time (Figs. 5-7 of papers/003): sigma_l (11), sigma_m (14) with its
    threshold, max |q_i - q_i^*| with its threshold, and the active stack (1 force, 2 manipulability,
    3 joint limit, 4 pose). ``runs``: label -> arrays (one run, or the hierarchy and the baseline)."""
    stacks = [a for a in runs.values() if "stack_id" in a]
    fig, axes = plt.subplots(3 + bool(stacks), 1, figsize=(8, 2.0 * (3 + bool(stacks))), sharex=True)
    colors = iter(["b", "r", "g", "k"])
    for label, a in runs.items():
        c = next(colors)
        axes[0].plot(a["t"], a["sigma_l"], c, lw=0.9, label=label)
        axes[1].plot(a["t"], a["sigma_m"], c, lw=0.9, label=label)
        axes[2].plot(a["t"], a["joint_deviation_max"], c, lw=0.9, label=label)
    axes[1].axhline(sigma_m_bar, color="k", ls="--", lw=0.7, label="threshold")
    axes[2].axhline(sigma_l_bar, color="k", ls="--", lw=0.7, label="threshold")
    for ax, name in zip(axes, ("sigma_l", "sigma_m", "max |q_i - q_i*| [rad]"), strict=False):
        ax.set_ylabel(name)
        ax.legend(fontsize=7)
    if stacks:
        a = stacks[0]
        axes[3].plot(a["t"], a["stack_id"], "b.", ms=1)
        axes[3].set_yticks([1, 2, 3, 4], ["force", "manip.", "joint lim.", "pose"])
        axes[3].set_ylim(0.5, 4.5)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    _save(fig, path)


def write_all(out: Path, arrays: dict, sc, tasks: dict, policy) -> list[Path]:
    """The figures that apply to this run; returns their paths."""
    written = []
    p = out / "joint_velocities.png"
    limits = None
    if "saturated" in arrays or sc.solver in ("sns_tpm", "sns") or "romeo" in sc.name:
        limits = getattr(policy, "velocity_limits", None)
    joint_velocities(p, arrays, limits, f"{sc.name}: joint velocities")
    written.append(p)
    p = out / "task_errors.png"
    task_errors(p, arrays, tasks, f"{sc.name}: task errors")
    written.append(p)
    if "pointing_error" in arrays:
        p = out / "pointing_error.png"
        pointing_error(p, arrays, f"{sc.name}: pointing error")
        written.append(p)
    if any(k in arrays for k in ("d_ee", "d_minimal", "d_obstacle", "d_self")):
        p = out / "distances.png"
        distances(p, arrays, getattr(policy, "thresholds", {}), f"{sc.name}: distances")
        written.append(p)
    if "sigma_m" in arrays:
        p = out / "comanipulation.png"
        comanipulation(p, {sc.name: arrays}, getattr(policy, "sigma_m_bar", 1.5), getattr(policy, "sigma_l_bar", 2.0),
                       f"{sc.name}: co-manipulation indices")
        written.append(p)
    return written
