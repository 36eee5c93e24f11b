"""The self-contained HTML replay of a run: meshcat's viewer, the scene and a meshcat animation in one file.

``replay.html#t=2.5`` opens it paused at t = 2.5 s; ``#ui=0`` hides the play bar and meshcat's controls.
"""

from __future__ import annotations

import base64
import html
import json
import os
import uuid
import warnings
from pathlib import Path

import numpy as np
import umsgpack

with warnings.catch_warnings():  # meshcat's server module imports the deprecated zmq.eventloop.ioloop
    warnings.filterwarnings("ignore", category=DeprecationWarning, module="meshcat")
    import meshcat
    from meshcat.animation import Animation, AnimationClip, AnimationTrack
    from meshcat.servers.tree import SceneTree, find_node, walk

from hqp_tpm.app.viewer_scene import (
    _TRACE_CHUNKS,
    COLORS,
    DEFAULT_VIEW,
    FORCE_SCALE,
    LINE_RADIUS,
    Scene,
    _decompose,
    _track_changes,
)
from hqp_tpm.control.policy import SceneItems
from hqp_tpm.errors import ParameterError, StateError
from hqp_tpm.robot.model import Robot

# ------------------------------------------------------------------------------------------ offline window
_HTML = """<!DOCTYPE html>
<html>
<head><meta charset="utf-8"><title>{title}</title>
<style>
body {{ margin: 0; }}
#meshcat-pane {{ width: 100vw; height: 100vh; overflow: hidden; }}
#hqp-bar {{ position: fixed; left: 8px; bottom: 8px; z-index: 10; padding: 4px 8px; border-radius: 4px;
  background: rgba(255, 255, 255, 0.85); font: 13px sans-serif; display: flex; align-items: center; gap: 8px; }}
#hqp-time {{ width: 40vw; }}
#hqp-stack {{ position: fixed; left: 8px; top: 8px; z-index: 10; padding: 3px 8px; border-radius: 4px;
  background: rgba(255, 255, 255, 0.85); font: 14px sans-serif; }}
#hqp-stack:empty {{ display: none; }}
#hqp-legend {{ position: fixed; right: 8px; bottom: 8px; z-index: 10; padding: 4px 8px; border-radius: 4px;
  background: rgba(255, 255, 255, 0.85); font: 12px sans-serif; line-height: 18px; }}
#hqp-legend:empty {{ display: none; }}
#hqp-legend .sw {{ display: inline-block; width: 12px; height: 12px; margin-right: 6px; vertical-align: -2px;
  border: 1px solid rgba(0, 0, 0, 0.3); border-radius: 2px; }}
</style></head>
<body>
<div id="meshcat-pane"></div>
<div id="hqp-bar"><button id="hqp-play" title="play / pause">&#9654;</button>
<input id="hqp-time" type="range" min="0" max="{duration}" step="0.001" value="0">
<span id="hqp-label">t = 0.000 s</span><span>{title}</span></div>
<div id="hqp-stack"></div>
<div id="hqp-legend">{legend}</div>
<script>
{mainjs}
</script>
<script>
var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
function hqpBytes(s) {{
  const b = atob(s); const u = new Uint8Array(b.length);
  for (let i = 0; i < b.length; i++) u[i] = b.charCodeAt(i);
  return u;
}}
const hqpCommands = [
{commands}
];
for (const c of hqpCommands) viewer.handle_command_bytearray(hqpBytes(c));
(function () {{
  const a = viewer.animator, t0 = {t0};
  const play = document.getElementById("hqp-play"), slider = document.getElementById("hqp-time");
  const label = document.getElementById("hqp-label"), stackLabel = document.getElementById("hqp-stack");
  const stacks = {stacks};
  function stackAt(t) {{
    let lo = 0, hi = stacks.length - 1;
    if (hi < 0) return "";
    while (lo < hi) {{ const mid = (lo + hi + 1) >> 1; if (stacks[mid][0] <= t + 1e-9) lo = mid; else hi = mid - 1; }}
    return stacks[lo][1];
  }}
  function show(t) {{
    slider.value = t; label.textContent = "t = " + (t + t0).toFixed(3) + " s";
    stackLabel.textContent = stackAt(t);
  }}
  function seek(t) {{
    if (!a.actions.length) return;
    t = Math.max(0, Math.min(a.duration, t));
    if (!a.playing) {{ a.play(); a.pause(); }}
    a.seek(t); a.display_progress(t); show(t);
  }}
  function fromHash() {{
    const h = new URLSearchParams(location.hash.slice(1));
    if (h.get("ui") === "0") {{
      document.getElementById("hqp-bar").style.display = "none";
      for (const e of document.querySelectorAll(".dg.main")) e.style.display = "none";
    }}
    if (h.has("t")) seek(parseFloat(h.get("t")) - t0);
  }}
  play.onclick = function () {{
    if (a.playing) {{ a.pause(); return; }}
    const t = a.time >= a.duration - 1e-9 ? 0 : a.time;
    a.play(); seek(t); a.play();
  }};
  slider.oninput = function () {{ if (a.playing) a.pause(); seek(parseFloat(slider.value)); }};
  (function loop() {{
    if (a.playing) show(a.time);
    play.innerHTML = a.playing ? "&#10074;&#10074;" : "&#9654;";
    requestAnimationFrame(loop);
  }})();
  window.addEventListener("hashchange", fromHash);
  fromHash();
}})();
</script>
</body>
</html>
"""


