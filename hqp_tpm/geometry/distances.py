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

The pieces live next door: :mod:`~hqp_tpm.geometry.pairs` (elements, obstacles, which pairs are computed
how, the broad phase), :mod:`~hqp_tpm.geometry.records` (the result arrays an update writes) and
:mod:`~hqp_tpm.geometry.witness` (``J_c`` and ``J̇_c q̇`` of (28)-(29) at a witness point, re-exported here).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import NamedTuple

import coal
import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ShapeError, unknown_name
from hqp_tpm.geometry import _compiled as _kernels
from hqp_tpm.geometry.obstacles import GeometryError, Obstacle
from hqp_tpm.geometry.pairs import Elements, Partition, checked_obstacles, near_pairs, self_pair_indices
from hqp_tpm.geometry.records import PairRecord, SelfPairRecord
from hqp_tpm.geometry.witness import point_jacobian, point_jdot_qdot
from hqp_tpm.robot import _compiled

__all__ = ["ELEMENT_KINDS", "DistanceField", "Nearest", "point_jacobian", "point_jdot_qdot"]

#: Kinds of robot elements: collision geometries of the links, and control points (frame origins).
ELEMENT_KINDS = ("geometry", "point")

#: From this many coal queries on, results are post-processed with numpy in one batch (measured crossover).
BATCH_MIN = 8

_TINY = 1e-12
_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
_EZ = np.array([0.0, 0.0, 1.0])


class Nearest(NamedTuple):
    """Minimum distances over the obstacles in the surveillance area, eqs. (22) and (31)."""

    elements: np.ndarray  #: element indices considered (k,)
    distance: np.ndarray  #: D_min per element (22), +inf if no obstacle in range (k,)
    obstacle: np.ndarray  #: obstacle index of that minimum, -1 if none (k,)
    element: int  #: element of the overall minimum D_minimal (31), -1 if none
    obstacle_index: int  #: obstacle of the overall minimum, -1 if none
    value: float  #: D_minimal (31), +inf if no obstacle in range


