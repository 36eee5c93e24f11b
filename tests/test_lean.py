"""The lean step (hqp_tpm.control.lean) equals the readable step (Task -> Level -> solver), step by step.

Two controllers built alike from the same state, one stepped by ``Controller.step()``, the other by
``LeanStep.step()``: commands, ``q`` and ``v`` compared at every step (1e-12; they are in fact equal),
on every set-up the lean step supports: the bundled ``romeo_tpm`` scenario (damped TPM), the
side-by-side benchmark's problems (EE pose > posture on the iiwa at velocity and acceleration level,
Romeo's five levels) and its closed loops (a moving reference), with null-space damping.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

from hqp_tpm.control.lean import LeanStep
from hqp_tpm.errors import NonFiniteError

TOL = 1e-12

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: ``benchmarks``


def rel_diff(a, b) -> float:
    return float(np.linalg.norm(a - b) / max(1.0, np.linalg.norm(b)))


def assert_same_steps(make, steps):
    ref, fast = make(), make()
    lean = LeanStep.of(fast)
    assert lean is not None, LeanStep.why_not(fast)
    for _ in range(steps):
        x_ref = ref.step().command
        x = lean.step()
        assert rel_diff(x, x_ref) <= TOL
        assert rel_diff(fast.q, ref.q) <= TOL and rel_diff(fast.v, ref.v) <= TOL
        assert fast.t == ref.t and fast.steps == ref.steps
    return ref, fast


def test_romeo_tpm_scenario():
    from hqp_tpm.app.build import build
    from hqp_tpm.app.scenario import load

    def make():
        return build(load("romeo_tpm"))[1]

    ref, _ = assert_same_steps(make, 150)
    assert ref.lambda_max > 0  # damped TPM


@pytest.mark.parametrize("kind", ["iiwa_vel", "iiwa_acc", "romeo_vel"])
def test_benchmark_problems(kind):
    from benchmarks.peers import problems as P

    robot = P.load_robot(P.ROMEO if kind.startswith("romeo") else P.IIWA)
    prob = P.romeo_problem(robot, n=4) if kind.startswith("romeo") else \
        P.iiwa_problem(robot, order=1 if kind == "iiwa_vel" else 2, n=4)
    for cfg in prob.configs:
        assert_same_steps(lambda cfg=cfg: P.hqp_controller(robot, prob, cfg), 30)


@pytest.mark.parametrize("order", [1, 2])
def test_closed_loop_with_a_moving_reference(order):
    from benchmarks.peers import problems as P

    robot = P.load_robot(P.IIWA)
    assert_same_steps(lambda: P.hqp_circle_controller(robot, order)[0], 400)


def test_nullspace_damping_and_mixed_steps():
    from benchmarks.peers import problems as P
    from hqp_tpm import Controller

    robot = P.load_robot(P.IIWA)
    ctrl0, _ = P.hqp_circle_controller(robot, 2)

    def make():
        return Controller(robot, ctrl0.policy.stack, order=2, dt=1e-3, nullspace_damping=5.0,
                          lambda_max=0.05, eps=0.1, q0=ctrl0.q, v0=np.full(7, 0.2))

    ref, fast = make(), make()
    lean = LeanStep.of(fast)
    for i in range(200):
        x_ref = ref.step().command
        x = lean.step() if i % 3 else fast.step().command  # the two paths mix on one controller
        assert rel_diff(x, x_ref) <= TOL and rel_diff(fast.v, ref.v) <= TOL
    assert rel_diff(lean.compute(), ref.compute().command) <= TOL


def test_unsupported_setups_are_named():
    from benchmarks.peers import problems as P

    robot = P.load_robot(P.IIWA)
    prob = P.iiwa_problem(robot, 1, n=1)
    sns = P.hqp_controller(robot, prob, prob.configs[0], "sns_tpm")
    assert LeanStep.of(sns) is None and "sns_tpm" in LeanStep.why_not(sns)


def test_non_finite_rows_raise_like_the_readable_step_and_change_nothing():
    from benchmarks.peers import problems as P

    robot = P.load_robot(P.IIWA)
    prob = P.iiwa_problem(robot, 1, n=1)
    ctrl = P.hqp_controller(robot, prob, prob.configs[0])
    lean = LeanStep.of(ctrl)
    lean.step()
    q, v, t = ctrl.q.copy(), ctrl.v.copy(), ctrl.t
    posture = ctrl.policy.stack.levels[1][0]
    posture.trajectory.start(np.full(7, np.nan))  # a non-finite target
    posture.trajectory.reference = lambda t: (np.full(7, np.nan), np.zeros(7), np.zeros(7))
    with pytest.raises(NonFiniteError, match="posture"):
        lean.step()
    np.testing.assert_array_equal(ctrl.q, q)
    np.testing.assert_array_equal(ctrl.v, v)
    assert ctrl.t == t
