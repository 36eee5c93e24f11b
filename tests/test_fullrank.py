"""The shortcut for stacks that reach rank n before their last level equals the readable TPM path.

:func:`hqp_tpm.solvers._compiled.past_rank` (the kernel of :mod:`hqp_tpm.solvers._fullrank`, taken by
:func:`tpm` and by :func:`sns_tpm` when ``m > n``) against :func:`tpm_reference` (padded QR, Steps 2-4, SVD
pseudo-inverse of ``R^T``) at 1e-12: random stacks exact and damped, ill-conditioned upper levels and crossing
levels, dependent stacks with a posture level, ``x0`` (no effect at rank n), and the side-by-side benchmark's
stacks and closed loops (no bundled scenario's stack goes past rank n: they keep the general path).
"""

import numpy as np
import pytest

from hqp_tpm.solvers import _compiled, nullspace, sns_tpm, sns_tpm_reference, tpm, tpm_reference
from hqp_tpm.solvers.levels import stacked
from hqp_tpm.testing.stacks import dependent_stack

TOL = 1e-12

DAMPING = [{}, {"lambda_max": 0.05, "eps": 0.1}, {"lambda_max": 0.1, "eps": 0.5}]


def rel_diff(a, b) -> float:
    return float(np.linalg.norm(a - b) / max(1.0, np.linalg.norm(b)))


def shortcut(levels, n, lambda_max=0.0, eps=0.0):
    _, J, b, sizes, n = stacked(levels, n)
    return _compiled.past_rank(J, b, sizes, n, lambda_max, eps)


def past_rank_stack(rng, n=None):
    """Gaussian levels with more rows than columns in total (the last ones past rank n)."""
    n = int(rng.integers(2, 14)) if n is None else n
    sizes = [int(rng.integers(1, n + 3)) for _ in range(int(rng.integers(1, 5)))]
    if sum(sizes) <= n:
        sizes.append(n - sum(sizes) + int(rng.integers(1, 4)))
    scale = 10.0 ** rng.uniform(-2, 2)
    return [(scale * rng.standard_normal((m, n)), rng.standard_normal(m)) for m in sizes], n


@pytest.mark.parametrize("damping", range(len(DAMPING)))
def test_random_stacks_past_rank_equal_reference(damping):
    damp = DAMPING[damping]
    rng = np.random.default_rng(14 + damping)
    taken = 0
    for _ in range(300):
        levels, n = past_rank_stack(rng)
        x = tpm(levels, **damp)
        assert rel_diff(x, tpm_reference(levels, **damp)) <= TOL
        taken += shortcut(levels, n, **{"lambda_max": 0.0, "eps": 0.0, **damp}) is not None
    assert taken >= (300 if not damp else 150)  # the common case (damped upper pivots: the general path)


def test_robot_shaped_stacks_take_the_shortcut():
    """EE pose (6) > posture (n) on 7 joints and sole > CoM > foot > hands > posture on 27: the benchmarks' shapes."""
    rng = np.random.default_rng(3)
    for sizes, n in [([6, 7], 7), ([6, 2, 3, 3, 3, 21], 27), ([6, 27], 27), ([3, 3, 7], 7)]:
        for _ in range(20):
            levels = [(rng.standard_normal((m, n)), rng.standard_normal(m)) for m in sizes]
            if sizes[-1] in (7, 27):
                levels[-1] = (np.eye(n)[-sizes[-1]:], rng.standard_normal(sizes[-1]))
            assert shortcut(levels, n) is not None
            for damp in DAMPING:
                assert rel_diff(tpm(levels, **damp), nullspace(levels, **damp)) <= TOL  # singular level: recursion


def test_x0_has_no_effect_at_full_rank():
    rng = np.random.default_rng(5)
    for _ in range(50):
        levels, n = past_rank_stack(rng)
        x0 = rng.standard_normal(n)
        assert rel_diff(tpm(levels, x0=x0), tpm_reference(levels, x0=x0)) <= TOL


