"""Sigmoid repulsion (23)-(24) with factor c, nearest and mean (25)-(26) directions, vectors (27)."""

import dataclasses
import warnings

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.errors import NonFiniteError, ShapeError, UnknownNameError
from hqp_tpm.geometry.distances import DistanceField
from hqp_tpm.geometry.obstacles import GeometryError, Obstacle
from hqp_tpm.geometry.repulsion import Repulsion, nearest_element, repulsion_direction, repulsion_magnitude

EE = Repulsion(v_max=5.0, rho=0.1, gamma=10.0, c=1.5)
BODY = Repulsion(v_max=0.15, rho=0.15, gamma=2.0, c=3.0)


@pytest.mark.parametrize("rep", [EE, BODY, Repulsion(1.0, 0.2, 7.0)], ids=["ee", "body", "paper"])
def test_values_at_zero_and_rho(rep):
    assert rep.magnitude(0.0) == pytest.approx(rep.v_max / (1.0 + np.exp(-rep.gamma)), rel=1e-15)
    assert rep.magnitude(rep.rho) == pytest.approx(rep.v_max / (1.0 + np.exp(rep.gamma * (rep.c - 1.0))), rel=1e-15)
    assert rep.magnitude(rep.rho / rep.c) == pytest.approx(rep.v_max / 2.0, rel=1e-15)  # the sigmoid's midpoint
    assert rep.magnitude(np.inf) == 0.0


def test_limits_of_eq_24_for_large_gamma():
    rep = Repulsion(v_max=3.0, rho=0.1, gamma=200.0, c=2.0)
    assert rep.magnitude(0.0) == pytest.approx(3.0, rel=1e-12)
    assert rep.magnitude(0.1) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("rep", [EE, BODY], ids=["ee", "body"])
def test_monotonic_decrease(rep):
    d = np.linspace(-0.05, 0.5, 2001)
    r = rep.magnitude(d)
    assert r.shape == d.shape
    assert np.all(np.diff(r) < 0) and np.all(r > 0) and np.all(r < rep.v_max)


def test_c2_is_the_papers_eq_23():
    v_max, rho, gamma = 2.5, 0.12, 6.0
    d = np.linspace(0.0, 0.3, 31)
    paper = v_max / (1.0 + np.exp((d / (rho / 2.0) - 1.0) * gamma))  # (23), D/(rho/2); printed as D/(2/rho)
    np.testing.assert_allclose(Repulsion(v_max, rho, gamma).magnitude(d), paper, rtol=1e-13)
    np.testing.assert_allclose(repulsion_magnitude(d, v_max, rho, gamma, 2.0), paper, rtol=1e-13)


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def test_mean_direction_eqs_25_26():
    # element 0: three obstacles in range with known unit normals, one out of range
    n = np.zeros((2, 4, 3))
    n[0] = [unit([1, 0, 0]), unit([0, 1, 0]), unit([1, 1, 1]), unit([-1, 0, 0])]
    n[1] = [unit([0, 0, 1]), unit([0, 0, -1]), unit([1, 2, 0]), unit([1, 0, 0])]
    d = np.array([[0.10, 0.05, 0.12, 0.30], [0.02, 0.02, np.inf, 0.5]])
    in_range = d <= 0.15
    d_min, nearest, r_hat = repulsion_direction(d, n, in_range, "mean")
    expected0 = unit(n[0, :3].mean(axis=0))
    np.testing.assert_allclose(r_hat[0], expected0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(r_hat, axis=1), 1.0)
    assert d_min[0] == 0.05 and nearest[0] == 1
    # element 1: the two in-range normals cancel -> falls back to the nearest (first minimum)
    np.testing.assert_allclose(r_hat[1], n[1, 0])
    # nearest direction
    _, _, r_near = repulsion_direction(d, n, in_range, "nearest")
    np.testing.assert_allclose(r_near[0], n[0, 1])
    # the surveillance argument narrows the range: only obstacle 1 of element 0 stays
    _, _, r_s = repulsion_direction(d, n, in_range, "mean", surveillance=0.06)
    np.testing.assert_allclose(r_s[0], n[0, 1])


def test_vectors_eq_27_and_empty_rows():
    n = np.zeros((3, 2, 3))
    n[0] = [unit([1, 0, 0]), unit([0, 1, 0])]
    n[1] = [unit([0, 0, 1]), unit([1, 1, 0])]
    d = np.array([[0.04, 0.08], [0.2, 0.3], [np.inf, np.inf]])
    mag, r_hat, d_min, nearest = BODY.vectors(d, n, d <= 0.15, direction="mean")
    np.testing.assert_allclose(mag[0], BODY.magnitude(0.04))  # intensity from the nearest obstacle (22)-(23)
    np.testing.assert_allclose(r_hat[0], unit([1, 1, 0]))
    assert mag[1] == 0.0 and mag[2] == 0.0 and np.all(r_hat[1:] == 0.0)
    np.testing.assert_array_equal(nearest, [0, -1, -1])
    assert np.isinf(d_min[1:]).all()


