"""The lean step's compiled frame kernels (:mod:`hqp_tpm.robot._compiled`) against pinocchio.

``frame_jacobian`` (the frame Jacobian from the joint Jacobians ``data.J``, as ``getFrameJacobian`` with
``LOCAL_WORLD_ALIGNED``) does pinocchio's operations: equal to the last bit on every frame of three robots (one with
a free flyer). ``log3`` follows pinocchio's ``log3_impl`` step by step but its sums may round otherwise: it is
within the rounding of pinocchio's own result (large near pi, where the logarithm is ill-conditioned), at generic
angles, tiny angles (the Taylor
branch), angles near pi (the axis branch) and slightly non-orthonormal matrices: a few ulps scaled by the
logarithm's condition ``1 / (pi - theta)``.
"""

import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.robot import _compiled
from hqp_tpm.robot.model import Robot
from hqp_tpm.robot.state import State

pytestmark = pytest.mark.skipif(not _compiled.AVAILABLE, reason="numba is not installed")


@pytest.mark.parametrize("name", ["iiwa7", "lwr4", "romeo21"])
def test_frame_jacobian_is_pinocchios_to_the_bit(name):
    robot = Robot.load(name)
    st, rng = State(robot), np.random.default_rng(11)
    model = st.model
    lo = np.where(np.isfinite(model.lowerPositionLimit), model.lowerPositionLimit, -1.0)
    up = np.where(np.isfinite(model.upperPositionLimit), model.upperPositionLimit, 1.0)
    checked = 0
    for k in range(20):
        q = pin.randomConfiguration(model, lo, up)
        if k % 2:  # the lean step's partial update (joint Jacobians, the frames asked for)
            st.update_positions(q, np.zeros(robot.nv), 0.0, range(model.nframes))
        else:
            st.update(q, rng.normal(size=robot.nv))
        for fid in range(model.nframes):
            JT, cols = st.frame_jacobian_source(fid)
            S = np.zeros((6, robot.nv))
            _compiled.frame_jacobian(JT, cols, st.data.oMf[fid].translation, S)
            want = pin.getFrameJacobian(model, st.data, fid, pin.LOCAL_WORLD_ALIGNED)
            np.testing.assert_array_equal(S, want, err_msg=model.frames[fid].name)
            checked += 1
    assert checked == 20 * model.nframes
    assert st.frame_jacobian_source(0)[0] is st.frame_jacobian_source(1)[0]  # one view of data.J for every task


@pytest.mark.parametrize("name", ["iiwa7", "lwr4", "romeo21"])
def test_frame_placement_is_pinocchios_to_the_bit(name):
    """frame_placement (the fused kernel placing a frame from its joint's placement) writes into pinocchio's own
    oMf what updateFramePlacement writes, to the bit, on every frame of three robots (one with a free flyer), in
    whatever pinocchio the suite runs with (4.x here, 3.4 in make test-pin-lowest)."""
    robot = Robot.load(name)
    st, ref = State(robot), State(robot)
    model = st.model
    lo = np.where(np.isfinite(model.lowerPositionLimit), model.lowerPositionLimit, -1.0)
    up = np.where(np.isfinite(model.upperPositionLimit), model.upperPositionLimit, 1.0)
    for _ in range(20):
        q = pin.randomConfiguration(model, lo, up)
        st.update_positions(q, np.zeros(robot.nv), 0.0, ())           # joints only: oMf as the last q left it
        ref.update_positions(q, np.zeros(robot.nv), 0.0, range(model.nframes))
        for fid in range(model.nframes):
            RiT, pi, P, RfT = st.frame_placement_source(fid)
            _compiled.frame_placement(RiT, pi, P, RfT, st.data.oMf[fid].translation)
            np.testing.assert_array_equal(st.data.oMf[fid].homogeneous, ref.data.oMf[fid].homogeneous,
                                          err_msg=model.frames[fid].name)


EPS = np.finfo(float).eps


def _bound(w_ref: np.ndarray, ulps: float) -> float:
    """``ulps`` ulps scaled by the logarithm's condition near pi, ``1 / (pi - theta)`` (``acos``' slope there)."""
    theta = min(float(np.linalg.norm(w_ref)), np.pi - 1e-12)
    return EPS * (4.0 + ulps / (np.pi - theta))


#: ulps (times 1 / (pi - theta)) log3 may be from pin.log3: measured worst 13 (generic, 20,000 draws), 430 in the
#: axis branch near pi, 660 for the frame tasks' R_d R^T (the product rounds otherwise too)
ULPS = {"generic": 64.0, "tiny": 64.0, "near_pi": 2048.0, "not_orthonormal": 64.0, "product": 2048.0}


@pytest.mark.parametrize("kind", ["generic", "tiny", "near_pi", "not_orthonormal"])
def test_log3_within_pinocchios_rounding(kind):
    rng = np.random.default_rng({"generic": 1, "tiny": 2, "near_pi": 3, "not_orthonormal": 4}[kind])
    w = np.zeros(3)
    for _ in range(5000):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = {"generic": rng.uniform(0.0, 3.0), "tiny": 10.0 ** rng.uniform(-14, -3),
                 "near_pi": np.pi - 10.0 ** rng.uniform(-9, -1), "not_orthonormal": rng.uniform(0.0, 3.0)}[kind]
        M = pin.exp3(angle * axis)
        if kind == "not_orthonormal":
            M = M + rng.normal(0.0, 1e-9, (3, 3))
        _compiled.log3(np.ascontiguousarray(M), w)
        want = pin.log3(M)
        assert np.abs(w - want).max() <= _bound(want, ULPS[kind]), (kind, angle, w, want)


def test_rotation_error_is_the_frame_tasks_error():
    """rotation_error(R_d^T, R^T) is log3(R_d R^T) (the frame tasks' error) from the transposed views the lean step
    passes (pinocchio's rotations are column-major: their transposes are row-major views)."""
    w = np.zeros(3)
    for _ in range(5000):
        Md, M = pin.SE3.Random(), pin.SE3.Random()
        RdT, RT = Md.rotation.T, M.rotation.T
        assert RdT.flags.c_contiguous and RT.flags.c_contiguous
        _compiled.rotation_error(RdT, RT, w)
        want = pin.log3(Md.rotation.dot(M.rotation.T))
        assert np.abs(w - want).max() <= _bound(want, ULPS["product"]), (w, want)