class _OfflineWindow:
    """A meshcat window without a server: keeps the scene tree like meshcat's server and writes static HTML."""

    web_url = None

    def __init__(self):
        self.tree = SceneTree()
        self.title = "hqp-tpm replay"
        self.duration = 0.0
        self.t0 = 0.0
        self.stacks: list[tuple[float, str]] = []
        self.legend: list[tuple[str, str]] = []

    def send(self, command) -> None:
        data = command.lower()
        packed = umsgpack.packb(data)
        kind = data["type"]
        path = [p for p in str(data.get("path", "")).split("/") if p]
        if kind == "delete":
            if path:
                parent = find_node(self.tree, path[:-1])
                parent.pop(path[-1], None)
            else:
                self.tree = SceneTree()
            return
        node = find_node(self.tree, path)
        if kind == "set_transform":
            node.transform = packed
        elif kind == "set_object":
            node.object = packed
            node.properties = []
        elif kind == "set_property":
            node.properties.append(packed)
        elif kind == "set_animation":
            node.animation = packed

    def get_scene(self) -> str:
        """The static HTML page: meshcat's viewer, the scene commands, the animation last."""
        cmds, anims = [], []
        for node in walk(self.tree):
            cmds.extend(x for x in (node.object, *node.properties, node.transform) if x is not None)
            if node.animation is not None:
                anims.append(node.animation)
        mainjs = Path(meshcat.__file__).parent.joinpath("viewer", "dist", "main.min.js").read_text(encoding="utf-8")
        text = ",\n".join(f'"{base64.b64encode(c).decode("ascii")}"' for c in [*cmds, *anims])
        stacks = json.dumps([[round(t, 6), s] for t, s in self.stacks]).replace("</", "<\\/")
        return _HTML.format(title=html.escape(self.title), duration=f"{self.duration:.6f}", t0=repr(float(self.t0)),
                            stacks=stacks, legend=legend_html(self.legend),
                            mainjs=mainjs.replace("</script", "<\\/script"), commands=text)

    def get_image(self):  # pragma: no cover - the offline window has no browser
        raise StateError("an offline meshcat window cannot capture images")



# ------------------------------------------------------------------------------------------ replay
def _frame_indices(t: np.ndarray, fps: float, max_frames: int) -> np.ndarray:
    n = len(t)
    if n == 0:
        return np.zeros(0, dtype=int)
    duration = float(t[-1] - t[0])
    count = int(min(max_frames, max(2, np.floor(duration * fps) + 1), n))
    return np.unique(np.round(np.linspace(0, n - 1, count)).astype(int))


