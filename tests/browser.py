"""Headless Chromium for the viewer tests: find (or, as root, install) Debian's chromium and take screenshots.

A test that cannot get its browser fails when ``CI=true`` (the viewer must be checked there) and is skipped
with the reason elsewhere.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

#: Flags that render meshcat's WebGL scene headless with software GL and no network.
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-gl=angle", "--use-angle=swiftshader",
         "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--hide-scrollbars", "--mute-audio"]

_CACHE: dict[str, str] = {}


def _unavailable(reason: str):
    """No browser: a failure in CI (``CI=true``), where the viewer must be checked, a skip elsewhere."""
    if os.environ.get("CI", "").strip().lower() in ("1", "true", "yes"):
        pytest.fail(f"CI: the browser test cannot run: {reason}", pytrace=False)
    pytest.skip(reason)


def chromium() -> str:
    """Path of the chromium executable; installs Debian's package when it is missing (as root).

    When there is no browser and it cannot be installed, the test fails under ``CI=true`` and is skipped
    otherwise (with the reason).
    """
    if "path" in _CACHE:
        return _CACHE["path"]
    found = shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)
    if found is None:
        if os.geteuid() != 0:
            _unavailable("chromium is not installed (/usr/bin/chromium missing) and installing it needs root: "
                         "run `apt-get update && apt-get install -y chromium`")
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        for cmd in (["apt-get", "update"], ["apt-get", "-o", "DPkg::Lock::Timeout=300", "install", "-y", "chromium"]):
            try:
                proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
            except (OSError, subprocess.TimeoutExpired) as exc:
                _unavailable(f"could not install chromium ({' '.join(cmd)}: {exc})")
            if proc.returncode != 0:
                _unavailable(f"could not install chromium ({' '.join(cmd)} exited {proc.returncode}): "
                             f"{proc.stderr.strip()[-400:]}")
        found = shutil.which("chromium") or "/usr/bin/chromium"
        if not Path(found).exists():
            _unavailable("apt-get install chromium succeeded but no chromium executable was found")
    _CACHE["path"] = found
    return found


def screenshot(url_or_file, out_png, width: int = 800, height: int = 600, budget_ms: int = 8000,
               timeout_s: float = 90.0) -> Path:
    """Render ``url_or_file`` (a URL or a file path, ``#fragment`` allowed) headless into ``out_png``."""
    exe = chromium()
    target = str(url_or_file)
    if "://" not in target:
        path, _, frag = target.partition("#")
        target = Path(path).resolve().as_uri() + (f"#{frag}" if frag else "")
    out = Path(out_png).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    out.unlink(missing_ok=True)
    with tempfile.TemporaryDirectory(prefix="chromium-profile-") as profile:
        cmd = [exe, *FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}",
               f"--virtual-time-budget={int(budget_ms)}", f"--screenshot={out}", target]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    if not out.exists():
        raise RuntimeError(f"chromium wrote no screenshot (exit {proc.returncode}): {proc.stderr.strip()[-1000:]}")
    return out
