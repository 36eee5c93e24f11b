"""The fused step of a fixed stack (hqp_tpm.control._planned_step) equals the readable step (Task -> Level -> solver).

Two controllers built alike from the same state, one stepped by ``Controller.step(record=True)`` (the readable
path, the oracle), the other by ``Controller.step()`` (its compiled step, :class:`Lean`): commands, ``q`` and ``v``
compared at every step (1e-12; they are in fact equal to
the last bit where the solver is deterministic, except the fused kernel's rotation error ``log3(R_d R^T)``,
which rounds within a few ulps of pinocchio's: those steps agree to ``ROUNDING``), on every set-up the lean step
supports:
every bundled scenario that qualifies (``romeo_tpm``, ``romeo_sns_tpm``, ``romeo_sns``, ``romeo_qp``), the
side-by-side benchmark's problems (EE pose > posture on the iiwa at velocity and acceleration level,
Romeo's five levels) with every solver and the joint box, and its closed loops (a moving reference), with
null-space damping. The pieces are compared apart too: every task's row writer against its ``jacobian`` and
``command`` (orders 1 and 2), the lean joint box against :class:`~hqp_tpm.robot.limits.JointLimits` (inside,
on and beyond the limits), and the state's partial update against the full one.
"""

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

from hqp_tpm.control import _compiled_step
from hqp_tpm.control._planned_step import PlannedStep
from hqp_tpm.control.policy import FixedStack
from hqp_tpm.errors import MagnitudeError, NonFiniteError

TOL = 1e-12


class Lean:
    """``ctrl.step()`` through its compiled step (a fused PlannedStep): :meth:`step`, :meth:`compute` give the command
    of ``ctrl.step()``, ``ctrl.compute()`` (asserting that the compiled step planned for it ran), :attr:`info` the last
    result's; any other name is the PlannedStep's (its internals)."""

    def __init__(self, ctrl, fast):
        self.__dict__.update(ctrl=ctrl, fast=fast, res=None)

    @classmethod
    def of(cls, ctrl):
        """The compiled step of ``ctrl`` if it is a fused PlannedStep (a fixed stack of equality tasks; the kernels
        switched off: the planned step of a fixed stack), else None."""
        fast = ctrl._compiled_step()
        if type(fast) is not PlannedStep:
            return None
        fused = fast._program is not None or not _compiled_step._compiled.ENABLED and type(ctrl.policy) is FixedStack
        return cls(ctrl, fast) if fused else None

    def _ran(self, res):
        assert self.ctrl._fast is self.fast and res._kept is not None  # (the compiled step ran, not a new one)
        self.res = res
        return res.command

    def step(self):
        return self._ran(self.ctrl.step())

    def compute(self):
        return self._ran(self.ctrl.compute())

    @property
    def info(self):
        return self.res.info

    def __getattr__(self, name):
        return getattr(self.fast, name)

    def __setattr__(self, name, value):
        setattr(self.fast, name, value) if name in type(self.fast).__slots__ else self.__dict__.update({name: value})

#: Both paths of the lean step's arithmetic: the compiled kernels (hqp_tpm.robot._compiled) and numpy.
PATHS = [pytest.param(True, id="compiled"), pytest.param(False, id="numpy")]


@pytest.fixture
def compiled(request, monkeypatch):
    from hqp_tpm.robot import _compiled

    if request.param and not _compiled.AVAILABLE:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(_compiled, "ENABLED", request.param)
    return request.param

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: ``benchmarks``


def rel_diff(a, b) -> float:
    return float(np.linalg.norm(a - b) / max(1.0, np.linalg.norm(b)))


#: How far the fused kernel's steps may be from the readable step's (relative): it computes a frame's rotation error
#: ``log3(R_d R^T)`` itself (:func:`hqp_tpm.robot._compiled.rotation_error`), a few ulps from pinocchio's (the
#: matrix product and ``log3`` round otherwise); every other operation is the readable path's, to the bit
#: (``test_rows_without_rotation_error_are_bit_identical``).
ROUNDING = 1e-12


def assert_equal_steps(a, b):
    """``a`` equals ``b`` to :data:`ROUNDING` (relative to ``max(1, |b|)``)."""
    assert rel_diff(a, b) <= ROUNDING, (rel_diff(a, b), a, b)


def assert_same_info(info, want):
    """The SNS info of a lean step equals the readable step's: the same saturated joints and iterations, the scale
    to :data:`ROUNDING`."""
    assert info["saturated"] == want["saturated"] and info["iterations"] == want["iterations"], (info, want)
    assert abs(info["scale"] - want["scale"]) <= ROUNDING, (info, want)


#: The cascaded QP is iterative: its answer moves with its input's last bits (the rotation error's rounding) by more
#: than the analytic solvers' (README, known problems).
QP_TOL = 1e-9


def assert_same_steps(make, steps, exact=True):
    ref, fast = make(), make()
    lean = Lean.of(fast)
    assert lean is not None, PlannedStep.why_not(fast)
    tol = TOL if exact else QP_TOL
    for _ in range(steps):
        x_ref = ref.step(record=True).command
        x = lean.step()
        assert rel_diff(x, x_ref) <= tol
        assert rel_diff(fast.q, ref.q) <= tol and rel_diff(fast.v, ref.v) <= tol
        assert fast.t == ref.t and fast.steps == ref.steps
        if exact:  # the same operations in the same order (but the rotation error): ROUNDING
            assert_equal_steps(x, x_ref)
            assert_equal_steps(fast.q, ref.q)
    return ref, fast


QUALIFYING = {"romeo_tpm", "romeo_sns_tpm", "romeo_sns", "romeo_qp", "romeo_standing", "talos_sns_tpm"}


def _scenario_names():
    from hqp_tpm.data import scenarios_dir

    return sorted(p.stem for p in Path(scenarios_dir()).glob("*.toml"))


@pytest.mark.parametrize("name", _scenario_names())
def test_every_qualifying_scenario(name):
    """Every bundled scenario the lean step accepts gives the readable step's numbers; the others say why."""
    from hqp_tpm.app.build import build
    from hqp_tpm.app.scenario import load

    built = [build(load(name))[1]]
    assert (Lean.of(built[0]) is not None) == (name in QUALIFYING)
    if name not in QUALIFYING:
        assert type(built[0]._compiled_step()) is PlannedStep or PlannedStep.why_not(built[0])
        return
    qp = built[0].solver.startswith("qp")  # the cascaded QP is not reproducible to the bit (README, known problems)
    ref, _ = assert_same_steps(lambda: built.pop() if built else build(load(name))[1], 20 if qp else 30, exact=not qp)
    assert name != "romeo_tpm" or ref.lambda_max > 0  # damped TPM


