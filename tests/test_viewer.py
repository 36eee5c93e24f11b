"""The meshcat viewer: replay contents (no browser), and what headless Chromium draws of the replay and live view."""

from __future__ import annotations

import base64
import re
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import umsgpack

from hqp_tpm.control.policy import SceneItems
from hqp_tpm.geometry.obstacles import Obstacle
from hqp_tpm.robot.model import Robot

STEPS = 3000  # 3 s of lwr_relaxed (dt = 1 ms)


# ------------------------------------------------------------------------------------------ helpers
def commands(html: str) -> list[dict]:
    """The meshcat commands embedded in a replay page (base64 msgpack strings)."""
    block = html[html.index("const hqpCommands = ["):]
    block = block[: block.index("];")]
    return [umsgpack.unpackb(base64.b64decode(s)) for s in re.findall(r'"([A-Za-z0-9+/=]+)"', block)]


def animation(cmds: list[dict]) -> dict[str, dict]:
    """``{node path: {track name: keys}}`` of the (single) set_animation command."""
    anims = [c for c in cmds if c["type"] == "set_animation"]
    assert len(anims) == 1
    assert anims[0]["options"]["play"] is False
    return {a["path"]: {t["name"]: t["keys"] for t in a["clip"]["tracks"]} for a in anims[0]["animations"]}


def object_paths(cmds: list[dict]) -> set[str]:
    return {c["path"] for c in cmds if c["type"] == "set_object"}


def rgb(png: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(png).convert("RGB")).astype(int)


def orange_mask(img: np.ndarray) -> np.ndarray:
    """Pixels in the LWR's shaded orange (URDF colour 1, 0.45, 0): red high, blue low, green in between."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r > 120) & (r - b > 100) & (g > 0.2 * r) & (g < 0.75 * r)


def coloured_mask(img: np.ndarray) -> np.ndarray:
    """Saturated pixels: neither the white-grey background nor the grey floor grid."""
    return (img.max(axis=-1) - img.min(axis=-1)) > 60


# ------------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def lwr_run(tmp_path_factory):
    """A real 3 s run of lwr_relaxed with its replay; returns (out dir, robot, arrays, run context)."""
    from hqp_tpm.app import build, scenario
    from hqp_tpm.app.cli import run_scenario

    out = tmp_path_factory.mktemp("lwr_relaxed")
    run_scenario("lwr_relaxed", out, steps=STEPS, progress=False, figures=False, replay=True)
    ctx = build.build_run(scenario.load("lwr_relaxed"))
    arrays = dict(np.load(out / "trajectory.npz"))
    return out, ctx.robot, arrays, ctx


# ------------------------------------------------------------------------------------------ replay file
def test_replay_is_self_contained_and_animates_the_robot(lwr_run):
    out, robot, arrays, _ = lwr_run
    page = out / "replay.html"
    assert page.is_file()
    assert 0.5e6 < page.stat().st_size < 15e6
    html = page.read_text(encoding="utf-8")
    assert "MeshCat.Viewer" in html  # meshcat's JavaScript is embedded
    assert not re.search(r"<script[^>]*\bsrc\s*=", html, re.I), "no external scripts"
    assert not re.search(r"""(?:src|href)\s*=\s*["']?(?:https?:)?//""", html, re.I), "no network resources"
    assert not list(out.glob(".replay.html.*")), "temporary file left behind"

    cmds = commands(html)
    anim = animation(cmds)
    objects = object_paths(cmds)
    visuals = robot.visual_model.geometryObjects
    for g in visuals:  # every visual geometry is drawn, every moving one is animated
        path = f"/meshcat/world/robot/visuals/{g.name}"
        assert path in objects
        if g.parentJoint != 0:
            assert {"position", "quaternion"} & {k.lstrip(".") for k in anim[path]}, g.name
    moving_links = {robot.model.frames[g.parentFrame].name for g in visuals if g.parentJoint != 0}
    animated = " ".join(anim)
    assert moving_links and all(link in animated for link in moving_links)
    for name in ("desired_path", "pointing_cone", "critical_point", "distance", "obstacles/o1", "obstacles/o2",
                 "obstacles/o3", "control_points/0_lwr_cp_1", "control_points/7_lwr_cp_8", "ee_trace/0"):
        assert f"/meshcat/world/{name}" in objects, name
    # real-time keys: at most max_frames of them, spanning the run (fps = 30)
    keys = anim[f"/meshcat/world/robot/visuals/{visuals[-1].name}"][".position"]
    times = np.array([k["time"] for k in keys]) / 30.0
    assert len(keys) <= 600
    assert times[0] == 0.0 and times[-1] == pytest.approx(arrays["t"][-1] - arrays["t"][0])
    # the critical point changes over the run (blue marker visible or hidden, moving)
    assert ".visible" in anim["/meshcat/world/critical_point"] or ".position" in anim["/meshcat/world/critical_point"]


