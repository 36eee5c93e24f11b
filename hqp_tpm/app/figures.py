"""Matplotlib figures of a run, in the style of the papers' figures (PNG files).

Figures are drawn on explicit :class:`matplotlib.figure.Figure` objects with the Agg canvas:
importing this module never touches pyplot or the user's backend, so a notebook that writes
figure files keeps showing its own inline plots.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from hqp_tpm.app.context import RunContext
from hqp_tpm.tasks import (
    CenterOfMass,
    Force,
    FrameOrientation,
    FramePose,
    FramePosition,
    JointLimit,
    Manipulability,
    Pointing,
    Posture,
    QuaternionOrientation,
    Task,
)
from hqp_tpm.tasks.avoidance import Avoidance

#: Colours and line styles of threshold lines, in the order the thresholds are given (distinct pairs).
THRESHOLD_STYLES = [("tab:red", "--"), ("tab:green", ":"), ("tab:orange", "-."), ("tab:purple", (0, (5, 1, 1, 1)))]

#: Above this many joints, a run without a joint box still gets one axis per joint (with the robot's limits).
GRID_JOINTS = 12

#: Labels and units of the recorded distances.
DISTANCE_LABELS = {"d_ee": "EE distance D_ee [m]", "d_minimal": "control-point distance D_minimal [m]",
                   "d_obstacle": "robot-obstacle distance [m]", "d_self": "self distance [m]"}


def _figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)  # the figure draws into memory; no pyplot, no global backend change
    return fig


def _save(fig: Figure, path: Path) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=110)


# ------------------------------------------------------------------------------------------ units of task errors
def error_groups(tasks: dict) -> list[tuple[str, str, slice | None, str]]:
    """How each task's recorded error ``error_<name>`` is plotted: ``(task name, quantity label, rows, unit)``.

    Tasks are grouped by physical unit (one axis each): positions in m, orientations in rad, forces in N,
    joint angles in rad, pointing in degrees, indices without unit. ``rows`` selects part of the error
    (a pose is split into its position and orientation rows); None means the whole vector.
    """
    out = []
    for name, task in tasks.items():
        if isinstance(task, FramePose):
            out += [(name, "position", slice(0, 3), "m"), (name, "orientation", slice(3, 6), "rad")]
        elif isinstance(task, (FramePosition, CenterOfMass)):
            out.append((name, "position", None, "m"))
        elif isinstance(task, FrameOrientation):
            out.append((name, "orientation", None, "rad"))
        elif isinstance(task, Posture):
            out.append((name, "joint angles", None, "rad"))
        elif isinstance(task, Force):
            out.append((name, "force", None, "N"))
        elif isinstance(task, Pointing):
            out.append((name, "pointing angle", None, "deg"))
        else:  # quaternion vector part, manipulability and joint-limit indices, avoidance, others: no unit
            quantity = next((q for cls, q in _QUANTITIES if isinstance(task, cls)), type(task).__name__)
            out.append((name, quantity, None, "1"))
    return out


#: What the error of a dimensionless task is, for the legend (any other task: its class name).
_QUANTITIES = ((QuaternionOrientation, "quaternion error (10)"), (Manipulability, r"$\sigma_m^* - \sigma_m$"),
               (JointLimit, r"$-\sigma_l$"), (Avoidance, "avoidance"))

_UNIT_TITLES = {"m": "position error [m]", "rad": "angle error [rad]", "N": "force error [N]",
                "deg": "pointing angle error [deg]\n(cone: outside it only)", "1": "error (dimensionless)"}


def _pointing_angle_deg(e: np.ndarray, alpha_d: float) -> np.ndarray:
    """Angle between the axis and ``z_d`` (deg) from the recorded ``e = cos(alpha_d) - p_rp``."""
    return np.rad2deg(np.arccos(np.clip(np.cos(alpha_d) - np.asarray(e, dtype=float), -1.0, 1.0)))


def _error_norm(arrays: dict, task: Task, name: str, rows, unit: str) -> np.ndarray | None:
    e = arrays.get(f"error_{name}")
    if e is None:
        return None
    e = np.asarray(e, dtype=float)
    if isinstance(task, Pointing):  # the cone (21): how far the axis is outside it; the equality (16): |α − α_d|
        dev = _pointing_angle_deg(e, task.alpha_d) - np.rad2deg(task.alpha_d)
        return np.maximum(dev, 0.0) if task.inequality else np.abs(dev)
    if e.ndim == 1:
        return np.abs(e)
    return np.linalg.norm(e[:, rows] if rows is not None else e, axis=1)


# ------------------------------------------------------------------------------------------ figures
def joint_velocities(path: Path, arrays: dict, limits=None, title: str = "", enforced: bool = True) -> None:
    """Joint velocities over time (Fig. 4 of papers/000; with limits, Fig. 3 of papers/002).

    Without ``limits``: one axis, every joint that moves. With ``limits`` (one per velocity column,
    ``inf`` for none): one small axis per limited joint, its velocity in blue and ``±limit`` in red;
    unlimited columns (a floating base) are left out and counted in the title. ``enforced=False``: the limits
    are the robot's, drawn for comparison (the run had no joint box).
    """
    t, dq, names = arrays["t"], arrays["dq"], arrays["joint_names"]
    if limits is not None:
        limits = np.asarray(limits, dtype=float)
        cols = [i for i in range(dq.shape[1]) if np.isfinite(limits[i])]
        skipped = dq.shape[1] - len(cols)
        n, ncol = len(cols), 4 if len(cols) > 9 else 3
        nrow = int(np.ceil(n / ncol))
        fig = _figure(12, 1.55 * nrow + 1.1)
        axes = np.atleast_1d(fig.subplots(nrow, ncol, sharex=True, squeeze=False)).ravel()
        for k, (ax, i) in enumerate(zip(axes, cols, strict=False)):
            ax.plot(t, dq[:, i], color="tab:blue", lw=0.8)
            ax.axhline(limits[i], color="tab:red", lw=0.8)
            ax.axhline(-limits[i], color="tab:red", lw=0.8)
            ax.set_title(str(names[i]), fontsize=8, pad=2)
            ax.tick_params(labelsize=7)
            if k % ncol == 0:
                ax.set_ylabel(r"$\dot q$ [rad/s]", fontsize=8)
            if k >= n - ncol:
                ax.set_xlabel("t [s]", fontsize=8)
                ax.tick_params(labelbottom=True)
        for ax in axes[n:]:
            ax.axis("off")
        handles = [Line2D([], [], color="tab:blue", lw=1.2, label=r"joint velocity $\dot q_i$"),
                   Line2D([], [], color="tab:red", lw=1.2, label=r"velocity limit $\pm\dot q_{\max,i}$"
                          + ("" if enforced else " (not enforced in this run)"))]
        fig.legend(handles=handles, loc="upper right", fontsize=8, ncol=2, frameon=False)
        note = f" ({n} limited joints; {skipped} floating-base columns not shown)" if skipped else ""
        fig.suptitle(title + note, x=0.02, ha="left", fontsize=10)
    else:
        cols = [i for i in range(dq.shape[1]) if np.ptp(dq[:, i]) > 0]
        fig = _figure(8, 3.6)
        ax = fig.subplots()
        for i in cols:
            ax.plot(t, dq[:, i], lw=0.8, label=str(names[i]))
        ax.set_xlabel("t [s]")
        ax.set_ylabel(r"joint velocity $\dot q$ [rad/s]")
        if cols:
            ax.legend(fontsize=7, ncol=min(4, len(cols)), loc="best")
        fig.suptitle(title)
    _save(fig, path)


#: The stack timeline shows at most this many stacks on rows of their own (the others share one row).
TIMELINE_ROWS = 8


def stack_spans(t: np.ndarray, stack) -> dict[str, list[tuple[float, float]]]:
    """Active stack label -> its ``(start, duration)`` spans (s), each step lasting until the next sample (the last
    one a median step); the labels in the order they first become active."""
    t = np.asarray(t, dtype=float)
    labels = np.asarray([str(s) for s in stack])
    if t.size == 0:
        return {}
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    ends = np.append(t[1:], t[-1] + dt)
    change = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    starts, stops = np.concatenate([[0], change]), np.concatenate([change, [t.size]])
    out: dict[str, list[tuple[float, float]]] = {}
    for a, b in zip(starts, stops, strict=True):
        out.setdefault(str(labels[a]), []).append((float(t[a]), float(ends[b - 1] - t[a])))
    return out


def stack_timeline(ax, t: np.ndarray, stack) -> list[str]:
    """Which stack is active when: one row per stack (its label written on it), bars where it is active; the
    rows of the :data:`TIMELINE_ROWS` longest-active stacks, the rest on one row. Returns the row labels."""
    spans = stack_spans(t, stack)
    total = {k: sum(w for _, w in v) for k, v in spans.items()}
    keep = sorted(spans, key=lambda k: -total[k])[:TIMELINE_ROWS]
    rows = [k for k in spans if k in keep]  # order of first activation
    rest = [k for k in spans if k not in keep]
    if rest:
        rows.append(f"{len(rest)} other stacks")
        spans[rows[-1]] = [sp for k in rest for sp in spans[k]]
    for k, label in enumerate(rows):  # the bar in the row's lower half, its label above it (never over a bar)
        ax.broken_barh(spans[label], (k - 0.02, 0.45), color=f"C{k % 10}", alpha=0.7, lw=0)
        share = sum(w for _, w in spans[label])
        ax.text(0.005, k - 0.06, f"{label}  ({share:.3g} s)", transform=ax.get_yaxis_transform(), va="bottom",
                ha="left", fontsize=7, clip_on=True)
    ax.set_ylim(len(rows) - 0.5, -0.5)
    ax.set_yticks([])
    ax.set_ylabel("active stack", fontsize=8)
    return rows


#: A log axis of task errors spans at most this ratio below its largest value (machine precision).
LOG_RANGE = 1e-15


def _legend_outside(ax) -> None:
    """The axis' legend right of it, outside the data (many tasks' legends covered their curves)."""
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, frameon=False)


def task_errors(path: Path, arrays: dict, tasks: dict, title: str = "") -> Figure:
    """Norm of each task's error over time, one log axis per unit (m, rad, N, deg, dimensionless), the
    SNS scale factor when there is one (Fig. 2 of papers/002), and which stack is active when
    (:func:`stack_timeline`). Returns the figure (saved to ``path``)."""
    t = arrays["t"]
    series: dict[str, list] = {}
    for name, quantity, rows, unit in error_groups(tasks):
        y = _error_norm(arrays, tasks[name], name, rows, unit)
        if y is None:
            continue
        label = name if quantity in ("position", "orientation", "force", "pointing angle") \
            and rows is None else f"{name} ({quantity})"
        if quantity == "joint angles":  # a posture: the norm over its joints
            label = f"{name} (norm over {tasks[name].dim} joints)"
        series.setdefault(unit, []).append((label, y))
    scale = np.asarray(arrays["scale"], dtype=float) if "scale" in arrays else None
    flat_scale = scale is not None and bool(np.all(scale == 1.0))
    n_rows = min(len(set(map(str, arrays["stack"]))), TIMELINE_ROWS + 1) if "stack" in arrays else 0
    heights = [2.0] * len(series) + ([0.9 if flat_scale else 1.6] if scale is not None else []) \
        + ([0.45 + 0.36 * n_rows] if n_rows else []) or [2.0]
    fig = _figure(9.5, 0.9 + sum(heights))
    axes = np.atleast_1d(fig.subplots(len(heights), 1, sharex=True, squeeze=False,
                                      gridspec_kw={"height_ratios": heights})).ravel()
    for ax, unit in zip(axes, series, strict=False):
        for k, (label, y) in enumerate(series[unit]):  # alternate styles: coinciding curves stay visible
            ax.plot(t, np.where(y > 0, y, np.nan), lw=1.0, ls=("-", "--", "-.", ":")[k % 4], label=label)
        pos = np.concatenate([y[np.isfinite(y) & (y > 0)] for _, y in series[unit]])
        later = np.concatenate([y[1:][np.isfinite(y[1:]) & (y[1:] > 0)] for _, y in series[unit]])
        if len(pos):
            ax.set_yscale("log")
            top = float(pos.max())
            # the first sample is left out of the range: a task that starts on its target has a numerically
            # zero error there (7.7e-20 rad on Talos' feet), which stretched the axis down to 1e-20
            bottom = max(float(later.min()) if len(later) else float(pos.min()), LOG_RANGE * top)
            ax.set_ylim(bottom / 2.0, top * 2.0)
        ax.set_ylabel(_UNIT_TITLES.get(unit, unit), fontsize=8)
        _legend_outside(ax)
        ax.grid(True, which="major", lw=0.3, alpha=0.6)
    if scale is not None:
        ax = axes[len(series)]
        ax.plot(t, scale, "k", lw=0.9, label="SNS scale factor s")
        ax.set_ylabel("SNS scale\nfactor s", fontsize=8)
        ax.set_ylim(-0.05, 1.1)
        ax.set_yticks([0.0, 0.5, 1.0])
        if flat_scale:
            ax.text(0.5, 0.45, "s = 1 throughout: no task was scaled", transform=ax.transAxes, ha="center",
                    va="center", fontsize=8, color="0.3")
    if n_rows:
        stack_timeline(axes[-1], t, arrays["stack"])
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    _save(fig, path)
    return fig


def pointing_error(path: Path, arrays: dict, alpha_d: float | None = None, title: str = "",
                   inequality: bool | None = None) -> Figure:
    """Angle between the pointing axis and ``z_d`` in degrees, with the cone half-angle ``alpha_d`` and the steps
    where the task is in the stack in red (Fig. 7 of papers/000, in degrees rather than cosines).

    Without ``alpha_d`` the recorded ``cos(alpha_d) - p_rp`` is plotted as it is (dimensionless). ``inequality``:
    the task keeps the axis inside the cone (True) or on it (False); the legend says which. Returns the figure."""
    t, e, stack = arrays["t"], np.asarray(arrays["pointing_error"], dtype=float), arrays["stack"]
    active = np.array(["pointing" in s for s in stack])
    fig = _figure(8, 3.2)
    ax = fig.subplots()
    if alpha_d is None:
        y, label, ylabel, ref = e, "cos α_d − p_rp", "pointing error cos α_d − p_rp [-]", 0.0
    else:
        y, label, ref = _pointing_angle_deg(e, alpha_d), "angle between EE z axis and z_d", np.rad2deg(alpha_d)
        ylabel = "angle to z_d [deg]"
    ax.plot(t, y, color="tab:blue", lw=0.8, label=label)
    ax.plot(t[active], y[active], ".", color="tab:red", ms=1.5, label="pointing task in the stack")
    what = {True: "the inequality's bound: the axis stays inside", False: "the equality's target",
            None: "cone half-angle"}[inequality]
    ref_label = f"α_d = {ref:g}° ({what})" if alpha_d is not None else "cone boundary"
    ax.axhline(ref, color="k", ls="--", lw=0.7, label=ref_label)
    ax.set_xlabel("t [s]")
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8, loc="best", markerscale=6)
    fig.suptitle(title)
    _save(fig, path)
    return fig


#: The 3-D EE path is drawn from at most this many samples.
PATH_SAMPLES = 3000


def ee_path(path: Path, arrays: dict, robot, scene, title: str = "") -> Figure | None:
    """The EE's path in Cartesian space (3-D, from the recorded ``q``), the EE task's desired path and the
    obstacles at t = 0 (their centres). Without an EE task, the same for each moving frame target of ``scene``
    (:attr:`SceneItems.targets`: a humanoid's hands). None (nothing written) without any of them."""
    import pinocchio as pin
    from matplotlib.ticker import MaxNLocator

    task = scene.ee_task
    frame = scene.ee_frame or (task.frame if task is not None else None)
    if task is not None and frame is not None and task.dim == 3:
        pairs = [(task, frame)]
    else:
        pairs = [(tk, tk.frame) for tk in scene.targets if tk.frame is not None and tk.dim == 3]
    if not pairs:
        return None
    t_all, q_all = np.asarray(arrays["t"], dtype=float), np.asarray(arrays["q"], dtype=float)
    idx = np.unique(np.linspace(0, len(t_all) - 1, min(len(t_all), PATH_SAMPLES)).round().astype(int))
    model, data = robot.model, robot.model.createData()
    fids = [robot.frame_id(f) for _, f in pairs]
    actual = np.empty((len(pairs), len(idx), 3))
    for k, i in enumerate(idx):
        pin.framesForwardKinematics(model, data, q_all[i])
        for j, fid in enumerate(fids):
            actual[j, k] = data.oMf[fid].translation
    fig = _figure(7, 6)
    ax = fig.add_subplot(projection="3d")
    pts, desired_all = [], []
    for j, (tk, f) in enumerate(pairs):
        desired = np.array([tk.reference(float(ti))[0] for ti in t_all[idx]], dtype=float)
        desired_all.append(desired)
        c_des, c_act = ("tab:green", "tab:red") if j == 0 else ("tab:olive", "tab:purple")
        ax.plot(*desired.T, color=c_des, lw=1.2, ls="--", label=f"desired ({tk.name})")
        ax.plot(*actual[j].T, color=c_act, lw=1.0, label=f"EE ({f})" if len(pairs) == 1 else f"{f}")
        pts += [actual[j], desired]
    ax.scatter(*actual[:, 0].T, color="k", marker="o", s=18, label="start")
    centres = np.array([o.placement_at(0.0).act(o.local_center) for o in scene.obstacles]).reshape(-1, 3)
    if len(centres):
        ax.scatter(*centres.T, color="k", marker="x", s=30, label="obstacles (t = 0)")
        pts.append(centres)
    allp = np.vstack(pts)
    mid, half = (allp.max(0) + allp.min(0)) / 2, max(np.ptp(allp, axis=0).max() / 2, 1e-3)
    for setter, m in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid, strict=True):
        setter(m - half, m + half)  # equal scales: a circle looks like one
    ax.set_box_aspect((1, 1, 1))
    centred = desired_all[0] - desired_all[0].mean(0)
    if np.ptp(centred, axis=0).max() > 1e-6:  # the desired path's plane seen face on, from above
        n = np.linalg.svd(centred, full_matrices=False)[2][-1]
        n = n if n[2] >= 0 else -n
        elev = np.degrees(np.arcsin(np.clip(n[2], -1, 1)))
        ax.view_init(elev=elev - 30.0 if elev > 45.0 else elev + 20.0, azim=np.degrees(np.arctan2(n[1], n[0])) + 30.0)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(4, prune="both"))  # no end ticks: two axes' corner labels collided
    ax.tick_params(labelsize=7, pad=1)
    ax.set_xlabel("x [m]", labelpad=4)
    ax.set_ylabel("y [m]", labelpad=4)
    ax.zaxis.set_rotate_label(False)
    ax.set_zlabel("z [m]", rotation=90, labelpad=4)
    ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(title)
    _save(fig, path)
    return fig