#: Every problem and solver on the compiled path; the numpy path on the iiwa problems with tpm and sns_tpm
#: (they cover its arithmetic).
BENCHMARK_CASES = [pytest.param(kind, solver, on, id=f"{kind}-{solver}-{'compiled' if on else 'numpy'}")
                   for on in (True, False) for solver in ("tpm", "sns_tpm", "sns", "qp:daqp")
                   for kind in ("iiwa_vel", "iiwa_acc", "romeo_vel")
                   if on or (kind != "romeo_vel" and solver in ("tpm", "sns_tpm"))]


@pytest.mark.parametrize(("kind", "solver", "compiled"), BENCHMARK_CASES, indirect=["compiled"])
def test_benchmark_problems(kind, solver, compiled):
    from benchmarks.peers import problems as P

    robot = P.load_robot(P.ROMEO if kind.startswith("romeo") else P.IIWA)
    prob = P.romeo_problem(robot, n=2) if kind.startswith("romeo") else \
        P.iiwa_problem(robot, order=1 if kind == "iiwa_vel" else 2, n=4)
    steps = 12 if kind == "romeo_vel" and solver == "sns_tpm" else 30  # (readable Romeo SNS-TPM steps are slow)
    for cfg in prob.configs:
        ref, _ = assert_same_steps(lambda cfg=cfg: P.hqp_controller(robot, prob, cfg, solver), steps,
                                   exact=not solver.startswith("qp"))
        if solver != "tpm":
            assert ref.box is not None


@pytest.mark.parametrize("solver", ["tpm", "sns_tpm"])
@pytest.mark.parametrize("order", [1, 2])
def test_closed_loop_with_a_moving_reference(order, solver):
    from benchmarks.peers import problems as P

    robot = P.load_robot(P.IIWA)
    assert_same_steps(lambda: P.hqp_circle_controller(robot, order, solver)[0], 400)


def test_nullspace_damping_and_mixed_steps():
    from benchmarks.peers import problems as P
    from hqp_tpm import Controller

    robot = P.load_robot(P.IIWA)
    ctrl0, _ = P.hqp_circle_controller(robot, 2)

    def make():
        return Controller(robot, ctrl0.policy.stack, order=2, dt=1e-3, nullspace_damping=5.0,
                          lambda_max=0.05, eps=0.1, q0=ctrl0.q, v0=np.full(7, 0.2))

    ref, fast = make(), make()
    lean = Lean.of(fast)
    for i in range(200):
        x_ref = ref.step(record=True).command
        x = lean.step() if i % 3 else fast.step().command  # the two paths mix on one controller
        assert rel_diff(x, x_ref) <= TOL and rel_diff(fast.v, ref.v) <= TOL
    assert rel_diff(lean.compute(), ref.compute(record=True).command) <= TOL


@pytest.mark.parametrize("solver", ["sns_tpm", "sns"])
def test_nullspace_damping_with_a_box(solver):
    """At acceleration level the damping term is one more (lowest) level under the box, as in the registry."""
    from benchmarks.peers import problems as P
    from hqp_tpm import Controller

    robot = P.load_robot(P.IIWA)
    ctrl0, _ = P.hqp_circle_controller(robot, 2, solver)

    def make():
        return Controller(robot, ctrl0.policy.stack, order=2, dt=1e-3, solver=solver, box=ctrl0.box,
                          nullspace_damping=5.0, lambda_max=0.05, eps=0.1, q0=ctrl0.q, v0=np.full(7, 0.4))

    assert_same_steps(make, 200)


def test_unsupported_setups_are_named():
    from hqp_tpm.app.build import build
    from hqp_tpm.app.scenario import load

    tracking = build(load("lwr_tracking"))[1]      # a pointing cone: inequality rows
    assert Lean.of(tracking) is None and type(tracking._compiled_step()) is PlannedStep
    avoid = build(load("lwr_avoid3d"))[1]           # Algorithm 1 rebuilds the stack every step
    assert Lean.of(avoid) is None and type(avoid._compiled_step()) is PlannedStep
    from benchmarks.peers import problems as P

    robot = P.load_robot(P.IIWA)
    prob = P.iiwa_problem(robot, 1, n=1)
    cross = P.hqp_controller(robot, prob, prob.configs[0])
    cross.crosscheck = "sns_tpm"
    assert Lean.of(cross) is None and "crosscheck" in PlannedStep.why_not(cross)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.parametrize("bad", [np.nan, 1e153, 1e160])
@pytest.mark.parametrize("solver", ["tpm", "sns_tpm", "qp:daqp"])
def test_non_finite_rows_raise_like_the_readable_step_and_change_nothing(solver, bad):
    """A NaN target, or one so large that the rows' sum of squares exceeds ``MAX_SUMSQ`` (1e153) or overflows
    (1e160): the readable step's typed error naming the task (a MagnitudeError for the large ones: before, they
    were solved into a wrong command or numpy's LinAlgError), and the controller keeps its state."""
    from benchmarks.peers import problems as P

    robot = P.load_robot(P.IIWA)
    prob = P.iiwa_problem(robot, 1, n=1)
    ctrl = P.hqp_controller(robot, prob, prob.configs[0], solver)
    lean = Lean.of(ctrl)
    lean.step()
    q, v, t = ctrl.q.copy(), ctrl.v.copy(), ctrl.t
    posture = ctrl.policy.stack.levels[1][0]
    posture.trajectory.value = np.full(7, bad)  # a non-finite target (a field assigned past the validation)
    with pytest.raises(NonFiniteError if np.isnan(bad) else MagnitudeError, match="posture"):
        lean.step()
    np.testing.assert_array_equal(ctrl.q, q)
    np.testing.assert_array_equal(ctrl.v, v)
    assert ctrl.t == t