def test_replay_subsamples_and_is_quick(lwr_run, tmp_path):
    from hqp_tpm.app.viewer import write_replay

    _, robot, arrays, ctx = lwr_run
    long = {k: (np.concatenate([v] * 6) if k in ("q", "active_point") else v) for k, v in arrays.items()}
    long["t"] = np.arange(len(long["q"])) * 1e-3  # 18,000 steps, as long as the paper's 6 pi s run
    t0 = time.perf_counter()
    page = write_replay(tmp_path / "long.html", robot, long, ctx.scene, max_frames=200)
    elapsed = time.perf_counter() - t0
    assert elapsed < 10.0
    anim = animation(commands(page.read_text(encoding="utf-8")))
    n_keys = {len(tr) for tracks in anim.values() for tr in tracks.values()}
    assert n_keys == {200}


def test_replay_draws_any_obstacle_and_policy_markers(tmp_path):
    from hqp_tpm.app.viewer import write_replay

    robot = Robot.load("lwr4")
    cube = np.array([[x, y, z] for x in (0, 0.1) for y in (0, 0.1) for z in (0, 0.1)]) + [0.3, 0.3, 0.3]
    obstacles = [Obstacle.sphere("point", [0.3, 0.0, 0.2]),
                 Obstacle.sphere("ball", [0.0, 0.4, 0.3], 0.05, velocity=[0.0, 0.0, 0.1]),
                 Obstacle.box("box", [0.3, -0.3, 0.0], [0.05, 0.1, 0.02]),
                 Obstacle.capsule("capsule", [-0.3, 0.2, 0.0], [-0.3, 0.2, 0.3], 0.03),
                 Obstacle.mesh("convex", cube)]

    def markers(t, q):
        return [("com", [0.0, 0.0, 0.1 + t], (0.6, 0.0, 0.8, 1.0))] + ([("late", [0.1, 0.1, 0.1], (1, 1, 0, 1))]
                                                                       if t > 0.5 else [])

    items = SceneItems(obstacles=obstacles, markers=markers)
    n = 50
    q = np.tile(robot.neutral(), (n, 1))
    q[:, 1] = np.linspace(0.0, 1.0, n)
    page = write_replay(tmp_path / "r.html", robot, {"t": np.linspace(0.0, 1.0, n), "q": q}, items)
    cmds = commands(page.read_text(encoding="utf-8"))
    objects = object_paths(cmds)
    for o in obstacles:
        assert f"/meshcat/world/obstacles/{o.name}" in objects
    point = next(c for c in cmds if c["type"] == "set_object" and c["path"].endswith("obstacles/point"))
    assert point["object"]["geometries"][0]["radius"] == pytest.approx(0.015)  # radius-0 point drawn 1.5 cm
    anim = animation(cmds)
    assert ".position" in anim["/meshcat/world/obstacles/ball"]  # moving obstacle
    assert "/meshcat/world/obstacles/box" not in anim  # static: no track
    assert ".position" in anim["/meshcat/world/markers/com"]
    late = [k["value"] for k in anim["/meshcat/world/markers/late"][".visible"]]
    assert late[0] is False and late[-1] is True
    # a robot alone (no policy) is fine too
    write_replay(tmp_path / "bare.html", robot, {"t": np.linspace(0.0, 1.0, n), "q": q}, None)
    assert pin.neutral(robot.model).shape == q[0].shape


