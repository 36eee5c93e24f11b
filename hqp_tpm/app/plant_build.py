"""The ``[plant]`` section of a scenario: close the loop on MuJoCo instead of perfect integration.

``kind = "mujoco"`` on a free-flyer robot: the robot stands on a ground plane (its soles are boxes,
:mod:`hqp_tpm.plants.humanoid`), its torques come from the contact QP
(:class:`~hqp_tpm.control.contact_dynamics.ContactInverseDynamics`) over the ``contacts`` (the names of the
scenario's ``frame_pose`` tasks that hold the soles), and the run records the torques, the forces and the
standing criteria (:class:`~hqp_tpm.plants.floating_base.ContactController`). Fields: ``kind``, ``contacts``,
``mu`` (the controller's friction coefficient), ``f_min`` (N, per sole corner), ``friction`` (MuJoCo's),
``integrator``, ``qp_solver``.
"""

from __future__ import annotations

import numpy as np

from hqp_tpm.app.scenario import Scenario, Section
from hqp_tpm.errors import HqpTpmError, ScenarioError
from hqp_tpm.robot.model import REDUCED_ROBOTS, Robot
from hqp_tpm.tasks import FramePose

KINDS = ("kinematic", "mujoco")


def plant_kind(sc: Scenario) -> str:
    """``[plant] kind``: ``"kinematic"`` (perfect integration, the default) or ``"mujoco"``."""
    sec = sc.plant
    return "kinematic" if sec is None else sec.string("kind", "kinematic", choices=KINDS)


def build_contact_controller(sc: Scenario, robot: Robot, tasks: dict, policy, q0: np.ndarray, **controller_args):
    """``(controller, q0)``: a :class:`ContactController` on a MuJoCo plant of ``robot`` for ``sc.plant``."""
    from hqp_tpm.control.contact_dynamics import ContactInverseDynamics, SoleContact, sole_corners
    from hqp_tpm.plants.floating_base import ContactController, FloatingBasePlant
    from hqp_tpm.plants.humanoid import ROMEO_SOLES, Ground, example_robot_urdf, floating_spec, standing_base

    sec: Section = sc.plant
    where = sec.where
    if sc.order != 2:
        raise ScenarioError(f"{where}: a MuJoCo plant with contacts needs level = \"acceleration\", got {sc.level!r}")
    if not robot.has_free_flyer:
        raise ScenarioError(f"{where}: robot {sc.robot!r} has no free-flyer base (contacts need one)")
    names = sec.raw("contacts", None)
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise ScenarioError(f"{where}.contacts: expected a list of frame_pose task names (the held soles)")
    contacts = []
    for n in names:
        task = tasks.get(n)
        if not isinstance(task, FramePose):
            valid = [k for k, t in tasks.items() if isinstance(t, FramePose)]
            raise ScenarioError(f"{where}.contacts: {n!r} is not a frame_pose task; frame_pose tasks: {valid}")
        if task.frame not in ROMEO_SOLES:
            raise ScenarioError(f"{where}.contacts: task {n!r} holds frame {task.frame!r}, which has no sole box; "
                                f"known soles: {sorted(ROMEO_SOLES)}")
        contacts.append(SoleContact(task, sole_corners(*ROMEO_SOLES[task.frame])))
    soles = {c.frame: ROMEO_SOLES[c.frame] for c in contacts}
    base = REDUCED_ROBOTS.get(sc.robot, (sc.robot,))[0]
    try:
        urdf = example_robot_urdf(base)
        ground = Ground(friction=sec.number("friction", 1.0))
        spec = floating_spec(robot, urdf, soles, ground=ground, timestep=sc.period,
                             integrator=sec.string("integrator", "implicitfast"))
        plant = FloatingBasePlant(robot, spec)
        cid = ContactInverseDynamics(robot, contacts, mu=sec.number("mu", 0.7), f_min=sec.number("f_min", 1.0),
                                     solver=sec.string("qp_solver", "daqp"))
    except ScenarioError:
        raise
    except HqpTpmError as exc:
        raise ScenarioError(f"{where}: {exc}") from exc
    sec.check_unused()
    q0 = standing_base(robot, q0, soles)
    ctrl = ContactController(robot, policy, plant, cid, feet_bodies=list(soles), q0=q0, **controller_args)
    return ctrl, q0
