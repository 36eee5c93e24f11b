"""The shipped LWR IV and LBR iiwa 7 URDFs (hqp_tpm/data/robots/) against their DH tables (docs/robots.md)."""

import importlib.util
import math
import subprocess
import sys
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import pytest

from hqp_tpm.data import robots_dir

TOOLS = Path(__file__).resolve().parents[1] / "tools"
ROBOTS = robots_dir()
N_SAMPLES = 1000
TOL = 1e-12

_spec = importlib.util.spec_from_file_location("dh_to_urdf", TOOLS / "dh_to_urdf.py")
dh_to_urdf = importlib.util.module_from_spec(_spec)
sys.modules["dh_to_urdf"] = dh_to_urdf  # dataclasses look their module up there
_spec.loader.exec_module(dh_to_urdf)

# The tables, typed in again from the set-ups in docs/setups.md (not read from the generator).
ALPHA = np.deg2rad([90.0, -90.0, -90.0, 90.0, 90.0, -90.0, 0.0])
TABLES = {
    "lwr": {
        "file": ROBOTS / "kuka_lwr4" / "lwr4.urdf",
        "robot": "kuka_lwr4",
        "d": [0.0, 0.0, 0.4, 0.0, 0.39, 0.0, 0.078],
        "limit_deg": [170, 120, 170, 120, 170, 120, 170],
        "velocity_deg": [110, 110, 128, 128, 204, 184, 184],
    },
    "iiwa": {
        "file": ROBOTS / "kuka_iiwa7" / "iiwa7.urdf",
        "robot": "kuka_iiwa7",
        "d": [0.34, 0.0, 0.40, 0.0, 0.40, 0.0, 0.126],
        "limit_deg": [170, 120, 170, 120, 170, 120, 175],
        "velocity_deg": [98, 98, 100, 130, 140, 180, 180],
    },
}
LWR_CP = [(0.40, "upper"), (0.35, "upper"), (0.30, "upper"), (0.25, "upper")]
LWR_CP += [(0.39, "fore"), (0.2925, "fore"), (0.195, "fore"), (0.0975, "fore")]


def dh_frames(q, d, alpha=ALPHA, a=None):
    """[T_0^0, T_0^1, ..., T_0^7] with A_i = Rot_z(q_i) Trans_z(d_i) Trans_x(a_i) Rot_x(alpha_i)."""
    a = np.zeros(7) if a is None else a
    T = [np.eye(4)]
    for qi, di, ai, al in zip(q, d, a, alpha, strict=True):
        ct, st, ca, sa = math.cos(qi), math.sin(qi), math.cos(al), math.sin(al)
        A = np.array(
            [[ct, -st * ca, st * sa, ai * ct], [st, ct * ca, -ct * sa, ai * st], [0, sa, ca, di], [0, 0, 0, 1]]
        )
        T.append(T[-1] @ A)
    return T


