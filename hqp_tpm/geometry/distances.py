"""Robot-obstacle (and self) distances for the avoidance task, papers/000 Sec. III-B, eqs. (22), (25), (31).

A :class:`DistanceField` is built once from a pinocchio model, the robot's collision geometries,
control points (frame names, zero-radius spheres at the frame origins: the paper's ``p_ck``) and
:class:`~hqp_tpm.geometry.obstacles.Obstacle` s. Every control step, after the caller has run forward
kinematics and ``pin.updateFramePlacements``, :meth:`DistanceField.update` fills preallocated
arrays over the (element, obstacle) grid, elements being the geometries then the control points:

- ``distance[e, j]``: signed distance ``D(p_ce, o_j)`` (negative on penetration), ``+inf`` if the pair
  was culled by the broad phase (then it is farther than the surveillance distance);
- ``p_robot[e, j]``, ``p_obstacle[e, j]``: witness points (world), NaN if culled; for a control point
  ``p_robot`` is the point itself;
- ``normal[e, j]``: unit vector from the obstacle towards the element (the direction of
  ``(p_ck - o_j)/||p_ck - o_j||`` in (25)); it equals ``sign(d) (p_robot - p_obstacle)/||.||``, so on
  penetration it still points out of the obstacle; zero if culled;
- ``in_range[e, j]``: ``distance <= surveillance``; ``computed[e, j]``: the pair passed the broad phase.

Broad phase: bounding spheres (centre, radius) of every element and obstacle; a pair is evaluated
only if its lower bound ``||c_e - c_o|| - r_e - r_o`` is ``<= surveillance``. Sphere-sphere pairs
(control points, spherical links, spherical/point obstacles) are computed in closed form with numpy
(``analytic_spheres=True``), all other pairs by ``coal`` (one ``ComputeDistance`` per pair, one
reused ``DistanceRequest``/``DistanceResult``, cleared before each query since coal keeps the
minimum over calls otherwise; signed distance enabled).

Degenerate normal (witness points coincide, e.g. a point exactly on the obstacle's surface, or
two concentric spheres): coal's own contact normal if it is a finite unit vector; else the direction
from the obstacle's bounding centre to the robot witness point; else the normal of the previous
update for that pair; else world +z.

Kinematics helpers :func:`point_jacobian` and :func:`point_jdot_qdot` give ``J_c`` and ``J̇_c q̇`` of
(28)-(29) for a point rigidly attached to a joint (e.g. a witness point).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import NamedTuple

import coal
import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ShapeError, UnknownFrameError, unknown_name
from hqp_tpm.geometry.obstacles import GeometryError, Obstacle, bounding_sphere, convex_from_points
from hqp_tpm.robot.spatial import cross, cross3

__all__ = ["ELEMENT_KINDS", "DistanceField", "Nearest", "point_jacobian", "point_jdot_qdot"]

#: Kinds of robot elements: collision geometries of the links, and control points (frame origins).
ELEMENT_KINDS = ("geometry", "point")

#: From this many coal queries on, results are post-processed with numpy in one batch (measured crossover).
BATCH_MIN = 8

_TINY = 1e-12
_EZ = np.array([0.0, 0.0, 1.0])
_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class Nearest(NamedTuple):
    """Minimum distances over the obstacles in the surveillance area, eqs. (22) and (31)."""

    elements: np.ndarray  #: element indices considered (k,)
    distance: np.ndarray  #: D_min per element (22), +inf if no obstacle in range (k,)
    obstacle: np.ndarray  #: obstacle index of that minimum, -1 if none (k,)
    element: int  #: element of the overall minimum D_minimal (31), -1 if none
    obstacle_index: int  #: obstacle of the overall minimum, -1 if none
    value: float  #: D_minimal (31), +inf if no obstacle in range


def point_jacobian(model: pin.Model, data: pin.Data, joint_id: int, p_world) -> np.ndarray:
    """3 x nv world-aligned Jacobian ``J_c`` (28) of the point currently at ``p_world``, fixed to ``joint_id``.

    Needs ``data.J`` and ``data.oMi``: run ``pin.computeJointJacobians(model, data, q)`` first.
    ``J_c = J_v - [r]x J_w`` with ``r = p_world - o_joint`` and ``J`` the joint's LOCAL_WORLD_ALIGNED Jacobian.
    """
    J = pin.getJointJacobian(model, data, int(joint_id), _LWA)
    r = np.asarray(p_world, dtype=float) - data.oMi[int(joint_id)].translation
    return J[:3] - pin.skew(r).dot(J[3:])


def point_jdot_qdot(model: pin.Model, data: pin.Data, joint_id: int, p_world) -> np.ndarray:
    """``J̇_c q̇`` (world frame) of the point currently at ``p_world``, fixed to ``joint_id`` (used in (29)).

    It is the classical acceleration of that point at zero joint acceleration. Needs ``data.oMi``,
    ``data.v`` and ``data.a`` from ``pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))``
    (``data.a`` must come from a zero ``q̈``; algorithms that overwrite ``data.a`` afterwards break this).
    """
    jid = int(joint_id)
    M = data.oMi[jid]
    R = M.rotation
    v = data.v[jid].vector  # local (linear, angular)
    a = data.a[jid].vector
    w_l = v[3:]
    a_o = R.dot(a[:3] + cross(w_l, v[:3])).tolist()  # classical acceleration of the joint origin
    alpha = R.dot(a[3:]).tolist()
    w = R.dot(w_l).tolist()
    r = (np.asarray(p_world, dtype=float) - M.translation).tolist()
    c1, c2 = cross3(alpha, r), cross3(w, cross3(w, r))
    return np.array([a_o[0] + c1[0] + c2[0], a_o[1] + c1[1] + c2[1], a_o[2] + c1[2] + c2[2]])


def _as_slice(index: np.ndarray):
    """A slice equal to the sorted index array ``index`` if it is contiguous, else ``index`` itself."""
    if index.size and np.array_equal(index, np.arange(index[0], index[0] + index.size)):
        return slice(int(index[0]), int(index[0]) + index.size)
    return index


def _convexified(shape: coal.CollisionGeometry, what: str) -> coal.CollisionGeometry:
    """The convex hull of a BVH mesh (control must not query raw meshes); other shapes unchanged."""
    if isinstance(shape, coal.BVHModelBase):
        return convex_from_points(np.asarray(shape.vertices(), dtype=float), what=what)
    return shape


class DistanceField:
    """Signed distances, witness points and normals between robot elements and obstacles (eqs. (22), (31)).

    Parameters
    ----------
    model: the pinocchio model.
    geometry_model: the robot's collision ``pin.GeometryModel`` (None: control points only).
    control_points: frame names; each is a zero-radius sphere at the frame origin.
    obstacles: :class:`Obstacle` s (unique names).
    surveillance: the surveillance distance ``epsilon_2``; pairs farther than it are not in range.
    geometries: names of the geometries to use (default: all of ``geometry_model``).
    self_pairs: pairs of geometry names (among ``geometries``) whose mutual distance is also computed.
    convexify: replace BVH meshes by their convex hull (default; raw meshes are ~1000x slower).
    broad_phase: cull pairs by bounding spheres (False: evaluate every pair, for checks).
    analytic_spheres: closed-form sphere-sphere pairs with numpy (False: coal for every pair).
    """

    def __init__(self, model: pin.Model, geometry_model: pin.GeometryModel | None = None,
                 control_points: Sequence[str] = (), obstacles: Sequence[Obstacle] = (),
                 surveillance: float = 0.15, geometries: Iterable[str] | None = None,
                 self_pairs: Iterable[tuple[str, str]] = (), *, convexify: bool = True,
                 broad_phase: bool = True, analytic_spheres: bool = True):
        surveillance = float(surveillance)
        if not np.isfinite(surveillance) or surveillance < 0.0:
            raise GeometryError(f"surveillance distance must be finite and >= 0, got {surveillance}")
        self.model = model
        self.surveillance = surveillance
        self.broad_phase = bool(broad_phase)
        self.analytic_spheres = bool(analytic_spheres)

        # ---- robot geometries (copied into an internal geometry model, BVH -> convex hull)
        all_geoms = [] if geometry_model is None else list(geometry_model.geometryObjects)
        by_name = {g.name: i for i, g in enumerate(all_geoms)}
        if geometries is None:
            names = [g.name for g in all_geoms]
        else:
            names = list(geometries)
            for name in names:
                if name not in by_name:
                    raise unknown_name("geometry", name, by_name)
        if len(set(names)) != len(names):
            raise GeometryError(f"duplicate geometry names in {names}")
        self._geom_source_index = np.array([by_name[n] for n in names], dtype=int)
        self._gmodel = pin.GeometryModel()
        for name in names:
            obj = pin.GeometryObject(all_geoms[by_name[name]])
            if convexify:
                obj.geometry = _convexified(obj.geometry, f"geometry {name!r}")
            self._gmodel.addGeometryObject(obj)
        self._gdata = pin.GeometryData(self._gmodel)
        self._shapes = [g.geometry for g in self._gmodel.geometryObjects]

        # ---- control points
        frame_names = [f.name for f in model.frames]
        self._frame_ids = []
        for name in control_points:
            if not model.existFrame(name):
                raise unknown_name("frame", name, frame_names, cls=UnknownFrameError)
            self._frame_ids.append(model.getFrameId(name))
        if len(set(control_points)) != len(control_points):
            raise GeometryError(f"duplicate control points in {list(control_points)}")
        clash = set(control_points) & set(names)
        if clash:
            raise GeometryError(f"control points and geometries share the names {sorted(clash)}")

        # ---- element tables
        ng, npts = len(names), len(self._frame_ids)
        self.names: list[str] = names + list(control_points)
        self.kinds: list[str] = ["geometry"] * ng + ["point"] * npts
        self.joint_ids = np.array([g.parentJoint for g in self._gmodel.geometryObjects]
                                  + [model.frames[f].parentJoint for f in self._frame_ids], dtype=int)
        self.n_geometries, self.n_points = ng, npts
        M = ng + npts
        bounds = [bounding_sphere(s) for s in self._shapes]
        self._elem_local_center = [None if not c.any() else c for c, _ in bounds]  # None: the shape origin
        self._elem_radius = np.array([r for _, r in bounds] + [0.0] * npts)
        is_sphere_elem = np.array([isinstance(s, coal.Sphere) for s in self._shapes] + [True] * npts, dtype=bool)

        # ---- obstacles
        self.obstacles: list[Obstacle] = list(obstacles)
        for o in self.obstacles:
            if not isinstance(o, Obstacle):
                raise GeometryError(f"obstacles must be Obstacle instances, got {type(o).__name__}")
        onames = [o.name for o in self.obstacles]
        if len(set(onames)) != len(onames):
            raise GeometryError(f"duplicate obstacle names in {onames}")
        H = len(self.obstacles)
        self._obs_radius = np.array([o.bounding_radius for o in self.obstacles])
        self._obs_moving = [i for i, o in enumerate(self.obstacles) if o.is_moving]
        self.obstacle_placements: list[pin.SE3] = [o.placement_at(0.0) for o in self.obstacles]
        self._obs_center = np.array([Mo.act(o.local_center) for Mo, o in zip(self.obstacle_placements,
                                                                             self.obstacles, strict=True)])
        self._obs_center = self._obs_center.reshape(H, 3)
        is_sphere_obs = np.array([isinstance(o.shape, coal.Sphere) for o in self.obstacles], dtype=bool)

        # ---- result arrays (preallocated)
        self.distance = np.full((M, H), np.inf)
        self.p_robot = np.full((M, H, 3), np.nan)
        self.p_obstacle = np.full((M, H, 3), np.nan)
        self.normal = np.zeros((M, H, 3))
        self.in_range = np.zeros((M, H), dtype=bool)
        self.computed = np.zeros((M, H), dtype=bool)
        self._last_normal = np.zeros((M, H, 3))
        self.t = 0.0

        # ---- pair partition: analytic sphere block and coal pairs
        if self.analytic_spheres:
            self._sph_e = np.flatnonzero(is_sphere_elem)
            self._sph_o = np.flatnonzero(is_sphere_obs)
        else:
            self._sph_e = np.zeros(0, dtype=int)
            self._sph_o = np.zeros(0, dtype=int)
        self._sph_re = self._elem_radius[self._sph_e]
        self._sph_ro = np.array([self.obstacles[j].shape.radius for j in self._sph_o])
        self._sph_rsum = self._sph_re[:, None] + self._sph_ro[None, :]
        self._sph_re_zero = not self._sph_re.any()
        self._sph_ro_zero = not self._sph_ro.any()
        # basic slices when the index sets are contiguous (the usual case: points last, all obstacles points)
        self._sph_erows, self._sph_orows = _as_slice(self._sph_e), _as_slice(self._sph_o)
        if isinstance(self._sph_erows, slice) and isinstance(self._sph_orows, slice):
            self._sph_grid = (self._sph_erows, self._sph_orows)
        else:
            self._sph_grid = np.ix_(self._sph_e, self._sph_o)
        in_block = np.zeros((M, H), dtype=bool)
        in_block[np.ix_(self._sph_e, self._sph_o)] = True
        self._sph_all = bool(in_block.all())  # every pair analytic: each update overwrites every entry
        ce, co = np.nonzero(~in_block)
        self._coal_e, self._coal_o = ce, co
        point_shape = coal.Sphere(0.0)
        self._point_shape = point_shape
        self._coal_e_list, self._coal_o_list = ce.tolist(), co.tolist()
        self._coal_buffers = (np.zeros(len(ce)), np.zeros((len(ce), 3)), np.zeros((len(ce), 3)))
        self._coal_fun = [coal.ComputeDistance(self._shapes[e] if e < ng else point_shape, self.obstacles[j].shape)
                          for e, j in zip(ce, co, strict=True)]

        # ---- self pairs
        pairs = []
        gindex = {n: i for i, n in enumerate(names)}
        for pair in self_pairs:
            if len(pair) != 2:
                raise ShapeError(f"a self pair must name two geometries, got {pair!r}")
            a, b = pair
            for n in (a, b):
                if n not in gindex:
                    raise unknown_name("geometry", n, gindex)
            if a == b:
                raise GeometryError(f"self pair ({a!r}, {b!r}) names the same geometry twice")
            pairs.append((gindex[a], gindex[b]))
        S = len(pairs)
        self.self_pairs = np.array(pairs, dtype=int).reshape(S, 2)
        self._self_fun = [coal.ComputeDistance(self._shapes[a], self._shapes[b]) for a, b in pairs]
        self._self_a_list, self._self_b_list = [a for a, _ in pairs], [b for _, b in pairs]
        self._self_buffers = (np.zeros(S), np.zeros((S, 3)), np.zeros((S, 3)))
        self.self_distance = np.full(S, np.inf)
        self.self_p1 = np.full((S, 3), np.nan)
        self.self_p2 = np.full((S, 3), np.nan)
        self.self_normal = np.zeros((S, 3))
        self.self_in_range = np.zeros(S, dtype=bool)
        self.self_computed = np.zeros(S, dtype=bool)
        self._self_last_normal = np.zeros((S, 3))

        self._req = coal.DistanceRequest()
        self._req.enable_signed_distance = True
        self._res = coal.DistanceResult()
        self._elem_center = np.zeros((M, 3))
        self._point_M = [pin.SE3.Identity() for _ in range(npts)]
        self._elem_M: list[pin.SE3 | None] = [None] * ng + list(self._point_M)
        self._refs_key = None

    # ------------------------------------------------------------------ lookup
    @property
    def n_elements(self) -> int:
        return len(self.names)

    @property
    def n_obstacles(self) -> int:
        return len(self.obstacles)

    @property
    def geometry_model(self) -> pin.GeometryModel:
        """The internal geometry model (selected geometries, BVH meshes replaced by convex hulls)."""
        return self._gmodel

    def element_index(self, name: str) -> int:
        """Index of the element (geometry or control-point frame) called ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise unknown_name("element", name, self.names) from None

    def obstacle_index(self, name: str) -> int:
        """Index of the obstacle called ``name``."""
        for j, o in enumerate(self.obstacles):
            if o.name == name:
                return j
        raise unknown_name("obstacle", name, [o.name for o in self.obstacles])

    def element_indices(self, *kinds: str) -> np.ndarray:
        """Indices of the elements of the given kinds ('geometry', 'point'; none given: all)."""
        for k in kinds:
            if k not in ELEMENT_KINDS:
                raise unknown_name("element kind", k, ELEMENT_KINDS)
        if not kinds:
            return np.arange(self.n_elements)
        return np.array([i for i, k in enumerate(self.kinds) if k in kinds], dtype=int)

    # ------------------------------------------------------------------ update
    def _placement_refs(self, data: pin.Data, geom_data: pin.GeometryData | None):
        """References (updated in place by pinocchio) to the element placements in ``data``/``geom_data``."""
        key = (id(data), id(geom_data))
        if key != self._refs_key:
            if geom_data is None:
                self._geom_refs = [self._gdata.oMg[i] for i in range(self.n_geometries)]
            else:
                if len(geom_data.oMg) <= (self._geom_source_index.max(initial=-1)):
                    raise ShapeError("geom_data does not belong to the geometry model given at construction")
                self._geom_refs = [geom_data.oMg[int(i)] for i in self._geom_source_index]
            self._frame_refs = [data.oMf[f] for f in self._frame_ids]
            self._elem_M[: self.n_geometries] = self._geom_refs
            self._refs_key = key
            self._refs_objects = (data, geom_data)  # keep the owners alive while we hold references

    def update(self, data: pin.Data, geom_data: pin.GeometryData | None = None, t: float = 0.0) -> DistanceField:
        """Recompute every pair for the current kinematics and obstacle time ``t``; returns ``self``.

        The caller has run ``pin.forwardKinematics`` and ``pin.updateFramePlacements`` on ``data``.
        ``geom_data``: the caller's ``GeometryData`` of the geometry model given at construction, with
        placements already updated; None: placements are computed here from ``data.oMi``.
        """
        if geom_data is None and self.n_geometries:
            pin.updateGeometryPlacements(self.model, data, self._gmodel, self._gdata)
        self._placement_refs(data, geom_data)
        self.t = t = float(t)
        ng = self.n_geometries
        C = self._elem_center
        for i, Mg in enumerate(self._geom_refs):
            c = self._elem_local_center[i]
            C[i] = Mg.translation if c is None else Mg.act(c)
        if self._frame_refs:
            C[ng:] = [Mf.translation for Mf in self._frame_refs]
        for j in self._obs_moving:
            o = self.obstacles[j]
            Mo = o.placement_at(t)
            self.obstacle_placements[j] = Mo
            self._obs_center[j] = Mo.act(o.local_center)

        if not self._sph_all:
            self.distance.fill(np.inf)
            self.p_robot.fill(np.nan)
            self.p_obstacle.fill(np.nan)
            self.normal.fill(0.0)
            self.computed.fill(False)
        if self._sph_e.size and self._sph_o.size:
            self._update_spheres()
        if self._coal_fun:
            self._update_coal()
        np.less_equal(self.distance, self.surveillance, out=self.in_range)
        if len(self._self_fun):
            self._update_self()
        return self

    def _update_spheres(self):
        """Closed-form sphere-sphere block (control points are zero-radius spheres)."""
        ce = self._elem_center[self._sph_erows]
        co = self._obs_center[self._sph_orows]
        diff = ce[:, None, :] - co[None, :, :]
        delta = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))
        if delta.min() > _TINY:
            n = diff / delta[..., None]
        else:
            ok = delta > _TINY
            n = np.divide(diff, delta[..., None], out=np.zeros_like(diff), where=ok[..., None])
            for a, b in zip(*np.nonzero(~ok), strict=True):
                n[a, b] = self._fallback_normal(self._sph_e[a], self._sph_o[b], ce[a], None)
        grid = self._sph_grid
        self.distance[grid] = delta - self._sph_rsum
        self.normal[grid] = n
        self._last_normal[grid] = n
        self.p_robot[grid] = ce[:, None, :] if self._sph_re_zero else ce[:, None, :] - self._sph_re[:, None, None] * n
        self.p_obstacle[grid] = co[None, :, :] if self._sph_ro_zero else co[None] + self._sph_ro[None, :, None] * n
        self.computed[grid] = True

    def _fallback_normal(self, e: int, j: int, p_robot, coal_normal) -> np.ndarray:
        """Normal when the witness points coincide (see the module docstring)."""
        if coal_normal is not None:
            n = -np.asarray(coal_normal, dtype=float)
            if np.all(np.isfinite(n)) and abs(n @ n - 1.0) < 1e-6:
                return n
        u = np.asarray(p_robot, dtype=float) - self._obs_center[j]
        nu = math.sqrt(u @ u)
        if nu > _TINY:
            return u / nu
        last = self._last_normal[e, j]
        if last @ last > 0.5:
            return last.copy()
        return _EZ.copy()

    def _query(self, funs, first, second, M_first, M_second, todo, buffers):
        """Run the coal queries ``funs[k](M_first[first[k]], M_second[second[k]])`` for ``k`` in ``todo``.

        Fills ``buffers`` (distances, witness points on the first and on the second shape) and returns
        views of their first ``len(todo)`` rows, plus coal's normal for the queries whose distance is ~0
        (used only if the witness points coincide).
        """
        req, res = self._req, self._res
        bd, b1, b2 = buffers
        touching = {}
        i = 0
        for k in todo.tolist():
            res.clear()  # coal keeps the minimum over calls otherwise (GJK pairs)
            d = bd[i] = funs[k](M_first[first[k]], M_second[second[k]], req, res)
            b1[i] = res.getNearestPoint1()
            b2[i] = res.getNearestPoint2()
            if -1e-6 < d < 1e-6:
                touching[i] = res.normal.copy()  # res.normal is a view into res
            i += 1
        return bd[:i], b1[:i], b2[:i], touching

    @staticmethod
    def _normals(D, P1, P2):
        """``sign(d) (p1 - p2)/||p1 - p2||`` row-wise, and the rows where the witness points coincide."""
        U = P1 - P2
        nu = np.sqrt(np.einsum("ij,ij->i", U, U))
        bad = nu <= _TINY
        scale = np.where(D >= 0.0, 1.0, -1.0) / np.where(bad, 1.0, nu)
        return U * scale[:, None], np.flatnonzero(bad)

    def _update_coal(self):
        ce, co = self._coal_e, self._coal_o
        if self.broad_phase:
            diff = self._elem_center[ce] - self._obs_center[co]
            lower = np.sqrt(np.einsum("ij,ij->i", diff, diff)) - self._elem_radius[ce] - self._obs_radius[co]
            todo = np.flatnonzero(lower <= self.surveillance)
            if todo.size == 0:
                return
        else:
            todo = np.arange(len(ce))
        if len(todo) < BATCH_MIN:
            self._update_coal_pairwise(todo)
            return
        ng = self.n_geometries
        E, J = ce[todo], co[todo]
        points = E >= ng
        if points.any():
            for e in E[points].tolist():
                self._point_M[e - ng].translation = self._elem_center[e]
        D, P1, P2, touching = self._query(self._coal_fun, self._coal_e_list, self._coal_o_list, self._elem_M,
                                          self.obstacle_placements, todo, self._coal_buffers)
        if points.any():
            P1[points] = self._elem_center[E[points]]  # a control point's witness is the point itself
        N, bad = self._normals(D, P1, P2)
        for i in bad:
            N[i] = self._fallback_normal(E[i], J[i], P1[i], touching.get(i))
        self.distance[E, J] = D
        self.p_robot[E, J] = P1
        self.p_obstacle[E, J] = P2
        self.normal[E, J] = N
        self._last_normal[E, J] = N
        self.computed[E, J] = True

    def _update_coal_pairwise(self, todo):
        """Same as the batched path of :meth:`_update_coal`, one pair at a time (cheaper for few pairs)."""
        ce, co, funs = self._coal_e_list, self._coal_o_list, self._coal_fun
        req, res = self._req, self._res
        ng = self.n_geometries
        placements, elem_M, C = self.obstacle_placements, self._elem_M, self._elem_center
        dist, p_rob, p_obs, nrm, last, comp = (self.distance, self.p_robot, self.p_obstacle, self.normal,
                                               self._last_normal, self.computed)
        for k in todo.tolist():
            e, j = ce[k], co[k]
            if e >= ng:
                self._point_M[e - ng].translation = C[e]
            res.clear()  # coal keeps the minimum over calls otherwise (GJK pairs)
            d = funs[k](elem_M[e], placements[j], req, res)
            pr = C[e] if e >= ng else res.getNearestPoint1()  # a control point's witness is the point itself
            po = res.getNearestPoint2()
            u = pr - po
            nu = math.sqrt(u.dot(u))
            if nu > _TINY:
                n = u * ((1.0 if d >= 0.0 else -1.0) / nu)
            else:
                n = self._fallback_normal(e, j, pr, res.normal)
            dist[e, j] = d
            p_rob[e, j] = pr
            p_obs[e, j] = po
            nrm[e, j] = n
            last[e, j] = n
            comp[e, j] = True

    def _update_self(self):
        self.self_distance.fill(np.inf)
        self.self_p1.fill(np.nan)
        self.self_p2.fill(np.nan)
        self.self_normal.fill(0.0)
        self.self_computed.fill(False)
        a, b = self.self_pairs[:, 0], self.self_pairs[:, 1]
        if self.broad_phase:
            diff = self._elem_center[a] - self._elem_center[b]
            lower = np.sqrt(np.einsum("ij,ij->i", diff, diff)) - self._elem_radius[a] - self._elem_radius[b]
            todo = np.flatnonzero(lower <= self.surveillance)
        else:
            todo = np.arange(len(a))
        if todo.size:
            D, P1, P2, touching = self._query(self._self_fun, self._self_a_list, self._self_b_list, self._elem_M,
                                              self._elem_M, todo, self._self_buffers)
            N, bad = self._normals(D, P1, P2)
            for i in bad:
                n = touching.get(i)
                n = None if n is None else -np.asarray(n, dtype=float)
                if n is None or not (np.all(np.isfinite(n)) and abs(n @ n - 1.0) < 1e-6):
                    last = self._self_last_normal[todo[i]]
                    n = last.copy() if last @ last > 0.5 else _EZ.copy()
                N[i] = n
            self.self_distance[todo] = D
            self.self_p1[todo] = P1
            self.self_p2[todo] = P2
            self.self_normal[todo] = N
            self._self_last_normal[todo] = N
            self.self_computed[todo] = True
        np.less_equal(self.self_distance, self.surveillance, out=self.self_in_range)

    # ------------------------------------------------------------------ queries
    def nearest(self, *kinds: str) -> Nearest:
        """D_min per element (22) and D_minimal overall (31) over obstacles in the surveillance area.

        ``kinds``: element kinds to consider ('geometry', 'point'; none given: all).
        """
        idx = self.element_indices(*kinds)
        D = np.where(self.in_range[idx], self.distance[idx], np.inf)
        if D.shape[1] == 0:
            dmin = np.full(len(idx), np.inf)
            omin = np.full(len(idx), -1, dtype=int)
        else:
            omin = np.argmin(D, axis=1)
            dmin = D[np.arange(len(idx)), omin]
            omin = np.where(np.isfinite(dmin), omin, -1)
        if len(idx) == 0 or not np.isfinite(dmin).any():
            return Nearest(idx, dmin, omin, -1, -1, math.inf)
        k = int(np.argmin(dmin))
        return Nearest(idx, dmin, omin, int(idx[k]), int(omin[k]), float(dmin[k]))

    def nearest_self(self) -> tuple[int, float]:
        """Index and distance of the closest self pair in range, (-1, inf) if none."""
        if not self.self_in_range.any():
            return -1, math.inf
        D = np.where(self.self_in_range, self.self_distance, np.inf)
        k = int(np.argmin(D))
        return k, float(D[k])

    def jacobian(self, data: pin.Data, element: int, obstacle: int) -> np.ndarray:
        """``J_c`` (28) of the robot witness point of pair (element, obstacle); see :func:`point_jacobian`."""
        return point_jacobian(self.model, data, self.joint_ids[element], self.p_robot[element, obstacle])

    def jdot_qdot(self, data: pin.Data, element: int, obstacle: int) -> np.ndarray:
        """``J̇_c q̇`` of the robot witness point of pair (element, obstacle); see :func:`point_jdot_qdot`."""
        return point_jdot_qdot(self.model, data, self.joint_ids[element], self.p_robot[element, obstacle])

    def __repr__(self) -> str:
        return (f"DistanceField({self.n_geometries} geometries, {self.n_points} control points, "
                f"{self.n_obstacles} obstacles, {len(self.self_pairs)} self pairs, "
                f"surveillance={self.surveillance})")