# ------------------------------------------------------------------------------------------ browser
def test_browser_replay_shows_the_robot_moving(lwr_run, tmp_path):
    from browser import screenshot

    out, *_ = lwr_run
    shots = {t: rgb(screenshot(f"{out / 'replay.html'}#t={t}&ui=0", tmp_path / f"replay_t{t}.png"))
             for t in (0.5, 2.5)}
    masks = {}
    for t, img in shots.items():
        assert img.shape == (600, 800, 3)
        assert img[5, 5].min() > 230, f"t={t}: background not drawn (corner pixel {img[5, 5]})"
        orange, coloured = orange_mask(img), coloured_mask(img)
        print(f"t={t}: orange {orange.mean():.3f}, coloured {coloured.mean():.3f} of the pixels")
        assert orange.mean() > 0.02, f"t={t}: robot not drawn ({orange.sum()} orange pixels)"
        assert coloured.mean() > 0.03 and orange.sum() > 0.5 * coloured.sum()
        masks[t] = orange
    moved = masks[0.5] ^ masks[2.5]
    print(f"robot pixels that changed between t=0.5 and t=2.5: {moved.sum()}")
    assert moved.sum() > 0.01 * moved.size, "the robot did not move between the two playback times"
    diff = np.abs(shots[0.5] - shots[2.5]).sum(axis=-1)
    assert (diff[masks[0.5] | masks[2.5]] > 60).mean() > 0.1


def test_browser_live_viewer_shows_the_robot(lwr_run, tmp_path):
    from browser import chromium, screenshot

    from hqp_tpm.app.viewer import LiveViewer

    chromium()  # skip (with the reason) before starting a server when there is no browser
    _, robot, arrays, ctx = lwr_run
    with LiveViewer(robot, ctx.scene, policy=ctx.policy) as live:
        assert live.url.startswith("http://127.0.0.1:")
        live.show(arrays["q"][1000], float(arrays["t"][1000]), int(arrays["active_point"][1000]))
        img = rgb(screenshot(live.url, tmp_path / "live.png"))
    orange, coloured = orange_mask(img), coloured_mask(img)
    print(f"live: orange {orange.mean():.3f}, coloured {coloured.mean():.3f} of the pixels")
    assert img[5, 5].min() > 230
    assert orange.mean() > 0.02, f"live viewer: robot not drawn ({orange.sum()} orange pixels)"


# -------------------------------------------------------------------------------- meshes, co-manipulation, live
def test_meshes_are_decimated_once_and_cached(tmp_path, monkeypatch):
    import hqp_tpm.app.viewer_scene as vs

    monkeypatch.setenv("HQP_TPM_CACHE", str(tmp_path))
    monkeypatch.setattr(vs, "_DECIMATED", {})
    robot = Robot.load("romeo21")
    full = sum(g.geometry.num_tris for g in robot.visual_model.geometryObjects)
    g1 = vs.viewer_geometry(robot)
    small = [g.geometry.num_tris for g in g1.geometryObjects]
    assert max(small) <= vs.MAX_TRIANGLES and sum(small) < 0.85 * full  # 88,433 of 107,840 at 3,000
    big = {g.meshPath for g in robot.visual_model.geometryObjects if g.geometry.num_tris > vs.MAX_TRIANGLES}
    assert len(list((tmp_path / "meshes").glob("*.npz"))) == len(big) > 5  # each mesh file written once
    calls = []
    monkeypatch.setattr(vs, "_DECIMATED", {})
    monkeypatch.setattr(vs, "decimate", lambda *a, **k: calls.append(1))
    g2 = vs.viewer_geometry(robot)  # from the disk cache: no decimation
    assert not calls and [g.geometry.num_tris for g in g2.geometryObjects] == small
    assert robot.visual_model.geometryObjects[0].meshPath  # the robot's own model is untouched


