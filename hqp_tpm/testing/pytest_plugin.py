"""pytest plugin of hqp-tpm (registered through the ``pytest11`` entry point ``hqp_tpm``).

Fixtures:

``hqp_tpm_stack_check(levels, solvers=..., **kwargs)``
    :func:`hqp_tpm.testing.assert_solvers_agree` with the failing case saved in a temporary directory
    (the path is named in the failure message); session-scoped, so usable under ``@given``. The default
    solvers come from ``--hqp-tpm-solvers`` (comma-separated) or the ini option ``hqp_tpm_solvers``,
    else ``tpm, nullspace, qp:proxqp, qp:daqp``.

``hqp_tpm_task_check(task, robot, states=5, **kwargs)``
    :func:`hqp_tpm.testing.assert_task_derivatives`.

The plugin imports nothing heavy until a fixture is used. Disable it with ``-p no:hqp_tpm``.
"""

from __future__ import annotations

import pytest


def pytest_addoption(parser):
    group = parser.getgroup("hqp_tpm", "hqp-tpm stack checks")
    group.addoption("--hqp-tpm-solvers", dest="hqp_tpm_solvers", default=None,
                    help="comma-separated solvers compared by the hqp_tpm_stack_check fixture")
    parser.addini("hqp_tpm_solvers", "comma-separated solvers compared by hqp_tpm_stack_check", default="")


def pytest_report_header(config):
    from hqp_tpm import __version__

    return f"hqp-tpm {__version__}: fixtures hqp_tpm_stack_check, hqp_tpm_task_check (solvers: " \
           f"{', '.join(_default_solvers(config))})"


def _default_solvers(config) -> tuple[str, ...]:
    text = config.getoption("hqp_tpm_solvers") or config.getini("hqp_tpm_solvers")
    if text:
        return tuple(s.strip() for s in str(text).split(",") if s.strip())
    from hqp_tpm.testing.agreement import DEFAULT_SOLVERS

    return DEFAULT_SOLVERS


@pytest.fixture(scope="session")
def hqp_tpm_stack_check(request, tmp_path_factory):
    """``check(levels, solvers=None, **kwargs) -> Report``: assert that the solvers agree on ``levels``.

    Session-scoped and stateless, so it may be used in hypothesis tests; failing cases go to one
    temporary directory of the session (named in each failure message)."""
    from hqp_tpm.testing.agreement import assert_solvers_agree

    defaults = _default_solvers(request.config)
    cases = tmp_path_factory.mktemp("hqp_tpm_cases")

    def check(levels, solvers=None, **kwargs):
        kwargs.setdefault("save_to", cases)
        __tracebackhide__ = True
        return assert_solvers_agree(levels, defaults if solvers is None else solvers, **kwargs)

    return check


@pytest.fixture(scope="session")
def hqp_tpm_task_check():
    """``check(task, robot, states=5, **kwargs)``: assert a task's Jacobian and J-dot q-dot (finite differences)."""
    from hqp_tpm.testing.derivatives import assert_task_derivatives

    def check(task, robot, states=5, **kwargs):
        __tracebackhide__ = True
        return assert_task_derivatives(task, robot, states, **kwargs)

    return check