def distances(path: Path, arrays: dict, thresholds: dict, title: str = "") -> None:
    """Closest distances over time with their thresholds (Figs. 5-6 of papers/000); each threshold of an axis
    has its own colour and line style."""
    keys = [k for k in ("d_ee", "d_minimal", "d_obstacle", "d_self") if k in arrays]
    extra = "active_point" in arrays
    n = len(keys) + extra
    fig = _figure(8, 0.9 + 2.0 * n)
    axes = np.atleast_1d(fig.subplots(n, 1, sharex=True, squeeze=False)).ravel()
    t = arrays["t"]
    for ax, k in zip(axes, keys, strict=False):
        ax.plot(t, arrays[k], color="tab:blue", lw=0.9, label=k)
        for (name, val), (color, ls) in zip(thresholds.get(k, {}).items(), THRESHOLD_STYLES, strict=False):
            ax.axhline(val, ls=ls, lw=1.0, color=color, label=f"{name} = {val:g} m")
        ax.set_ylabel(DISTANCE_LABELS.get(k, k + " [m]"), fontsize=8)
        ax.legend(fontsize=7, loc="best")
    if extra:
        ax = axes[-1]
        ax.plot(t, arrays["active_point"] + 1, "k.", ms=1)
        ax.set_ylabel("critical control point #\n(0: none)", fontsize=8)
        ax.set_ylim(-0.5, np.nanmax(arrays["active_point"]) + 1.5)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    _save(fig, path)