def test_decimate_keeps_the_shape():
    from hqp_tpm.app.viewer_scene import decimate

    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 80), np.linspace(0, np.pi, 60))
    V = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], axis=-1).reshape(-1, 3)
    idx = np.arange(80 * 60).reshape(60, 80)
    F = np.concatenate([np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:]], -1).reshape(-1, 3),
                        np.stack([idx[:-1, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 3)])
    W, G = decimate(V, F, 500)
    assert len(G) <= 500 and G.max() < len(W)
    assert np.allclose(np.linalg.norm(W, axis=1), 1.0, atol=0.1)  # still a unit sphere


def test_comanipulation_replay_draws_markers_force_and_stack(tmp_path):
    from hqp_tpm.app import build, scenario
    from hqp_tpm.app.cli import run_scenario

    run_scenario("iiwa_comanipulation", tmp_path, steps=2500, progress=False, figures=False, replay=True)
    html = (tmp_path / "replay.html").read_text(encoding="utf-8")
    cmds = commands(html)
    objects = object_paths(cmds)
    _, _, _, policy = build.build(scenario.load("iiwa_comanipulation"))
    for i in range(len(policy.operator.markers)):
        assert f"/meshcat/world/operator_markers/{i}" in objects
    assert {"/meshcat/world/target_marker", "/meshcat/world/operator_force"} <= objects
    anim = animation(cmds)
    force = anim["/meshcat/world/operator_force"]
    assert ".visible" in force and ".scale" in force  # shown while the operator pushes, length ~ |f|
    assert ".position" in anim["/meshcat/world/target_marker"]  # the first marker is reached at 1.68 s
    assert "force stack: force > orientation > manipulability > joint_limit" in html
    assert '"stack: position > orientation"' not in html or "pose stack" in html


def test_lwr_replay_has_no_co_manipulation_items(lwr_run):
    out, *_ = lwr_run
    objects = object_paths(commands((out / "replay.html").read_text(encoding="utf-8")))
    assert not {p for p in objects if "operator" in p or "target_marker" in p}


def test_rate_limiter_paces_and_counts_overruns():
    from hqp_tpm.app.viewer_live import RateLimiter

    now = [0.0]
    slept = []

    def sleep(dt):
        slept.append(dt)
        now[0] += dt

    rate = RateLimiter(1.0, tolerance=0.02, clock=lambda: now[0], sleep=sleep)
    rate.wait(0.0)
    now[0] += 0.001
    rate.wait(0.01)  # early: sleeps 9 ms
    assert slept == [pytest.approx(0.009)]
    now[0] += 0.2  # the loop stalls
    rate.wait(0.02)
    assert rate.overruns == 1 and rate.max_lag == pytest.approx(0.19)
    assert "1 behind real time" in rate.report()
    fast = RateLimiter(10.0, clock=lambda: now[0], sleep=sleep)
    fast.wait(0.0)
    fast.wait(1.0)
    assert slept[-1] == pytest.approx(0.1)  # ten times faster than real time


def test_live_viewer_prints_its_url_once(capfd):
    from hqp_tpm.app.viewer_live import LiveViewer

    robot = Robot.load("planar5")
    with LiveViewer(robot) as live:
        live.show(robot.neutral(), 0.0)
    out = capfd.readouterr().out
    assert out.count("http://") == 1, out


