"""Reference layer: task targets over time (constant, hold, harmonic, line, DMP) and the simulated operator.

May import: :mod:`hqp_tpm.robot`, :mod:`hqp_tpm.errors`, numpy.
"""

from hqp_tpm.references.dmp import DmpTrajectory
from hqp_tpm.references.line import Line
from hqp_tpm.references.operator import Operator
from hqp_tpm.references.trajectories import Constant, Harmonic, Hold, Trajectory

__all__ = ["Constant", "DmpTrajectory", "Harmonic", "Hold", "Line", "Operator", "Trajectory"]