def replay_html(robot: Robot, arrays: dict, items: SceneItems | None = None, *, fps: float = 30.0,
                max_frames: int = 600, title: str = "", view=DEFAULT_VIEW) -> str:
    """The replay page of a run (see :func:`write_replay`) as a string."""
    t_all = np.asarray(arrays["t"], dtype=float)
    q_all = np.asarray(arrays["q"], dtype=float)
    if q_all.ndim != 2 or len(q_all) != len(t_all) or not len(t_all):
        raise ParameterError(f"arrays['q'] must be (N, nq) with N = len(arrays['t']) > 0, got {q_all.shape}")
    idx = _frame_indices(t_all, fps, max_frames)
    t = t_all[idx]
    active = arrays.get("active_point")
    active = None if active is None else np.asarray(active, dtype=float)[idx]
    recorded = {k: np.asarray(arrays[k], dtype=float)[idx] for k in ("operator_force", "marker") if k in arrays}

    window = _OfflineWindow()
    vis = meshcat.Visualizer(window=window)
    scene = Scene(vis, robot, items)

    states, ee, view_pts = [], [], []
    for i, (ti, qi) in enumerate(zip(t, q_all[idx], strict=True)):
        st = scene.state(qi, float(ti), None if active is None else active[i],
                         record={k: v[i] for k, v in recorded.items()})
        states.append(st)
        ee.append(scene.ee_position())
        if i % 5 == 0 or i == len(t) - 1:  # the robot's whole geometry, every few frames
            view_pts.extend(scene.key_points())
            T, shown = st.get("operator_force", (None, False))
            if shown:  # the force arrow's tip
                view_pts.append(T[:3, 3] + T[:3, 2])
    # desired path (whole run) and EE trace (in chunks that appear as the EE reaches them)
    ts = np.linspace(t_all[0], t_all[-1], min(len(t_all), 2000))
    desired = [x for x in (scene.desired_position(s) for s in ts) if x is not None]
    if len(desired) > 1:
        scene.draw_path("desired_path", desired, COLORS["desired_path"], radius=0.7 * LINE_RADIUS)
        view_pts.extend(desired)
    target_paths = scene.draw_target_paths(ts)
    view_pts.extend(target_paths)
    chunks = []
    if ee and ee[0] is not None and len(ee) > 1:
        E = np.asarray(ee)
        bounds = np.unique(np.linspace(0, len(E) - 1, min(_TRACE_CHUNKS, len(E) - 1) + 1).round().astype(int))
        for c, (s, e) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
            name = f"ee_trace/{c}"
            scene.draw_path(name, E[s:e + 1], COLORS["ee_trace"], visible=False)
            chunks.append((name, int(e)))
    view_pts.extend(o.placement_at(float(t[0])).translation for o in scene.obstacles)
    scene.frame_scene(view_pts, direction=view, floor=scene.floor_height(q_all[0]))
    paths = list(dict.fromkeys(p for st in states for p in st))  # markers may appear late
    for path in paths:
        first = next(st[path][0] for st in states if path in st)
        for st in states:
            st.setdefault(path, (first, False))
    scene.apply(states[0])

    keys = list((t - t[0]) * fps)
    anim = Animation(default_framerate=fps)
    for path in paths:
        mats = np.array([st[path][0] for st in states])
        vis_flags = [bool(st[path][1]) for st in states]
        dec = [_decompose(T) for T in mats]
        pos, quat, scale = (np.array([d[k] for d in dec]) for k in range(3))
        tracks = {}
        if _track_changes(pos):
            tracks["position"] = AnimationTrack("position", "vector3", list(keys), pos.tolist())
        if _track_changes(quat):
            tracks["quaternion"] = AnimationTrack("quaternion", "quaternion", list(keys), quat.tolist())
        if _track_changes(scale):
            tracks["scale"] = AnimationTrack("scale", "vector3", list(keys), scale.tolist())
        if len(set(vis_flags)) > 1:
            tracks["visible"] = AnimationTrack("visible", "boolean", list(keys), vis_flags)
        if tracks:
            anim.clips[scene.root[path].path] = AnimationClip(tracks=tracks, fps=fps)
    for name, frame in chunks:
        flags = [i >= frame for i in range(len(t))]
        anim.clips[scene.root[name].path] = AnimationClip(
            tracks={"visible": AnimationTrack("visible", "boolean", list(keys), flags)}, fps=fps)
    if len(t) > 1 and anim.clips:
        vis.set_animation(anim, play=False)
    window.title = title or f"hqp-tpm replay: {robot.name}"
    window.duration = float(t[-1] - t[0])
    window.t0 = float(t[0])
    window.stacks = stack_timeline(arrays, float(t_all[0]))
    window.legend = legend_entries(scene, desired=len(desired) > 1, trace=bool(chunks),
                                   target_paths=bool(target_paths))
    return vis.static_html()


