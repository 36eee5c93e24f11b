"""The documentation site builds with warnings as errors and its pages render in headless chromium.

`make docs` runs the same build (`mkdocs build --strict`, mkdocs.yml). Here the site is built into a temporary
folder from this checkout (the hook tools/docs_hooks.py fills the generated pages from the results files,
mkdocstrings reads the docstrings) and four pages are shot in the browser the viewer tests use
(tests/browser.py: fails under CI=true when there is no browser). HQP_TPM_DOCS_SHOTS=DIR keeps the shots.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow


def nav_pages() -> list[str]:
    """The Markdown files mkdocs.yml's nav lists."""
    class Loader(yaml.SafeLoader):
        pass

    Loader.add_multi_constructor("", lambda loader, suffix, node: None)  # mkdocs' !ENV and python tags
    config = yaml.load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"), Loader=Loader)

    def walk(items):
        for item in items:
            for value in item.values() if isinstance(item, dict) else [item]:
                yield from walk(value) if isinstance(value, list) else [value]

    return list(walk(config["nav"]))


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert "WARNING" not in proc.stderr, proc.stderr[-4000:]
    return out


def test_every_page_of_the_nav_is_built(site):
    pages = nav_pages()
    assert len(pages) > 30 and "speed.md" in pages and "api/control.md" in pages
    for page in pages:
        html = (site / page).with_suffix(".html").read_text(encoding="utf-8")
        assert not re.search(r"<!-- generated: |\[\[[a-z0-9_]+\.[A-Za-z0-9_.> ]+(?::[^\]]*)?\]\]", html), page
        assert not re.search(r"<(?:script|link)[^>]+(?:src|href)=\"https?://", html), f"{page} loads from the network"


def test_generated_pages_hold_the_results(site):
    import csv

    speed = (site / "speed.html").read_text(encoding="utf-8")
    with (ROOT / "benchmarks" / "results" / "peers.csv").open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert rows and all(r.get("contender", "") in speed for r in rows if r.get("contender")), "speed page is stale"
    peers_md = (ROOT / "benchmarks" / "results" / "peers.md").read_text(encoding="utf-8")
    title = next(line for line in peers_md.splitlines() if line.startswith("#")).lstrip("# ").strip()
    assert title.split()[0] in speed
    repro = (site / "reproductions.html").read_text(encoding="utf-8")
    assert "lwr_relaxed" in repro and "romeo_obstacles_qp" in repro and "scenarios.json" in repro
    guarantees = (site / "guarantees.html").read_text(encoding="utf-8")
    assert "tpm == nullspace" in guarantees
    api = (site / "api" / "control.html").read_text(encoding="utf-8")
    for name in ("Controller", "StepResult", "compute", "step", "levels"):
        assert name in api, name
    assert ":class:" not in api  # Sphinx roles left in the docstrings are shown as plain code


def rgb(png: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(png).convert("RGB")).astype(int)


@pytest.mark.parametrize("page", ["index", "reproductions", "speed", "api/control"])
def test_pages_render_in_the_browser(site, page, tmp_path):
    from browser import chromium, screenshot

    chromium()
    png = screenshot(site / f"{page}.html", tmp_path / f"{page.replace('/', '_')}.png", width=1200, height=900,
                     budget_ms=3000)
    if os.environ.get("HQP_TPM_DOCS_SHOTS"):
        Path(os.environ["HQP_TPM_DOCS_SHOTS"]).mkdir(parents=True, exist_ok=True)
        shutil.copyfile(png, Path(os.environ["HQP_TPM_DOCS_SHOTS"]) / png.name)
    img = rgb(png)
    assert img.shape[:2] == (900, 1200)
    nav = img[:, :250]
    assert (nav.max(axis=-1) < 80).mean() > 0.5, "the theme's dark navigation column is missing (CSS not loaded)"
    body = img[150:, 350:1050]
    text = body.max(axis=-1) < 110
    assert 0.01 < text.mean() < 0.5, "no text in the page body"
    if page == "index":  # the replay frames are shown: the LWR's orange links
        shot = img[:, 300:]
        r, g, b = shot[..., 0], shot[..., 1], shot[..., 2]
        orange = (r > 150) & (b < 40) & (g > 50) & (g < 0.75 * r)  # not the theme's red code text (blue ~60)
        assert orange.mean() > 0.002, "the index page's images did not load"
