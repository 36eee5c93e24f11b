"""Explain every step: which task lost how much, and which joint bound or higher task took it.

The robot-aware layer above :mod:`hqp_tpm.solvers.account`: task names (a level of several tasks is
split by the tasks' dimensions), joint names, and the kind of each joint bound reached (velocity,
position one period ahead, braking distance, acceleration; :mod:`hqp_tpm.robot.joint_boxes`).

* :class:`Explainer` -- a runner probe (``hqp-tpm run ... --explain``): per step it records, compactly,
  each task's fraction met, residual, damping, cause bits and blocking set, and each joint's bound;
  nothing is computed when it is not attached (the controller and the solvers never compute it).
* :func:`summary` -- ``metrics.json`` numbers: time each task spent degraded, per cause, per blocking
  joint bound and per blocking task.
* :func:`figure` -- each task's fraction met over the run, the saturated joints as a band below.
* :func:`explain_run` -- the text ``hqp-tpm explain RUN_DIR --t T`` prints: from the recording when the
  run stored the account, else by re-running the run's scenario up to that step.
* :func:`annotate_replay` -- the current frame's account in a panel of ``replay.html``.

Arrays of ``trajectory.npz`` with ``--explain`` (``T`` steps, ``K`` tasks in ``explain_tasks`` order, ``n``
velocity columns in ``joint_names`` order; NaN where a task is not in the step's stack):

=============================  ===========  ====================================================================
``explain_fraction``           (T, K)       fraction met (:mod:`hqp_tpm.solvers.account`)
``explain_residual``           (T, K)       norm of the residual (achieved - desired)
``explain_damping``            (T, K)       ``lambda`` of the damping law on the level's projected rows (0: none)
``explain_scale``              (T, K)       SNS scale factor of the task's level (NaN for other solvers)
``explain_cause``              (T, K)       cause bits (:data:`CAUSE_BITS`; 0: met)
``explain_block_levels``       (T, K)       bit ``h`` set: task ``h`` is in the blocking set (higher levels/damping)
``explain_block_joints``       (T, K, n)    blocking joint bounds: ``side * kind`` (``10 + kind``: both sides)
``explain_fraction_without``   (T, K)       fraction met once the blocking joint bounds are released (re-solved)
``explain_bound``              (T, n)       joints at a bound of the box: ``side * kind`` (:data:`BOUND_KINDS`)
``explain_desired_{task}``     (T, m)       the task's desired command (``b``)
``explain_achieved_{task}``    (T, m)       the task's achieved command (``J x``)
=============================  ===========  ====================================================================
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from hqp_tpm.errors import ParameterError, ResultFolderError
from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.solvers.account import StepAccount, account, explain

#: Cause bits of ``explain_cause`` (0: met; NaN: the task is not in the stack at that step).
CAUSE_BITS = {"higher_levels": 1, "damping": 2, "joint_bounds": 4, "unexplained": 8}
#: Bound kinds of ``explain_bound`` (its sign is the side: + upper, - lower; 0: not at a bound).
BOUND_KINDS = {1: "velocity", 2: "position", 3: "braking", 4: "acceleration", 5: "box"}
_KIND_CODE = {v: k for k, v in BOUND_KINDS.items()}


def _code(side: int, kind: str) -> float:
    """A joint bound as one number: ``side * kind`` (+ upper, - lower), ``10 + kind`` for both sides."""
    return float(side * _KIND_CODE[kind] if side else 10 + _KIND_CODE[kind])


def _decode(code: float) -> tuple[str, str]:
    """``(side, kind)`` of :func:`_code`."""
    c = int(code)
    if c > 10:
        return "both", BOUND_KINDS.get(c - 10, "box")
    return ("upper" if c > 0 else "lower"), BOUND_KINDS.get(abs(c), "box")


def bound_kinds(limits, state, x_bound: np.ndarray, joints, sides, *, columns=None) -> list[str]:
    """Which limit defines the box bound each of ``joints`` sits at (side +1 upper, -1 lower).

    ``x_bound[j]`` is the bound's value for ``j`` in ``joints``; ``columns`` (default ``joints``): the
    joints' velocity columns.
    ``limits``: the controller's :class:`hqp_tpm.robot.limits.JointLimits` (any other box function: "box").
    Velocity level: ``v_max``, the position limit one period ahead, or the braking term; acceleration
    level: ``a_max``, the velocity limit one period ahead, or the position/braking (viability) term.
    """
    if not isinstance(limits, JointLimits):
        return ["box"] * len(joints)
    cols, lim = limits.cols, limits.limits
    where = {int(c): k for k, c in enumerate(cols)}
    q = state.q[limits.qidx]
    v = state.v[cols]
    out = []
    columns = joints if columns is None else columns
    for j, c, side in zip(joints, columns, sides, strict=True):
        k = where.get(int(c))
        if k is None:
            out.append("box")
            continue
        b = float(x_bound[j])
        tol = 1e-9 * (1.0 + abs(b))
        qk, vmax, amax, dt = q[k], lim.v_max[k], lim.a_max[k], lim.dt
        qlim = lim.q_max[k] if side > 0 else lim.q_min[k]
        if limits.order == 1:
            cands = [("velocity", side * vmax), ("position", (qlim - qk) / dt)]
            if np.isfinite(qlim) and amax > 0:
                cands.append(("braking", side * np.sqrt(2 * amax * max(side * (qlim - qk), 0.0))))
        else:
            cands = [("acceleration", side * amax), ("velocity", (side * vmax - v[k]) / dt)]
            if np.isfinite(qlim):
                cands.append(("position", None))
        kind = next((name for name, val in cands if val is not None and abs(val - b) <= tol), None)
        out.append(kind or ("position" if limits.order == 2 else "box"))
    return out


def _task_split(stack_level, m: int) -> list[tuple[str, slice]]:
    """Rows of a level per task: by the tasks' dimensions when they add up, else all rows to each."""
    dims = [int(t.dim) for t in stack_level]
    if len(stack_level) > 1 and sum(dims) == m:
        edges = np.cumsum([0, *dims])
        return [(t.name, slice(int(a), int(b))) for t, a, b in zip(stack_level, edges, edges[1:], strict=False)]
    return [(t.name, slice(0, m)) for t in stack_level]


