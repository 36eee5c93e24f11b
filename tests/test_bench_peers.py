"""The hqp-tpm side of the peer benchmark (``benchmarks/peers/``) builds well-formed problems.

No timing here: the problems have the stated sizes (more rows than joints once the posture level
is in), the hqp-tpm commands are finite and solve the top level exactly where no box binds, the
joint box keeps SNS-TPM's command inside the velocity limits, the closed loop tracks its circle, and
the reduced URDF given to PlaCo has the 21 joints of ``romeo21``.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: ``benchmarks`` package

from benchmarks.peers import contenders as C  # noqa: E402
from benchmarks.peers import problems as P  # noqa: E402


@pytest.fixture(scope="module")
def iiwa():
    return P.load_robot(P.IIWA)


@pytest.fixture(scope="module")
def romeo():
    return P.load_robot(P.ROMEO)


def _rows(levels):
    return [np.asarray(lv.J).shape[0] for lv in levels]


@pytest.mark.parametrize("order", [1, 2])
def test_iiwa_problem(iiwa, order):
    prob = P.iiwa_problem(iiwa, order, n=4)
    assert P.urdf_path(iiwa).is_file()
    assert len(prob.configs) == 4 and iiwa.nv == 7
    for cfg in prob.configs:
        ctrl = P.hqp_controller(iiwa, prob, cfg, "tpm")
        res = ctrl.compute()
        assert _rows(res.levels) == [6, 7]  # 13 rows > 7 joints
        assert np.isfinite(res.command).all()
        J0, b0 = P.first_level(ctrl)
        res0, _ = P.quality(J0, b0, res.command, iiwa.velocity_limits())
        assert res0 < 1e-9 * max(1.0, np.linalg.norm(b0))


def test_iiwa_box(iiwa):
    prob = P.iiwa_problem(iiwa, 1, n=6)
    vmax = iiwa.velocity_limits()
    for cfg in prob.configs:
        for solver in ("sns_tpm", "qp:daqp"):
            x = P.hqp_controller(iiwa, prob, cfg, solver).compute().command
            assert np.all(np.abs(x) <= vmax + 1e-9), solver


def test_romeo_problem(romeo):
    prob = P.romeo_problem(romeo, n=3)
    assert romeo.nv == 27
    for cfg in prob.configs:
        res = P.hqp_controller(romeo, prob, cfg, "tpm").compute()
        assert _rows(res.levels) == [6, 2, 3, 3, 3, 21]  # 6 levels, 38 rows > 27
        assert np.isfinite(res.command).all()
    # the configurations differ and stay inside the position limits
    lo, up = romeo.position_limits()
    q = np.array([c.q for c in prob.configs])
    assert np.ptp(q[:, 7:], axis=0).max() > 0
    for j in range(2, romeo.model.njoints):
        jt = romeo.model.joints[j]
        assert np.all((q[:, jt.idx_q] >= lo[jt.idx_v]) & (q[:, jt.idx_q] <= up[jt.idx_v]))


@pytest.mark.parametrize("order", [1, 2])
def test_circle_loop(iiwa, order):
    import time

    times, qs, cmds = C.circle_loop("hqp", iiwa, order, 100, time.perf_counter_ns)
    assert len(times) == len(qs) == 100 and np.isfinite(np.array(qs)).all()
    ctrl, p0 = P.hqp_circle_controller(iiwa, order)
    assert np.allclose(P.circle_reference(p0, 0.0)[0], p0)


def test_romeo_has_the_scenario_s_damping_and_gains(romeo):
    """The Romeo problem is solved as the romeo_sns_tpm scenario solves it: lambda_max 0.05, eps 0.1, kp 100 (issue
    29: the benchmark's undamped kp-10 Romeo kept the solves on the compiled path the scenarios leave)."""
    from hqp_tpm.app import scenario

    sc = scenario.load("romeo_sns_tpm")
    prob = P.romeo_problem(romeo, n=1)
    ctrl = P.hqp_controller(romeo, prob, prob.configs[0], "sns_tpm")
    assert (ctrl.lambda_max, ctrl.eps) == (sc.lambda_max, sc.eps) == (0.05, 0.1)
    assert all(t.gains.kp == 100.0 for t in ctrl.tasks() if t.name != "posture")


@pytest.mark.parametrize("solver", ["tpm", "sns_tpm"])
def test_the_hqp_step_feeds_the_state_and_moves_the_targets(iiwa, solver):
    """hqp-tpm's timed step is what a user runs: the state fed in (one kinematics update per call), the targets
    assigned again and moving (consecutive calls alternate between two target sets: two commands), and its rows +
    solve give the command of ``compute()`` at that state."""
    prob = P.iiwa_problem(iiwa, 1, n=2)
    c = C.Hqp(iiwa, prob, solver)
    c.setup(prob.configs[0])
    updates = c.ctrl.state.updates
    x1, x2, x3 = c.step(), c.step(), c.step()
    assert c.ctrl.state.updates == updates + 3
    assert np.array_equal(x1, x3) and not np.allclose(x1, x2, rtol=0.0, atol=1e-9)
    assert np.allclose(c.rows_solve(), x3, rtol=0.0, atol=1e-9)
    moved = P.moved(prob.configs[0].targets)
    assert np.allclose(moved["ee"].translation - prob.configs[0].targets["ee"].translation, P.NUDGE)


def test_reduced_urdf(tmp_path):
    from hqp_tpm.robot.model import ROMEO21_JOINTS

    path = C.reduced_urdf(C.romeo_urdf(), set(ROMEO21_JOINTS), tmp_path)
    text = path.read_text()
    assert "<visual" not in text and "<collision" not in text
    import pinocchio as pin

    model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    assert model.nv == 27
    assert sorted(model.names[2:]) == sorted(ROMEO21_JOINTS)


def test_the_environment_records_how_fast_the_host_ran(monkeypatch):
    """Every benchmark's environment has the host speed probe at its start and end (the same fixed workload:
    runs whose probes differ are not comparable in µs); the probe times its workload, in µs."""
    from benchmarks import common

    env = common.environment()
    common.close_environment(env)
    for key in ("host speed probe at start", "host speed probe at end"):
        assert float(env[key].split()[0]) > 0.0, env[key]
    clock = iter(range(0, 10**9, 7000))                 # a host where the workload takes exactly 7 µs
    monkeypatch.setattr(common.time, "perf_counter_ns", lambda: next(clock))
    assert common.host_probe().startswith("7 µs")

