"""The scene of a run on a meshcat visualizer (shared by the replay and the live viewer).

Drawn: the robot (its visual model, through ``pinocchio.visualize.MeshcatVisualizer``; large meshes
decimated once and cached, :func:`viewer_geometry`), the obstacles (a zero-radius sphere, the paper's
point obstacle, as a small sphere), the control points (red; the critical one, ``arrays["active_point"]``,
blue) with a green segment from it to the nearest obstacle witness point, the desired EE path (green)
and the EE trace (red), the pointing cone (cyan, apex at the EE, axis ``z_d``, half-angle ``alpha_d``),
markers (purple; the co-manipulation operator's markers, the one it pulls towards in green) and the
operator's force (a blue arrow at the flange). Whatever the run lacks is left out.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin

from hqp_tpm.control.policy import SceneItems
from hqp_tpm.errors import HqpTpmError
from hqp_tpm.references.trajectories import Harmonic
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.spatial import rotation_z_to

with warnings.catch_warnings():  # meshcat's server module imports the deprecated zmq.eventloop.ioloop
    warnings.filterwarnings("ignore", category=DeprecationWarning, module="meshcat")
    import meshcat
    import meshcat.geometry as mg


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
    "target_marker": (0.0, 0.75, 0.2, 1.0),
    "force": (0.05, 0.35, 1.0, 1.0),
    "target": (0.95, 0.0, 0.55, 0.9),
    "target_path": (0.0, 0.55, 0.1, 1.0),
}
POINT_OBSTACLE_RADIUS = 0.015  #: drawn radius of a zero-radius sphere obstacle (m)
CONTROL_POINT_RADIUS = 0.012
CRITICAL_POINT_RADIUS = 0.016
MARKER_RADIUS = 0.02
TARGET_MARKER_RADIUS = 0.03  #: the marker the operator pulls towards
TARGET_RADIUS = 0.025  #: a frame task's target (drawn over the robot: the hand holds it when tracking)
FORCE_SCALE = 0.025  #: drawn length of the operator's force arrow per newton (m/N)
FORCE_MIN = 0.2  #: forces below this (N) are not drawn
#: Meshes with more triangles than this are decimated for the viewer (once, cached on disk).
MAX_TRIANGLES = 3000
MESH_CACHE_VERSION = 2  #: 2: quadric edge collapse (1: vertex clustering)
LINE_RADIUS = 0.003  #: radius of the tubes drawing the paths and the distance segment (m)
CONE_HEIGHT = 0.2
BACKGROUND = ([1.0, 1.0, 1.0], [0.86, 0.88, 0.92])  #: top and bottom colours (0-1)
GRID_COLOR = 0xA0A4AC
DEFAULT_VIEW = (1.1, 0.45, 0.5)  #: camera direction from the scene centre (world frame)
VIEW_ASPECT = 4.0 / 3.0  #: the narrowest window (width / height) the framing keeps the whole scene in
VIEW_MARGIN = 0.88  #: the scene fills at most this fraction of the half-angles (room for the labels)
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


def arrow(shaft_radius: float = 0.6, head_radius: float = 1.5, head_length: float = 0.25,
          sides: int = 16) -> mg.TriangularMeshGeometry:
    """An arrow of length 1 along +z from the origin; radii as fractions of the length (scaled by the transform)."""
    ang = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(sides)])
    z0, z1 = 0.0, 1.0 - head_length
    r_s, r_h = 0.04 * shaft_radius, 0.04 * head_radius
    V = np.vstack([r_s * ring + [0, 0, z0], r_s * ring + [0, 0, z1], r_h * ring + [0, 0, z1], [[0, 0, 1.0]],
                   [[0, 0, z0]]])
    k = np.arange(sides)
    n = (k + 1) % sides
    apex, bottom = 3 * sides, 3 * sides + 1
    F = np.vstack([np.column_stack([k, n, sides + n]), np.column_stack([k, sides + n, sides + k]),
                   np.column_stack([2 * sides + k, 2 * sides + n, np.full(sides, apex)]),
                   np.column_stack([2 * sides + n, 2 * sides + k, sides + k]),
                   np.column_stack([n, k, np.full(sides, bottom)])])
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


# ------------------------------------------------------------------------------------------ decimated meshes
def _mesh_arrays(bvh) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N x 3) and triangles (M x 3) of a coal BVH model."""
    V = np.asarray(bvh.vertices(), dtype=float).reshape(-1, 3)
    F = np.empty((bvh.num_tris, 3), dtype=np.int64)
    for i in range(bvh.num_tris):
        tri = bvh.tri_indices(i)
        F[i] = (tri[0], tri[1], tri[2])
    return V, F


