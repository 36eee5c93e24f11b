"""Random stacks and boxes from a numpy generator (the builders of :mod:`hqp_tpm.solvers.random_stacks`).

Each builder consumes ``rng`` in a fixed order, so a seed names a stack; see that module for the table.
"""

from hqp_tpm.solvers.random_stacks import (
    DAMPING,
    box_for,
    box_without_zero,
    dependent_singular_stack,
    dependent_stack,
    nearly_dependent_stack,
    random_problem,
    random_stack,
)

__all__ = ["DAMPING", "box_for", "box_without_zero", "dependent_singular_stack", "dependent_stack",
           "nearly_dependent_stack", "random_problem", "random_stack"]
