"""Meshcat views of a run, as papers/000 Fig. 3: a self-contained HTML replay and a live viewer.

Drawn: the robot (its visual model, through ``pinocchio.visualize.MeshcatVisualizer``), the obstacles
(a zero-radius sphere, the paper's point obstacle, as a small sphere), the control points (red; the
critical one, ``arrays["active_point"]``, blue) with a green segment from it to the nearest obstacle
witness point, the desired EE path (green) and the EE trace (red), and the pointing cone (cyan, apex at
the EE, axis ``z_d``, half-angle ``alpha_d``). Whatever a policy lacks is left out; a policy may add
points with ``viewer_markers(t) -> [(name, position, rgba), ...]`` (``viewer_markers(t, q)`` if it takes
``q``).

- :func:`write_replay` writes one HTML file (meshcat's JavaScript embedded, works offline) with the run
  as a meshcat animation and a play/pause bar; ``replay.html#t=2.5`` opens it paused at t = 2.5 s.
- :class:`LiveViewer` starts a meshcat server and updates the scene from a runner probe.
"""

from __future__ import annotations

import base64
import html
import inspect
import os
import uuid
import warnings
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import umsgpack

from hqp_tpm.errors import ParameterError, StateError

with warnings.catch_warnings():  # meshcat's server module imports the deprecated zmq.eventloop.ioloop
    warnings.filterwarnings("ignore", category=DeprecationWarning, module="meshcat")
    import meshcat
    import meshcat.geometry as mg
    from meshcat.animation import Animation, AnimationClip, AnimationTrack
    from meshcat.servers.tree import SceneTree, find_node, walk

__all__ = ["COLORS", "LiveViewer", "Scene", "replay_html", "write_replay"]

#: RGBA colours of the drawn items (papers/000 Fig. 3).
COLORS = {
    "control_point": (0.9, 0.05, 0.05, 1.0),
    "critical_point": (0.05, 0.2, 1.0, 1.0),
    "distance": (0.0, 0.75, 0.0, 1.0),
    "desired_path": (0.0, 0.65, 0.0, 1.0),
    "ee_trace": (0.9, 0.0, 0.0, 1.0),
    "cone": (0.0, 0.85, 0.85, 0.35),
    "point_obstacle": (0.15, 0.15, 0.15, 1.0),
    "obstacle": (0.45, 0.45, 0.5, 0.55),
    "marker": (0.6, 0.0, 0.8, 1.0),
}
POINT_OBSTACLE_RADIUS = 0.015  #: drawn radius of a zero-radius sphere obstacle (m)
CONTROL_POINT_RADIUS = 0.012
CRITICAL_POINT_RADIUS = 0.016
MARKER_RADIUS = 0.02
LINE_RADIUS = 0.003  #: radius of the tubes drawing the paths and the distance segment (m)
CONE_HEIGHT = 0.2
BACKGROUND = ([1.0, 1.0, 1.0], [0.86, 0.88, 0.92])  #: top and bottom colours (0-1)
GRID_COLOR = 0xA0A4AC
DEFAULT_VIEW = (1.1, 0.45, 0.5)  #: camera direction from the scene centre (world frame)
_TRACE_CHUNKS = 120


# ------------------------------------------------------------------------------------------ geometry helpers
def _hex(rgba) -> int:
    r, g, b = (int(round(255 * float(c))) for c in rgba[:3])
    return (r << 16) + (g << 8) + b


def _material(rgba, xray: bool = False, **extra) -> mg.MeshPhongMaterial:
    """A Phong material; ``xray``: drawn over everything (after the opaque robot, no depth test)."""
    alpha = float(rgba[3]) if len(rgba) > 3 else 1.0
    if alpha < 1.0:
        extra.setdefault("depthWrite", False)
    if xray:
        extra.update(depthTest=False, depthWrite=False)
    return mg.MeshPhongMaterial(color=_hex(rgba), opacity=alpha, transparent=alpha < 1.0 or xray, **extra)


