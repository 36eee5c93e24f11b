"""Fault injection on the output folder (not collected by pytest; the README quotes its numbers).

    python tests/fault_campaign.py [ROUNDS] [SEED]

Each round starts ``hqp-tpm run planar5_exact`` into one folder that holds a complete result, then either
sends SIGINT, SIGTERM or SIGKILL after a random delay (while building, stepping or writing), or starts three
runs into the folder at once. After each round the folder must hold a complete, consistent result (manifest,
metrics.json, trajectory.npz agreeing), a ``.partial`` sibling (if any) must be consistent too, and no
temporary folder may remain once the next run has started (a SIGKILLed run's folder is removed by the next).
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CMD = [sys.executable, "-m", "hqp_tpm.app.cli", "run", "planar5_exact", "--quiet", "--no-replay", "--no-figures"]


def _default_sigint() -> None:
    """A shell that starts this script in the background ignores SIGINT for it (and so for its children):
    give the runs the default disposition, as a terminal would."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def consistent(folder: Path) -> bool:
    man = json.loads((folder / "manifest.json").read_text())
    names = {p.name for p in folder.iterdir()} - {"manifest.json"}
    metrics = json.loads((folder / "metrics.json").read_text())
    with np.load(folder / "trajectory.npz") as z:
        n = z["t"].shape[0]
    return set(man["files"]) == names and n == man["steps"] == metrics["steps"]


def main(rounds: int = 20, seed: int = 0) -> dict:
    rng = random.Random(seed)
    root = Path(tempfile.mkdtemp(prefix="hqp-tpm-faults-"))
    out = root / "out"
    subprocess.run([*CMD, "--out", str(out), "--steps", "200"], check=True, stdout=subprocess.DEVNULL)
    counts = {"rounds": 0, "SIGINT": 0, "SIGTERM": 0, "SIGKILL": 0, "concurrent": 0, "partial_results": 0,
              "complete_result_lost": 0, "inconsistent": 0, "leftovers": 0}
    for _ in range(rounds):
        counts["rounds"] += 1
        kind = rng.choice(["SIGINT", "SIGTERM", "SIGKILL", "concurrent"])
        counts[kind] += 1
        if kind == "concurrent":
            procs = [subprocess.Popen([*CMD, "--out", str(out), "--steps", str(rng.randint(50, 3000))],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                      preexec_fn=_default_sigint) for _ in range(3)]
            for p in procs:
                p.wait()
        else:
            p = subprocess.Popen([*CMD, "--out", str(out), "--steps", str(rng.randint(500, 400_000))],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=_default_sigint)
            if rng.random() < 0.25:  # now and then while starting up
                time.sleep(rng.uniform(0.2, 3.0))
            else:  # mostly while stepping (or writing, for a short run)
                t0 = time.time()
                while time.time() - t0 < 60 and p.poll() is None and not list(root.glob(".out.hqp-tpm-*/.columns")):
                    time.sleep(0.05)
                time.sleep(rng.uniform(0.0, 4.0))
            p.send_signal(getattr(signal, kind))
            p.wait()
        try:
            ok = consistent(out) and json.loads((out / "manifest.json").read_text())["status"] == "complete"
        except (OSError, ValueError, KeyError):
            ok = False
        if not ok:
            counts["complete_result_lost"] += 1
        part = root / "out.partial"
        if part.exists():
            counts["partial_results"] += 1
            try:
                if not consistent(part):
                    counts["inconsistent"] += 1
            except (OSError, ValueError, KeyError):
                counts["inconsistent"] += 1
            import shutil

            shutil.rmtree(part)
        stale = [q for q in root.iterdir() if q.name.startswith(".")]
        alive = [q for q in stale if kind != "SIGKILL"]
        counts["leftovers"] += len(alive)
        if kind == "SIGKILL" and stale:  # the next run must sweep the killed run's folder
            subprocess.run([*CMD, "--out", str(out), "--steps", "50"], check=True, stdout=subprocess.DEVNULL)
            counts["leftovers"] += sum(1 for q in root.iterdir() if q.name.startswith("."))
    return counts


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    print(json.dumps(main(*args)))
    os._exit(0)