class DistanceField:
    """Signed distances, witness points and normals between robot elements and obstacles (eqs. (22), (31)).

    Parameters
    ----------
    model: the pinocchio model.
    geometry_model: the robot's collision ``pin.GeometryModel`` (None: control points only).
    control_points: frame names; each is a zero-radius sphere at the frame origin.
    obstacles: :class:`Obstacle` s (unique names).
    surveillance: the surveillance distance ``epsilon_2``; pairs farther than it are not in range.
    self_surveillance: the same for the self pairs (default: ``surveillance``).
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
                 broad_phase: bool = True, analytic_spheres: bool = True, self_surveillance: float | None = None):
        geometries = None if geometries is None else tuple(geometries)
        self_pairs = tuple(self_pairs)
        # what a copy is built from (coal's functors and pinocchio's GeometryData do not pickle: __reduce__)
        self._built_from = ((model, geometry_model, tuple(control_points), tuple(obstacles), surveillance, geometries,
                             self_pairs),
                            {"convexify": convexify, "broad_phase": broad_phase, "analytic_spheres": analytic_spheres,
                             "self_surveillance": self_surveillance})
        surveillance = float(surveillance)
        self_surveillance = surveillance if self_surveillance is None else float(self_surveillance)
        for value in (surveillance, self_surveillance):
            if not np.isfinite(value) or value < 0.0:
                raise GeometryError(f"surveillance distance must be finite and >= 0, got {value}")
        self.self_surveillance = self_surveillance
        self.model = model
        self.surveillance = surveillance
        self.broad_phase = bool(broad_phase)
        self.analytic_spheres = bool(analytic_spheres)

        elements = Elements(model, geometry_model, control_points, geometries, convexify)
        self._geom_source_index = elements.geom_source_index
        self._gmodel, self._gdata, self._shapes = elements.gmodel, elements.gdata, elements.shapes
        self._frame_ids = elements.frame_ids
        self.names: list[str] = elements.names
        self.kinds: list[str] = elements.kinds
        self.joint_ids = elements.joint_ids
        self.n_geometries, self.n_points = ng, npts = elements.n_geometries, elements.n_points
        M = ng + npts
        self._elem_local_center = elements.local_center
        self._elem_radius = elements.radius

        self.obstacles: list[Obstacle] = checked_obstacles(obstacles)
        H = len(self.obstacles)
        self._obs_radius = np.array([o.bounding_radius for o in self.obstacles])
        self._obs_moving = [i for i, o in enumerate(self.obstacles) if o.is_moving]
        self.obstacle_placements: list[pin.SE3] = [o.placement_at(0.0) for o in self.obstacles]
        self._obs_center = np.array([Mo.act(o.local_center) for Mo, o in zip(self.obstacle_placements,
                                                                             self.obstacles, strict=True)])
        self._obs_center = self._obs_center.reshape(H, 3)

        # ---- results of the last update (preallocated; the attributes below are views of the records)
        self.record = PairRecord(M, H)
        r = self.record
        self.distance, self.p_robot, self.p_obstacle, self.normal = r.distance, r.p_robot, r.p_obstacle, r.normal
        self.in_range, self.computed, self._last_normal = r.in_range, r.computed, r.last_normal
        self.t = 0.0

        # ---- pair partition: analytic sphere block and coal pairs
        part = Partition(elements, self.obstacles, self.analytic_spheres)
        self._sph_e, self._sph_o = part.sph_e, part.sph_o
        self._sph_re, self._sph_ro, self._sph_rsum = part.sph_re, part.sph_ro, part.sph_rsum
        self._sph_re_zero, self._sph_ro_zero = part.sph_re_zero, part.sph_ro_zero
        self._sph_erows, self._sph_orows, self._sph_grid = part.sph_erows, part.sph_orows, part.sph_grid
        self._sph_all = part.sph_all
        # the sphere block as basic slices: updated in place through views of the records
        self._sph_views = isinstance(self._sph_grid, tuple) and all(isinstance(g, slice) for g in self._sph_grid)
        self._sph_diff = np.zeros((len(part.sph_e), len(part.sph_o), 3))
        self._sph_delta = np.zeros((len(part.sph_e), len(part.sph_o)))
        # the compiled sphere block's arguments (views of the records: written in place)
        self._sph_kernel_args = None
        if self._sph_views and len(part.sph_e) and len(part.sph_o):
            g = self._sph_grid
            self._sph_kernel_args = (
                np.asarray(part.sph_e, dtype=np.int64), np.asarray(part.sph_o, dtype=np.int64),
                np.ascontiguousarray(part.sph_rsum, dtype=float), np.asarray(part.sph_re, dtype=float),
                np.asarray(part.sph_ro, dtype=float), bool(part.sph_re_zero), bool(part.sph_ro_zero),
                self.distance[g], self.normal[g], self._last_normal[g], self.p_robot[g], self.p_obstacle[g],
                self.computed[g], self._sph_delta, _TINY)
        self._coal_e, self._coal_o = part.coal_e, part.coal_o
        self._point_shape = part.point_shape
        self._coal_e_list, self._coal_o_list = part.coal_e_list, part.coal_o_list
        self._coal_buffers = (np.zeros(len(part.coal_e)), np.zeros((len(part.coal_e), 3)),
                              np.zeros((len(part.coal_e), 3)))
        self._coal_fun = part.coal_fun
        # the compiled update's arguments: each coal pair's flat row in the records (e * H + j), views of the records
        # as flat rows (C-contiguous arrays: reshape gives views), the rows whose witness points coincide
        self._coal_flat = (np.asarray(part.coal_e, dtype=np.int64) * H + np.asarray(part.coal_o, dtype=np.int64))
        self._coal_points = bool(npts) and bool((part.coal_e >= ng).any())
        self._flat = (self.distance.reshape(-1), self.p_robot.reshape(-1, 3), self.p_obstacle.reshape(-1, 3),
                      self.normal.reshape(-1, 3), self._last_normal.reshape(-1, 3), self.computed.reshape(-1))
        self._bad = np.zeros(len(part.coal_e) + 1, dtype=np.int64)

        # ---- self pairs
        pairs = self_pair_indices(elements.geometry_names, self_pairs)
        S = len(pairs)
        self.self_pairs = np.array(pairs, dtype=int).reshape(S, 2)
        self._self_fun = [coal.ComputeDistance(self._shapes[a], self._shapes[b]) for a, b in pairs]
        self._self_a_list, self._self_b_list = [a for a, _ in pairs], [b for _, b in pairs]
        self._self_a = np.array(self._self_a_list, dtype=np.int64)
        self._self_b = np.array(self._self_b_list, dtype=np.int64)
        self._self_bad = np.zeros(S + 1, dtype=np.int64)
        self._nearest_self = None  # (k, d) of nearest_self, when the last update's compiled call found it
        self._self_buffers = (np.zeros(S), np.zeros((S, 3)), np.zeros((S, 3)))
        self.self_record = SelfPairRecord(S)
        r = self.self_record
        self.self_distance, self.self_p1, self.self_p2, self.self_normal = r.distance, r.p1, r.p2, r.normal
        self.self_in_range, self.self_computed, self._self_last_normal = r.in_range, r.computed, r.last_normal

        self._req = coal.DistanceRequest()
        self._req.enable_signed_distance = True
        self._res = coal.DistanceResult()
        self._elem_center = np.zeros((M, 3))
        self._point_M = [pin.SE3.Identity() for _ in range(npts)]
        self._elem_M: list[pin.SE3 | None] = [None] * ng + list(self._point_M)
        self._refs_key = None
        self._block = None  # the geometry placements as one (ng, 4, 3) view (_placements_block), when pinocchio's
        # memory allows: the compiled update's broad phase reads them in one call
        self._todo = (np.zeros(max(len(part.coal_e), 1), dtype=np.int64), np.zeros(max(S, 1), dtype=np.int64))
        self._self_index = np.arange(S, dtype=np.int64)
        self._flat_in_range = self.in_range.reshape(-1)
        self._geom_views = None  # views of the geometry placements pinocchio updates in place: rotations, origins
        self._local_centres = np.array([np.zeros(3) if c is None else c for c in self._elem_local_center],
                                       dtype=float).reshape(ng, 3)
        self._nearest_last = [-1, -1]  # nearest_within's last nearest obstacle and self pair
        self._rsums = None  # nearest_within's sums of the bounding radii of the obstacle and of the self pairs
        self._joint_views: dict = {}  # (id(data), joint) -> views of its placement, velocity, acceleration
        # control points and fixed obstacles only, all sphere pairs in the compiled block: update()'s short path
        self._points_only = (not ng and npts > 0 and not self._obs_moving and bool(self._sph_all)
                             and self._sph_kernel_args is not None and not self._coal_fun and not S)

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
        ng = self.n_geometries
        if key != self._refs_key:
            if geom_data is None:
                self._geom_refs = [self._gdata.oMg[i] for i in range(self.n_geometries)]
            else:
                if len(geom_data.oMg) <= (self._geom_source_index.max(initial=-1)):
                    raise ShapeError("geom_data does not belong to the geometry model given at construction")
                self._geom_refs = [geom_data.oMg[int(i)] for i in self._geom_source_index]
            self._frame_refs = [data.oMf[f] for f in self._frame_ids]
            # the control points' positions as views pinocchio updates in place (None if it returns copies)
            views = [M.translation for M in self._frame_refs]
            again = [M.translation for M in self._frame_refs]
            self._frame_views = views if all(np.shares_memory(x, y) for x, y in zip(views, again, strict=True)) \
                else None
            self._elem_M[: self.n_geometries] = self._geom_refs
            rot, org = [M.rotation for M in self._geom_refs], [M.translation for M in self._geom_refs]
            again = [M.rotation for M in self._geom_refs] + [M.translation for M in self._geom_refs]
            shared = all(np.shares_memory(x, y) for x, y in zip(rot + org, again, strict=True))
            self._geom_views = (rot, org) if shared else None
            self._block = _placements_block(self._geom_refs) if shared and geom_data is None and ng else None
            self._refs_key = key
            self._refs_objects = (data, geom_data)  # keep the owners alive while we hold references

    def update(self, data: pin.Data, geom_data: pin.GeometryData | None = None, t: float = 0.0) -> DistanceField:
        """Recompute every pair for the current kinematics and obstacle time ``t``; returns ``self``.

        The caller has run ``pin.forwardKinematics`` and ``pin.updateFramePlacements`` on ``data``.
        ``geom_data``: the caller's ``GeometryData`` of the geometry model given at construction, with
        placements already updated; None: placements are computed here from ``data.oMi``.
        """
        self._nearest_self = None
        if self._points_only and geom_data is None and _compiled.ENABLED and self._refs_key == (id(data), id(None)) \
                and self._frame_views is not None:  # the steps below in fewer calls (the same operations)
            self.t = float(t)
            C, a = self._elem_center, self._sph_kernel_args
            C[:] = self._frame_views
            if _kernels.sphere_block(C, a[0], self._obs_center, a[1], *a[2:]):
                np.less_equal(self.distance, self.surveillance, out=self.in_range)
                return self
        if geom_data is None and self.n_geometries:
            pin.updateGeometryPlacements(self.model, data, self._gmodel, self._gdata)
        self._placement_refs(data, geom_data)
        self.t = t = float(t)
        ng = self.n_geometries
        C = self._elem_center
        fused = self._block is not None and geom_data is None and _compiled.ENABLED and self.broad_phase
        if fused:  # the centres in _update_compiled's first call
            pass
        elif self._geom_views is not None and _compiled.ENABLED and ng:  # one compiled call, SE3.act's operations
            _kernels.centres(np.array(self._geom_views[0]), np.array(self._geom_views[1]), self._local_centres, C)
        else:
            for i, Mg in enumerate(self._geom_refs):
                c = self._elem_local_center[i]
                C[i] = Mg.translation if c is None else Mg.act(c)
        if self._frame_refs:
            views = self._frame_views
            C[ng:] = [Mf.translation for Mf in self._frame_refs] if views is None else views
        for j in self._obs_moving:
            o = self.obstacles[j]
            Mo = o.placement_at(t)
            self.obstacle_placements[j] = Mo
            self._obs_center[j] = Mo.act(o.local_center)
        if fused:
            self._update_compiled()
            return self

        if not self._sph_all:
            self.record.clear()
        if self._sph_e.size and self._sph_o.size:
            self._update_spheres()
        if self._coal_fun:
            self._update_coal()
        np.less_equal(self.distance, self.surveillance, out=self.in_range)
        if len(self._self_fun):
            self._update_self()
        return self

    def _update_compiled(self):
        """:meth:`update`'s records from the centres on, in three compiled calls around the coal queries (the
        operations of the readable path): :func:`~hqp_tpm.geometry._compiled.broad_phase` (the geometries' centres,
        the obstacle and the self pairs' broad phases), then per record the queries it keeps and
        :func:`~hqp_tpm.geometry._compiled.rewrite_pairs` (cleared, written, ``in_range``)."""
        todo, self_todo = self._todo
        n, ns = _kernels.broad_phase(self._block, self._local_centres, self._elem_center, self._elem_radius,
                                     self._obs_center, self._obs_radius, self._coal_e, self._coal_o, self.surveillance,
                                     self._self_a, self._self_b, self.self_surveillance, todo, self_todo)
        if self._coal_fun:
            touching, ng = {}, self.n_geometries
            if n:
                if self._coal_points:
                    for k in todo[:n].tolist():
                        e = self._coal_e_list[k]
                        if e >= ng:
                            self._point_M[e - ng].translation = self._elem_center[e]
                D, P1, P2, touching = self._query(self._coal_fun, self._coal_e_list, self._coal_o_list, self._elem_M,
                                                  self.obstacle_placements, todo[:n], self._coal_buffers)
                if self._coal_points:
                    E = self._coal_e[todo[:n]]
                    points = E >= ng
                    P1[points] = self._elem_center[E[points]]  # a control point's witness is the point itself
            bd, b1, b2 = self._coal_buffers
            f = self._flat
            nb = _kernels.rewrite_pairs(bd, b1, b2, self._coal_flat, todo, n, f[0], f[1], f[2], f[3], f[4], f[5],
                                        self._flat_in_range, self.surveillance, _TINY, self._bad)
            for i in self._bad[:nb].tolist():
                e, j = self._coal_e_list[todo[i]], self._coal_o_list[todo[i]]
                self.normal[e, j] = self._last_normal[e, j] = self._fallback_normal(e, j, b1[i], touching.get(i))
        if self._sph_e.size and self._sph_o.size:
            self._update_spheres()
            np.less_equal(self.distance, self.surveillance, out=self.in_range)
        if not len(self._self_fun):
            return
        touching = {}
        if ns:
            touching = self._query(self._self_fun, self._self_a_list, self._self_b_list, self._elem_M, self._elem_M,
                                   self_todo[:ns], self._self_buffers)[3]
        bd, b1, b2 = self._self_buffers
        nb = _kernels.rewrite_pairs(bd, b1, b2, self._self_index, self_todo, ns, self.self_distance, self.self_p1,
                                    self.self_p2, self.self_normal, self._self_last_normal, self.self_computed,
                                    self.self_in_range, self.self_surveillance, _TINY, self._self_bad)
        k = int(self._self_bad[nb])
        self._nearest_self = (-1, math.inf) if k < 0 else (k, float(self.self_distance[k]))
        for i in self._self_bad[:nb].tolist():
            k = int(self_todo[i])
            self.self_normal[k] = self._self_last_normal[k] = self._self_fallback_normal(k, touching.get(i))

    def _update_spheres(self):
        """Closed-form sphere-sphere block (control points are zero-radius spheres).

        Same operations as :meth:`_update_spheres_reference`, into preallocated buffers and, when the block
        is a pair of basic slices, straight into the record's views (equal bit for bit, tests/test_distances.py).
        """
        grid = self._sph_grid
        if not self._sph_views:
            self._update_spheres_reference()
            return
        if _compiled.ENABLED:  # one compiled call, the same operations (False: coinciding centres, below)
            a = self._sph_kernel_args
            if _kernels.sphere_block(self._elem_center, a[0], self._obs_center, a[1], *a[2:]):
                return
        ce = self._elem_center[self._sph_erows]
        co = self._obs_center[self._sph_orows]
        diff = np.subtract(ce[:, None, :], co[None, :, :], out=self._sph_diff)
        delta = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff, out=self._sph_delta), out=self._sph_delta)
        n = self.normal[grid]                                          # a view
        if delta.min() > _TINY:
            np.divide(diff, delta[..., None], out=n)
        else:
            ok = delta > _TINY
            n[...] = 0.0
            np.divide(diff, delta[..., None], out=n, where=ok[..., None])
            for a, b in zip(*np.nonzero(~ok), strict=True):
                n[a, b] = self._fallback_normal(self._sph_e[a], self._sph_o[b], ce[a], None)
        np.subtract(delta, self._sph_rsum, out=self.distance[grid])
        self._last_normal[grid] = n
        if self._sph_re_zero:
            self.p_robot[grid] = ce[:, None, :]
        else:
            np.subtract(ce[:, None, :], self._sph_re[:, None, None] * n, out=self.p_robot[grid])
        if self._sph_ro_zero:
            self.p_obstacle[grid] = co[None, :, :]
        else:
            np.add(co[None], self._sph_ro[None, :, None] * n, out=self.p_obstacle[grid])
        self.computed[grid] = True

    def _update_spheres_reference(self):
        """The closed-form sphere-sphere block, readable (any index sets)."""
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

    def _self_fallback_normal(self, k: int, coal_normal) -> np.ndarray:
        """Normal of self pair ``k`` when its witness points coincide: coal's (from the second body to the first),
        else the pair's last normal, else world +z."""
        n = None if coal_normal is None else -np.asarray(coal_normal, dtype=float)
        if n is None or not (np.all(np.isfinite(n)) and abs(n @ n - 1.0) < 1e-6):
            last = self._self_last_normal[k]
            n = last.copy() if last @ last > 0.5 else _EZ.copy()
        return n

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
        if self.broad_phase and _compiled.ENABLED:  # the broad phase and the records in compiled calls, the same
            todo = _kernels.near_pairs(self._elem_center, ce, self._obs_center, co, self._elem_radius,
                                       self._obs_radius, self.surveillance)
            if todo.size:
                self._scatter_coal(todo)
            return
        if self.broad_phase:
            todo = near_pairs(self._elem_center[ce], self._obs_center[co], self._elem_radius[ce],
                               self._obs_radius[co], self.surveillance)
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

    def _scatter_coal(self, todo: np.ndarray) -> None:
        """:meth:`_update_coal`'s queries ``todo`` written into the records by one compiled call
        (:func:`~hqp_tpm.geometry._compiled.scatter_pairs`: the operations of the numpy paths)."""
        ng = self.n_geometries
        if self._coal_points:
            for k in todo.tolist():
                e = self._coal_e_list[k]
                if e >= ng:
                    self._point_M[e - ng].translation = self._elem_center[e]
        D, P1, P2, touching = self._query(self._coal_fun, self._coal_e_list, self._coal_o_list, self._elem_M,
                                          self.obstacle_placements, todo, self._coal_buffers)
        if self._coal_points:
            E = self._coal_e[todo]
            points = E >= ng
            P1[points] = self._elem_center[E[points]]  # a control point's witness is the point itself
        f = self._flat
        nb = _kernels.scatter_pairs(D, P1, P2, self._coal_flat[todo], f[0], f[1], f[2], f[3], f[4], f[5], _TINY,
                                    self._bad)
        for i in self._bad[:nb].tolist():
            e, j = self._coal_e_list[todo[i]], self._coal_o_list[todo[i]]
            self.normal[e, j] = self._last_normal[e, j] = self._fallback_normal(e, j, P1[i], touching.get(i))

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
            u = (pr - po)[None]
            nu = math.sqrt(np.einsum("ij,ij->i", u, u)[0])  # the batched path's expression: the same bits
            u = u[0]
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
        self.self_record.clear()
        a, b = self.self_pairs[:, 0], self.self_pairs[:, 1]
        if self.broad_phase and _compiled.ENABLED:  # the broad phase and the records in compiled calls, the same
            todo = _kernels.near_pairs(self._elem_center, self._self_a, self._elem_center, self._self_b,
                                       self._elem_radius, self._elem_radius, self.self_surveillance)
            if todo.size:
                D, P1, P2, touching = self._query(self._self_fun, self._self_a_list, self._self_b_list, self._elem_M,
                                                  self._elem_M, todo, self._self_buffers)
                nb = _kernels.scatter_pairs(D, P1, P2, todo, self.self_distance, self.self_p1, self.self_p2,
                                            self.self_normal, self._self_last_normal, self.self_computed, _TINY,
                                            self._self_bad)
                for i in self._self_bad[:nb].tolist():
                    k = int(todo[i])
                    self.self_normal[k] = self._self_last_normal[k] = self._self_fallback_normal(k, touching.get(i))
            np.less_equal(self.self_distance, self.self_surveillance, out=self.self_in_range)
            return
        if self.broad_phase:
            todo = near_pairs(self._elem_center[a], self._elem_center[b], self._elem_radius[a],
                               self._elem_radius[b], self.self_surveillance)
        else:
            todo = np.arange(len(a))
        if todo.size:
            D, P1, P2, touching = self._query(self._self_fun, self._self_a_list, self._self_b_list, self._elem_M,
                                              self._elem_M, todo, self._self_buffers)
            N, bad = self._normals(D, P1, P2)
            for i in bad:
                N[i] = self._self_fallback_normal(int(todo[i]), touching.get(i))
            self.self_distance[todo] = D
            self.self_p1[todo] = P1
            self.self_p2[todo] = P2
            self.self_normal[todo] = N
            self._self_last_normal[todo] = N
            self.self_computed[todo] = True
        np.less_equal(self.self_distance, self.self_surveillance, out=self.self_in_range)

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
        """Index and distance of the closest self pair in range, (-1, inf) if none (the first such pair, as
        ``np.argmin`` takes it; after a compiled update, as that update's last call found it)."""
        if self._nearest_self is not None:
            return self._nearest_self
        if not self.self_in_range.any():
            return -1, math.inf
        D = np.where(self.self_in_range, self.self_distance, np.inf)
        k = int(np.argmin(D))
        return k, float(D[k])

    def nearest_within(self, bound: float) -> tuple[float, float]:
        """``(d_obstacle, d_self)``: the smallest robot-obstacle and self distance at most ``bound`` (+inf: none) at
        the last :meth:`update`'s placements, as a field updated with surveillance ``bound`` (both) finds them, in
        fewer coal queries: the pairs this update's broad phase culled are queried in increasing order of their
        bounding-sphere lower bound (the last call's nearest pair first), until that bound passes the smallest
        distance found (a pair's distance is at least its bound, which the broad phase assumes too). Writes none of
        the update's arrays."""
        C, elem_M, ng = self._elem_center, self._elem_M, self.n_geometries
        ce, co, placements = self._coal_e, self._coal_o, self.obstacle_placements
        if self._rsums is None:  # (the bounding radii do not change)
            self._rsums = (self._elem_radius[ce] + self._obs_radius[co],
                           self._elem_radius[self.self_pairs[:, 0]] + self._elem_radius[self.self_pairs[:, 1]])

        def obstacle_pair(k):
            e = ce[k]
            if e >= ng:
                self._point_M[e - ng].translation = C[e]
            return self._coal_fun[k](elem_M[e], placements[co[k]], self._req, self._res)

        def self_pair(k):
            return self._self_fun[k](elem_M[self._self_a_list[k]], elem_M[self._self_b_list[k]], self._req, self._res)

        out = []
        for which, known, computed, ca, cb, query in (
                (0, self.distance, self.computed, C[ce], self._obs_center[co], obstacle_pair),
                (1, self.self_distance, self.self_computed, C[self.self_pairs[:, 0]], C[self.self_pairs[:, 1]],
                 self_pair)):
            best = float(np.where(computed, known, np.inf).min(initial=np.inf))
            if len(ca):
                diff = ca - cb
                lower = np.sqrt(np.einsum("ij,ij->i", diff, diff)) - self._rsums[which]
                lower[computed[ce, co] if which == 0 else computed] = np.inf  # (known already)
                best = self._bounded_min(which, lower, best, query, bound)
            out.append(best if best <= bound else math.inf)
        return out[0], out[1]

    def _bounded_min(self, which: int, lower: np.ndarray, best: float, query, bound: float) -> float:
        """:meth:`nearest_within`'s search over one pair set: ``lower`` the pairs' lower bounds (+inf: computed by the
        update), ``best`` the smallest distance the update computed, ``query(k)`` the distance of pair ``k``."""
        first = self._nearest_last[which]  # the last nearest pair, tried first: the bound falls sooner
        if first >= 0 and lower[first] <= bound:
            self._res.clear()  # coal keeps the minimum over calls otherwise (GJK pairs)
            best = min(best, query(first))
        else:
            first = -1
        for k in np.argsort(lower, kind="stable").tolist():
            if lower[k] > min(best, bound):
                break
            if k == first:
                continue
            self._res.clear()
            d = query(k)
            if d < best:
                best, self._nearest_last[which] = d, k
        return best

    def jacobian(self, data: pin.Data, element: int, obstacle: int) -> np.ndarray:
        """``J_c`` (28) of the robot witness point of pair (element, obstacle); see :func:`point_jacobian`."""
        return point_jacobian(self.model, data, self.joint_ids[element], self.p_robot[element, obstacle])

    def normal_jacobian(self, data: pin.Data, element: int, obstacle: int, out: np.ndarray) -> np.ndarray:
        """``n^T J_c`` (nv) of pair (element, obstacle) into ``out``: its distance's rate per joint velocity,
        ``normal @ jacobian(data, element, obstacle)`` (compiled kernels on: one compiled call, the same numbers)."""
        if not _compiled.ENABLED:
            np.matmul(self.normal[element, obstacle], self.jacobian(data, element, obstacle), out=out)
            return out
        jid = int(self.joint_ids[element])
        views = self._joint_views.get((id(data), jid))
        if views is None or views[4] is not data:
            views = self._views_of_joint(data, jid)
        _kernels.normal_row(pin.getJointJacobian(self.model, data, jid, _LWA), views[1],
                            self.p_robot[element, obstacle], self.normal[element, obstacle], out)
        return out

    def self_normal_jacobian(self, data: pin.Data, k: int, out: np.ndarray) -> np.ndarray:
        """``n^T (J_1 - J_2)`` (nv) of self pair ``k`` into ``out``: its distance's rate per joint velocity, ``J_1``,
        ``J_2`` the Jacobians of its witness points (:func:`point_jacobian`); compiled kernels on: one compiled call,
        the same numbers."""
        a, b = self._self_a_list[k], self._self_b_list[k]
        ja, jb = int(self.joint_ids[a]), int(self.joint_ids[b])
        if not _compiled.ENABLED:
            np.matmul(self.self_normal[k], point_jacobian(self.model, data, ja, self.self_p1[k])
                      - point_jacobian(self.model, data, jb, self.self_p2[k]), out=out)
            return out
        va, vb = (self._joint_views.get((id(data), j)) for j in (ja, jb))
        if va is None or va[4] is not data:
            va = self._views_of_joint(data, ja)
        if vb is None or vb[4] is not data:
            vb = self._views_of_joint(data, jb)
        _kernels.self_normal_row(pin.getJointJacobian(self.model, data, ja, _LWA), va[1], self.self_p1[k],
                                 pin.getJointJacobian(self.model, data, jb, _LWA), vb[1], self.self_p2[k],
                                 self.self_normal[k], out)
        return out

    def jdot_qdot(self, data: pin.Data, element: int, obstacle: int) -> np.ndarray:
        """``J̇_c q̇`` of the robot witness point of pair (element, obstacle); see :func:`point_jdot_qdot`."""
        if _compiled.ENABLED:  # one compiled call, the same operations
            jid = int(self.joint_ids[element])
            M, out = data.oMi[jid], np.empty(3)
            _kernels.point_jdot_qdot(M.rotation, M.translation, data.v[jid].vector, data.a[jid].vector,
                                     self.p_robot[element, obstacle], out)
            return out
        return point_jdot_qdot(self.model, data, self.joint_ids[element], self.p_robot[element, obstacle])

    def avoidance_row(self, data: pin.Data, element: int, obstacle: int, normal: np.ndarray, magnitude: float,
                      order: int, J: np.ndarray, b: np.ndarray) -> None:
        """The 1-D avoidance row (29) of pair (element, obstacle) into ``J`` (1 x nv) and ``b`` (1) in one compiled
        call: ``n^T J_c`` and ``r`` (order 1) or ``r - n^T J̇_c q̇`` (order 2), the numbers of
        :class:`~hqp_tpm.tasks.avoidance.Avoidance` given :meth:`jacobian` and :meth:`jdot_qdot` (compiled kernels
        on; else those readable calls)."""
        if not _compiled.ENABLED:
            Jc = self.jacobian(data, element, obstacle)
            J[0] = normal.dot(Jc)
            b[0] = magnitude * 1.0 if order == 1 else magnitude * 1.0 - normal.dot(self.jdot_qdot(data, element,
                                                                                                  obstacle))
            return
        jid = int(self.joint_ids[element])
        views = self._joint_views.get((id(data), jid))
        if views is None or views[4] is not data:
            views = self._views_of_joint(data, jid)
        _kernels.avoidance_row(pin.getJointJacobian(self.model, data, jid, _LWA), views[0], views[1], views[2],
                               views[3], self.p_robot[element, obstacle], normal, magnitude, order, J, b)

    def _views_of_joint(self, data: pin.Data, jid: int) -> tuple:
        """Rotation, origin, velocity and acceleration vectors of joint ``jid`` in ``data``: views pinocchio updates
        in place, kept for the next calls (copies, read every call, if this pinocchio returns copies)."""
        def read():
            M = data.oMi[jid]
            return M.rotation, M.translation, data.v[jid].vector, data.a[jid].vector
        views = read()
        if all(np.shares_memory(x, y) for x, y in zip(views, read(), strict=True)):
            if len(self._joint_views) > 64:  # other Data objects: forget them
                self._joint_views.clear()
            views = self._joint_views[(id(data), jid)] = (*views, data)  # keeps data alive: its id stays its own
        return views

    def bounding_spheres(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres ``(M, 3)`` (world, at the last update) and radii ``(M,)`` of the elements' bounding spheres
        (control points: radius 0), copies."""
        return self._elem_center.copy(), self._elem_radius.copy()

    def snapshot(self) -> tuple:
        """The history an update carries over (the last normals, used where witness points coincide).

        Everything else is recomputed from the kinematics and ``t`` by every :meth:`update`.
        """
        return self.t, self._last_normal.copy(), self._self_last_normal.copy()

    def restore(self, snapshot: tuple) -> None:
        """Put back a :meth:`snapshot` (a rejected control step)."""
        self.t, last, self_last = snapshot
        self._last_normal[...] = last
        self._self_last_normal[...] = self_last

    def __reduce__(self):
        """Copied and pickled as built again from its constructor's arguments, with its :meth:`snapshot` (coal's
        functors and pinocchio's ``GeometryData`` do not pickle, and the records' views must stay views): the
        copy's next :meth:`update` gives the numbers the original's would."""
        args, kwargs = self._built_from
        return _built_again, (args, kwargs, self.snapshot())

    def __repr__(self) -> str:
        return (f"DistanceField({self.n_geometries} geometries, {self.n_points} control points, "
                f"{self.n_obstacles} obstacles, {len(self.self_pairs)} self pairs, "
                f"surveillance={self.surveillance})")


def _placements_block(refs: list) -> np.ndarray | None:
    """The placements ``refs`` (``pin.SE3`` s pinocchio keeps side by side, as in a ``GeometryData``'s ``oMg``) as one
    read-only ``(n, 4, 3)`` view of their memory: ``[i, :3]`` the rotation's columns, ``[i, 3]`` the origin; None
    unless every rotation and origin view lies where that view reads it (Eigen's column-major 3 x 3 then 3-vector,
    12 doubles apart), so another layout or a pinocchio that returns copies keeps the per-placement reads."""
    rot, org = [M.rotation for M in refs], [M.translation for M in refs]
    if not rot or any(R.dtype != np.float64 or R.strides != (8, 24) or t.strides != (8,) for R, t in zip(rot, org,
                                                                                                           strict=True)):
        return None
    base = rot[0].__array_interface__["data"][0]
    for i, (R, t) in enumerate(zip(rot, org, strict=True)):
        if R.__array_interface__["data"][0] != base + 96 * i or t.__array_interface__["data"][0] != base + 96 * i + 72:
            return None
    block = np.lib.stride_tricks.as_strided(rot[0], shape=(len(rot), 4, 3), strides=(96, 24, 8), writeable=False)
    for i, (R, t) in enumerate(zip(rot, org, strict=True)):  # (the same numbers, read through the view)
        if not (np.array_equal(block[i, :3].T, R) and np.array_equal(block[i, 3], t)):
            return None
    return block


def _built_again(args: tuple, kwargs: dict, snapshot: tuple) -> DistanceField:
    """A :class:`DistanceField` built from ``args``, ``kwargs`` with ``snapshot`` restored (its unpickling)."""
    field = DistanceField(*args, **kwargs)
    field.restore(snapshot)
    return field