def _perpendicular(v: np.ndarray) -> np.ndarray:
    helper = np.array([1.0, 0.0, 0.0]) if abs(v[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    n = np.cross(v, helper)
    return n / np.linalg.norm(n)


def _rotation_z_to(axis) -> np.ndarray:
    """A rotation whose z column is the unit vector ``axis``."""
    z = np.asarray(axis, dtype=float)
    z = z / np.linalg.norm(z)
    x = _perpendicular(z)
    return np.column_stack([x, np.cross(z, x), z])


def tube(points, radius: float, sides: int = 8) -> mg.TriangularMeshGeometry | None:
    """A tube mesh of ``radius`` along the polyline ``points`` (N x 3); None if it has no length."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) < 2:
        return None
    keep = np.r_[True, np.linalg.norm(np.diff(P, axis=0), axis=1) > 1e-7]
    P = P[keep]
    if len(P) < 2:
        return None
    T = np.gradient(P, axis=0)
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    N = np.empty_like(P)
    n = _perpendicular(T[0])
    for i, t in enumerate(T):  # rotation-minimising frame: carry the previous normal along
        n = n - (n @ t) * t
        norm = np.linalg.norm(n)
        n = n / norm if norm > 1e-9 else _perpendicular(t)
        N[i] = n
    B = np.cross(T, N)
    ang = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.cos(ang)[None, :, None] * N[:, None, :] + np.sin(ang)[None, :, None] * B[:, None, :]
    V = (P[:, None, :] + radius * ring).reshape(-1, 3)
    i = np.arange(len(P) - 1)[:, None] * sides
    k = np.arange(sides)[None, :]
    a, b = i + k, i + (k + 1) % sides
    c, d = a + sides, b + sides
    F = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return mg.TriangularMeshGeometry(V, F)


def cone(height: float, half_angle: float, sides: int = 48) -> mg.TriangularMeshGeometry:
    """The lateral surface of a cone, apex at the origin, axis +z, ``height`` long."""
    r = height * np.tan(half_angle)
    ang = 2.0 * np.pi * np.arange(sides) / sides
    V = np.vstack([np.zeros(3), np.column_stack([r * np.cos(ang), r * np.sin(ang), np.full(sides, height)])])
    k = np.arange(sides)
    F = np.column_stack([np.zeros(sides, dtype=int), 1 + k, 1 + (k + 1) % sides])
    return mg.TriangularMeshGeometry(V, F)


def floor_grid(center_xy, half: float, z: float, step: float = 0.1) -> mg.LineSegments:
    """Square grid lines at height ``z`` around ``center_xy``, ``half`` wide each way, on multiples of ``step``."""
    lo = np.floor((np.asarray(center_xy, dtype=float) - half) / step) * step
    n = int(np.ceil(2.0 * half / step)) + 1
    xs, ys = lo[0] + step * np.arange(n), lo[1] + step * np.arange(n)
    seg = [[(x, ys[0], z), (x, ys[-1], z)] for x in xs] + [[(xs[0], y, z), (xs[-1], y, z)] for y in ys]
    pts = np.asarray(seg, dtype=np.float32).reshape(-1, 3)
    return mg.LineSegments(mg.PointsGeometry(pts.T), mg.LineBasicMaterial(color=GRID_COLOR))


def _shape_geometry(name: str, shape: coal.CollisionGeometry):
    """A meshcat geometry for an obstacle shape (pinocchio's primitive loader; point obstacle enlarged)."""
    from pinocchio.visualize.meshcat_visualizer import loadMesh, loadPrimitive

    if isinstance(shape, coal.Sphere) and shape.radius <= 0.0:
        return mg.Sphere(POINT_OBSTACLE_RADIUS)
    if isinstance(shape, coal.ShapeBase):
        return loadPrimitive(pin.GeometryObject(name, 0, pin.SE3.Identity(), shape))
    if isinstance(shape, coal.BVHModelBase):
        return loadMesh(shape)
    return None


def _clean(name: str) -> str:
    return str(name).replace("/", "_") or "_"


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
</style></head>
<body>
<div id="meshcat-pane"></div>
<div id="hqp-bar"><button id="hqp-play" title="play / pause">&#9654;</button>
<input id="hqp-time" type="range" min="0" max="{duration}" step="0.001" value="0">
<span id="hqp-label">t = 0.000 s</span><span>{title}</span></div>
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
  const label = document.getElementById("hqp-label");
  function show(t) {{ slider.value = t; label.textContent = "t = " + (t + t0).toFixed(3) + " s"; }}
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
        return _HTML.format(title=html.escape(self.title), duration=f"{self.duration:.6f}", t0=repr(float(self.t0)),
                            mainjs=mainjs.replace("</script", "<\\/script"), commands=text)

    def get_image(self):  # pragma: no cover - the offline window has no browser
        raise StateError("an offline meshcat window cannot capture images")


# ------------------------------------------------------------------------------------------ the scene
class Scene:
    """The objects of a run on a meshcat visualizer, under ``vis["world"]`` (shifted so the scene is centred).

    ``state(q, t, active_point)`` gives the pose and visibility of every moving node for one instant,
    ``apply(state)`` sends it to the visualizer; :func:`write_replay` turns a sequence of states into
    a meshcat animation.
    """

    def __init__(self, vis: meshcat.Visualizer, robot, policy=None):
        self.vis = vis
        self.root = vis["world"]
        self.robot = robot
        self.policy = policy
        self.model = robot.model
        self.data = robot.model.createData()
        gmodel = robot.visual_model if robot.visual_model is not None else robot.collision_model
        self.gmodel = gmodel
        self.viz = None
        self._visual_paths: list[str] = []
        if gmodel is not None and len(gmodel.geometryObjects):
            from pinocchio.visualize import MeshcatVisualizer

            self.viz = MeshcatVisualizer(robot.model, None, gmodel)
            self.viz.initViewer(viewer=self.root)
            self.viz.loadViewerModel(rootNodeName="robot")
            self.gdata = self.viz.visual_data
            self._visual_paths = [self.viz.getViewerNodeName(g, pin.GeometryType.VISUAL)
                                  for g in gmodel.geometryObjects]
        # policy items (all optional)
        p = policy
        self.obstacles = list(getattr(p, "obstacles", None) or [])
        self.cp_names = [str(n) for n in (getattr(p, "control_points", None) or []) if robot.model.existFrame(str(n))]
        self.cp_fids = [robot.model.getFrameId(n) for n in self.cp_names]
        self.field = getattr(p, "field", None)
        self._cp_elements = self._control_point_elements()
        self.ee_task = getattr(p, "ee_task", None)
        self.ee_fid = self._ee_frame()
        self.pointing = getattr(p, "pointing", None)
        self.markers_fn = getattr(p, "viewer_markers", None)
        self._markers_with_q = False
        if callable(self.markers_fn):
            try:
                self._markers_with_q = "q" in inspect.signature(self.markers_fn).parameters
            except (TypeError, ValueError):
                pass
        self.marker_names: list[str] = []
        self._marker_pos: dict[str, np.ndarray] = {}
        self._last_visible: dict[str, bool] = {}
        self._draw_static()

    # -- what the policy offers ------------------------------------------------------------------
    def _control_point_elements(self) -> list[int] | None:
        f = self.field
        if f is None or not self.cp_names or not all(hasattr(f, a) for a in ("p_robot", "p_obstacle", "update")):
            return None
        try:
            return [int(f.element_index(n)) for n in self.cp_names]
        except Exception:  # noqa: BLE001 - a field without these names: draw no distance segment
            n_geom = int(getattr(f, "n_geometries", 0))
            return [n_geom + k for k in range(len(self.cp_names))]

    def _ee_frame(self) -> int | None:
        for cand in (getattr(self.policy, "ee_frame", None), getattr(self.ee_task, "frame", None)):
            if isinstance(cand, str) and self.model.existFrame(cand):
                return self.model.getFrameId(cand)
        fid = getattr(self.ee_task, "fid", None)
        return int(fid) if fid is not None else None

    def desired_position(self, t: float) -> np.ndarray | None:
        """The EE task's desired position at ``t`` (None if there is none or it is not 3-D)."""
        traj = getattr(self.ee_task, "trajectory", None)
        if traj is None:
            return None
        try:
            x = np.asarray(traj.reference(float(t))[0], dtype=float)
        except Exception:  # noqa: BLE001 - e.g. a relative trajectory never started
            return None
        return x if x.shape == (3,) and np.all(np.isfinite(x)) else None

    def _pointing_params(self):
        pt = self.pointing
        z_d, alpha, fid = getattr(pt, "z_d", None), getattr(pt, "alpha_d", None), getattr(pt, "fid", None)
        if z_d is None or alpha is None or fid is None or not (0.0 < float(alpha) < np.radians(85.0)):
            return None
        return np.asarray(z_d, dtype=float), float(alpha), int(fid)

    def _markers(self, t: float, q) -> list:
        if not callable(self.markers_fn):
            return []
        out = self.markers_fn(t, q=q) if self._markers_with_q else self.markers_fn(t)
        return list(out or [])

    # -- static objects ----------------------------------------------------------------------------
    def _draw_static(self) -> None:
        r = self.root
        for o in self.obstacles:
            geom = _shape_geometry(o.name, o.shape)
            if geom is None:
                continue
            point = isinstance(o.shape, coal.Sphere) and o.shape.radius <= 0.0
            rgba = COLORS["point_obstacle"] if point else COLORS["obstacle"]
            r[f"obstacles/{_clean(o.name)}"].set_object(geom, _material(rgba))
        for k, name in enumerate(self.cp_names):
            r[f"control_points/{k}_{_clean(name)}"].set_object(mg.Sphere(CONTROL_POINT_RADIUS),
                                                               _material(COLORS["control_point"], xray=True))
        if self.cp_names:
            r["critical_point"].set_object(mg.Sphere(CRITICAL_POINT_RADIUS),
                                           _material(COLORS["critical_point"], xray=True))
        if self._cp_elements is not None:
            r["distance"].set_object(tube([[0, 0, 0], [0, 0, 1]], 1.0, sides=10),
                                     _material(COLORS["distance"], xray=True))
        cone_p = self._pointing_params()
        if cone_p is not None:
            r["pointing_cone"].set_object(cone(CONE_HEIGHT, cone_p[1]), _material(COLORS["cone"]))

    def draw_path(self, name: str, points, rgba, visible: bool = True, radius: float = LINE_RADIUS) -> None:
        """A static polyline (tube) under ``world/<name>``."""
        geom = tube(points, radius)
        if geom is None:
            return
        node = self.root[name]
        node.set_object(geom, _material(rgba))
        if not visible:
            node.set_property("visible", False)

    def frame_scene(self, points, direction=DEFAULT_VIEW, fov_deg: float = 45.0, floor: float | None = None) -> None:
        """Centre the scene on the bounding box of ``points``, place the camera along ``direction``, floor grid."""
        P = np.asarray(points, dtype=float).reshape(-1, 3)
        P = P[np.all(np.isfinite(P), axis=1)]
        if not len(P):
            P = np.zeros((1, 3))
        lo, hi = P.min(axis=0), P.max(axis=0)
        center = 0.5 * (lo + hi)
        radius = max(float(np.max(np.linalg.norm(P - center, axis=1))), 0.3)
        d = np.asarray(direction, dtype=float)
        d = d / np.linalg.norm(d)
        dist = 0.95 * radius / np.sin(np.radians(fov_deg) / 2.0)
        eye = dist * d  # relative to the centre, which the shift below puts at the world origin
        shift = np.eye(4)
        shift[:3, 3] = -center
        self.root.set_transform(shift)
        # meshcat's 20 m grid loses its lines through the camera plane in headless software GL: a local grid
        self.vis["/Grid"].set_property("visible", False)
        self.vis["/Axes"].set_property("visible", False)
        z = lo[2] if floor is None else floor
        self.root["floor"].set_object(floor_grid(center[:2], 1.4 * radius, z))
        cam = self.vis["/Cameras/default/rotated/<object>"]
        cam.set_property("position", [float(eye[0]), float(eye[2]), float(-eye[1])])  # rotated frame: y up
        cam.set_property("fov", float(fov_deg))
        self.vis["/Background"].set_property("top_color", BACKGROUND[0])
        self.vis["/Background"].set_property("bottom_color", BACKGROUND[1])

    def floor_height(self, q) -> float | None:
        """Lowest point of the robot's drawn geometry at ``q`` (for the floor grid), None without geometry."""
        if self.viz is None:
            return None
        pin.forwardKinematics(self.model, self.data, q)
        pin.updateGeometryPlacements(self.model, self.data, self.gmodel, self.gdata)
        zmin = np.inf
        for g, M in zip(self.gmodel.geometryObjects, self.gdata.oMg, strict=True):
            geom = g.geometry
            try:
                geom.computeLocalAABB()
                c, r = np.asarray(geom.aabb_center, dtype=float), float(geom.aabb_radius)
            except Exception:  # noqa: BLE001
                c, r = np.zeros(3), 0.0
            zmin = min(zmin, float(M.act(c * np.asarray(g.meshScale))[2]) - r * float(np.max(g.meshScale)))
        return zmin if np.isfinite(zmin) else None

    # -- per-instant state -------------------------------------------------------------------------
    def kinematics(self, q) -> None:
        pin.framesForwardKinematics(self.model, self.data, q)
        if self.viz is not None:
            pin.updateGeometryPlacements(self.model, self.data, self.gmodel, self.gdata)

    def ee_position(self) -> np.ndarray | None:
        """EE position after :meth:`kinematics` (None without an EE frame)."""
        return None if self.ee_fid is None else self.data.oMf[self.ee_fid].translation.copy()

    def key_points(self) -> list[np.ndarray]:
        """Positions that the camera must see, after :meth:`kinematics` (joints, control points, EE)."""
        pts = [M.translation.copy() for M in self.data.oMi[1:]]
        pts += [self.data.oMf[f].translation.copy() for f in self.cp_fids]
        if self.ee_fid is not None:
            pts.append(self.data.oMf[self.ee_fid].translation.copy())
        pts += [p.copy() for p in self._marker_pos.values()]
        return pts

    def state(self, q, t: float = 0.0, active_point: int | None = None, update_field: bool = True) -> dict:
        """``{path: (T 4x4, visible)}`` of every moving node at ``q``, ``t``.

        ``active_point``: index of the critical control point (< 0: none; None: not known, then the
        nearest in-range control point gets the distance segment and no point is blue).
        ``update_field``: recompute the policy's distance field here (False: it already holds ``q``).
        """
        from pinocchio.visualize.meshcat_visualizer import applyScalingOnHomegeneousTransform

        self.kinematics(q)
        out: dict[str, tuple[np.ndarray, bool]] = {}
        if self.viz is not None:
            for path, g, M in zip(self._visual_paths, self.gmodel.geometryObjects, self.gdata.oMg, strict=True):
                out[path] = (applyScalingOnHomegeneousTransform(M.homogeneous, g.meshScale), True)
        for o in self.obstacles:
            out[f"obstacles/{_clean(o.name)}"] = (o.placement_at(t).homogeneous, True)
        cps = [self.data.oMf[f].translation for f in self.cp_fids]
        for k, (name, p) in enumerate(zip(self.cp_names, cps, strict=True)):
            out[f"control_points/{k}_{_clean(name)}"] = (_translation(p), True)
        if self.cp_names:
            k = -1 if active_point is None or not np.isfinite(active_point) else int(active_point)
            ok = 0 <= k < len(cps)
            out["critical_point"] = (_translation(cps[k] if ok else np.zeros(3)), ok)
        if self._cp_elements is not None:
            out["distance"] = self._distance_segment(t, active_point, update_field)
        cone_p = self._pointing_params()
        if cone_p is not None:
            z_d, _, fid = cone_p
            T = np.eye(4)
            T[:3, :3] = _rotation_z_to(z_d)
            T[:3, 3] = self.data.oMf[fid].translation
            out["pointing_cone"] = (T, True)
        present = self._marker_pos = {}
        for name, pos, rgba in self._markers(t, q):
            present[_clean(name)] = np.asarray(pos, dtype=float)
            if _clean(name) not in self.marker_names:
                self.marker_names.append(_clean(name))
                color = COLORS["marker"] if rgba is None else rgba
                self.root[f"markers/{_clean(name)}"].set_object(mg.Sphere(MARKER_RADIUS), _material(color))
        for name in self.marker_names:
            pos = present.get(name)
            out[f"markers/{name}"] = (_translation(pos if pos is not None else np.zeros(3)), pos is not None)
        return out

    def _distance_segment(self, t: float, active_point, update_field: bool):
        f = self.field
        hidden = (np.diag([LINE_RADIUS, LINE_RADIUS, 1e-6, 1.0]), False)
        try:
            if update_field:
                f.update(self.data, None, t)
            elems = self._cp_elements
            if active_point is None:
                d = np.array([np.min(np.where(f.in_range[e], f.distance[e], np.inf)) for e in elems])
                if not len(d) or not np.isfinite(d.min()):
                    return hidden
                e = elems[int(np.argmin(d))]
            else:
                k = int(active_point) if np.isfinite(active_point) else -1
                if not 0 <= k < len(elems):
                    return hidden
                e = elems[k]
            dist = np.where(f.in_range[e], f.distance[e], np.inf)
            if not np.isfinite(dist.min()):
                dist = np.asarray(f.distance[e], dtype=float)
            j = int(np.argmin(dist))
            a, b = np.asarray(f.p_robot[e, j], dtype=float), np.asarray(f.p_obstacle[e, j], dtype=float)
        except Exception:  # noqa: BLE001 - a field we cannot query: no segment
            return hidden
        v = b - a
        length = float(np.linalg.norm(v))
        if not np.isfinite(length) or length < 1e-6:
            return hidden
        T = np.eye(4)
        T[:3, :3] = _rotation_z_to(v) @ np.diag([LINE_RADIUS, LINE_RADIUS, length])
        T[:3, 3] = a
        return T, True

    def apply(self, state: dict) -> None:
        """Send ``state`` (from :meth:`state`) to the visualizer; visibility only when it changes."""
        for path, (T, visible) in state.items():
            node = self.root[path]
            node.set_transform(T)
            if self._last_visible.get(path) != visible:
                node.set_property("visible", bool(visible))
                self._last_visible[path] = visible


def _translation(p) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = p
    return T


def _decompose(T: np.ndarray):
    """Position, quaternion (x, y, z, w) and scale of a 4x4 transform ``R diag(s)``."""
    A = T[:3, :3]
    s = np.linalg.norm(A, axis=0)
    R = A / np.where(s > 0, s, 1.0)
    return T[:3, 3].copy(), pin.Quaternion(R).normalized().coeffs().copy(), s


def _track_changes(values: np.ndarray) -> bool:
    return bool(np.ptp(values, axis=0).max() > 1e-9) if len(values) > 1 else False


# ------------------------------------------------------------------------------------------ replay
def _frame_indices(t: np.ndarray, fps: float, max_frames: int) -> np.ndarray:
    n = len(t)
    if n == 0:
        return np.zeros(0, dtype=int)
    duration = float(t[-1] - t[0])
    count = int(min(max_frames, max(2, np.floor(duration * fps) + 1), n))
    return np.unique(np.round(np.linspace(0, n - 1, count)).astype(int))


def replay_html(robot, arrays: dict, policy=None, *, fps: float = 30.0, max_frames: int = 600, title: str = "",
                view=DEFAULT_VIEW) -> str:
    """The replay page of a run (see :func:`write_replay`) as a string."""
    t_all = np.asarray(arrays["t"], dtype=float)
    q_all = np.asarray(arrays["q"], dtype=float)
    if q_all.ndim != 2 or len(q_all) != len(t_all) or not len(t_all):
        raise ParameterError(f"arrays['q'] must be (N, nq) with N = len(arrays['t']) > 0, got {q_all.shape}")
    idx = _frame_indices(t_all, fps, max_frames)
    t = t_all[idx]
    active = arrays.get("active_point")
    active = None if active is None else np.asarray(active, dtype=float)[idx]

    window = _OfflineWindow()
    vis = meshcat.Visualizer(window=window)
    scene = Scene(vis, robot, policy)

    states, ee, view_pts = [], [], []
    for i, (ti, qi) in enumerate(zip(t, q_all[idx], strict=True)):
        st = scene.state(qi, float(ti), None if active is None else active[i])
        states.append(st)
        ee.append(scene.ee_position())
        view_pts.extend(scene.key_points())
    # desired path (whole run) and EE trace (in chunks that appear as the EE reaches them)
    ts = np.linspace(t_all[0], t_all[-1], min(len(t_all), 2000))
    desired = [x for x in (scene.desired_position(s) for s in ts) if x is not None]
    if len(desired) > 1:
        scene.draw_path("desired_path", desired, COLORS["desired_path"], radius=0.7 * LINE_RADIUS)
        view_pts.extend(desired)
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
    window.title = title or f"hqp-tpm replay: {getattr(robot, 'name', '')}"
    window.duration = float(t[-1] - t[0])
    window.t0 = float(t[0])
    return vis.static_html()


def write_replay(path, robot, arrays: dict, policy=None, fps: float = 30.0, max_frames: int = 600, *,
                 title: str = "", view=DEFAULT_VIEW) -> Path:
    """Write the run as a self-contained HTML replay (meshcat animation, at most ``max_frames`` frames).

    The animation plays in real time (``fps`` key frames per simulated second while that fits in
    ``max_frames``). Open ``<path>#t=2.5`` to show t = 2.5 s (paused); ``#ui=0`` hides the play bar
    and meshcat's controls.
    Uses (and overwrites the state of) ``policy.field`` to redraw the nearest-distance segment.
    """
    path = Path(path)
    title = title or f"hqp-tpm replay: {path.resolve().parent.name} ({getattr(robot, 'name', '')})"
    text = replay_html(robot, arrays, policy, fps=fps, max_frames=max_frames, title=title, view=view)
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


# ------------------------------------------------------------------------------------------ live
class LiveViewer:
    """A meshcat server showing the run as it goes; ``probe`` is a runner probe (returns ``{}``)."""

    def __init__(self, robot, policy=None, every: int = 10, *, view=DEFAULT_VIEW, trace_every: int = 10,
                 zmq_url: str | None = None):
        self.vis = meshcat.Visualizer(zmq_url=zmq_url)
        self.url = self.vis.url()
        print(f"hqp-tpm: live meshcat viewer at {self.url}", flush=True)
        self.every = max(1, int(every))
        self.trace_every = max(1, int(trace_every))
        self.scene = Scene(self.vis, robot, policy)
        self.view = view
        self._count = 0
        self._updates = 0
        self._framed = False
        self._trace: list[np.ndarray] = []
        self._desired: list[np.ndarray] = []
        self._chunk = 0

    def show(self, q, t: float = 0.0, active_point: int | None = None, update_field: bool = True) -> None:
        """Draw configuration ``q`` at time ``t`` (the first call also places the camera)."""
        q = np.asarray(q, dtype=float)
        state = self.scene.state(q, t, active_point, update_field=update_field)
        if not self._framed:
            pts = self.scene.key_points()
            pts += [o.placement_at(t).translation for o in self.scene.obstacles]
            traj = getattr(self.scene.ee_task, "trajectory", None)
            omega = getattr(traj, "omega", None)
            if omega:  # a periodic target: its whole path is known
                ts = t + np.linspace(0.0, 2.0 * np.pi / abs(float(omega)), 400)
                path = [x for x in (self.scene.desired_position(s) for s in ts) if x is not None]
                if len(path) > 1:
                    self.scene.draw_path("desired_path", path, COLORS["desired_path"], radius=0.7 * LINE_RADIUS)
                    pts += path
            self.scene.frame_scene(pts, direction=self.view, floor=self.scene.floor_height(q))
            self._framed = True
        self.scene.apply(state)
        ee = self.scene.ee_position()
        if ee is not None:
            self._trace.append(ee)
            if len(self._trace) > self.trace_every:
                self.scene.draw_path(f"ee_trace/{self._chunk}", self._trace, COLORS["ee_trace"])
                self._chunk += 1
                self._trace = self._trace[-1:]

    def probe(self, ctrl, res) -> dict:
        """Runner probe: every ``every`` steps, show the state the step was computed from."""
        self._count += 1
        if (self._count - 1) % self.every:
            return {}
        st = getattr(ctrl, "state", None)
        q = getattr(st, "q", None) if st is not None else None
        t = getattr(st, "t", None) if st is not None else None
        active = None
        pol = self.scene.policy
        if callable(getattr(pol, "probe", None)):
            try:
                active = pol.probe(ctrl, res).get("active_point")
            except Exception:  # noqa: BLE001 - the policy's record is only a nicety here
                active = None
        self.show(ctrl.q if q is None else q, float(ctrl.t if t is None else t), active, update_field=q is None)
        return {}

    def close(self) -> None:
        """Stop the meshcat server this viewer started."""
        proc = getattr(self.vis.window, "server_proc", None)
        if proc is not None and proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=5)
            except Exception:  # noqa: BLE001
                proc.kill()

    def __enter__(self) -> LiveViewer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
