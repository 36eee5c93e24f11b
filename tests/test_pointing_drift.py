"""Issue 31, item 2: the control-law remedy for the lwr_relaxed divergence (docs/pointing_drift.md).

``hqp-tpm sweep lwr_relaxed --random 20 --seed 1 "obstacles.o1.center=[0.07,0.47,0.07]:[0.13,0.53,0.13]"`` stopped
2 of 20 variants (v003, v016) at the velocity bound: the relaxed pointing row, cancelling its drift ``Jdot_rp qdot``
(quadratic in qdot) in a nearly dependent stack, pumps the joint velocities up (v003: 0.44 rad/s at t = 5.30 s,
23.9 rad/s at 5.618 s). With ``drift_limit`` (lwr_relaxed: 40 rad/s^2) the drift is left out of the command while
cancelling it takes more joint acceleration than that; the reference run never needs more (31.8), so its numbers
stay papers/000's as written.
"""

from __future__ import annotations

import numpy as np
import pytest

from hqp_tpm.app import scenario
from hqp_tpm.app.build import build_run
from hqp_tpm.app.cli import run_scenario
from hqp_tpm.app.sweep import Variant, variant_scenario
from hqp_tpm.errors import DivergedError, ParameterError, ScenarioError
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.tasks import Gains, Pointing
from hqp_tpm.tasks.pointing import drift_left_out

#: v003 of the README's sweep (seed 1), the obstacle o1 it moves
V003 = {"obstacles.o1.center": [0.0716535467945841, 0.5152107865204885, 0.1022885987931567]}
#: v003's state at step 5,300 (t = 5.30 s) on 7f723e3 (its trajectory.npz), 319 steps before it left the bound
T_5300 = 5.300000000000105
Q_5300 = [0.6783588584798516, -1.122895572188675, 1.3042954003566736, 1.750560315995974, 0.5623587965436943,
          2.283757926923511, -1.4252312776182897e-16]
V_5300 = [-0.44301576119834424, 0.0768577208991938, 0.05985911304573992, -0.27275879768123895,
          -0.09744527232729935, -0.3376572749478521, -2.6348506152538678e-15]


def _v003(**overrides):
    sc = variant_scenario(scenario.read(scenario.resolve_path("lwr_relaxed")), "lwr_relaxed",
                          Variant("v003", {**V003, **overrides}))
    return sc


def test_v003_stays_bounded_past_where_it_diverged():
    """On 7f723e3 max|qdot| passes 22 rad/s (10x the URDF limits) 319 steps after this state; now it stays below
    3.4 rad/s for 400 steps (asserted: 5)."""
    ctrl = build_run(_v003()).controller
    ctrl.set_state(np.array(Q_5300), np.array(V_5300))
    ctrl.t = T_5300
    vmax = 0.0
    for _ in range(400):
        ctrl.step()
        vmax = max(vmax, float(np.abs(ctrl.v).max()))
    assert vmax < 5.0, f"max|v| = {vmax:.3g} rad/s within 400 steps of t = 5.30 s"


def test_papers_law_as_written_still_diverges_and_stops_at_the_bound(tmp_path):
    """The forced divergence: v003 with ``drift_limit = false`` (papers/000 as written) leaves the velocity bound
    at step 5,619 and stops there, the 5,618 steps before it kept as a partial result."""
    with pytest.raises(DivergedError, match=r"at step 5619 \(t = 5\.618000 s\) the velocity of joint lwr_joint_3 "
                                            r"is 23\.877 rad/s") as err:
        run_scenario(_v003(**{"tasks.pointing.drift_limit": False}), tmp_path / "v003", progress=False,
                     figures=False, replay=False)
    out = err.value.partial_result
    assert out is not None
    dq = np.load(out / "trajectory.npz")["dq"]
    assert dq.shape == (5618, 7) and np.abs(dq).max() < 22.3402


def test_the_reference_run_is_papers_law_to_the_bit(tmp_path):
    """lwr_relaxed with its drift_limit and without (false) computes the same trajectory: the limit never acts."""
    base = scenario.read(scenario.resolve_path("lwr_relaxed"))
    runs = {}
    for name, limit in (("limited", None), ("paper", False)):
        over = {} if limit is None else {"tasks.pointing.drift_limit": limit}
        run_scenario(variant_scenario(base, "lwr_relaxed", Variant(name, over)), tmp_path / name, progress=False,
                     figures=False, replay=False)
        runs[name] = np.load(tmp_path / name / "trajectory.npz")
    for key in ("q", "dq", "ddq"):
        np.testing.assert_array_equal(runs["limited"][key], runs["paper"][key])
    assert runs["limited"]["q"].shape[0] == 18_850


@pytest.mark.parametrize("limit", [1e-3, 1e6])
def test_the_compiled_row_writes_the_commands_numbers(limit):
    """The lean step's row (one compiled call) and :meth:`Pointing.command` agree (to rounding: the row's sums run in
    another order) with the drift left out (a tiny limit) and kept (a large one); left out, the command is the
    feedback alone (the drift added back)."""
    lwr = Robot.load("lwr4")
    task = Pointing(lwr, "lwr_ee", [1.0, 0.0, 0.0], np.deg2rad(5.0), Gains(5.0, 2.0), drift_limit=limit)
    paper = Pointing(lwr, "lwr_ee", [1.0, 0.0, 0.0], np.deg2rad(5.0), Gains(5.0, 2.0))
    ref, st = State(lwr), State(lwr)
    q, v = np.array(Q_5300), 3.0 * np.array(V_5300)
    ref.update(q, v, 0.0)
    for t in (task, paper):
        t.start(ref)
    J = np.full((1, lwr.nv), np.nan)
    b = np.full(1, np.nan)
    write = task.row_writer(st, 2, J, b)
    st.update(q, v, 0.0, frames=(task.fid,), velocities=True)
    write(0.0)
    Jt = task.jacobian(ref)
    np.testing.assert_allclose(J, Jt, rtol=0.0, atol=1e-15)
    np.testing.assert_allclose(b, task.command(ref, 0.0, 2, None, Jt), rtol=1e-12, atol=1e-15)
    jdq = task.jdot_qdot(ref)
    left_out = drift_left_out(jdq[0], Jt[0], limit)
    assert left_out == (limit < 1.0)  # this state's drift needs ~ 1 rad/s^2 along the row, far from either limit
    expected = paper.command(ref, 0.0, 2, None, Jt) + (jdq if left_out else 0.0)
    np.testing.assert_array_equal(task.command(ref, 0.0, 2, None, Jt), expected)
    np.testing.assert_array_equal(task.command(ref, 0.0, 1, None, Jt), paper.command(ref, 0.0, 1, None, Jt))


@pytest.mark.parametrize("bad", [0.0, -1.0, float("inf"), float("nan"), True])
def test_a_bad_drift_limit_is_named(bad):
    lwr = Robot.load("lwr4")
    with pytest.raises(ParameterError, match="drift_limit"):
        Pointing(lwr, "lwr_ee", [1.0, 0.0, 0.0], 0.1, drift_limit=bad)


def test_a_bad_drift_limit_in_a_scenario_names_the_file_and_task():
    data = scenario.read(scenario.resolve_path("lwr_relaxed"))
    data["tasks"][1]["drift_limit"] = -2.0
    with pytest.raises(ScenarioError, match=r"lwr_relaxed\.toml\.tasks\[1\].*drift_limit = -2\.0"):
        build_run(scenario.parse(data, scenario.resolve_path("lwr_relaxed")))