# -- the pieces ------------------------------------------------------------------------------------
@pytest.mark.parametrize("compiled", PATHS, indirect=True)
@pytest.mark.parametrize("position", [True, False])
@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("robot_name", ["iiwa7", "romeo21"])
def test_lean_joint_box_equals_joint_limits(robot_name, order, position, compiled):
    """The compiled step's box (joint_box) and JointLimits' (all the robot kernels) equal the
    literal formulas (tests/test_joint_boxes.py) to the last bit: inside the limits, on them, beyond them."""
    import pinocchio as pin
    from test_joint_boxes import literal_acceleration_box, literal_velocity_box

    from hqp_tpm import JointLimits
    from hqp_tpm.control._planned_step import joint_box
    from hqp_tpm.robot.model import Robot
    from hqp_tpm.robot.state import State

    robot = Robot.load(robot_name)
    limits = JointLimits(robot, order=order, dt=1e-3, position=position)
    box, st = joint_box(limits, np.empty(robot.nv), np.empty(robot.nv)), State(robot)
    P = limits.kernel_limits
    assert (P is not None) == position
    lo, up = robot.position_limits()
    rng = np.random.default_rng(5)
    fast = 0
    for k in range(400):
        q = robot.neutral()
        scale = (0.5, 1.0, 1.01)[k % 3]  # inside, near and beyond the limits
        q[limits.qidx] = rng.uniform(lo[limits.cols] * scale, up[limits.cols] * scale)
        if k % 5 == 0:
            q[limits.qidx[k % limits.cols.size]] = (lo if k % 2 else up)[limits.cols[k % limits.cols.size]]
        if robot.has_free_flyer:
            q[:7] = pin.SE3ToXYZQUAT(pin.SE3.Random())
        v = rng.normal(0.0, (0.05, 0.5, 3.0)[k % 3], robot.nv)
        st.update(q, v)
        qj, vj, L = st.q[limits.qidx], st.v[limits.cols], limits.limits
        if order == 1:
            lit = literal_velocity_box(qj, L.q_min, L.q_max, L.v_max, L.a_max, L.dt,
                                       vj if limits.command_rate else None)
        else:
            lit = literal_acceleration_box(qj, vj, L.q_min, L.q_max, L.v_max, L.a_max, L.dt)
        want = np.full(robot.nv, -np.inf), np.full(robot.nv, np.inf)
        want[0][limits.cols], want[1][limits.cols] = lit[0], lit[1]
        for got in (box(st), limits(st, 0.0)):
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])
        if compiled and P is not None:
            from hqp_tpm.robot import _compiled

            lo_k, up_k = np.full(robot.nv, -np.inf), np.full(robot.nv, np.inf)
            idx = limits.kernel_indices
            fast += (_compiled.velocity_box(st.q, P, idx, 1e-3, lo_k, up_k) if order == 1 else
                     _compiled.acceleration_box(st.q, st.v, P, idx, 1e-3, lo_k, up_k))
    assert (fast > 100) == (position and compiled)  # the kernels do the common case (without numba: BoxLimits)


def test_partial_state_update_completes_on_demand():
    """After a lean (partial) update, every State method still gives the full update's numbers."""
    from benchmarks.peers import problems as P
    from hqp_tpm.robot.state import State

    robot = P.load_robot(P.ROMEO)
    rng = np.random.default_rng(2)
    q = P.romeo_q0(robot)
    v = rng.normal(0.0, 0.5, robot.nv)
    full, part = State(robot).update(q, v), State(robot)
    fid, other = robot.frame_id("r_sole"), robot.frame_id("l_gripper")
    part.update(q, v, frames=(fid,), velocities=False)
    np.testing.assert_array_equal(part.data.oMf[fid].translation, full.position(fid))
    np.testing.assert_array_equal(part.jacobian(other), full.jacobian(other))
    np.testing.assert_array_equal(part.jdot_qdot(other), full.jdot_qdot(other))
    np.testing.assert_array_equal(part.position(other), full.position(other))
    np.testing.assert_array_equal(part.velocity(other), full.velocity(other))
    np.testing.assert_array_equal(part.com_jdot_qdot(), full.com_jdot_qdot())


def test_compiled_integration_equals_numpy(monkeypatch):
    """State.integrate at acceleration level: the compiled and the numpy arithmetic give the same bits."""
    from benchmarks.peers import problems as P
    from hqp_tpm.robot import _compiled
    from hqp_tpm.robot.state import State

    if not _compiled.AVAILABLE:
        pytest.skip("numba is not installed")
    robot = P.load_robot(P.ROMEO)
    st, rng = State(robot), np.random.default_rng(4)
    q = P.romeo_q0(robot)
    for _ in range(50):
        v, a = rng.normal(0.0, 2.0, robot.nv), rng.normal(0.0, 50.0, robot.nv)
        monkeypatch.setattr(_compiled, "ENABLED", True)
        got = st.integrate(q, v, a, 1e-3, 2)
        monkeypatch.setattr(_compiled, "ENABLED", False)
        want = st.integrate(q, v, a, 1e-3, 2)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])


# -- the fused tpm step (hqp_tpm.control._compiled_step) -------------------------------------------------
def _flags(monkeypatch, rows: bool, solve: bool) -> None:
    """The compiled switch, by the names of the lean step's arithmetic (robot) and of the solvers' kernels: one
    switch (:data:`hqp_tpm._jit.ENABLED`), so the last one set holds."""
    from hqp_tpm.robot import _compiled
    from hqp_tpm.solvers import _compiled as _solvers_compiled

    if (rows or solve) and not _compiled.AVAILABLE:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(_compiled, "ENABLED", rows)
    monkeypatch.setattr(_solvers_compiled, "ENABLED", solve)


@pytest.mark.parametrize(("rows", "solve"), [(True, True), (False, False)])
@pytest.mark.parametrize("kind", ["iiwa_vel", "iiwa_acc", "romeo_vel"])
def test_fused_tpm_step_under_every_switch(kind, rows, solve, monkeypatch):
    """The fused step (row programs, finiteness and TPM in one kernel) runs when the compiled switch is on, and both
    settings give the readable step's bits; so does switching it (by either module's name) while a controller runs."""
    from benchmarks.peers import problems as P

    _flags(monkeypatch, rows, solve)
    robot = P.load_robot(P.ROMEO if kind.startswith("romeo") else P.IIWA)
    prob = P.romeo_problem(robot, n=1) if kind.startswith("romeo") else \
        P.iiwa_problem(robot, order=1 if kind == "iiwa_vel" else 2, n=2)
    for cfg in prob.configs:
        _, fast = assert_same_steps(lambda cfg=cfg: P.hqp_controller(robot, prob, cfg, "tpm"), 15)
        lean = Lean.of(fast)
        assert (lean._kernel is not None) == solve
        if solve:  # every task of these stacks has a row program (the CoM's at velocity level)
            assert lean._program.ints[5] == len(lean.tasks)
    from hqp_tpm.robot import _compiled
    from hqp_tpm.solvers import _compiled as _solvers_compiled

    ref, fast = (P.hqp_controller(robot, prob, prob.configs[0], "tpm") for _ in range(2))
    lean = Lean.of(fast)
    for i in range(24):  # the switches flipped between steps, on one lean step
        monkeypatch.setattr(_compiled, "ENABLED", rows and i % 2 == 0)
        monkeypatch.setattr(_solvers_compiled, "ENABLED", solve and i % 3 != 0)
        assert_equal_steps(lean.step(), ref.step(record=True).command)
        assert_equal_steps(fast.q, ref.q)