class Explainer:
    """Runner probe recording each step's account (module doc). ``causes=False``: the account only."""

    def __init__(self, ctrl, *, causes: bool = True):
        self.tasks = [t.name for t in ctrl.tasks()]
        self.index = {name: i for i, name in enumerate(self.tasks)}
        self.dims = {t.name: int(t.dim) for t in ctrl.tasks()}
        self.joint_names = list(ctrl.robot.joint_names)
        self.causes = causes
        self.last: StepAccount | None = None
        self.hints: dict = {}  # the last step's joint blocking sets, re-verified at the next step

    # -- the account of one step -----------------------------------------------------------------
    def account(self, ctrl, res, *, causes: bool | None = None) -> StepAccount:
        """The :class:`StepAccount` of the step ``res`` just computed by ``ctrl`` (before the next one)."""
        st = ctrl.state  # still the step's state: the controller updates it at the next compute()
        box = ctrl.box(st, res.t) if ctrl.box is not None else None
        x0 = -ctrl.nullspace_damping * st.v if (ctrl.order == 2 and ctrl.nullspace_damping) else None
        kw = {"box": box, "info": res.info, "solver": ctrl.solver, "lambda_max": ctrl.lambda_max, "eps": ctrl.eps}
        want = self.causes if causes is None else causes
        if not want:
            return account(res.levels, res.command, **kw)
        acc = explain(res.levels, res.command, x0=x0, hints=self.hints, **kw)
        self.hints = {la.name: tuple(zip(c.joints, c.sides, strict=True))
                      for la, cs in zip(acc.levels, acc.causes, strict=True) for c in cs if c.kind == "joint_bounds"}
        return acc

    def row(self, ctrl, res, acc: StepAccount) -> dict:
        """The compact per-step values of ``acc`` (see :func:`summary` for their meaning)."""
        nt, nv = len(self.tasks), len(self.joint_names)
        frac, resid, damp, cause = (np.full(nt, np.nan) for _ in range(4))
        block_levels, without, scale = np.full(nt, np.nan), np.full(nt, np.nan), np.full(nt, np.nan)
        block_joints = np.zeros((nt, nv))
        desired = {name: np.full(self.dims.get(name, 0), np.nan) for name in self.tasks}
        achieved = {name: np.full(self.dims.get(name, 0), np.nan) for name in self.tasks}
        level_tasks = [_task_split(lv, la.achieved.size) for lv, la in zip(res.stack.levels, acc.levels, strict=False)]
        for k, la in enumerate(acc.levels):
            causes = acc.causes[k] if acc.causes is not None else ()
            bits = sum(CAUSE_BITS[c.kind] for c in causes)
            blockers = {t for c in causes for j in c.levels for t, _ in level_tasks[j]}
            for name, rows in level_tasks[k]:
                i = self.index.get(name)
                if i is None:
                    continue
                frac[i], resid[i], damp[i] = la.fraction, la.residual_norm, la.damping
                scale[i] = np.nan if la.scale is None else la.scale
                cause[i] = bits if (acc.causes is not None or la.met) else np.nan
                block_levels[i] = float(sum(2.0**self.index[t] for t in blockers if t in self.index))
                for c in causes:
                    if c.joints:
                        kinds = self._kinds(ctrl, acc, c.joints, c.sides)
                        block_joints[i, list(c.joints)] = [_code(s, kd) for s, kd in zip(c.sides, kinds, strict=True)]
                        without[i] = c.fraction_without
                d, a = la.desired[rows], la.achieved[rows]
                if desired[name].size == d.size:
                    desired[name], achieved[name] = d, a
        bound = np.zeros(nv)
        if acc.at_bound:
            kinds = self._kinds(ctrl, acc, acc.at_bound, acc.sides)
            for j, s, kind in zip(acc.at_bound, acc.sides, kinds, strict=True):
                bound[j] = s * _KIND_CODE[kind]
        out = {"explain_fraction": frac, "explain_residual": resid, "explain_damping": damp, "explain_cause": cause,
               "explain_block_levels": block_levels, "explain_block_joints": block_joints, "explain_bound": bound,
               "explain_fraction_without": without, "explain_scale": scale}
        for name in self.tasks:
            out[f"explain_desired_{name}"] = desired[name]
            out[f"explain_achieved_{name}"] = achieved[name]
        return out

    @staticmethod
    def _kinds(ctrl, acc: StepAccount, joints, sides) -> list[str]:
        if acc.box is None:
            return ["box"] * len(joints)
        lo, up = acc.box
        sides = [s or 1 for s in sides]  # both sides released: named by the upper one
        return bound_kinds(ctrl.box, ctrl.state, np.where(np.asarray(sides) > 0, up[list(joints)], lo[list(joints)]),
                           range(len(joints)), sides, columns=joints)

    def probe(self, ctrl, res) -> dict:
        acc = self.account(ctrl, res)
        self.last = acc
        return self.row(ctrl, res, acc)

    __call__ = probe

    def finish(self, arrays: dict) -> None:
        """Add the names the compact columns refer to (after ``Recording.arrays()``)."""
        arrays["explain_tasks"] = np.array(self.tasks, dtype=str)


