"""papers/004 Sec. 6: DMPs (44)-(48) and the obstacle coupling term (49)-(54) (Fig. 17)."""

import math

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.errors import ScenarioError, ShapeError
from hqp_tpm.references.dmp import DMP, Coupling

Y0, G = np.zeros(3), np.array([1.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def line_dmp():
    t = np.linspace(0, 1, 1001)
    s = 10 * t**3 - 15 * t**4 + 6 * t**5  # minimum-jerk demonstration along a straight line
    demo = Y0 + s[:, None] * (G - Y0)
    return DMP.learn(t, demo), t, demo


def test_dmp_reproduces_the_demonstration_and_converges(line_dmp):
    dmp, t, demo = line_dmp
    T, Y, V, C = dmp.rollout(0.001, 2.0)
    assert np.abs(Y[: t.size] - demo).max() < 0.01
    assert np.linalg.norm(Y[-1] - G) < 1e-6 and np.linalg.norm(V[-1]) < 1e-5
    assert not C.any()
    T2, Y2, _, _ = dmp.rollout(0.001, 2.0, goal=[1.0, 0.5, 0.0])  # a new goal: the attractor (44)-(45) moves
    assert np.linalg.norm(Y2[-1] - [1.0, 0.5, 0.0]) < 1e-6


def test_coupling_direction_49_53():
    """R yd is orthogonal to o - y, in the plane of o - y and yd, on the side of yd away from the obstacle; with the
    printed (53) (an axis of norm sin phi) it would not be orthogonal."""
    rng = np.random.default_rng(0)
    cp = Coupling(gamma=1.0, beta=0.5, eta=10.0, d=1.0)
    for _ in range(200):
        y, yd, o = rng.standard_normal(3), rng.standard_normal(3), rng.standard_normal(3)
        c = cp(y, yd, o)
        r = o - y
        assert abs(c @ r) < 1e-10 * np.linalg.norm(c) * np.linalg.norm(r) + 1e-14
        assert abs(c @ np.cross(r, yd)) < 1e-10 * np.linalg.norm(c) * np.linalg.norm(np.cross(r, yd)) + 1e-14
        perp = yd - (yd @ r) / (r @ r) * r
        assert c @ perp > 0
        phi = math.acos((r @ yd) / np.linalg.norm(r) / np.linalg.norm(yd))
        n_printed = np.cross(r, yd) / np.linalg.norm(r) / np.linalg.norm(yd)
        if math.sin(phi) < 0.9 and abs(math.pi / 2 - phi) > 0.2:
            assert abs((pin.exp3((math.pi / 2 - phi) * n_printed) @ yd) @ r) > 1e-6
    assert not cp(np.zeros(3), np.zeros(3), np.ones(3)).any()  # no velocity, no coupling
    assert not cp(np.zeros(3), np.array([1.0, 0, 0]), np.array([2.0, 0, 0])).any()  # head-on: no plane
    far = Coupling(d=0.15)(np.zeros(3), np.array([1.0, 0, 0]), np.array([20.0, 0.1, 0]))
    assert np.linalg.norm(far) < 1e-100  # sig (51) switches it off beyond d
    with pytest.raises(ShapeError):
        cp(np.zeros(2), np.zeros(2), np.zeros(2))


def test_fig17_obstacle_on_the_path(line_dmp):
    """Fig. 17: a point obstacle 2 cm off the demonstrated line; the coupled DMP (54) passes it at a larger distance
    and still reaches the goal; the coupling acts only near the obstacle."""
    dmp, _, _ = line_dmp
    o = np.array([0.5, 0.02, 0.0])
    _, Y, _, _ = dmp.rollout(0.001, 2.0)
    T, Yc, Vc, C = dmp.rollout(0.001, 2.0, [o], Coupling(gamma=1000.0, d=0.2))
    free, coupled = np.linalg.norm(Y - o, axis=1).min(), np.linalg.norm(Yc - o, axis=1).min()
    assert free < 0.021 and coupled > 3 * free
    assert (Yc[:, 1] < 0.0).any() and Yc[:, 1].min() < -0.04  # it goes round on the side away from the obstacle
    assert np.linalg.norm(Yc[-1] - G) < 1e-6
    active = np.linalg.norm(C, axis=1) > 1e-3
    assert np.linalg.norm(Yc[active] - o, axis=1).max() < 0.5


def test_dmp_target_on_the_planar_arm(tmp_path):
    """Figs. 17-19 on planar5_dmp: the DMP with coupling moves the EE round the ball on its line (the plain DMP, gamma
    = 0, goes through it), the arm tracks it (EE error < 1e-4 m) with smooth joint velocities, the target returns to
    the goal, and the coupling acts only near the ball."""
    from hqp_tpm.app import build, scenario
    from hqp_tpm.app.cli import run_scenario

    s = run_scenario("planar5_dmp", tmp_path / "dmp", progress=False, figures=False, replay=False)
    a = dict(np.load(tmp_path / "dmp" / "trajectory.npz"))
    assert s["d_obstacle_min"] > 0.1 and s["ee_error_max"] < 1e-4 and s["max_dq_jump"] < 0.02
    assert np.linalg.norm(a["error_ee"][-1]) < 1e-8
    spec = tmp_path / "plain.toml"
    spec.write_text('[scenario]\nextends = "planar5_dmp"\nname = "plain"\n\n[[tasks]]\nname = "ee"\n'
                    'target = { gamma = 0.0 }\n')
    p = run_scenario(str(spec), tmp_path / "plain", progress=False, figures=False, replay=False)
    assert p["d_obstacle_min"] < 0.0  # without the coupling the EE goes through the ball
    sc = scenario.load("planar5_dmp")
    _, ctrl, tasks, _ = build.build(sc)
    ctrl.start()
    T, Y, V, A, C = tasks["ee"].trajectory._roll
    np.testing.assert_allclose(Y[-1] - Y[0], [0.0, -1.2], atol=1e-9)
    r = np.linalg.norm(Y - [1.99, 0.0], axis=1)
    c = np.linalg.norm(C, axis=1)
    assert c[r > 0.5].max() < 0.01 * c.max()
    with pytest.raises(ScenarioError, match="obstacles"):
        bad = tmp_path / "bad.toml"
        bad.write_text('[scenario]\nextends = "planar5_dmp"\nname = "bad"\n\n[[tasks]]\nname = "ee"\n'
                       'target = { obstacles = [[1.0, 2.0]] }\n')
        build.build(scenario.load(bad))