@pytest.mark.parametrize("solver", ["sns_tpm", "sns"])
@pytest.mark.parametrize("kind", ["iiwa_vel", "iiwa_acc"])
def test_fused_rows_for_other_solvers(kind, solver, monkeypatch):
    """With another solver the fused kernel writes the programs' rows and tests them, without solving (WRITTEN);
    the solver then runs on J and b: the readable step's bits."""
    from benchmarks.peers import problems as P

    _flags(monkeypatch, True, True)
    robot = P.load_robot(P.IIWA)
    prob = P.iiwa_problem(robot, order=1 if kind == "iiwa_vel" else 2, n=2)
    for cfg in prob.configs:
        _, fast = assert_same_steps(lambda cfg=cfg: P.hqp_controller(robot, prob, cfg, solver), 15)
        lean = Lean.of(fast)
        fused_sns = solver == "sns_tpm" and not lean.damping  # SNS-TPM without the x0 level: solved in the kernel
        mode = _compiled_step.SNS if fused_sns else _compiled_step.ROWS
        assert lean._kernel is not None and lean._program.ints[6] == mode and lean._program.ints[5] == 2


def _sns_spy(monkeypatch):
    """Counts the lean step's calls of sns_tpm_stacked (the path after the fused kernel hands back)."""
    from hqp_tpm.control import _planned_step as lean_mod

    calls = []
    real = lean_mod.sns_tpm_stacked
    monkeypatch.setattr(lean_mod, "sns_tpm_stacked", lambda *a, **k: calls.append(1) or real(*a, **k))
    return calls


@pytest.mark.parametrize("kind", ["iiwa_vel", "romeo_vel"])
def test_fused_sns_tpm_equals_the_readable_step(kind, monkeypatch):
    """SNS-TPM inside the fused kernel (the joint limits' box written into its buffer, the compiled SNS loop):
    the readable step's commands, states and solver info (scale, saturated joints, iterations) to the last bit,
    with joints saturating; sns_tpm_stacked runs only on the steps the kernel hands back."""
    from benchmarks.peers import problems as P
    from hqp_tpm import JointLimits

    _flags(monkeypatch, True, True)
    calls = _sns_spy(monkeypatch)
    robot = P.load_robot(P.ROMEO if kind == "romeo_vel" else P.IIWA)
    prob = P.romeo_problem(robot, n=2) if kind == "romeo_vel" else P.iiwa_problem(robot, order=1, n=4)
    steps = saturated = 0
    for cfg in prob.configs:
        ref, fast = (P.hqp_controller(robot, prob, cfg, "sns_tpm") for _ in range(2))
        for c in (ref, fast):  # the iiwa's velocity limits at 5 % of the URDF's (Romeo's URDF limits bind already)
            c.box = JointLimits(robot, order=1, dt=P.DT, velocity_scale=1.0 if kind == "romeo_vel" else 0.05)
        lean = Lean.of(fast)
        assert lean._program.solve == _compiled_step.SNS
        for _ in range(12 if kind == "romeo_vel" else 30):
            res = ref.step(record=True)
            assert_equal_steps(lean.step(), res.command)
            assert_equal_steps(fast.q, ref.q)
            assert_same_info(lean.info, res.info)
            steps += 1
            saturated += bool(res.info["saturated"])
    assert saturated >= 5, saturated                   # the box binds: the loop saturates joints
    assert len(calls) < steps // 2, (len(calls), steps)  # the kernel solved most steps itself (the rest: SHIFT)


def test_fused_sns_tpm_box_beyond_the_position_limits(monkeypatch):
    """The kernel computes the joint limits' box; with a joint beyond its position limit (the box's recovery
    rules) it hands back: the joint box's BoxLimits path and sns_tpm_stacked give the readable step's numbers."""
    from benchmarks.peers import problems as P
    from hqp_tpm.robot import _compiled

    _flags(monkeypatch, True, True)
    calls = _sns_spy(monkeypatch)
    robot = P.load_robot(P.IIWA)
    prob = P.iiwa_problem(robot, order=1, n=1)
    q = prob.configs[0].q.copy()
    q[1] = robot.model.upperPositionLimit[1] + 0.5  # too far to stop inside: an empty position box
    cfg = dataclasses.replace(prob.configs[0], q=q)
    ref, fast = (P.hqp_controller(robot, prob, cfg, "sns_tpm") for _ in range(2))
    lean = Lean.of(fast)
    box = fast.box
    assert not lean._program.box_given  # the kernel computes the box, and declines here
    assert not _compiled.velocity_box(q, box.kernel_limits, box.kernel_indices, box.limits.dt, np.zeros(7),
                                      np.zeros(7))
    for _ in range(5):
        res = ref.step(record=True)
        assert_equal_steps(lean.step(), res.command)
        assert_equal_steps(fast.q, ref.q)
        assert_same_info(lean.info, res.info)
    assert len(calls) >= 1


def _singular_damped_pair(solver: str):
    """Two iiwa controllers (readable and lean) at the stretched-out configuration q = 0, where the EE pose Jacobian
    loses rank, with damped pivots (lambda_max > 0): the compiled kernels decline there."""
    from benchmarks.peers import problems as P

    robot = P.load_robot(P.IIWA)
    prob = P.iiwa_problem(robot, order=1, n=1)
    cfg = dataclasses.replace(prob.configs[0], q=np.zeros(robot.nq))
    ctrls = [P.hqp_controller(robot, prob, cfg, solver) for _ in range(2)]
    for c in ctrls:
        c.lambda_max, c.eps = 0.05, 0.02
    return ctrls[0], ctrls[1]


