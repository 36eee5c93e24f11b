"""The replay in headless Chromium for three kinds of scene: the LWR (papers/000), the whole Romeo (papers/002)
and the co-manipulation (papers/003, with markers, operator force and the active stack's name).

With ``HQP_TPM_UPDATE_SCREENSHOTS=1`` the shots are written to ``docs/img/replay_<scenario>.png``.
"""

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

#: scenario -> (steps run, time of the shot)
SHOTS = {"lwr_relaxed": (11500, 11.3), "romeo_sns_tpm": (1600, 1.5), "iiwa_comanipulation": (1500, 1.2)}


def rgb(png: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(png).convert("RGB")).astype(int)


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    from browser import chromium, screenshot

    from hqp_tpm.app.cli import run_scenario

    chromium()  # fails in CI, skips elsewhere, before the runs when there is no browser
    out = {}
    for name, (steps, t) in SHOTS.items():
        d = tmp_path_factory.mktemp(name)
        summary = run_scenario(name, d, steps=steps, progress=False, figures=False, replay=True)
        png = screenshot(f"{d / 'replay.html'}#t={t}&ui=0", d / f"replay_{name}.png", width=1000, height=750,
                         budget_ms=15000)
        out[name] = (png, d / "replay.html", summary)
        if os.environ.get("HQP_TPM_UPDATE_SCREENSHOTS") == "1":
            shutil.copyfile(png, ROOT / "docs" / "img" / f"replay_{name}.png")
    return out


def drawn(img: np.ndarray) -> np.ndarray:
    """Pixels that are neither the white-grey background nor the grey grid: saturated, or dark (Romeo is grey)."""
    sat = (img.max(axis=-1) - img.min(axis=-1)) > 60
    return sat | (img.max(axis=-1) < 150)


def test_lwr_replay_shows_the_scene(shots):
    img = rgb(shots["lwr_relaxed"][0])
    assert img[5, -5].min() > 230
    orange = (img[..., 0] > 120) & (img[..., 0] - img[..., 2] > 100) & (img[..., 1] < 0.75 * img[..., 0])
    assert orange.mean() > 0.02


def test_romeo_is_framed_whole(shots):
    png, page, _ = shots["romeo_sns_tpm"]
    img = rgb(png)
    grey = ((img.max(axis=-1) - img.min(axis=-1)) < 8) & (img.max(axis=-1) < 232)  # the robot's neutral grey
    grey[:40] = False  # the stack label
    robot = grey[1:-1, 1:-1].copy()  # erode 3 x 3: thin grid lines go, the body stays
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            robot &= grey[1 + dy:grey.shape[0] - 1 + dy, 1 + dx:grey.shape[1] - 1 + dx]
    rows = np.flatnonzero(robot.mean(axis=1) > 0.01)
    cols = np.flatnonzero(robot.mean(axis=0) > 0.01)
    print(f"robot rows {rows.min()}..{rows.max()}, cols {cols.min()}..{cols.max()} of {img.shape}")
    assert rows.min() > 10 and rows.max() < img.shape[0] - 10, "the robot touches the top or bottom edge"
    assert cols.min() > 10 and cols.max() < img.shape[1] - 10, "the robot touches a side"
    size = page.stat().st_size
    print(f"romeo replay: {size / 1e6:.2f} MB")
    assert size < 8e6  # the decimated meshes (the full meshes made ~20 MB)


def test_comanipulation_replay_shows_markers_force_and_stack(shots):
    png, page, summary = shots["iiwa_comanipulation"]
    img = rgb(png)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    purple = (r > 100) & (b > 120) & (g < 60)
    blue = (b > 180) & (r < 60) & (g < 140)
    green = (g > 130) & (r < 80) & (b < 110)
    print(f"purple {purple.sum()}, blue {blue.sum()}, green {green.sum()} pixels")
    assert purple.sum() > 100, "the operator's markers are not drawn"
    assert blue.sum() > 100, "the operator's force arrow is not drawn"
    assert green.sum() > 100, "the marker the operator pulls towards is not drawn"
    html = page.read_text(encoding="utf-8")
    assert "force stack: force &gt; orientation" in html or "force stack: force > orientation" in html
