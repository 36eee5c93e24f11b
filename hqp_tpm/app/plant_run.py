"""A run closed through a plant (``[plant] kind = "mujoco"``): the plant built from the scenario, the per-step probe
that steps it, and what the run writes about it (``plant.xml``, the ``plant*`` metrics).

The probe runs after every control step, last of the probes: it applies the operator's hand force (a co-manipulation
run) to the flange as an external wrench, steps the plant with the command the controller just computed, and sets
the controller's state to the plant's measurement -- the only thing the plant writes into the controller. Recorded
per step: ``tau`` (the applied motor torques, N m), ``dq`` (the measured velocity the step read), with sensor
noise or delay ``q_true``/``dq_true`` (the plant's true state at that time), and where the run has a distance field
``distance_crosscheck``: the largest difference between the field's distances and MuJoCo's own on the same pairs
(:mod:`hqp_tpm.plants.distances`; NaN at a step where the field computed no pair).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hqp_tpm.app.context import RunContext
from hqp_tpm.errors import HqpTpmError, ScenarioError


def build_plant(ctx: RunContext):
    """The plant of ``ctx``'s scenario (None: kinematic), at the controller's initial state; the controller then
    starts from the plant's first measurement."""
    config = ctx.scenario.plant
    if config is None or config.kind == "kinematic":
        return None
    from hqp_tpm.plants import MujocoPlant
    from hqp_tpm.plants.distances import field_geoms

    ctrl = ctx.controller
    field = ctx.scene.field
    try:
        if config.contacts is None:
            geoms = field_geoms(ctx.robot, field) if field is not None else ()
            plant = MujocoPlant(ctx.robot, ctrl.dt, ctrl.order, config.options, geoms=geoms)
        else:  # a floating base on its soles: the standing model, torques from the contact QP
            plant = _standing_plant(ctx, config)
    except HqpTpmError as exc:
        if isinstance(exc, ScenarioError):
            raise
        raise ScenarioError(f"{ctx.scenario.path.name}.plant: {exc}") from exc
    plant.reset(ctrl.q, ctrl.v)
    ctrl.set_state(*plant.measure())
    return plant


def contact_soles(sc, tasks: dict) -> dict:
    """``[plant] contacts``: sole frame -> its box (:data:`~hqp_tpm.plants.humanoid.ROMEO_SOLES`), checked against
    the scenario's tasks (each a ``frame_pose`` task on a known sole)."""
    from hqp_tpm.plants.humanoid import ROMEO_SOLES
    from hqp_tpm.tasks import FramePose

    where = f"{sc.path.name}.plant.contacts"
    soles = {}
    for name in sc.plant.contacts.tasks:
        task = tasks.get(name)
        if not isinstance(task, FramePose):
            valid = [k for k, t in tasks.items() if isinstance(t, FramePose)]
            raise ScenarioError(f"{where}: {name!r} is not a frame_pose task; frame_pose tasks: {valid}")
        if task.frame not in ROMEO_SOLES:
            raise ScenarioError(f"{where}: task {name!r} holds frame {task.frame!r}, which has no sole box; known "
                                f"soles: {sorted(ROMEO_SOLES)}")
        soles[task.frame] = ROMEO_SOLES[task.frame]
    return soles


def _standing_plant(ctx: RunContext, config):
    """A :class:`MujocoPlant` on :func:`~hqp_tpm.plants.humanoid.standing_xml` driven by a
    :class:`~hqp_tpm.plants.contact_torque.ContactTorque` law over the scenario's sole tasks."""
    from hqp_tpm.plants import MujocoPlant
    from hqp_tpm.plants.contact_dynamics import ContactInverseDynamics, SoleContact, sole_corners
    from hqp_tpm.plants.contact_torque import ContactTorque
    from hqp_tpm.plants.humanoid import Ground, standing_xml

    c, sc, ctrl = config.contacts, ctx.scenario, ctx.controller
    if sc.order != 2:
        raise ScenarioError(f"{sc.path.name}.plant.contacts: the contact QP needs level = \"acceleration\", got "
                            f"{sc.level!r}")
    soles = contact_soles(sc, ctx.tasks)
    contacts = [SoleContact(ctx.tasks[n], sole_corners(*soles[ctx.tasks[n].frame])) for n in c.tasks]
    cid = ContactInverseDynamics(ctx.robot, contacts, mu=c.mu, f_min=c.f_min, solver=c.qp_solver)
    xml = standing_xml(ctx.robot, ctrl.dt, soles, config.options, Ground(friction=c.ground_friction))
    return MujocoPlant(ctx.robot, ctrl.dt, ctrl.order, config.options, xml=xml,
                       law=ContactTorque(cid, feet_bodies=list(soles)))


def plant_probe(ctx: RunContext, plant):
    """``probe(ctrl, res) -> dict`` that steps ``plant`` with the step's command (see the module docstring)."""
    from hqp_tpm.plants.distances import DistanceCheck

    operator = ctx.scene.operator
    truth = bool(plant.options.noise_q or plant.options.noise_v or plant.options.delay)
    standing = ctx.scenario.plant.contacts is not None
    read = {"v": plant.measure()[1], "state": plant.state()}
    check = DistanceCheck(plant, ctx.scene.field) if ctx.scene.field is not None else None
    if check is not None and not check.pairs:
        check = None

    def probe(ctrl, res) -> dict:
        row = {} if check is None else {"distance_crosscheck": check()}  # the plant still at the step's state
        if operator is not None:
            plant.push(operator.fid, operator.force)
        tau = plant.step(res.command)
        row.update(tau=tau, dq=read["v"])
        if standing:  # the contact QP's forces and the standing criteria (hqp_tpm.plants.contact_torque)
            row.update(plant.law.record(plant))
        if truth:
            row["q_true"], row["dq_true"] = read["state"]
        q, v = plant.measure()
        ctrl.set_state(q, v)
        read["v"], read["state"] = v, plant.state()
        return row

    return probe


def plant_summary(ctx: RunContext, plant, arrays: dict) -> dict:
    """The ``plant*`` metrics: the plant's kind, and for MuJoCo its integrator, timestep and largest torque."""
    if plant is None:
        return {"plant": "kinematic"}
    o = plant.options
    out = {"plant": plant.kind, "plant_integrator": o.integrator, "plant_timestep_s": float(plant.model.opt.timestep),
           "plant_unmodelled": o.unmodelled_effects()}
    if "tau" in arrays and len(arrays["tau"]):
        out["tau_max"] = float(np.abs(arrays["tau"]).max())
    if "distance_crosscheck" in arrays:
        diff = np.asarray(arrays["distance_crosscheck"])
        out["distance_crosscheck_max"] = float(np.nanmax(diff)) if np.isfinite(diff).any() else None
        out["distance_crosscheck_steps"] = int(np.isfinite(diff).sum())
    if ctx.scenario.plant.contacts is not None:
        out.update(plant.law.summary(arrays))
    return out


def write_plant_xml(folder: Path, plant) -> str | None:
    """``plant.xml``: the exact model the plant simulated (None for a kinematic run)."""
    if plant is None:
        return None
    (Path(folder) / "plant.xml").write_text(plant.xml)
    return "plant.xml"
