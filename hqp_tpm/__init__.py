"""hqp-tpm: hierarchical whole-body control with the Task Priority Matrix, SNS-TPM and a cascaded-QP reference.

The package reads bottom-up (each layer imports only the ones above it in this list)::

    errors, data        exception types; robot files and scenarios shipped as package data
    solvers             arrays only: tpm, nullspace, sns_tpm, sns, cascaded_qp, pwdls, the name registry
    robot               Robot (pinocchio model), State (one update per step), joint limits and boxes
    geometry            obstacles, coal distance field, repulsion
    references          task targets over time, DMP, the simulated operator
    tasks               one task per module: value, Jacobian, J-dot q-dot, command, bounds
    control             Stack, Controller, the Policy contract
    policies            the dynamic-stack policies of the papers
    app                 scenario files, runner, results, figures, viewer, the hqp-tpm CLI

The names below are loaded on first access, so ``import hqp_tpm`` stays cheap.
"""

from __future__ import annotations

import importlib

__version__ = "0.2.0"

_EXPORTS = {
    # robot
    "Robot": "hqp_tpm.robot.model", "State": "hqp_tpm.robot.state", "JointLimits": "hqp_tpm.robot.limits",
    "BoxLimits": "hqp_tpm.robot.joint_boxes",
    # geometry
    "Obstacle": "hqp_tpm.geometry.obstacles", "DistanceField": "hqp_tpm.geometry.distances",
    "Repulsion": "hqp_tpm.geometry.repulsion",
    # references
    "Constant": "hqp_tpm.references.trajectories", "Harmonic": "hqp_tpm.references.trajectories",
    "Hold": "hqp_tpm.references.trajectories", "Trajectory": "hqp_tpm.references.trajectories",
    "Line": "hqp_tpm.references.line", "DmpTrajectory": "hqp_tpm.references.dmp",
    "Operator": "hqp_tpm.references.operator",
    # tasks
    **{name: "hqp_tpm.tasks" for name in (
        "Task", "Gains", "CenterOfMass", "Force", "FrameOrientation", "FramePose", "FramePosition", "JointLimit",
        "JointVelocity", "Manipulability", "Pointing", "Posture", "QuaternionOrientation")},
    # control
    "Stack": "hqp_tpm.control.stack", "FixedStack": "hqp_tpm.control.policy",
    "Controller": "hqp_tpm.control.controller", "StepResult": "hqp_tpm.control.controller",
    "Policy": "hqp_tpm.control.policy", "DistancePolicy": "hqp_tpm.control.policy",
    "SceneItems": "hqp_tpm.control.policy", "StackPolicy": "hqp_tpm.control.policy",
    "PlanningPolicy": "hqp_tpm.control.policy",
    # solvers
    **{name: "hqp_tpm.solvers" for name in (
        "Level", "tpm", "tpm_reference", "tpm_factors", "nullspace", "sns_tpm", "sns_tpm_reference", "sns",
        "cascaded_qp", "pwdls", "pinv", "solve")},
    # results from Python (the folder ``hqp-tpm run`` writes)
    "record": "hqp_tpm.app.record",
    # errors
    **{name: "hqp_tpm.errors" for name in (
        "HqpTpmError", "ShapeError", "NonFiniteError", "MagnitudeError", "UnknownNameError", "UnknownFrameError",
        "RobotFileError", "SolverNotAvailableError", "SolverFailedError", "BoxError", "GeometryError",
        "ScenarioError", "ParameterError", "ArgumentTypeError", "StateError", "DivergedError", "ExtraNotInstalledError",
        "SolverBudgetError", "InfeasibleError", "EmptyBoxError", "SweepError", "OutputError", "ResultFolderError",
        "PlantError")},
}

__all__ = ["__version__", *sorted(_EXPORTS)]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'hqp_tpm' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