def comanipulation(path: Path, runs: dict, sigma_m_bar: float = 1.5, sigma_l_bar: float = 2.0,
                   title: str = "") -> None:
    """Co-manipulation indices over time (Figs. 5-7 of papers/003): sigma_l (11), sigma_m (14) with its
    threshold, max |q_i - q_i*| with its threshold, and the active stack. ``runs``: label -> arrays (one
    run, or the hierarchy and the baseline)."""
    stacks = [a for a in runs.values() if "stack_id" in a]
    n = 3 + bool(stacks)
    fig = _figure(8, 0.9 + 1.9 * n)
    axes = fig.subplots(n, 1, sharex=True)
    colors = iter(["tab:blue", "tab:red", "tab:green", "k"])
    for label, a in runs.items():
        c = next(colors)
        axes[0].plot(a["t"], a["sigma_l"], color=c, lw=0.9, label=label)
        axes[1].plot(a["t"], a["sigma_m"], color=c, lw=0.9, label=label)
        axes[2].plot(a["t"], a["joint_deviation_max"], color=c, lw=0.9, label=label)
    axes[1].axhline(sigma_m_bar, color="k", ls="--", lw=0.8, label=rf"$\bar\sigma_m$ = {sigma_m_bar:g}")
    axes[2].axhline(sigma_l_bar, color="k", ls="--", lw=0.8, label=rf"$\bar\sigma_l$ = {sigma_l_bar:g} rad")
    names = (r"joint-limit index $\sigma_l$ [-]", r"manipulability $\sigma_m$ [-]", r"max $|q_i - q_i^*|$ [rad]")
    for ax, name in zip(axes, names, strict=False):
        ax.set_ylabel(name, fontsize=8)
        ax.legend(fontsize=7, loc="best")
    if stacks:
        a = stacks[0]
        axes[3].plot(a["t"], a["stack_id"], "b.", ms=1)
        axes[3].set_yticks([1, 2, 3, 4], ["force", "manip.", "joint lim.", "pose"])
        axes[3].set_ylim(0.5, 4.5)
        axes[3].set_ylabel("active stack", fontsize=8)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    _save(fig, path)


