"""Robot layer: the pinocchio model wrapper, the per-step state update, joint limits and boxes.

May import: :mod:`hqp_tpm.errors`, :mod:`hqp_tpm.data`, pinocchio, numpy.
"""

from hqp_tpm.robot.joint_boxes import BoxLimits, acceleration_box, velocity_box
from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State

__all__ = ["BoxLimits", "JointLimits", "Robot", "State", "acceleration_box", "velocity_box"]