def test_with_distance_field_point_obstacles():
    """Control point vs docs/setups.md's three point obstacles: (25) as (p - o_j)/||p - o_j||."""
    model = pin.Model()
    j = model.addJoint(0, pin.JointModelTranslation(), pin.SE3.Identity(), "xyz")
    model.addFrame(pin.Frame("cp", j, pin.SE3.Identity(), pin.FrameType.OP_FRAME))
    o = np.array([[0.1, 0.5, 0.1], [-0.2, 0.3, 0.2], [-0.1, 0.4, -0.1]])
    field = DistanceField(model, None, ["cp"], [Obstacle.sphere(f"o{k}", c) for k, c in enumerate(o)],
                          surveillance=0.3)
    p = np.array([0.05, 0.45, 0.12])
    data = model.createData()
    pin.framesForwardKinematics(model, data, p)
    field.update(data)
    dist = np.linalg.norm(p - o, axis=1)
    inside = dist <= 0.3
    assert inside.sum() == 2  # o2 is 0.302 away
    mag, r_hat, d_min, nearest = BODY.vectors(field.distance, field.normal, field.in_range, direction="mean")
    r_mean = ((p - o[inside]) / dist[inside, None]).mean(axis=0)
    np.testing.assert_allclose(r_hat[0], r_mean / np.linalg.norm(r_mean), atol=1e-12)
    np.testing.assert_allclose(mag[0], BODY.magnitude(dist.min()), rtol=1e-12)
    _, r_near, _, _ = EE.vectors(field.distance, field.normal, field.in_range)
    k = int(np.argmin(dist))
    np.testing.assert_allclose(r_near[0], (p - o[k]) / dist[k], atol=1e-12)


def test_errors_and_frozen():
    with pytest.raises(UnknownNameError, match="'mean', 'nearest'"):
        repulsion_direction(np.zeros((1, 1)), np.zeros((1, 1, 3)), direction="average")
    with pytest.raises(ShapeError):
        repulsion_direction(np.zeros((2, 1)), np.zeros((2, 3)))
    with pytest.raises(GeometryError, match="rho"):
        Repulsion(1.0, 0.0, 1.0)
    with pytest.raises(GeometryError, match="gamma.*-1"):
        Repulsion(1.0, 0.1, -1.0)
    with pytest.raises(NonFiniteError, match="v_max"):
        Repulsion(np.nan, 0.1, 1.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        EE.c = 2.0


def random_pairs(rng, M, H):
    """(M, H) distances with culled pairs (inf), exact ties and pairs beyond a surveillance of 0.15."""
    d = rng.choice([0.02, 0.05, 0.1, 0.12, 0.2, np.inf], size=(M, H)) + rng.choice([0.0, 1e-3], size=(M, H))
    n = rng.standard_normal((M, H, 3))
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    u = unit(rng.standard_normal(3))
    n[rng.random((M, H)) < 0.2] = u  # equal and opposite normals: the mean (25) may cancel
    n[rng.random((M, H)) < 0.2] = -u
    return d, n, d <= 0.15


@pytest.mark.parametrize("direction", ["nearest", "mean"])
def test_nearest_element_equals_the_per_element_directions(direction):
    """The policy's fast path (one element) equals repulsion_direction's row of the argmin of d_min."""
    rng = np.random.default_rng(7)
    for _ in range(2000):
        M, H = int(rng.integers(0, 10)), int(rng.integers(0, 5))
        d, n, in_range = random_pairs(rng, M, H)
        surveillance = rng.choice([None, 0.1])
        k, j, d_k, r_k = nearest_element(d, n, in_range, direction, surveillance)
        if M == 0:
            assert (k, j, d_k, r_k) == (-1, -1, np.inf, None)
            continue
        d_min, nearest, r_hat = repulsion_direction(d, n, in_range, direction, surveillance)
        k_ref = int(np.argmin(d_min))
        if not np.isfinite(d_min[k_ref]):
            assert (k, j, d_k, r_k) == (-1, -1, np.inf, None)
            continue
        assert (k, j, d_k) == (k_ref, nearest[k_ref], d_min[k_ref])
        np.testing.assert_allclose(r_k, r_hat[k_ref], rtol=0, atol=1e-15)
        np.testing.assert_allclose(BODY.magnitude(d_k), BODY.vectors(d, n, in_range, direction, surveillance)[0][k],
                                   rtol=1e-15)


def test_magnitude_without_overflow_warning():
    """Past exp's range the magnitude is exactly 0, as with an overflowing exp, and no warning is raised."""
    rep = Repulsion(5.0, 0.1, 10.0, 1.5)
    d = np.array([0.0, 0.05, 4.7, 4.8, 5.0, 1e3, 1e300, np.inf])  # x = 10 (15 d - 1) crosses 709.78 near d = 4.8
    with np.errstate(over="ignore"):
        expected = 5.0 / (1.0 + np.exp(10.0 * (d * (1.5 / 0.1) - 1.0)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(rep.magnitude(d), expected)
        np.testing.assert_array_equal([rep.magnitude(float(x)) for x in d], expected)  # the float path
        assert rep.magnitude(1e300) == 0.0
    d = np.random.default_rng(2).uniform(-0.1, 1.0, 5000)
    for r in (EE, BODY):
        np.testing.assert_array_equal([r.magnitude(float(x)) for x in d], r.magnitude(d))
