"""Write docs/img/viewer_lwr_relaxed.png: the lwr_relaxed replay in headless Chromium (as papers/000 Fig. 3).

Run ``.venv/bin/python docs/make_screenshot.py`` (needs Debian's chromium; tests/browser.py installs it as root).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from browser import screenshot  # noqa: E402

from hqp_tpm.app.cli import run_scenario  # noqa: E402


def main(out: Path = ROOT / "docs" / "img" / "viewer_lwr_relaxed.png", at: float = 0.6) -> Path:
    """Run the whole scenario, write its replay and shoot it at the critical-point instant nearest ``at`` x duration."""
    with tempfile.TemporaryDirectory() as tmp:
        run_scenario("lwr_relaxed", Path(tmp), progress=False, figures=False, replay=True)
        arrays = np.load(Path(tmp) / "trajectory.npz")
        t, active = arrays["t"], arrays["active_point"]
        candidates = np.flatnonzero(active >= 0) if np.any(active >= 0) else np.arange(len(t))
        k = candidates[np.argmin(np.abs(t[candidates] - at * t[-1]))]
        screenshot(f"{Path(tmp) / 'replay.html'}#t={t[k]:.3f}&ui=0", out, width=1000, height=750, budget_ms=10000)
    print(f"wrote {out} (t = {t[k]:.3f} s)")
    return out


if __name__ == "__main__":
    main()