# ------------------------------------------------------------------------------------------ a run's figures
def _first_pointing(tasks: dict) -> Pointing | None:
    return next((task for task in tasks.values() if isinstance(task, Pointing)), None)


#: Co-manipulation thresholds drawn when the policy's ``thresholds`` do not give them (papers/003 values).
SIGMA_M_BAR, SIGMA_L_BAR = 1.5, 2.0


def write_all(out: Path, arrays: dict, ctx: RunContext) -> list[Path]:
    """The figures that apply to this run, chosen from what it recorded; returns their paths.

    From the run context ``ctx``: ``scenario.name`` (titles), ``tasks`` (task errors, pointing),
    ``velocity_limits`` (the joint box; None: none, then a robot of more than :data:`GRID_JOINTS` joints
    has its ``robot.velocity_limits()`` drawn for comparison) and ``thresholds`` (the policy's; a policy
    without them: none drawn on distances, :data:`SIGMA_M_BAR` / :data:`SIGMA_L_BAR` on co-manipulation)."""
    out = Path(out)
    name, tasks = ctx.scenario.name, ctx.tasks
    written = []
    limits = ctx.velocity_limits  # the run's joint box
    if limits is not None and not np.isfinite(np.asarray(limits, dtype=float)).any():
        limits = None
    enforced = limits is not None
    if limits is None and arrays["dq"].shape[1] > GRID_JOINTS:
        robot_limits = np.asarray(ctx.robot.velocity_limits(), dtype=float)  # many joints: one axis each, with
        if np.isfinite(robot_limits).any():  # the robot's limits for comparison
            limits = robot_limits
    thresholds = ctx.thresholds
    p = out / "joint_velocities.png"
    joint_velocities(p, arrays, limits, f"{name}: joint velocities", enforced=enforced)
    written.append(p)
    p = out / "task_errors.png"
    task_errors(p, arrays, tasks, f"{name}: task errors")
    written.append(p)
    if "pointing_error" in arrays:
        p = out / "pointing_error.png"
        task = _first_pointing(tasks)
        pointing_error(p, arrays, None if task is None else task.alpha_d, f"{name}: pointing",
                       inequality=None if task is None else bool(task.inequality))
        written.append(p)
    p = out / "ee_path.png"
    what = "EE path" if ctx.scene.ee_task is not None else "paths of the frames with moving targets"
    if ee_path(p, arrays, ctx.robot, ctx.scene, f"{name}: {what}") is not None:
        written.append(p)
    if any(k in arrays for k in ("d_ee", "d_minimal", "d_obstacle", "d_self")):
        p = out / "distances.png"
        distances(p, arrays, thresholds, f"{name}: distances")
        written.append(p)
    if "sigma_m" in arrays:
        p = out / "comanipulation.png"
        sigma_m_bar = thresholds.get("sigma_m", {}).get("sigma_bar_m", SIGMA_M_BAR)
        sigma_l_bar = thresholds.get("joint_deviation_max", {}).get("sigma_bar_l", SIGMA_L_BAR)
        comanipulation(p, {name: arrays}, sigma_m_bar, sigma_l_bar, f"{name}: co-manipulation indices")
        written.append(p)
    return written
