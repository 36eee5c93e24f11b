"""The pair set of a distance field: robot elements, obstacles, which pairs are computed how, the broad phase.

Elements are the robot's collision geometries (copied into an internal geometry model, BVH meshes
replaced by their convex hulls) followed by its control points (frame origins, zero-radius spheres).
Each element and obstacle has a bounding sphere; :func:`near_pairs` keeps a pair only if the lower
bound ``||c_a - c_b|| - r_a - r_b`` of its distance is ``<= surveillance``.

:class:`Partition` splits the (element, obstacle) grid into the closed-form sphere-sphere block
(control points, spherical links, spherical/point obstacles) and the pairs coal computes (one
``ComputeDistance`` functor each); :func:`self_pair_indices` resolves self pairs by geometry name.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import coal
import numpy as np
import pinocchio as pin

from hqp_tpm.errors import ShapeError, UnknownFrameError, unknown_name
from hqp_tpm.geometry.obstacles import GeometryError, Obstacle, bounding_sphere, convexified

__all__ = ["Elements", "Partition", "as_slice", "checked_obstacles", "near_pairs", "self_pair_indices"]


def as_slice(index: np.ndarray):
    """A slice equal to the sorted index array ``index`` if it is contiguous, else ``index`` itself."""
    if index.size and np.array_equal(index, np.arange(index[0], index[0] + index.size)):
        return slice(int(index[0]), int(index[0]) + index.size)
    return index


def near_pairs(centers_a: np.ndarray, centers_b: np.ndarray, radius_a: np.ndarray, radius_b: np.ndarray,
                surveillance: float) -> np.ndarray:
    """Indices of the pairs (rows) whose bounding spheres are at most ``surveillance`` apart."""
    diff = centers_a - centers_b
    lower = np.sqrt(np.einsum("ij,ij->i", diff, diff)) - radius_a - radius_b
    return np.flatnonzero(lower <= surveillance)


class Elements:
    """The robot side: selected geometries (internal geometry model) then control points, with bounding spheres.

    ``names``, ``kinds`` ('geometry' / 'point'), ``joint_ids`` (parent joints), ``local_center`` (None: the
    shape origin; geometries only), ``radius`` and ``is_sphere`` are per element.
    """

    def __init__(self, model: pin.Model, geometry_model: pin.GeometryModel | None, control_points: Sequence[str],
                 geometries: Iterable[str] | None, convexify: bool):
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
        self.geom_source_index = np.array([by_name[n] for n in names], dtype=int)
        self.gmodel = pin.GeometryModel()
        for name in names:
            obj = pin.GeometryObject(all_geoms[by_name[name]])
            if convexify:
                obj.geometry = convexified(obj.geometry, f"geometry {name!r}")
            self.gmodel.addGeometryObject(obj)
        self.gdata = pin.GeometryData(self.gmodel)
        self.shapes = [g.geometry for g in self.gmodel.geometryObjects]

        frame_names = [f.name for f in model.frames]
        self.frame_ids = []
        for name in control_points:
            if not model.existFrame(name):
                raise unknown_name("frame", name, frame_names, cls=UnknownFrameError)
            self.frame_ids.append(model.getFrameId(name))
        if len(set(control_points)) != len(control_points):
            raise GeometryError(f"duplicate control points in {list(control_points)}")
        clash = set(control_points) & set(names)
        if clash:
            raise GeometryError(f"control points and geometries share the names {sorted(clash)}")

        ng, npts = len(names), len(self.frame_ids)
        self.geometry_names = names
        self.names: list[str] = names + list(control_points)
        self.kinds: list[str] = ["geometry"] * ng + ["point"] * npts
        self.joint_ids = np.array([g.parentJoint for g in self.gmodel.geometryObjects]
                                  + [model.frames[f].parentJoint for f in self.frame_ids], dtype=int)
        self.n_geometries, self.n_points = ng, npts
        bounds = [bounding_sphere(s) for s in self.shapes]
        self.local_center = [None if not c.any() else c for c, _ in bounds]  # None: the shape origin
        self.radius = np.array([r for _, r in bounds] + [0.0] * npts)
        self.is_sphere = np.array([isinstance(s, coal.Sphere) for s in self.shapes] + [True] * npts, dtype=bool)


def checked_obstacles(obstacles: Sequence[Obstacle]) -> list[Obstacle]:
    """The obstacles as a list, each an :class:`Obstacle`, names unique."""
    out = list(obstacles)
    for o in out:
        if not isinstance(o, Obstacle):
            raise GeometryError(f"obstacles must be Obstacle instances, got {type(o).__name__}")
    names = [o.name for o in out]
    if len(set(names)) != len(names):
        raise GeometryError(f"duplicate obstacle names in {names}")
    return out


class Partition:
    """The (element, obstacle) grid split into the analytic sphere block and the coal pairs.

    Sphere block: element rows ``sph_e`` x obstacle columns ``sph_o`` (``grid`` indexes it, basic slices when
    both are contiguous), radii ``sph_re``/``sph_ro`` and their sums. Coal pairs: ``coal_e[k]``, ``coal_o[k]``
    with the functor ``coal_fun[k]`` (control points as a zero-radius ``point_shape``).
    """

    def __init__(self, elements: Elements, obstacles: list[Obstacle], analytic_spheres: bool):
        M, H = len(elements.names), len(obstacles)
        is_sphere_obs = np.array([isinstance(o.shape, coal.Sphere) for o in obstacles], dtype=bool)
        if analytic_spheres:
            self.sph_e = np.flatnonzero(elements.is_sphere)
            self.sph_o = np.flatnonzero(is_sphere_obs)
        else:
            self.sph_e = np.zeros(0, dtype=int)
            self.sph_o = np.zeros(0, dtype=int)
        self.sph_re = elements.radius[self.sph_e]
        self.sph_ro = np.array([obstacles[j].shape.radius for j in self.sph_o])
        self.sph_rsum = self.sph_re[:, None] + self.sph_ro[None, :]
        self.sph_re_zero = not self.sph_re.any()
        self.sph_ro_zero = not self.sph_ro.any()
        # basic slices when the index sets are contiguous (the usual case: points last, all obstacles points)
        self.sph_erows, self.sph_orows = as_slice(self.sph_e), as_slice(self.sph_o)
        if isinstance(self.sph_erows, slice) and isinstance(self.sph_orows, slice):
            self.sph_grid = (self.sph_erows, self.sph_orows)
        else:
            self.sph_grid = np.ix_(self.sph_e, self.sph_o)
        in_block = np.zeros((M, H), dtype=bool)
        in_block[np.ix_(self.sph_e, self.sph_o)] = True
        self.sph_all = bool(in_block.all())  # every pair analytic: each update overwrites every entry
        ce, co = np.nonzero(~in_block)
        self.coal_e, self.coal_o = ce, co
        self.point_shape = coal.Sphere(0.0)
        self.coal_e_list, self.coal_o_list = ce.tolist(), co.tolist()
        ng = elements.n_geometries
        self.coal_fun = [coal.ComputeDistance(elements.shapes[e] if e < ng else self.point_shape, obstacles[j].shape)
                         for e, j in zip(ce, co, strict=True)]


def self_pair_indices(geometry_names: list[str], self_pairs: Iterable[tuple[str, str]]) -> list[tuple[int, int]]:
    """Element indices of the self pairs, given by geometry names (two different ones each)."""
    pairs = []
    gindex = {n: i for i, n in enumerate(geometry_names)}
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
    return pairs