def test_fused_sns_tpm_solves_damped_singular_stacks_itself(monkeypatch):
    """A damped, singular pivot (the arm stretched out, lambda_max > 0): the SNS kernel answers inside the fused
    kernel (the recursion for the stack's TPM), with the readable step's numbers; sns_tpm_stacked does not run. (The
    kernel before issue 28 handed these steps back to a numpy loop.)"""
    from hqp_tpm.solvers import _compiled_sns

    _flags(monkeypatch, True, True)
    calls = _sns_spy(monkeypatch)
    loops = []
    real_loop = _compiled_sns.sns_tpm_loop
    monkeypatch.setattr(_compiled_sns, "sns_tpm_loop", lambda *a: loops.append(1) or real_loop(*a))
    ref, fast = _singular_damped_pair("sns_tpm")
    lean = Lean.of(fast)
    for _ in range(5):
        res = ref.step(record=True)
        loops.clear()
        assert_equal_steps(lean.step(), res.command)
        assert not loops, len(loops)  # (the fused kernel's own loop: sns_tpm_loop is not called)
        assert_same_info(lean.info, res.info)
    assert not calls, len(calls)


def test_fused_sns_tpm_solves_the_stacks_it_once_stopped_at(monkeypatch):
    """Romeo configurations where a free-column stack ``J W`` met on the way is one the factorization's certificates
    cannot decide (17 free joints left, the hands' rows nearly dependent in what the levels above leave; the
    benchmark's configurations 15, 54, 66, 67): the kernel before issue 28 stopped there (SNS_RESUME) and a numpy loop
    went on. Now the recursion answers that pass inside the fused kernel: the readable step's command and info, and
    sns_tpm_stacked never runs."""
    from benchmarks.peers import problems as P

    _flags(monkeypatch, True, True)
    calls = _sns_spy(monkeypatch)
    robot = P.load_robot(P.ROMEO)
    prob = P.romeo_problem(robot, n=70)
    for k in (15, 54, 66, 67):
        cfg = prob.configs[k]
        ref, fast = (P.hqp_controller(robot, prob, cfg, "sns_tpm") for _ in range(2))
        lean = Lean.of(fast)
        assert lean._program.solve == _compiled_step.SNS
        res = ref.step(record=True)
        assert_equal_steps(lean.step(), res.command)
        assert_equal_steps(fast.q, ref.q)
        assert_same_info(lean.info, res.info)
        assert res.info["iterations"] >= 8, res.info
    assert not calls, len(calls)


def _program_stacks(robot):
    """Stacks whose every kind of row program (and a row writer beside them) meets the fused kernel."""
    from hqp_tpm import CenterOfMass, FrameOrientation, FramePose, FramePosition, Gains, Harmonic, Line, Posture, Stack

    g = Gains(7.0, 3.0)
    circle = Harmonic(center=np.array([0.4, 0.1, 0.5]), cos_amplitude=np.array([0.0, 0.1, 0.0]),
                      sin_amplitude=np.array([0.0, 0.0, 0.1]), omega=2.0)
    line = Line(start_point=[0.4, 0.1, 0.5], end_point=[0.5, 0.2, 0.4], v_max=2.0, a_max=20.0)  # moves 0-0.2 s
    two = ["iiwa_joint_2", "iiwa_joint_5"]
    return [
        Stack.of(FramePose(robot, "iiwa_ee", None, g), Posture(robot, None, g, joints=two)),
        Stack.of((FramePosition(robot, "iiwa_link_4", [0.1, 0.3], g, axes="zx"),
                  FrameOrientation(robot, "iiwa_ee", None, g)),
                 CenterOfMass(robot, [0.0, 0.1], g, axes="xy"), Posture(robot, np.linspace(-1, 1, 7), g)),
        Stack.of((FramePosition(robot, "iiwa_ee", line, g), FrameOrientation(robot, "iiwa_ee", None, g))),
        # a Harmonic reference: FramePosition's row writer (its one compiled call) instead of the program
        Stack.of((FramePosition(robot, "iiwa_ee", circle, g), FrameOrientation(robot, "iiwa_ee", None, g)),
                 Posture(robot, None, g)),
    ]


@pytest.mark.parametrize("which", [0, 1, 2, 3])
@pytest.mark.parametrize("order", [1, 2])
def test_row_programs_follow_targets_gains_and_trajectories_changed_mid_run(order, which, monkeypatch):
    """Every row program (frame pose, position on selected axes, orientation, posture) gives the readable step's
    bits, also after its target placement, gains or trajectory are replaced while the controller runs (a moving
    reference is copied every step, a constant one once)."""
    import pinocchio as pin

    from hqp_tpm import Constant, Controller, FramePose, FramePosition, Gains, Harmonic, Posture
    from hqp_tpm.robot.model import Robot

    _flags(monkeypatch, True, True)
    robot = Robot.load("iiwa7")
    q0 = np.linspace(-0.6, 0.8, 7)

    def make():
        return Controller(robot, _program_stacks(robot)[which], order=order, dt=1e-3, q0=q0,
                          v0=np.full(7, 0.3) if order == 2 else None)

    ref, fast = make(), make()
    lean = Lean.of(fast)
    assert lean._kernel is not None and lean._program.ints[5] >= 2
    for i, task in enumerate(lean.tasks):  # a frame position a row program (a Harmonic reference too: copied)
        assert type(task) is not FramePosition or "write_own_rows" not in repr(lean._gathers[i])
    target = pin.SE3(pin.rpy.rpyToMatrix(0.1, -0.2, 0.3), np.array([0.3, 0.2, 0.7]))
    wave = Harmonic(center=np.array([0.2, 0.3]), cos_amplitude=np.array([0.1, 0.0]),
                    sin_amplitude=np.array([0.0, 0.1]), omega=3.0)
    for i in range(40):
        for ctrl in (ref, fast):
            for task in ctrl.policy.stack.tasks():
                if i == 10 and type(task) is FramePose:
                    task.target = target
                if i == 20:
                    task.gains = Gains(2.0, 5.0)
                if i == 30 and type(task) is Posture:
                    task.trajectory = Constant(value=np.full(task.dim, 0.2))
                if i == 30 and type(task) is FramePosition and task.dim == 2:
                    task.trajectory = wave
                if i == 35 and type(task) is Posture:  # a field of the trajectory, not the task's attribute
                    task.trajectory.value = np.full(task.dim, -0.1)
        assert_equal_steps(lean.step(), ref.step(record=True).command)
        assert_equal_steps(fast.q, ref.q)
        assert_equal_steps(fast.v, ref.v)