def decimate(V: np.ndarray, F: np.ndarray, max_triangles: int = MAX_TRIANGLES) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_triangles`` triangles of the mesh (``V`` N x 3, ``F`` M x 3): quadric edge collapse
    (fast-simplification). It keeps the surface closed and the triangles' orientation, so the shading (vertex
    normals) stays smooth; vertex clustering left holes and shards on Talos' torso (tests/test_viewer.py)."""
    if len(F) <= max_triangles:
        return V, F
    import fast_simplification

    W, G = np.asarray(V, dtype=float), np.asarray(F, dtype=np.int32)
    for k in range(4):  # an aggressive pass may stop short of the count: once more on the result
        if len(G) <= max_triangles:
            break
        W, G = fast_simplification.simplify(W, G.astype(np.int32), target_count=int(max_triangles * 0.97 ** k))
    if len(G) > max_triangles:  # still short (a pathological mesh): keep the largest triangles
        area = np.linalg.norm(np.cross(W[G[:, 1]] - W[G[:, 0]], W[G[:, 2]] - W[G[:, 0]]), axis=1)
        G = G[np.sort(np.argsort(-area, kind="stable")[:max_triangles])]
    used, G = np.unique(G, return_inverse=True)
    return np.asarray(W[used], dtype=float), G.reshape(-1, 3).astype(np.int64)