def random_configs(model, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(model.lowerPositionLimit, model.upperPositionLimit, size=(n, model.nq))


def frame_id(model, name):
    assert model.existFrame(name), name
    return model.getFrameId(name)


@pytest.fixture(scope="module", params=sorted(TABLES))
def arm(request):
    table = TABLES[request.param]
    model, collision, visual = pin.buildModelsFromUrdf(str(table["file"]))
    return request.param, table, model, collision, visual


def test_names_and_structure(arm):
    p, table, model, collision, visual = arm
    assert model.name == table["robot"]
    assert model.nq == model.nv == 7
    assert [model.names[j] for j in range(1, 8)] == [f"{p}_joint_{i}" for i in range(1, 8)]
    for i in range(8):
        assert model.frames[frame_id(model, f"{p}_link_{i}")].type == pin.FrameType.BODY
    for name in (f"{p}_ee", f"{p}_shoulder", f"{p}_elbow", f"{p}_wrist"):
        frame_id(model, name)
    if p == "lwr":
        for k in range(1, 9):
            frame_id(model, f"lwr_cp_{k}")
    assert visual.ngeoms > 0


def test_ee_matches_dh(arm):
    p, table, model, _, _ = arm
    data = model.createData()
    ee = frame_id(model, f"{p}_ee")
    frames = [frame_id(model, f"{p}_{n}") for n in ("shoulder", "elbow", "wrist")]
    for q in random_configs(model, N_SAMPLES, seed=1):
        pin.framesForwardKinematics(model, data, q)
        T = dh_frames(q, table["d"])
        M = data.oMf[ee]
        np.testing.assert_allclose(M.translation, T[7][:3, 3], rtol=0, atol=TOL)
        np.testing.assert_allclose(M.rotation[:, 2], T[7][:3, 2], rtol=0, atol=TOL)
        np.testing.assert_allclose(M.homogeneous, T[7], rtol=0, atol=TOL)  # the whole flange frame
        for fid, k in zip(frames, (2, 3, 5), strict=True):  # shoulder, elbow, wrist = DH frames 2, 3, 5
            np.testing.assert_allclose(data.oMf[fid].homogeneous, T[k], rtol=0, atol=TOL)


def test_lwr_control_points_match_dh():
    table = TABLES["lwr"]
    model = pin.buildModelFromUrdf(str(table["file"]))
    data = model.createData()
    cps = [frame_id(model, f"lwr_cp_{k}") for k in range(1, 9)]
    for q in random_configs(model, N_SAMPLES, seed=2):
        pin.framesForwardKinematics(model, data, q)
        T = dh_frames(q, table["d"])
        shoulder, elbow, wrist = T[2][:3, 3], T[3][:3, 3], T[5][:3, 3]
        for fid, (s, seg) in zip(cps, LWR_CP, strict=True):
            start, end = (shoulder, elbow) if seg == "upper" else (elbow, wrist)
            expected = start + s * (end - start) / np.linalg.norm(end - start)
            np.testing.assert_allclose(data.oMf[fid].translation, expected, rtol=0, atol=TOL)
    # cp_1 is the elbow, cp_5 the wrist (0.40 = d3, 0.39 = d5)
    np.testing.assert_allclose(data.oMf[cps[0]].translation, elbow, rtol=0, atol=TOL)
    np.testing.assert_allclose(data.oMf[cps[4]].translation, wrist, rtol=0, atol=TOL)


def test_lwr_q7_moves_neither_ee_position_nor_axis():
    model = pin.buildModelFromUrdf(str(TABLES["lwr"]["file"]))
    data = model.createData()
    ee = frame_id(model, "lwr_ee")
    rng = np.random.default_rng(3)
    for q in random_configs(model, 200, seed=3):
        pin.framesForwardKinematics(model, data, q)
        p0, z0 = data.oMf[ee].translation.copy(), data.oMf[ee].rotation[:, 2].copy()
        q[6] = rng.uniform(model.lowerPositionLimit[6], model.upperPositionLimit[6])
        pin.framesForwardKinematics(model, data, q)
        np.testing.assert_allclose(data.oMf[ee].translation, p0, rtol=0, atol=TOL)
        np.testing.assert_allclose(data.oMf[ee].rotation[:, 2], z0, rtol=0, atol=TOL)
        # the 7th Jacobian column: no linear velocity, angular velocity along z_e (so z_e does not turn)
        J = pin.computeFrameJacobian(model, data, q, ee, pin.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(J[:3, 6], 0.0, rtol=0, atol=TOL)
        np.testing.assert_allclose(np.cross(J[3:, 6], z0), 0.0, rtol=0, atol=TOL)


def test_limits_in_si(arm):
    _, table, model, _, _ = arm
    lim = np.deg2rad(table["limit_deg"])
    np.testing.assert_allclose(model.upperPositionLimit, lim, rtol=0, atol=TOL)
    np.testing.assert_allclose(model.lowerPositionLimit, -lim, rtol=0, atol=TOL)
    np.testing.assert_allclose(model.velocityLimit, np.deg2rad(table["velocity_deg"]), rtol=0, atol=TOL)
    assert np.all(model.effortLimit > 0)


def test_collision_capsules(arm):
    """One capsule per segment (base, shoulder-elbow, elbow-wrist, wrist-flange), no NaN, axis on the DH segment."""
    p, table, model, collision, _ = arm
    assert collision.ngeoms == 4
    links = [model.frames[g.parentFrame].name for g in collision.geometryObjects]
    assert links == [f"{p}_link_{i}" for i in (0, 3, 5, 7)]
    for g in collision.geometryObjects:
        assert isinstance(g.geometry, coal.Capsule)  # pinocchio reads <collision_checking><capsule .../>
        assert 0.05 <= g.geometry.radius <= 0.08 and g.geometry.halfLength > 0
        assert np.all(np.isfinite(g.placement.homogeneous))
    data, gdata = model.createData(), collision.createData()
    for q in random_configs(model, 100, seed=4):
        pin.updateGeometryPlacements(model, data, collision, gdata, q)
        T = dh_frames(q, table["d"])
        expected = [(T[2][:3, 3], T[3][:3, 3]), (T[3][:3, 3], T[5][:3, 3]), (T[5][:3, 3], T[7][:3, 3])]
        for g, M, (start, end) in zip(collision.geometryObjects[1:], gdata.oMg[1:], expected, strict=True):
            h = g.geometry.halfLength
            np.testing.assert_allclose(M.act(np.array([0, 0, -h])), start, rtol=0, atol=TOL)
            np.testing.assert_allclose(M.act(np.array([0, 0, h])), end, rtol=0, atol=TOL)
        M0 = gdata.oMg[0]  # base capsule: on the base z axis, ending at the shoulder
        np.testing.assert_allclose(M0.rotation[:, 2], [0, 0, 1], rtol=0, atol=TOL)
        np.testing.assert_allclose(M0.translation[:2], 0.0, rtol=0, atol=TOL)
        np.testing.assert_allclose(M0.translation[2] + collision.geometryObjects[0].geometry.halfLength, table["d"][0])


def test_cylinders_to_capsules(arm):
    """The fallback for loaders that read the cylinders as cylinders."""
    _, table, model, _, _ = arm
    geom = pin.buildGeomFromUrdf(model, str(table["file"]), pin.VISUAL)  # cylinders + end spheres
    cylinders = [
        (g.name, g.geometry.radius, g.geometry.halfLength)
        for g in geom.geometryObjects
        if isinstance(g.geometry, coal.Cylinder)
    ]
    assert len(cylinders) == 4
    dh_to_urdf.cylinders_to_capsules(geom)
    capsules = [
        (g.name, g.geometry.radius, g.geometry.halfLength)
        for g in geom.geometryObjects
        if isinstance(g.geometry, coal.Capsule)
    ]
    assert capsules == cylinders
    assert not any(isinstance(g.geometry, coal.Cylinder) for g in geom.geometryObjects)


def test_dynamics_work(arm):
    _, _, model, _, _ = arm
    data = model.createData()
    assert all(model.inertias[j].mass > 0 for j in range(1, 8))
    for q in random_configs(model, 20, seed=5):
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        assert np.all(np.linalg.eigvalsh(M) > 0)
        tau = pin.rnea(model, data, q, np.zeros(7), np.zeros(7))
        assert np.all(np.isfinite(tau))


def test_generator_reproduces_committed_files():
    generated = dh_to_urdf.generate()
    assert {p.name for p in generated} == {"lwr4.urdf", "iiwa7.urdf"}
    for path, text in generated.items():
        assert path.read_bytes() == text.encode(), f"{path} is stale: run python tools/dh_to_urdf.py"
    assert dh_to_urdf.generate() == generated  # deterministic
    run = subprocess.run([sys.executable, str(TOOLS / "dh_to_urdf.py"), "--check"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
