"""Test helpers for your own stacks, tasks and robots -- what ``numpy.testing`` is to arrays.

* :func:`assert_solvers_agree` -- solve a stack with several solvers and check what the library
  guarantees between them (equal commands where the problem is the same, the level-by-level
  residual order where it is not); on failure an ``AssertionError`` with a readable table and the
  case saved to a file (:func:`load_case` reads it back). :func:`check_solvers` returns the report
  without raising.
* :func:`assert_task_derivatives` -- a task's Jacobian against central finite differences and its
  J-dot q-dot against a finite difference of J along q-dot (on the configuration manifold).
* :mod:`hqp_tpm.testing.strategies` -- hypothesis strategies for random stacks, boxes and robot
  states (needs ``pip install hqp-tpm[testing]``; nothing else here needs hypothesis).
* :mod:`hqp_tpm.testing.tolerances` -- the default tolerances and the ranges each equivalence is
  proven on (:data:`~hqp_tpm.testing.tolerances.GUARANTEES`).
* a pytest plugin (registered through the ``pytest11`` entry point): the fixture
  ``hqp_tpm_stack_check``.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "assert_solvers_agree": "hqp_tpm.testing.agreement", "check_solvers": "hqp_tpm.testing.agreement",
    "load_case": "hqp_tpm.testing.agreement", "save_case": "hqp_tpm.testing.agreement",
    "Report": "hqp_tpm.testing.agreement", "DEFAULT_SOLVERS": "hqp_tpm.testing.agreement",
    "assert_task_derivatives": "hqp_tpm.testing.derivatives", "task_derivative_errors": "hqp_tpm.testing.derivatives",
    "plot_crosscheck": "hqp_tpm.testing.plots",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'hqp_tpm.testing' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
