"""A run that diverges: lwr_relaxed with its obstacles moved (variant v009 of the README's obstacle sweep).

From t = 5.393 s (the avoidance moved above the EE task) the pointing level, last in a nearly dependent stack,
pumps energy into the joint velocities; max|v| reaches 20 rad/s within 160 steps and ~4e251 rad/s by
step 7,249, where the pointing level's ``Jdot qdot`` (quadratic in v) overflows into NaN. That step must
raise a typed error naming the level and the state it started from, and change nothing. The states
below are the run's own, recorded before those steps (exact float64 values).
"""

from __future__ import annotations

import numpy as np
import pytest

from hqp_tpm.app import scenario
from hqp_tpm.app.build import build_run
from hqp_tpm.app.sweep import Variant, variant_scenario
from hqp_tpm.control.controller import Controller
from hqp_tpm.errors import NonFiniteError
from hqp_tpm.robot.model import Robot
from hqp_tpm.tasks import FramePosition, Gains

#: v009 of ``hqp-tpm sweep lwr_relaxed --random 10 --seed 16 "obstacles.o1.center=..." ...`` (README)
V009 = {"obstacles.o1.center": [0.07500026454370642, 0.5106136618389018, 0.08808637688829374],
        "obstacles.o2.center": [-0.17048118359558667, 0.29074673600762957, 0.21298382557314968],
        "obstacles.o3.center": [-0.0923663394878636, 0.4052243860046332, -0.12656007288600443]}

#: the state of v009 after 7,248 steps (t = 7.248 s), where its step 7,249 fails
T_7248 = 7.248000000000755
Q_7248 = [-3.4308128275355255e+247, 1.0382392759114256e+248, 2.3230270481462195e+246, 2.0689619506528301e+248,
          1.2861244677468961e+247, 3.979318129989129e+246, 1.0353927391628382e+232]
V_7248 = [-6.861625655071051e+250, 2.0764785518228512e+251, 4.6460540962924386e+249, 4.13792390130566e+251,
          2.5722489354937923e+250, 7.958636259978258e+249, 2.0707854783256762e+235]

#: the state after 5,380 steps (t = 5.38 s), 13 steps before the avoidance goes on top and the run diverges
T_5380 = 5.380000000000131
Q_5380 = [0.7068688295048335, -1.0623237049620202, 1.226294980352592, 1.7334335337152975, 0.6699128193450615,
          2.222194021934387, 5.3230137340374345e-16]
V_5380 = [-0.47858999167961147, 0.12024865371536778, -0.031653133688864486, -0.3419895124354203,
          -0.24468318135760989, -0.6576835462394788, 7.512707762245309e-15]


def v009_at(q, v, t) -> Controller:
    """The v009 controller, built as the sweep builds it, put into the recorded state (Algorithm 1 keeps no
    memory across steps: its distance field is recomputed from the state at every step)."""
    sc = variant_scenario(scenario.read(scenario.resolve_path("lwr_relaxed")), "lwr_relaxed",
                          Variant("v009", V009))
    ctrl = build_run(sc).controller
    ctrl.set_state(np.array(q), np.array(v))
    ctrl.t = t
    return ctrl


def test_the_nan_of_a_diverged_state_is_named_with_the_state_and_changes_nothing():
    ctrl = v009_at(Q_7248, V_7248, T_7248)
    with pytest.raises(NonFiniteError, match=r"level 'pointing': lower holds NaN at rows \[0\]: \[nan\] "
                                             r"\(step at t = 7\.248000 from max\|q\| = 2\.07e\+248, "
                                             r"max\|v\| = 4\.14e\+251\)"):
        ctrl.step()
    np.testing.assert_array_equal(ctrl.q, Q_7248)
    np.testing.assert_array_equal(ctrl.v, V_7248)
    assert (ctrl.t, ctrl.steps) == (T_7248, 0)


class _NanDrift(FramePosition):
    """A task whose ``Jdot qdot`` is NaN at any state (a task with a bug, not a diverged run)."""

    def jdot_qdot(self, state):
        return np.full(3, np.nan)


def test_a_nan_at_a_sane_state_says_the_state_was_sane():
    """The note names the state also when a task is at fault, not only after a divergence."""
    lwr = Robot.load("lwr4")
    bad = _NanDrift(lwr, "lwr_ee", [0.0, 0.5, 0.0], Gains(40, 20), name="ee")
    ctrl = Controller(lwr, [bad], order=2, dt=1e-3, q0=np.array(Q_5380), v0=np.array(V_5380))
    with pytest.raises(NonFiniteError, match=r"'ee'.*\(step at t = 0\.000000 from max\|q\| = 2\.22, "
                                             r"max\|v\| = 0\.658\)"):
        ctrl.step()
    assert ctrl.steps == 0


def test_v009_stays_bounded_past_the_priority_switch():
    """Past the switch at t = 5.393 s the pointing level, last in a nearly dependent stack, drove max|v| to 20 rad/s
    by t = 5.55 s (7f723e3); with lwr_relaxed's pointing drift_limit (docs/pointing_drift.md) it stays below
    3.3 rad/s (asserted: 5; the whole run completes with max|v| 5.35 rad/s)."""
    ctrl = v009_at(Q_5380, V_5380, T_5380)
    vmax = 0.0
    for _ in range(200):
        ctrl.step()
        vmax = max(vmax, float(np.abs(ctrl.v).max()))
    assert vmax < 5.0, f"max|v| = {vmax:.3g} rad/s within 200 steps of t = 5.38 s"
