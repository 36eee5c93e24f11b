"""Geometry layer: obstacles, the coal distance field between robot links and obstacles, repulsion laws.

Modules: obstacles (shapes, hulls), pairs (pair set, broad phase), records (update results), witness
(witness-point Jacobians), distances (the field), repulsion.

May import: :mod:`hqp_tpm.robot`, :mod:`hqp_tpm.errors`, coal, pinocchio, numpy.
"""

from hqp_tpm.geometry.distances import DistanceField
from hqp_tpm.geometry.obstacles import Obstacle
from hqp_tpm.geometry.repulsion import Repulsion

__all__ = ["DistanceField", "Obstacle", "Repulsion"]