def test_targets_assigned_every_step_are_followed_without_edit_counters():
    """Assignments to tasks and trajectories are plain (no process-wide edit counter: ``Task`` has no
    ``__setattr__``, ``Trajectory.__setattr__`` only stores its arrays read-only); the row programs copy a reference
    or gains when they are not the ones they hold (compared by identity). Targets and gains assigned between every
    two steps, as a user's loop does, give the readable step's commands (to ROUNDING: the pose's log3)."""
    import pinocchio as pin

    from hqp_tpm import Controller, FramePose, FramePosition, Gains, Posture, Stack
    from hqp_tpm.references import trajectories
    from hqp_tpm.robot.model import Robot
    from hqp_tpm.tasks.base import Task

    assert Task.__setattr__ is object.__setattr__ and "edits" not in vars(trajectories)
    if not _compiled_step._compiled.AVAILABLE:
        pytest.skip("numba is not installed")
    robot = Robot.load("iiwa7")
    g = Gains(5.0, 2.0)
    rng = np.random.default_rng(8)

    def make(order):
        stack = Stack.of(FramePose(robot, "iiwa_ee", None, g),
                         FramePosition(robot, "iiwa_link_4", [0.1, 0.3], g, axes="zx"), Posture(robot, None, g))
        return Controller(robot, stack, order=order, dt=1e-3, q0=np.linspace(-0.6, 0.8, 7))

    for order in (1, 2):
        ref, fast = make(order), make(order)
        lean = Lean.of(fast)
        assert all("write_own_rows" not in repr(g) for g in lean._gathers)  # every task: a row program
        for i in range(30):
            M = pin.SE3(pin.rpy.rpyToMatrix(*rng.uniform(-0.3, 0.3, 3)), rng.uniform(0.2, 0.6, 3))
            x, q_d, kp = rng.uniform(-0.2, 0.4, 2), rng.uniform(-1, 1, 7), float(rng.uniform(1, 9))
            for ctrl in (ref, fast):
                pose, point, posture = ctrl.policy.stack.tasks()
                if i % 3:
                    pose.target = M
                point.trajectory.value = x
                posture.trajectory.value = q_d
                if i % 4 == 0:
                    posture.gains = Gains(kp, 1.0)
            assert_equal_steps(lean.step(), ref.step(record=True).command)
            assert_equal_steps(fast.q, ref.q)


@pytest.mark.parametrize("solver", ["tpm", "sns_tpm"])
@pytest.mark.parametrize("order", [1, 2])
def test_rows_without_rotation_error_are_bit_identical(order, solver, monkeypatch):
    """Frame positions (on all and on selected axes), the CoM and a posture, no orientation: the fused kernel writes
    the frame Jacobians from pinocchio's joint Jacobians with pinocchio's operations (the CoM's: pinocchio's, read in
    place), so at velocity level the steps are the readable step's to the last bit (with a rotation error they agree
    to ROUNDING; so at acceleration level, where the kernel sums J qd in its own order where the readable step calls
    numpy's dot)."""
    from hqp_tpm import CenterOfMass, Controller, FramePosition, Gains, JointLimits, Posture, Stack
    from hqp_tpm.robot.model import Robot

    _flags(monkeypatch, True, True)
    robot = Robot.load("iiwa7")
    g = Gains(7.0, 3.0)
    stack = Stack.of(FramePosition(robot, "iiwa_ee", [0.5, 0.1, 0.6], g),
                     (FramePosition(robot, "iiwa_link_4", [0.1, 0.3], g, axes="zx"),
                      CenterOfMass(robot, [0.0, 0.05], g, axes="yx")), Posture(robot, None, g))

    def make():
        return Controller(robot, stack, order=order, dt=1e-3, q0=np.linspace(-0.6, 0.8, 7), solver=solver,
                          v0=np.full(7, 0.3) if order == 2 else None,
                          box=JointLimits(robot, order=order, dt=1e-3, velocity_scale=0.1) if solver != "tpm" else None)

    ref, fast = make(), make()
    lean = Lean.of(fast)
    assert lean._kernel is not None and lean._program.ints[5] == (4 if order == 1 else 3)  # (the CoM: order 1)
    same = np.testing.assert_array_equal if order == 1 else assert_equal_steps
    for _ in range(40):
        res = ref.step(record=True)
        same(lean.step(), res.command)
        same(fast.q, ref.q)
        same(fast.v, ref.v)
        if solver == "sns_tpm":
            assert_same_info(lean.info, res.info)


def test_positions_only_state_update_equals_the_partial_update():
    """State.update_positions (the lean step's update at velocity level) leaves pinocchio's data as
    ``update(..., velocities=False)`` does, to the bit, and the state completes on demand."""
    from benchmarks.peers import problems as P
    from hqp_tpm.robot.state import State

    robot = P.load_robot(P.ROMEO)
    rng = np.random.default_rng(3)
    q, v = P.romeo_q0(robot), rng.normal(0.0, 0.5, robot.nv)
    fid, other = robot.frame_id("r_sole"), robot.frame_id("l_gripper")
    a, b, full = State(robot), State(robot), State(robot).update(q, v)
    a.update(q, v, 0.5, validate=False, frames=(fid,), velocities=False)
    b.update_positions(q, v, 0.5, (fid,))
    assert b.t == a.t and b.updates == a.updates == 1 and b._partial
    for i in range(robot.model.njoints):
        np.testing.assert_array_equal(b.data.oMi[i].homogeneous, a.data.oMi[i].homogeneous)
        np.testing.assert_array_equal(b.data.oMi[i].homogeneous, full.data.oMi[i].homogeneous)
    np.testing.assert_array_equal(b.data.J, a.data.J)
    np.testing.assert_array_equal(b.data.J, full.data.J)
    np.testing.assert_array_equal(b.data.oMf[fid].homogeneous, full.data.oMf[fid].homogeneous)
    np.testing.assert_array_equal(b.jdot_qdot(other), full.jdot_qdot(other))


