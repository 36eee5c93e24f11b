"""Our stack and our task, checked with hqp-tpm's testing tools (fixtures from its pytest plugin)."""

import my_robot_stacks as mine
import pytest
from hypothesis import given, settings

from hqp_tpm.robot.limits import JointLimits
from hqp_tpm.robot.state import State
from hqp_tpm.testing.strategies import robot_states

ROBOT = mine.robot()
TASKS = mine.tasks(ROBOT)


@pytest.mark.parametrize("task", TASKS, ids=lambda t: t.name)
def test_task_derivatives(hqp_tpm_task_check, task):
    hqp_tpm_task_check(task, ROBOT, states=5)


@settings(max_examples=25, deadline=None, derandomize=True)
@given(state=robot_states(ROBOT, margin=0.02))
def test_solvers_agree_on_our_stack(hqp_tpm_stack_check, state):
    q, v = state
    hqp_tpm_stack_check(mine.levels_at(ROBOT, TASKS, q, v))


@settings(max_examples=25, deadline=None, derandomize=True)
@given(state=robot_states(ROBOT, margin=0.02))
def test_boxed_solvers_keep_the_joint_limits(hqp_tpm_stack_check, state):
    q, v = state
    box = JointLimits(ROBOT, order=1, dt=1e-2)(State(ROBOT).update(q, v), 0.0)
    report = hqp_tpm_stack_check(mine.levels_at(ROBOT, TASKS, q, v), ("tpm", "sns_tpm", "sns", "qp:daqp"), box=box)
    assert all(c.ok for c in report.comparisons)
