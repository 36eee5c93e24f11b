"""papers/004 Sec. 5.2: the priority-weighted damped least squares (37)-(43) and the 4-DOF example of Fig. 14."""

import numpy as np
import pytest

from hqp_tpm.errors import NonFiniteError, ShapeError
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State
from hqp_tpm.solvers.pwdls import pwdls, pwdls_inverse, task_mapping


def random_levels(rng, n=5, sizes=(2, 1, 3)):
    return [(rng.standard_normal((m, n)), rng.standard_normal(m)) for m in sizes]


def test_eq_38_and_the_cost_it_minimises():
    """(38) J_E^T (J_E J_E^T + lambda^2 P)^-1 equals the n x n form; qd minimises lambda^2 |qd|^2 + sum (1/p_i)|e_i|^2
    (the printed (40), with p_i, has another minimiser); P = I is the plain DLS of the extended Jacobian."""
    rng = np.random.default_rng(0)
    for _ in range(100):
        levels = random_levels(rng)
        p = rng.uniform(0.2, 5.0, 3)
        lam = rng.uniform(0.05, 1.0)
        J = np.vstack([L[0] for L in levels])
        b = np.concatenate([L[1] for L in levels])
        P = np.diag(np.repeat(p, [2, 1, 3]))
        np.testing.assert_allclose(pwdls_inverse(levels, p, lam), J.T @ np.linalg.inv(J @ J.T + lam**2 * P),
                                   atol=1e-10)
        qd = pwdls(levels, p, lam)
        w = np.sqrt(1.0 / np.diag(P))
        ls = np.linalg.lstsq(np.vstack([w[:, None] * J, lam * np.eye(5)]), np.concatenate([w * b, np.zeros(5)]),
                             rcond=None)[0]
        np.testing.assert_allclose(qd, ls, atol=1e-10)
        w40 = np.sqrt(np.diag(P))
        printed = np.linalg.lstsq(np.vstack([w40[:, None] * J, lam * np.eye(5)]),
                                  np.concatenate([w40 * b, np.zeros(5)]), rcond=None)[0]
        assert np.linalg.norm(printed - qd) > 1e-6
        np.testing.assert_allclose(pwdls(levels, [1, 1, 1], lam), J.T @ np.linalg.solve(J @ J.T + lam**2 * np.eye(6),
                                                                                          b), atol=1e-10)


def test_priority_changes_are_continuous():
    """"The priority change can be done continuously and no discontinuity in qd is experienced" (Sec. 5.2)."""
    rng = np.random.default_rng(1)
    levels = random_levels(rng, n=4, sizes=(2, 2, 2))
    qs = np.array([pwdls(levels, [1.0, 1.0 + 4 * s, 1.0 + 24 * s], 1e-3) for s in np.linspace(0, 1, 1001)])
    assert np.abs(np.diff(qs, axis=0)).max() < 0.02 * np.abs(qs).max()


A = 5.0
CASES = {"a": [1, 1, 1], "b": [1, A, A * A], "c": [A, 1, A * A], "d": [A, A * A, 1]}


def fig14():
    """planar 4-DOF arm, three 2-D control points (tips of links 2, 3, 4) pushed in different directions."""
    robot = Robot.load("planar4")
    st = State(robot).update(np.deg2rad([30.0, 40.0, -30.0, 50.0]), np.zeros(4))
    Js = [st.jacobian(robot.frame_id(f))[:2] for f in ("planar4_tip_2", "planar4_tip_3", "planar4_ee")]
    xs = [np.array([0.0, 1.0]), np.array([1.0, 0.0]), np.array([-0.7, -0.7])]
    return list(zip(Js, xs, strict=True))


def test_fig14_priorities_of_three_control_points():
    """Fig. 14 (a = 5, lambda = 1e-8, m_t = 6 > n = 4): with equal p, A = J_E J_E^# is symmetric (the classic
    extended Jacobian); with unequal p it is not, and the task with the smallest p_i is achieved best: its A_ii is the
    closest to the identity and its residual the smallest, smaller than with equal p (41)."""
    levels = fig14()
    res = {}
    for case, p in CASES.items():
        blocks = task_mapping(levels, p, 1e-8)
        Af = np.block(blocks)
        qd = pwdls(levels, p, 1e-8)
        res[case] = [np.linalg.norm(x - J @ qd) for J, x in levels]
        dist = [np.linalg.norm(blocks[i][i] - np.eye(2), 2) for i in range(3)]
        np.testing.assert_allclose(Af @ np.concatenate([x for _, x in levels]), np.concatenate([J @ qd for J, _ in
                                                                                               levels]), atol=1e-9)
        if case == "a":
            np.testing.assert_allclose(Af, Af.T, atol=1e-8)
            np.testing.assert_allclose(Af @ Af, Af, atol=1e-7)  # lambda -> 0: the projector on range(J_E)
        else:
            top = int(np.argmin(p))
            assert np.abs(Af - Af.T).max() > 0.3
            assert np.argmin(dist) == top and np.argmin(res[case]) == top
            assert res[case][top] < res["a"][top]
    assert np.argmax(res["d"]) == 1  # case d: control point 2 (lowest priority) is the one left behind


def test_errors():
    with pytest.raises(ShapeError, match="one priority per level"):
        pwdls([(np.eye(2), np.ones(2))], [1, 2], 0.1)
    with pytest.raises(NonFiniteError, match="priorities"):
        pwdls([(np.eye(2), np.ones(2))], [0.0], 0.1)
    with pytest.raises(ShapeError, match="level 1"):
        pwdls([(np.eye(2), np.ones(2)), (np.ones((1, 3)), np.ones(1))], [1, 2], 0.1)