@pytest.mark.parametrize("robot_name", ["iiwa7", "romeo21"])
def test_state_update_with_the_com_is_the_two_passes_in_one(robot_name, monkeypatch):
    """State.update_positions(com=True) (one pinocchio pass, jacobianCenterOfMass from q) leaves the joint placements,
    the joint Jacobians, the CoM and the CoM Jacobian as computeJointJacobians then jacobianCenterOfMass do, to the bit;
    com_kinematics(1) then calls nothing in that update, and computes again after the next update without the CoM.
    A lean step whose stack has a CoM task uses it."""
    import pinocchio as pin

    from hqp_tpm.robot.model import Robot
    from hqp_tpm.robot.state import State

    robot = Robot.load(robot_name)
    model = robot.model
    rng = np.random.default_rng(11)
    one = [model.joints[j].idx_q for j in range(1, model.njoints) if model.nqs[j] == 1]  # (revolute joints)
    lo, up = np.maximum(model.lowerPositionLimit[one], -2.0), np.minimum(model.upperPositionLimit[one], 2.0)
    for _ in range(5):
        q = robot.neutral()
        q[one] = rng.uniform(lo, up)
        v = rng.normal(0.0, 0.5, robot.nv)
        a, b = State(robot), State(robot)
        a.update_positions(q, v, 0.0, ())
        a.com_kinematics(1)
        b.update_positions(q, v, 0.0, (), com=True)
        for i in range(model.njoints):
            np.testing.assert_array_equal(b.data.oMi[i].homogeneous, a.data.oMi[i].homogeneous)
        np.testing.assert_array_equal(b.data.J, a.data.J)
        np.testing.assert_array_equal(b.data.Jcom, a.data.Jcom)
        np.testing.assert_array_equal(b.data.com[0], a.data.com[0])
    calls = []
    real = pin.jacobianCenterOfMass
    monkeypatch.setattr(pin, "jacobianCenterOfMass", lambda *args: calls.append(len(args)) or real(*args))
    b.com_kinematics(1)
    assert calls == []                                 # done by the update
    b.update_positions(q, v, 0.0, ())
    b.com_kinematics(1)
    assert calls == [3]                                # an update without the CoM: computed here
    monkeypatch.undo()
    if robot_name == "romeo21":
        from benchmarks.peers import problems as P
        from benchmarks.peers.contenders import Hqp

        prob = P.romeo_problem(robot, 1)
        h = Hqp(robot, prob, "sns_tpm")
        h.setup(prob.configs[0])
        fast = h.ctrl._compiled_step()
        assert fast._com and fast.ctrl.state._com_update == fast.ctrl.state.updates


@pytest.mark.parametrize("robot_name", ["iiwa7", "lwr4", "romeo21"])
def test_euclidean_integration_equals_pinocchio(robot_name, monkeypatch):
    """State.integrate on a Euclidean configuration space (one compiled call) gives pin.integrate's bits at both
    orders; a robot with a free flyer is not Euclidean (pinocchio integrates it)."""
    import pinocchio as pin

    from hqp_tpm.robot import _compiled
    from hqp_tpm.robot.model import Robot
    from hqp_tpm.robot.state import State

    if not _compiled.AVAILABLE:
        pytest.skip("numba is not installed")
    robot = Robot.load(robot_name)
    st, rng = State(robot), np.random.default_rng(5)
    assert st.euclidean == (robot_name != "romeo21")
    for _ in range(100):
        q = pin.randomConfiguration(robot.model, -np.ones(robot.nq), np.ones(robot.nq)) if robot_name != "romeo21" \
            else robot.neutral()
        v, a = rng.normal(0.0, 2.0, robot.nv), rng.normal(0.0, 50.0, robot.nv)
        for order in (1, 2):
            monkeypatch.setattr(_compiled, "ENABLED", True)
            got = st.integrate(q, v, a, 1e-3, order)
            monkeypatch.setattr(_compiled, "ENABLED", False)
            want = st.integrate(q, v, a, 1e-3, order)
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])
            dq = a * 1e-3 if order == 1 else v * 1e-3 + 0.5 * a * 1e-3 * 1e-3
            np.testing.assert_array_equal(got[0], pin.integrate(robot.model, q, dq))


@pytest.mark.parametrize("which", [0, 1, 2])
@pytest.mark.parametrize("order", [1, 2])
def test_row_programs_without_pinocchio_views(order, which, monkeypatch):
    """Where the state cannot give the joint Jacobians as a view (a pinocchio that returns copies, mimic joints), the
    frame tasks gather getFrameJacobian, log3 and J qd into the program's arrays themselves: the readable step's
    bits."""
    from hqp_tpm import Controller
    from hqp_tpm.robot.model import Robot
    from hqp_tpm.robot.state import State

    _flags(monkeypatch, True, True)
    monkeypatch.setattr(State, "frame_jacobian_source", lambda self, fid: None)
    robot = Robot.load("iiwa7")

    def make():
        return Controller(robot, _program_stacks(robot)[which], order=order, dt=1e-3, q0=np.linspace(-0.6, 0.8, 7),
                          v0=np.full(7, 0.3) if order == 2 else None)

    ref, fast = make(), make()
    lean = Lean.of(fast)
    assert lean._kernel is not None and lean._program.ints[5] >= 2
    for _ in range(20):
        np.testing.assert_array_equal(lean.step(), ref.step(record=True).command)
        np.testing.assert_array_equal(fast.q, ref.q)
        np.testing.assert_array_equal(fast.v, ref.v)


def test_program_slots_take_c_contiguous_float_arrays():
    """The kernel reads a slot's array by its address: a slot refuses what it could not read as such."""
    program = _compiled_step.Program(6, 7, (6,), 1, 0.0, 0.0, False)
    program.add_frame(0, range(6), range(3), 1.0, 0.0)
    program.build()
    program.bind_mat(0, np.zeros((6, 7)))
    for bad in (np.zeros((7, 6)).T, np.zeros((6, 7), dtype=np.float32), np.zeros(42)):
        with pytest.raises(ValueError, match="C-contiguous float64"):
            program.bind_mat(0, bad)
    with pytest.raises(ValueError, match="C-contiguous float64"):
        program.bind_vec(0, np.zeros(12)[::2])
    at = program.ints[7]
    a = np.ones((6, 7))
    program.bind_mat(0, a)
    assert program.mats[0] is a and program.ints[at + 1: at + 3].tolist() == [6, 7]
    assert program.ints[at] == a.__array_interface__["data"][0]