# -- metrics.json --------------------------------------------------------------------------------
def _names(arrays, key, default):
    return [str(s) for s in arrays[key]] if key in arrays else default


def summary(arrays: dict) -> dict:
    """``explain`` section of ``metrics.json``: seconds each task was degraded, per cause kind, per
    blocking joint bound (``"RElbowRoll upper velocity"``) and per blocking higher task."""
    if "explain_fraction" not in arrays:
        return {}
    t = arrays["t"]
    dt = float(t[1] - t[0]) if t.size > 1 else 0.0
    tasks = _names(arrays, "explain_tasks", [])
    joints = _names(arrays, "joint_names", [])
    frac, cause = arrays["explain_fraction"], arrays["explain_cause"]
    bj, bl = arrays["explain_block_joints"], arrays["explain_block_levels"]
    out: dict = {"degraded_s": {}, "by_cause_s": {}, "by_joint_bound_s": {}, "by_higher_task_s": {},
                 "fraction_met_min": {}}
    for i, name in enumerate(tasks):
        present = ~np.isnan(frac[:, i])
        bad = present & (cause[:, i] > 0)
        out["degraded_s"][name] = round(float(bad.sum() * dt), 6)
        out["fraction_met_min"][name] = float(np.nanmin(frac[:, i])) if present.any() else None
        bits = np.nan_to_num(cause[:, i]).astype(int)
        out["by_cause_s"][name] = {kind: round(float(((bits & bit) > 0).sum() * dt), 6)
                                   for kind, bit in CAUSE_BITS.items()}
        per_joint = {}
        for j in np.flatnonzero(np.abs(bj[:, i, :]).sum(axis=0)):
            for code in np.unique(bj[:, i, j]):
                if code == 0:
                    continue
                label = f"{joints[j] if j < len(joints) else j} {' '.join(_decode(code))}"
                per_joint[label] = round(float((bj[:, i, j] == code).sum() * dt), 6)
        out["by_joint_bound_s"][name] = dict(sorted(per_joint.items(), key=lambda kv: -kv[1]))
        masks = np.nan_to_num(bl[:, i]).astype(np.int64)
        out["by_higher_task_s"][name] = {other: round(float(((masks >> h) & 1).sum() * dt), 6)
                                        for h, other in enumerate(tasks) if ((masks >> h) & 1).any()}
    return out