def test_viz_keeps_the_server_until_ctrl_c(tmp_path):
    import signal
    import subprocess
    import sys
    import urllib.request

    cmd = [sys.executable, "-m", "hqp_tpm.app.cli", "run", "planar5_exact", "--steps", "300", "--viz", "--realtime",
           "--no-figures", "--no-replay", "--quiet", "--out", str(tmp_path)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line)
            if "press Ctrl-C" in line:
                break
        text = "".join(lines)
        assert text.count("http://") == 1, text
        assert "real-time pacing: 30 frames" in text, text
        url = re.search(r"(http://\S+)", text).group(1)
        time.sleep(1.0)
        assert proc.poll() is None, "the viewer did not stay up after the run"
        with urllib.request.urlopen(url, timeout=10) as resp:
            assert resp.status == 200
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()


def test_replay_has_a_colour_legend_of_what_it_draws(tmp_path):
    """Issue 32, item 5: 0d7b885's replay.html had no colour legend. Each drawn item has its swatch in the item's
    colour; items not drawn have none."""
    import re

    from hqp_tpm.app import runner
    from hqp_tpm.app.build import build_run
    from hqp_tpm.app.scenario import load
    from hqp_tpm.app.viewer import COLORS, write_replay

    def legend_of(name, steps):
        ctx = build_run(load(name))
        rec, _ = runner.run(ctx.controller, steps, probes=ctx.probes(),
                            recording=runner.Recording(ctx.robot.joint_names, tmp_path / name))
        page = write_replay(tmp_path / f"{name}.html", ctx.robot, rec.load(), ctx.scene).read_text()
        block = re.search(r'<div id="hqp-legend">(.*?)</div>\n<script>', page, re.S).group(1)
        return dict(re.findall(r'background: (rgba\([^)]*\))"></span>([^<]+)</div>', block))

    lwr = legend_of("lwr_relaxed", 60)
    for label, key in (("point obstacle", "point_obstacle"), ("control point", "control_point"),
                       ("desired EE path", "desired_path"), ("EE trace", "ee_trace"),
                       ("pointing cone (alpha_d)", "cone")):
        r, g, b, _ = COLORS[key]
        assert any(v == label and c.startswith(f"rgba({round(255 * r)}, {round(255 * g)}, {round(255 * b)},")
                   for c, v in lwr.items()), (label, lwr)
    assert "operator's markers" not in lwr.values()
    assert not any(v.startswith("target") for v in lwr.values())  # its EE task is drawn as the desired path
    romeo = legend_of("romeo_tpm", 5)  # the robot and its two hands' moving targets
    assert sorted(romeo.values()) == ["target of left_hand, right_hand", "target path"], romeo
    planar = legend_of("planar5_primary", 5)
    assert "EE trace" in planar.values() and not any(v.startswith("target") for v in planar.values())


def test_camera_distance_fits_every_point_in_the_view():
    """The camera placed by ``camera_distance`` sees every point within the margin of both half-angles, and one
    point lies on that margin (the fit is tight): a tall humanoid is framed head to feet."""
    from hqp_tpm.app.viewer_scene import VIEW_ASPECT, VIEW_MARGIN, camera_distance

    rng = np.random.default_rng(3)
    for scale in ([0.3, 0.2, 0.8], [0.6, 0.6, 0.1], [0.05, 0.05, 0.05]):  # a humanoid, a flat scene, a small one
        P = rng.uniform(-1, 1, (400, 3)) * scale
        d = np.array([1.1, 0.45, 0.5]) / np.linalg.norm([1.1, 0.45, 0.5])
        dist = camera_distance(P, d, 45.0)
        right = np.cross(-d, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, -d)
        depth = dist - P @ d
        assert (depth > 0).all()
        v, h = np.abs(P @ up) / depth, np.abs(P @ right) / depth
        tan_v = VIEW_MARGIN * np.tan(np.radians(22.5))
        assert (v <= tan_v + 1e-12).all() and (h <= VIEW_ASPECT * tan_v + 1e-12).all()
        if dist > 0.5 + 1e-9:  # not the minimum distance: tight on one of the two
            assert max(v.max() / tan_v, h.max() / (VIEW_ASPECT * tan_v)) > 0.999 or dist <= 1.05 * np.linalg.norm(
                P, axis=1).max() + 1e-9
