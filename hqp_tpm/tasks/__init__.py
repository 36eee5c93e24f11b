"""Tasks: robot-side quantities (value, Jacobian, J-dot q-dot, command, bounds); no solver knowledge."""

from hqp_tpm.tasks.base import Gains, Task
from hqp_tpm.tasks.com import CenterOfMass
from hqp_tpm.tasks.frame_orientation import FrameOrientation
from hqp_tpm.tasks.frame_pose import FramePose
from hqp_tpm.tasks.frame_position import FramePosition
from hqp_tpm.tasks.pointing import Pointing
from hqp_tpm.tasks.posture import Posture

__all__ = ["CenterOfMass", "FrameOrientation", "FramePose", "FramePosition", "Gains", "Pointing", "Posture", "Task"]