# -- the figure ----------------------------------------------------------------------------------
def figure(path: Path, arrays: dict, title: str = "") -> Path | None:
    """Each task's fraction met over the run; below, the joints at a bound as a band (red upper, blue lower)."""
    if "explain_fraction" not in arrays:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = arrays["t"]
    tasks = _names(arrays, "explain_tasks", [])
    joints = _names(arrays, "joint_names", [])
    bound = arrays["explain_bound"]
    used = np.flatnonzero(np.abs(bound).sum(axis=0))
    fig, (ax, band) = plt.subplots(2, 1, sharex=True, figsize=(9, 5 + 0.12 * len(used)),
                                   gridspec_kw={"height_ratios": [3, max(1, 0.25 * len(used))]})
    for i, name in enumerate(tasks):
        ax.plot(t, 100 * arrays["explain_fraction"][:, i], label=name, lw=1.2)
    ax.set_ylabel("fraction met [%]")
    ax.set_ylim(-5, 105)
    ax.legend(loc="lower left", fontsize=8, ncol=min(4, max(1, len(tasks))))
    ax.set_title(title or "fraction of each task met")
    if used.size:
        img = np.sign(bound[:, used]).T
        band.imshow(img, aspect="auto", interpolation="nearest", cmap="bwr", vmin=-1, vmax=1,
                    extent=(t[0], t[-1], used.size - 0.5, -0.5))
        band.set_yticks(range(used.size))
        band.set_yticklabels([joints[j] if j < len(joints) else str(j) for j in used], fontsize=7)
    else:
        band.text(0.5, 0.5, "no joint at a bound", ha="center", va="center", transform=band.transAxes)
        band.set_yticks([])
    band.set_xlabel("t [s]")
    band.set_ylabel("at a bound")
    band.set_title("joints at a bound (red: upper, blue: lower)", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# -- the HTML replay -------------------------------------------------------------------------------
_PANEL = """<pre id="hqp-explain" style="position: fixed; right: 8px; top: 8px; z-index: 10; max-width: 46vw;
 max-height: 80vh; overflow: auto; margin: 0; padding: 6px 8px; border-radius: 4px; font: 11px monospace;
 background: rgba(255, 255, 255, 0.88); white-space: pre-wrap;"></pre>
<script>
(function () {
  const frames = %s;
  const panel = document.getElementById("hqp-explain"), label = document.getElementById("hqp-label");
  let last = -1;
  function update() {
    const m = label ? /t = ([-0-9.]+)/.exec(label.textContent) : null;
    const t = m ? parseFloat(m[1]) : frames.t[0];
    let lo = 0, hi = frames.t.length - 1;
    while (lo < hi) { const mid = (lo + hi) >> 1; if (frames.t[mid] < t) lo = mid + 1; else hi = mid; }
    if (lo > 0 && Math.abs(frames.t[lo - 1] - t) <= Math.abs(frames.t[lo] - t)) lo -= 1;
    if (lo !== last) { panel.textContent = frames.text[frames.index[lo]]; last = lo; }
    requestAnimationFrame(update);
  }
  update();
})();
</script>
"""


def annotate_replay(path, arrays: dict, *, fps: float = 30.0, solver: str = "") -> bool:
    """Add the account of the current frame beside the robot in a replay page (``replay.html``).

    The page's time label (``t = ... s``) is read every frame and the account of the nearest recorded
    step (sampled at ``fps``; equal texts stored once) is shown in a panel. Returns False (page left as it
    is) when the run has no account or the page has no time label.
    """
    path = Path(path)
    if "explain_fraction" not in arrays or not path.exists():
        return False
    page = path.read_text(encoding="utf-8")
    if 'id="hqp-label"' not in page or 'id="hqp-explain"' in page:
        return False
    t = np.asarray(arrays["t"], dtype=float)
    step = max(1, int(round(1.0 / (fps * (t[1] - t[0]))))) if t.size > 1 else 1
    idx = list(range(0, t.size, step))
    texts, index, seen = [], [], {}
    for i in idx:
        text = format_step(arrays, i, solver=solver).split("\n", 1)[-1]  # the page shows t itself
        if text not in seen:
            seen[text] = len(texts)
            texts.append(text)
        index.append(seen[text])
    data = json.dumps({"t": [round(float(t[i]), 6) for i in idx], "index": index, "text": texts})
    panel = _PANEL % data.replace("</", "<\\/")
    path.write_text(page.replace("</body>", panel + "</body>", 1), encoding="utf-8")
    return True


# -- text ----------------------------------------------------------------------------------------
def _fmt_vec(v) -> str:
    return "[" + ", ".join(f"{x:+.3f}" for x in np.asarray(v)) + "]"


def format_step(arrays: dict, i: int, *, solver: str = "") -> str:
    """The account of step ``i`` of a recording with ``explain_*`` columns, as text."""
    tasks = _names(arrays, "explain_tasks", [])
    joints = _names(arrays, "joint_names", [])
    frac, cause = arrays["explain_fraction"][i], arrays["explain_cause"][i]
    resid, damp = arrays["explain_residual"][i], arrays["explain_damping"][i]
    bound, bj, bl = arrays["explain_bound"][i], arrays["explain_block_joints"][i], arrays["explain_block_levels"][i]

    def jname(j):
        return joints[j] if j < len(joints) else str(j)

    head = f"t = {float(arrays['t'][i]):.4f} s (step {i})"
    if solver:
        head += f", solver {solver}"
    if "scale" in arrays:
        head += f", {'smallest level ' if solver == 'sns' else ''}scale factor {float(arrays['scale'][i]):.3g}"
    if "stack" in arrays:
        head += f"\nstack: {arrays['stack'][i]}"
    lines = [head]
    width = max((len(n) for n in tasks), default=4)
    for k, name in enumerate(tasks):
        if np.isnan(frac[k]):
            lines.append(f"  {name:{width}s}  not in the stack")
            continue
        c = int(np.nan_to_num(cause[k]))
        text = f"  {name:{width}s}  met {100 * frac[k]:5.1f} %"
        if c:
            text += f"  (residual {resid[k]:.3g})"
        sc = arrays.get("explain_scale")
        if sc is not None and np.isfinite(sc[i][k]) and sc[i][k] < 1.0:
            text += f"  scale factor {sc[i][k]:.3g}"
        des, ach = arrays.get(f"explain_desired_{name}"), arrays.get(f"explain_achieved_{name}")
        if c and des is not None and des.ndim == 2 and des.shape[1]:
            text += f"\n  {'':{width}s}    desired {_fmt_vec(des[i])}\n  {'':{width}s}    achieved {_fmt_vec(ach[i])}"
        reasons = []
        if c & CAUSE_BITS["joint_bounds"]:
            js = np.flatnonzero(bj[k])
            text_j = ", ".join(f"{jname(j)} {' '.join(_decode(bj[k, j]))}" for j in js)
            wo = arrays.get("explain_fraction_without")
            after = f" (released: met {100 * wo[i][k]:.0f} %)" if wo is not None and np.isfinite(wo[i][k]) else ""
            reasons.append(f"joint bounds {text_j}{after}")
        mask = int(np.nan_to_num(bl[k]))
        above = [tasks[h] for h in range(len(tasks)) if (mask >> h) & 1]
        if c & CAUSE_BITS["higher_levels"]:
            reasons.append(f"{', '.join(above) or 'higher tasks'} above it take the directions it needs")
        if c & CAUSE_BITS["damping"]:
            who = f"its rows depend on {', '.join(above)}" if above else "its own rows are near singular"
            reasons.append(f"damped pivot (lambda = {damp[k]:.3g}): {who}")
        if c & CAUSE_BITS["unexplained"]:
            reasons.append("no verified cause (solver tolerance?)")
        for r in reasons:
            text += f"\n  {'':{width}s}    <- {r}"
        lines.append(text)
    at = np.flatnonzero(bound)
    if at.size:
        lines.append("joints at a bound: " + ", ".join(
            f"{jname(j)} ({'upper' if bound[j] > 0 else 'lower'}, {BOUND_KINDS.get(int(abs(bound[j])), 'box')})"
            for j in at))
    else:
        lines.append("joints at a bound: none")
    return "\n".join(lines)


def headline(arrays: dict, i: int) -> str:
    """One sentence for the worst task of step ``i``: ``"right_hand met 12 % at t = 2.31 s: ..."``."""
    frac = arrays["explain_fraction"][i]
    if np.all(np.isnan(frac)) or np.nanmin(frac) >= 1.0:
        return f"every task met at t = {float(arrays['t'][i]):.3f} s"
    k = int(np.nanargmin(frac))
    text = format_step(arrays, i).splitlines()
    name = _names(arrays, "explain_tasks", [])[k]
    reasons = []
    on = False
    for line in text:
        if line.strip().startswith(name + " "):
            on = True
            continue
        if on:
            if line.strip().startswith("<-"):
                reasons.append(line.strip()[3:])
            elif not line.startswith("      "):
                break
    return f"{name} met {100 * frac[k]:.0f} % at t = {float(arrays['t'][i]):.3f} s: {'; '.join(reasons)}"


def _rerun(run_dir: Path, step: int):
    """Re-run the scenario of ``run_dir`` (its ``metrics.json``) up to ``step``; the recording of that step."""
    from hqp_tpm.app import build, runner, scenario

    meta = json.loads((run_dir / "metrics.json").read_text())
    manifest = run_dir / "manifest.json"
    spec = meta["scenario"]
    if manifest.exists():  # the scenario file the run read (a file given by path has no shipped name)
        path = json.loads(manifest.read_text()).get("scenario_file")
        spec = path if path and Path(path).exists() else spec
    if manifest.exists() and json.loads(manifest.read_text()).get("scenario_file") == "<python>":
        raise ResultFolderError(f"{str(run_dir)!r} was recorded from Python (hqp_tpm.record) without the per-step "
                                "account, and its controller is in no scenario file to re-run: record it again with "
                                "hqp_tpm.record(ctrl, out, steps=..., explain=True), then hqp-tpm explain reads it")
    sc = scenario.load(spec)
    robot, ctrl, tasks, policy = build.build(sc, solver=meta.get("solver"))
    for _ in range(step):
        ctrl.step()
    ex = Explainer(ctrl)
    rec, _ = runner.run(ctrl, 1, probes=[ex.probe], record=True)  # (the full record: the readable step)
    arrays = rec.arrays()
    ex.finish(arrays)
    return arrays, ctrl.solver


def explain_run(run_dir, t: float) -> str:
    """The text of ``hqp-tpm explain RUN_DIR --t T`` (module doc)."""
    run_dir = Path(run_dir)
    if not (run_dir / "trajectory.npz").is_file():
        what = "no such folder" if not run_dir.exists() else "not a folder" if not run_dir.is_dir() else \
            "it holds no trajectory.npz"
        raise ResultFolderError(f"{str(run_dir)!r}: {what}; expected the folder of a run (hqp-tpm run SCENARIO --out "
                                "RUN_DIR, or hqp_tpm.record(...))")
    arrays = dict(np.load(run_dir / "trajectory.npz"))
    meta = json.loads((run_dir / "metrics.json").read_text()) if (run_dir / "metrics.json").exists() else {}
    times = np.asarray(arrays["t"], dtype=float)
    if not times.size:
        raise ResultFolderError(f"{str(run_dir)!r}: the run recorded no step")
    half = 0.5 * (float(times[1] - times[0]) if times.size > 1 else 0.0)
    if not (np.isfinite(t) and times[0] - half <= t <= times[-1] + half):
        raise ParameterError(f"--t {t:g}: the run {str(run_dir)!r} covers t = {times[0]:g} .. {times[-1]:g} s "
                             f"({times.size} steps); give a time in that range")
    i = int(np.argmin(np.abs(times - t)))
    if "explain_fraction" in arrays:
        return format_step(arrays, i, solver=meta.get("solver", ""))
    one, solver = _rerun(run_dir, i)
    for key in ("t", "scale", "stack"):  # keep the recorded step's own values where they exist
        if key in arrays:
            one[key] = arrays[key][i: i + 1]
    return (format_step(one, 0, solver=solver) + "\n(the run did not store the account, "
            "`hqp-tpm run ... --explain` does: re-ran the scenario to this step)")