def ill_conditioned_past_rank(rng):
    """Upper levels nearly dependent (delta 1e-11 .. 1e-3), a crossing level nearly in their span, a posture."""
    n = int(rng.integers(3, 13))
    sizes = [int(rng.integers(1, 4)) for _ in range(int(rng.integers(2, 5)))]
    while sum(sizes) > n - 1 and len(sizes) > 1:
        sizes.pop()
    Js = [rng.standard_normal((k, n)) for k in sizes]
    if len(Js) > 1:
        k = int(rng.integers(1, len(Js)))
        above = np.vstack(Js[:k])
        r = int(rng.integers(1, sizes[k] + 1))
        Js[k][:r] = rng.standard_normal((r, above.shape[0])) @ above + 10.0 ** rng.uniform(-11, -3) * \
            rng.standard_normal((r, n))
    above = np.vstack(Js)
    cross = rng.standard_normal((n - above.shape[0] + int(rng.integers(0, 3)), n))
    if rng.random() < 0.5:  # nearly in the span of the levels above
        cross = rng.standard_normal((cross.shape[0], above.shape[0])) @ above + 10.0 ** rng.uniform(-11, -3) * cross
    Js += [cross, np.eye(n)]
    return [(J, rng.standard_normal(J.shape[0])) for J in Js], n


@pytest.mark.parametrize("damping", range(len(DAMPING)))
def test_ill_conditioned_draws_equal_reference(damping):
    """Where the shortcut is taken on these draws it equals the reference at 1e-12 (cond(J_<k) up to ~1e5)."""
    damp = DAMPING[damping]
    rng = np.random.default_rng(140 + damping)
    taken = 0
    for _ in range(300):
        levels, n = ill_conditioned_past_rank(rng)
        x = shortcut(levels, n, **{"lambda_max": 0.0, "eps": 0.0, **damp})
        if x is not None:  # declined near a rank loss (COND): the general path, as before
            taken += 1
            assert rel_diff(x, tpm_reference(levels, **damp)) <= TOL
            np.testing.assert_array_equal(tpm(levels, **damp), x)
    assert taken >= 15


@pytest.mark.parametrize("damping", range(len(DAMPING)))
def test_dependent_stacks_with_a_posture_level(damping):
    damp = DAMPING[damping]
    rng = np.random.default_rng(41 + damping)
    for i in range(40):
        levels = dependent_stack(rng, singular_within=bool(i % 2))
        levels = list(levels) + [(np.eye(12), rng.standard_normal(12))]
        assert rel_diff(tpm(levels, **damp), nullspace(levels, **damp)) <= TOL  # singular level: recursion


def test_sns_tpm_inside_the_box_takes_the_shortcut_and_equals_reference():
    rng = np.random.default_rng(8)
    for _ in range(100):
        levels, n = past_rank_stack(rng)
        x = tpm_reference(levels)
        for scale in (2.0, 0.5):  # the box holds x, or cuts it
            lo, up = -scale * np.abs(x) - 1e-3, scale * np.abs(x) + 1e-3
            assert rel_diff(sns_tpm(levels, lo, up), sns_tpm_reference(levels, lo, up)) <= 1e-10


def _peers():
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: ``benchmarks``
    from benchmarks.peers import problems

    return problems


@pytest.mark.parametrize("kind", ["iiwa_vel", "iiwa_acc", "romeo_vel"])
def test_benchmark_stacks_equal_reference(kind):
    """The side-by-side benchmark's stacks (EE pose > posture; sole > CoM > foot > hands > posture: m > n)."""
    P = _peers()
    robot = P.load_robot(P.ROMEO if kind.startswith("romeo") else P.IIWA)
    prob = P.romeo_problem(robot, n=30) if kind.startswith("romeo") else \
        P.iiwa_problem(robot, order=1 if kind == "iiwa_vel" else 2, n=30)
    n = robot.nv
    for cfg in prob.configs:
        ctrl = P.hqp_controller(robot, prob, cfg)
        levels = ctrl.compute().levels
        _, J, b, sizes, _ = stacked(levels, n)
        assert J.shape[0] > n and _compiled.past_rank(J, b, sizes, n, 0.0, 0.0) is not None
        for damp in DAMPING:
            assert rel_diff(tpm(levels, n=n, **damp), tpm_reference(levels, n=n, **damp)) <= TOL


@pytest.mark.parametrize("order", [1, 2])
def test_benchmark_closed_loop_steps_equal_reference(order):
    """Every step of 300 of the iiwa circle loop (EE position + orientation > posture)."""
    P = _peers()
    robot = P.load_robot(P.IIWA)
    ctrl, _ = P.hqp_circle_controller(robot, order)
    for _ in range(300):
        res = ctrl.step()
        assert rel_diff(res.command, tpm_reference(res.levels, n=robot.nv)) <= TOL