def legend_entries(scene: Scene, *, desired: bool, trace: bool, target_paths: bool = False) -> list[tuple[str, str]]:
    """``[(COLORS key, what it shows), ...]`` of the items this replay draws (the colour legend)."""
    out = []
    points = [type(o.shape).__name__ == "Sphere" and o.shape.radius <= 0.0 for o in scene.obstacles]
    if any(points):
        out.append(("point_obstacle", "point obstacle"))
    if not all(points):
        out.append(("obstacle", "obstacle"))
    if scene.cp_names:
        out += [("control_point", "control point"), ("critical_point", "critical control point (nearest)")]
    if scene._cp_elements is not None:
        out.append(("distance", "distance to the nearest obstacle"))
    if desired:
        out.append(("desired_path", "desired EE path"))
    if trace:
        out.append(("ee_trace", "EE trace"))
    if scene.targets:
        names = ", ".join(t.name for t in scene.targets)
        out.append(("target", f"target of {names}"))
    if target_paths:
        out.append(("target_path", "target path"))
    if scene._pointing_params() is not None:
        out.append(("cone", "pointing cone (alpha_d)"))
    if scene.operator_markers is not None:
        out += [("marker", "operator's markers"), ("target_marker", "marker it pulls towards"),
                ("force", f"operator's force ({100 * FORCE_SCALE:g} cm/N)")]
    return out


def legend_html(entries) -> str:
    """The legend's HTML: a colour swatch and a label per entry."""
    rows = []
    for key, label in entries:
        r, g, b, a = COLORS[key]
        colour = f"rgba({round(255 * r)}, {round(255 * g)}, {round(255 * b)}, {max(a, 0.6):.2f})"
        rows.append(f'<div><span class="sw" style="background: {colour}"></span>{html.escape(label)}</div>')
    return "".join(rows)


#: Names of the co-manipulation stacks by ``stack_id`` (Fig. 3 of papers/003).
STACK_NAMES = {1: "force", 2: "manipulability", 3: "joint limit", 4: "pose"}


def stack_timeline(arrays: dict, t0: float) -> list[tuple[float, str]]:
    """``[(time from t0, text), ...]`` at every change of the active stack (its label, and its name when the
    run recorded ``stack_id``): shown in the replay's bar."""
    if "stack" not in arrays or not len(arrays["stack"]):
        return []
    labels = [str(s) for s in arrays["stack"]]
    ids = arrays.get("stack_id")
    t = np.asarray(arrays["t"], dtype=float)
    out = []
    for i, label in enumerate(labels):
        text = f"stack: {label or '(empty)'}"
        if ids is not None and np.isfinite(ids[i]) and int(ids[i]) in STACK_NAMES:
            text = f"{STACK_NAMES[int(ids[i])]} stack: {label}"
        if not out or out[-1][1] != text:
            out.append((float(t[i] - t0), text))
    return out


def write_replay(path, robot: Robot, arrays: dict, items: SceneItems | None = None, fps: float = 30.0,
                 max_frames: int = 600, *, title: str = "", view=DEFAULT_VIEW) -> Path:
    """Write the run as a self-contained HTML replay (meshcat animation, at most ``max_frames`` frames).

    The animation plays in real time (``fps`` key frames per simulated second while that fits in
    ``max_frames``). Open ``<path>#t=2.5`` to show t = 2.5 s (paused); ``#ui=0`` hides the play bar
    and meshcat's controls.
    ``items``: what to draw besides the robot (the run's ``RunContext.scene``, a policy's ``scene()``, or
    None: the robot alone). Uses (and overwrites the state of) the distance field of ``items`` to redraw the
    nearest-distance segment.
    """
    path = Path(path)
    title = title or f"hqp-tpm replay: {path.resolve().parent.name} ({robot.name})"
    text = replay_html(robot, arrays, items, fps=fps, max_frames=max_frames, title=title, view=view)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        with open(tmp, "x", encoding="utf-8") as fh:  # normal permissions (umask), unlike mkstemp's 0600
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


