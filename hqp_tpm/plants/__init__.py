"""Plants: what a controller's command drives. ``kinematic`` (the default of a run: the controller integrates its
own command perfectly) or a MuJoCo plant (:class:`MujocoPlant`: a body with mass, torques through inverse dynamics
or a joint impedance, and the effects the controller does not model, :class:`PlantOptions`).

One concept per module: :mod:`~hqp_tpm.plants.options` (what is simulated), :mod:`~hqp_tpm.plants.mjcf` (the
MuJoCo model from the robot's URDF), :mod:`~hqp_tpm.plants.conventions` (free-joint conventions),
:mod:`~hqp_tpm.plants.joint_map` (joints by name), :mod:`~hqp_tpm.plants.frames` (a frame's MuJoCo body),
:mod:`~hqp_tpm.plants.torque` (command -> torque),
:mod:`~hqp_tpm.plants.contact_dynamics` (torques and contact forces of a floating base on rigid contacts),
:mod:`~hqp_tpm.plants.mujoco_plant` (the loop),
:mod:`~hqp_tpm.plants.replay` (torques replayed with MuJoCo alone), :mod:`~hqp_tpm.plants.distances` (MuJoCo's
distances against a run's distance field); docs/plant.md. MuJoCo is an optional dependency (``pip install
hqp-tpm[sim]``), imported when a plant is built.
"""

from hqp_tpm.plants.joint_map import JointMap
from hqp_tpm.plants.mjcf import plant_xml
from hqp_tpm.plants.mujoco_plant import MujocoPlant
from hqp_tpm.plants.options import KINDS, PlantOptions
from hqp_tpm.plants.replay import replay_torques
from hqp_tpm.plants.torque import InverseDynamics, JointImpedance

__all__ = ["KINDS", "InverseDynamics", "JointImpedance", "JointMap", "MujocoPlant", "PlantOptions", "plant_xml",
           "replay_torques"]