def _cache_dir() -> Path:
    root = os.environ.get("HQP_TPM_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "hqp-tpm")
    return Path(root) / "meshes"


_DECIMATED: dict[str, tuple[np.ndarray, np.ndarray]] = {}


def decimated_mesh(g, max_triangles: int = MAX_TRIANGLES) -> tuple[np.ndarray, np.ndarray]:
    """The decimated (vertices, triangles) of geometry object ``g``'s mesh: computed once, then read from the
    in-process memo or the disk cache (``$HQP_TPM_CACHE``, default ``~/.cache/hqp-tpm/meshes``), keyed by the
    mesh file (path, size, modification time) and the triangle budget."""
    path = str(g.meshPath)
    try:
        st = os.stat(path)
        stamp = f"{path}|{st.st_size}|{st.st_mtime_ns}"
    except OSError:
        stamp = f"{path}|{g.geometry.num_vertices}|{g.geometry.num_tris}"
    key = hashlib.sha1(f"{stamp}|{max_triangles}|{MESH_CACHE_VERSION}".encode()).hexdigest()[:20]
    if key in _DECIMATED:
        return _DECIMATED[key]
    file = _cache_dir() / f"{key}.npz"
    try:
        with np.load(file) as z:
            out = (z["V"], z["F"])
    except (OSError, KeyError, ValueError):
        out = decimate(*_mesh_arrays(g.geometry), max_triangles)
        try:  # the cache is an optimisation: a read-only home still works
            file.parent.mkdir(parents=True, exist_ok=True)
            tmp = file.with_name(f".{file.name}.{os.getpid()}.tmp.npz")
            np.savez_compressed(tmp, V=out[0].astype(np.float32), F=out[1].astype(np.int32))
            os.replace(tmp, file)
        except OSError:
            pass
    _DECIMATED[key] = out
    return out


def viewer_geometry(robot, max_triangles: int = MAX_TRIANGLES):
    """The geometry model to draw: the visual model (else the collision model) with every mesh of more than
    ``max_triangles`` triangles replaced by its decimated copy (:func:`decimated_mesh`). Every mesh is drawn from
    its triangles (no mesh file embedded: a COLLADA file is XML several times the size of its triangles), so a
    replay of Romeo is a few MB instead of ~20 MB."""
    gmodel = robot.visual_model if robot.visual_model is not None else robot.collision_model
    if gmodel is None:
        return None
    out = gmodel.copy()
    for i, g in enumerate(out.geometryObjects):
        geom = g.geometry
        if not isinstance(geom, coal.BVHModelBase):
            continue
        g2 = g.copy()
        if geom.num_tris > max_triangles:
            V, F = decimated_mesh(g, max_triangles)
            bvh = coal.BVHModelOBBRSS()
            bvh.beginModel(len(F), len(V))
            bvh.addVertices(np.asarray(V, dtype=float))
            bvh.addTriangles(np.asarray(F, dtype=np.int64))
            bvh.endModel()
            g2.geometry = bvh
        g2.meshPath = ""  # drawn from the BVH (pinocchio's loader prefers a mesh file when there is one)
        out.geometryObjects[i] = g2
    return out


def camera_distance(points, direction, fov_deg: float = 45.0, aspect: float = VIEW_ASPECT,
                    margin: float = VIEW_MARGIN) -> float:
    """Distance from the origin along ``direction`` (unit) at which a camera looking at the origin (up: +z)
    sees every point of ``points`` (N x 3, relative to the origin) within ``margin`` of its vertical half-angle
    ``fov_deg / 2`` and of the horizontal one (``aspect`` = width / height, the narrowest window expected)."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    d = np.asarray(direction, dtype=float)
    d = d / np.linalg.norm(d)
    right = np.cross(-d, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-9:  # looking straight down or up: any horizontal axis
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, -d)
    tan_v = margin * np.tan(np.radians(fov_deg) / 2.0)
    need = P @ d + np.maximum(np.abs(P @ up) / tan_v, np.abs(P @ right) / (aspect * tan_v))
    radius = float(np.max(np.linalg.norm(P, axis=1), initial=0.0))
    return max(float(np.max(need, initial=0.0)), 1.05 * radius, 0.5)


def _clean(name: str) -> str:
    return str(name).replace("/", "_") or "_"


# ------------------------------------------------------------------------------------------ the scene
class Scene:
    """The objects of a run on a meshcat visualizer, under ``vis["world"]`` (shifted so the scene is centred).

    ``state(q, t, active_point)`` gives the pose and visibility of every moving node for one instant,
    ``apply(state)`` sends it to the visualizer; :func:`write_replay` turns a sequence of states into
    a meshcat animation.
    """

    def __init__(self, vis: meshcat.Visualizer, robot: Robot, items: SceneItems | None = None):
        """``items``: what to draw besides the robot (a run's ``RunContext.scene``, a policy's
        :meth:`~hqp_tpm.control.policy.Policy.scene`, or None: the robot alone)."""
        items = SceneItems() if items is None else items
        self.vis = vis
        self.root = vis["world"]
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        gmodel = viewer_geometry(robot)  # large meshes decimated (once, cached)
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
        self.obstacles = items.obstacles
        self.cp_names = [str(n) for n in items.control_points if robot.model.existFrame(str(n))]
        self.cp_fids = [robot.model.getFrameId(n) for n in self.cp_names]
        self.field = items.field
        self._cp_elements = self._control_point_elements()
        self.ee_task = items.ee_task
        self._ee_frame_name = items.ee_frame
        self.ee_fid = self._ee_frame()
        self.pointing = items.pointing
        self.operator = items.operator  # co-manipulation: its markers, the flange its force acts on
        self.operator_markers = None if self.operator is None else self.operator.markers.reshape(-1, 3)
        self.force_fid = None if self.operator is None else int(self.operator.fid)
        self._local_boxes = self._geometry_boxes()
        self.targets = [t for t in items.targets if t.frame is not None and robot.model.existFrame(t.frame)]
        self.markers_fn = items.markers
        self.marker_names: list[str] = []
        self._marker_pos: dict[str, np.ndarray] = {}
        self._last_visible: dict[str, bool] = {}
        self._draw_static()

    # -- what the scene items offer --------------------------------------------------------------
    def _control_point_elements(self) -> list[int] | None:
        f = self.field
        if f is None or not self.cp_names:
            return None
        try:
            return [int(f.element_index(n)) for n in self.cp_names]
        except HqpTpmError:  # control points the field does not know by name: the elements after its geometries
            return [f.n_geometries + k for k in range(len(self.cp_names))]

    def _ee_frame(self) -> int | None:
        """The EE frame: ``ee_frame`` if the model has it, else the EE task's frame (:attr:`Task.frame`)."""
        for cand in (self._ee_frame_name, None if self.ee_task is None else self.ee_task.frame):
            if cand is not None and self.model.existFrame(cand):
                return self.model.getFrameId(cand)
        return None

    def periodic_target(self) -> float | None:
        """The period (s) of the EE task's target when it is periodic (a :class:`Harmonic`), else None."""
        return None if self.ee_task is None else _period(self.ee_task.trajectory)

    def target_period(self) -> float | None:
        """The longest period (s) of the targets (:attr:`SceneItems.targets`) when all are periodic, else None."""
        periods = [_period(task.trajectory) for task in self.targets]
        return max(periods) if periods and None not in periods else None

    def desired_position(self, t: float) -> np.ndarray | None:
        """The EE task's desired position at ``t`` (None if there is none or it is not 3-D)."""
        if self.ee_task is None:
            return None
        try:
            x = np.asarray(self.ee_task.reference(float(t))[0], dtype=float)
        except Exception:  # noqa: BLE001 - e.g. a relative trajectory never started
            return None
        return x if x.shape == (3,) and np.all(np.isfinite(x)) else None

    @staticmethod
    def _target_path(k: int, task) -> str:
        return f"targets/{k}_{_clean(task.name)}"

    def target_position(self, task, t: float) -> np.ndarray | None:
        """A target task's desired 3-D position at ``t`` (None if it has none there)."""
        try:
            x = np.asarray(task.reference(float(t))[0], dtype=float)
        except Exception:  # noqa: BLE001 - e.g. a relative trajectory never started
            return None
        return x if x.shape == (3,) and np.all(np.isfinite(x)) else None

    def draw_target_paths(self, ts) -> list[np.ndarray]:
        """Draw the path of every target over the times ``ts``; returns the points drawn (for the framing)."""
        out = []
        for k, task in enumerate(self.targets):
            path = [x for x in (self.target_position(task, s) for s in ts) if x is not None]
            if len(path) > 1:
                self.draw_path(f"target_paths/{k}_{_clean(task.name)}", path, COLORS["target_path"],
                               radius=0.7 * LINE_RADIUS)
                out += path
        return out

    def _pointing_params(self):
        pt = self.pointing
        if pt is None or not (0.0 < pt.alpha_d < np.radians(85.0)):
            return None
        return np.asarray(pt.z_d, dtype=float), float(pt.alpha_d), int(pt.fid)

    def _markers(self, t: float, q) -> list:
        if self.markers_fn is None:
            return []
        return list(self.markers_fn(t, q) or [])

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
        if self.operator_markers is not None:
            for i, m in enumerate(self.operator_markers):
                node = r[f"operator_markers/{i}"]
                node.set_object(mg.Sphere(MARKER_RADIUS), _material(COLORS["marker"]))
                node.set_transform(_translation(m))
            r["target_marker"].set_object(mg.Sphere(TARGET_MARKER_RADIUS), _material(COLORS["target_marker"]))
        if self.force_fid is not None:
            r["operator_force"].set_object(arrow(), _material(COLORS["force"], xray=True))
        for k, task in enumerate(self.targets):
            r[self._target_path(k, task)].set_object(mg.Sphere(TARGET_RADIUS), _material(COLORS["target"], xray=True))

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
        """Centre the scene on the bounding box of ``points``, place the camera along ``direction`` just far
        enough that every point projects inside the view (:func:`camera_distance`), floor grid."""
        P = np.asarray(points, dtype=float).reshape(-1, 3)
        P = P[np.all(np.isfinite(P), axis=1)]
        if not len(P):
            P = np.zeros((1, 3))
        lo, hi = P.min(axis=0), P.max(axis=0)
        center = 0.5 * (lo + hi)
        radius = max(float(np.max(np.linalg.norm(P - center, axis=1))), 0.3)
        d = np.asarray(direction, dtype=float)
        d = d / np.linalg.norm(d)
        eye = camera_distance(P - center, d, fov_deg) * d  # relative to the centre, which the shift below puts at 0
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

    def _geometry_boxes(self) -> list[tuple[int, np.ndarray]]:
        """(geometry index, 8 x 3 corners of its local bounding box, scaled) of every drawn robot geometry."""
        out = []
        if self.viz is None:
            return out
        for k, g in enumerate(self.gmodel.geometryObjects):
            try:
                g.geometry.computeLocalAABB()
                lo, hi = np.asarray(g.geometry.aabb_local.min_), np.asarray(g.geometry.aabb_local.max_)
            except Exception:  # noqa: BLE001 - a geometry without a box: its placement only
                lo = hi = np.zeros(3)
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
                continue
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            out.append((k, corners * np.asarray(g.meshScale)))
        return out

    def robot_box_points(self) -> list[np.ndarray]:
        """World corners of the bounding boxes of the robot's drawn geometry, after :meth:`kinematics`."""
        pts = []
        for k, corners in self._local_boxes:
            M = self.gdata.oMg[k]
            pts.extend(corners @ M.rotation.T + M.translation)
        return pts

    def key_points(self) -> list[np.ndarray]:
        """Positions that the camera must see, after :meth:`kinematics` (the robot's whole geometry, joints,
        control points, EE, markers)."""
        pts = [M.translation.copy() for M in self.data.oMi[1:]]
        pts += self.robot_box_points()
        if self.operator_markers is not None:
            pts += list(self.operator_markers)
        pts += [self.data.oMf[f].translation.copy() for f in self.cp_fids]
        if self.ee_fid is not None:
            pts.append(self.data.oMf[self.ee_fid].translation.copy())
        pts += [p.copy() for p in self._marker_pos.values()]
        return pts

    def state(self, q, t: float = 0.0, active_point: int | None = None, update_field: bool = True,
              record: dict | None = None) -> dict:
        """``{path: (T 4x4, visible)}`` of every moving node at ``q``, ``t``.

        ``active_point``: index of the critical control point (< 0: none; None: not known, then the
        nearest in-range control point gets the distance segment and no point is blue).
        ``update_field``: recompute the policy's distance field here (False: it already holds ``q``).
        ``record``: what the run recorded at this instant (``operator_force``, ``marker``), drawn when present.
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
            T[:3, :3] = rotation_z_to(z_d)
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
        record = record or {}
        if self.operator_markers is not None:
            k = record.get("marker")
            ok = k is not None and np.isfinite(k) and 0 <= int(k) < len(self.operator_markers)
            out["target_marker"] = (_translation(self.operator_markers[int(k)] if ok else np.zeros(3)), bool(ok))
        if self.force_fid is not None:
            out["operator_force"] = self._force_arrow(record.get("operator_force"))
        for k, task in enumerate(self.targets):
            x = self.target_position(task, t)
            out[self._target_path(k, task)] = (_translation(np.zeros(3) if x is None else x), x is not None)
        return out

    def _force_arrow(self, f):
        """Transform and visibility of the force arrow: from the flange, ``FORCE_SCALE`` m per newton."""
        f = None if f is None else np.asarray(f, dtype=float).reshape(-1)
        norm = float(np.linalg.norm(f)) if f is not None and f.size == 3 and np.all(np.isfinite(f)) else 0.0
        T = np.eye(4)
        T[:3, 3] = self.data.oMf[self.force_fid].translation
        if norm < FORCE_MIN:
            T[:3, :3] = np.diag([1e-3, 1e-3, 1e-3])
            return T, False
        length = FORCE_SCALE * norm
        T[:3, :3] = rotation_z_to(f) @ np.diag([length, length, length])
        return T, True

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
        T[:3, :3] = rotation_z_to(v) @ np.diag([LINE_RADIUS, LINE_RADIUS, length])
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


def _period(traj) -> float | None:
    """The period (s) of a periodic trajectory (a :class:`Harmonic`), else None."""
    if isinstance(traj, Harmonic) and traj.omega:
        return 2.0 * np.pi / abs(float(traj.omega))
    return None


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

