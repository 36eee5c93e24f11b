"""Tasks: robot-side quantities (value, Jacobian, J-dot q-dot, command, bounds); no solver knowledge."""

from hqp_tpm.tasks.base import Gains, Task
from hqp_tpm.tasks.com import CenterOfMass
from hqp_tpm.tasks.force import Force
from hqp_tpm.tasks.frame_orientation import FrameOrientation
from hqp_tpm.tasks.frame_pose import FramePose
from hqp_tpm.tasks.frame_position import FramePosition
from hqp_tpm.tasks.joint_limit import JointLimit
from hqp_tpm.tasks.joint_velocity import JointVelocity
from hqp_tpm.tasks.manipulability import Manipulability
from hqp_tpm.tasks.pointing import Pointing
from hqp_tpm.tasks.posture import Posture
from hqp_tpm.tasks.quaternion_orientation import QuaternionOrientation

__all__ = ["CenterOfMass", "Force", "FrameOrientation", "FramePose", "FramePosition", "Gains", "JointLimit",
           "JointVelocity", "Manipulability", "Pointing", "Posture", "QuaternionOrientation", "Task"]