def test_a_declined_fused_tpm_step_does_not_run_the_tpm_kernel_again(monkeypatch):
    """Where the fused kernel's TPM declines (a singular EE pose, damped pivots), tpm_stacked goes straight to the
    compiled recursion with the kernel's answer (kernel_status) instead of running the same kernel (or TPM's one
    kernel, which would run it first) again: the readable step's numbers. (Each step from the singular pose: a step
    moves away from it, where the damped, regular pivots are factorized by the kernel itself.)"""
    from hqp_tpm.solvers import _compiled as _solvers_compiled

    _flags(monkeypatch, True, True)
    again = []
    for name in ("past_rank", "general", "tpm"):
        real = getattr(_solvers_compiled, name)
        monkeypatch.setattr(_solvers_compiled, name, lambda *a, real=real, **k: again.append(1) or real(*a, **k))
    recursions = []
    real_r = _solvers_compiled.recursion
    monkeypatch.setattr(_solvers_compiled, "recursion", lambda *a, **k: recursions.append(1) or real_r(*a, **k))
    ref, fast = _singular_damped_pair("tpm")
    lean = Lean.of(fast)
    for _ in range(5):
        for c in (ref, fast):
            c.set_state(np.zeros_like(c.q), c.v)
        want = ref.step(record=True).command
        again.clear()
        recursions.clear()
        assert_equal_steps(lean.step(), want)
        assert not again and recursions, (len(again), len(recursions))


def test_copied_and_pickled_lean_steps_step_their_own_controller():
    """A lean step's fused program reads its controller's arrays (pinocchio's data) by address: a deep-copied or an
    unpickled controller plans its own compiled step, which steps that controller with the readable step's numbers,
    and the original goes on with its own; the program itself refuses to be copied."""
    import copy
    import pickle

    from benchmarks.peers import problems as P

    robot = P.load_robot(P.IIWA)
    prob = P.iiwa_problem(robot, order=1, n=1)
    ref, fast = (P.hqp_controller(robot, prob, prob.configs[0], "sns_tpm") for _ in range(2))
    lean = Lean.of(fast)
    for _ in range(5):
        assert_equal_steps(lean.step(), ref.step(record=True).command)
    for copied in (copy.deepcopy(fast), pickle.loads(pickle.dumps(fast))):
        twin = Lean.of(copied)
        assert twin.ctrl is not fast and twin.fast.ctrl is copied and twin._program is not lean._program
        ref2 = copy.deepcopy(ref)
        for _ in range(10):
            assert_equal_steps(twin.step(), ref2.step(record=True).command)
            assert_equal_steps(twin.ctrl.q, ref2.q)
    for _ in range(5):  # the original, untouched by its copies' steps
        assert_equal_steps(lean.step(), ref.step(record=True).command)
        assert_equal_steps(fast.q, ref.q)
    if lean._program is not None:
        with pytest.raises(TypeError, match="addresses"):
            copy.deepcopy(lean._program)
        with pytest.raises(TypeError, match="addresses"):
            pickle.dumps(lean._program)


def test_kernel_places_the_frames_its_tasks_read(monkeypatch):
    """At velocity level the fused kernel places the frames of its frame tasks itself (pinocchio's
    updateFramePlacement left out of the state update): pinocchio's oMf after a lean step is the full update's, to
    the bit, and so is the command of a lean step whose frames the state update places; with a Harmonic reference
    and an orientation task on the same frame too (independent rows, no level repeating another's)."""
    import pinocchio as pin

    from hqp_tpm import Controller, FrameOrientation, FramePose, FramePosition, Gains, Posture, Robot, Stack
    from hqp_tpm.references.trajectories import Harmonic
    from hqp_tpm.robot.state import State

    _flags(monkeypatch, True, True)
    robot = Robot.load("romeo21")
    g = Gains(5.0)
    rng = np.random.default_rng(4)
    circle = Harmonic(center=[0.3, -0.2, 0.9], cos_amplitude=[0.05, 0.0, 0.0], sin_amplitude=[0.0, 0.05, 0.0],
                      omega=3.0)
    fids = [robot.frame_id(f) for f in ("r_sole", "l_gripper", "r_gripper")]
    for harmonic in (False, True):
        q0 = pin.integrate(robot.model, pin.neutral(robot.model), rng.normal(0.0, 0.3, robot.nv))
        levels = [FramePose(robot, "r_sole", pin.SE3(pin.exp3(rng.normal(0.0, 0.2, 3)), rng.normal(0.0, 0.3, 3)), g),
                  (FramePosition(robot, "l_gripper", rng.normal(0.0, 0.5, 3), g),
                   FramePosition(robot, "r_gripper", circle if harmonic else rng.normal(0.0, 0.5, 3), g))]
        if harmonic:                                   # r_gripper read by two row programs
            levels.append(FrameOrientation(robot, "r_gripper", pin.exp3(rng.normal(0.0, 0.3, 3)), g))
        stack = Stack.of(*levels, Posture(robot, None, g))
        ref, fast, placed_by_state = (Controller(robot, stack, order=1, dt=1e-3, q0=q0, solver="tpm")
                                      for _ in range(3))
        lean = Lean.of(fast)
        with monkeypatch.context() as m:               # (no views: the state update places every frame)
            m.setattr(State, "frame_placement_source", lambda self, fid: None)
            other = Lean.of(placed_by_state)
        assert lean._program.placed == set(fids) and not other._program.placed
        assert lean._frames == ()  # (a Harmonic reference too: its rows are the kernel's)
        for _ in range(5):
            x = lean.step()
            np.testing.assert_array_equal(x, other.step())
            np.testing.assert_allclose(x, ref.step(record=True).command, rtol=0.0, atol=1e-12)  # (log3: a few ulps)
            full = fast.robot.model.createData()
            pin.framesForwardKinematics(fast.robot.model, full, fast.state.q)
            for fid in fids:
                np.testing.assert_array_equal(fast.state.data.oMf[fid].homogeneous, full.oMf[fid].homogeneous)


def test_a_pivot_block_that_needs_its_svd_switches_the_fused_kernel():
    """``romeo_tpm`` (m <= n) meets a pivot block only its SVD decides at its first step: the fused TPM kernel hands
    the step back (``PIVOT_SVD``), the lean step finishes it with ``tpm_stacked`` and from then on runs the fused
    kernel that decides every pivot at once (no hand-back each such step, as before); every command equals the
    readable step's to the bit."""
    from hqp_tpm.app.build import build
    from hqp_tpm.app.scenario import load

    fast, ref = (build(load("romeo_tpm"))[1] for _ in range(2))
    lean = fast._compiled_step()
    assert type(lean) is PlannedStep
    first = lean._kernel
    for _ in range(60):
        np.testing.assert_array_equal(fast.step().command, ref.step(record=True).command)
    if first is not None:  # (compiled)
        assert lean._kernel is not first
        assert _compiled_step._KERNELS.get((_compiled_step.TPM, False, True)) is not None
    np.testing.assert_array_equal(fast.q, ref.q)
