"""Control layer: stacks of tasks, the controller that steps them, and the policy contract.

May import: :mod:`hqp_tpm.tasks`, :mod:`hqp_tpm.references`, :mod:`hqp_tpm.geometry`, :mod:`hqp_tpm.robot`,
:mod:`hqp_tpm.solvers`, :mod:`hqp_tpm.errors`.
"""

from hqp_tpm.control.controller import Controller, StepResult
from hqp_tpm.control.policy import (
                                    DistancePolicy,
                                    FixedStack,
                                    FunctionPolicy,
                                    PlanningPolicy,
                                    Policy,
                                    SceneItems,
                                    StackPolicy,
)
from hqp_tpm.control.stack import Stack

__all__ = ["Controller", "DistancePolicy", "FixedStack", "FunctionPolicy", "PlanningPolicy", "Policy", "SceneItems",
           "Stack", "StackPolicy", "StepResult"]
