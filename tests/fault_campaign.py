"""Fault injection on the output folder (not collected by pytest; the README quotes its numbers).

    python tests/fault_campaign.py [ROUNDS] [SEED]

Each round starts ``hqp-tpm run planar5_exact`` into one folder that holds a complete result, then either
sends SIGINT, SIGTERM or SIGKILL after a random delay (while building, stepping or writing), or starts three
runs into the folder at once. After each round the folder must hold a complete, consistent result (manifest,
metrics.json, trajectory.npz agreeing), a ``.partial`` sibling (if any) must be consistent too, and no
temporary folder may remain once the next run has started (a SIGKILLed run's folder is removed by the next).

Issue 31 adds three kinds of round: ``fsize`` (a run under a random file-size limit, ``ulimit -f``: exit 2 with
an ``OutputError``, no traceback, the result as it was), ``symlink`` (the run through a symbolic link to the
folder: the link stays, nothing hidden is left beside it) and ``sweep_kill`` (a two-worker ``hqp-tpm sweep``
sent SIGKILL, SIGTERM or SIGHUP: no worker may outlive it by 10 s, counted in ``orphaned_workers``).
"""

from __future__ import annotations

import json
import os
import random
import shutil
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


def _limit_file_size(nbytes: int):
    def apply() -> None:
        import resource

        _default_sigint()
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
    return apply


def _children(pid: int) -> list[int]:
    out = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                if int((p / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    out.append(int(p.name))
            except (OSError, ValueError, IndexError):
                continue
    return out


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def sweep_kill(root: Path, rng: random.Random) -> int:
    """A sweep sent a fatal signal while its workers step: the number of workers alive 10 s later."""
    sw = root / "sweep"
    cmd = [sys.executable, "-m", "hqp_tpm.app.cli", "sweep", "planar5_exact", "--set", "policy.d_m=0.15,0.25",
           "--steps", "5000000", "--workers", "2", "--out", str(sw), "--quiet"]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=_default_sigint)
    t0 = time.time()
    while time.time() - t0 < 120 and p.poll() is None and not list(sw.glob(".v00*.hqp-tpm-*/.columns")):
        time.sleep(0.05)
    time.sleep(rng.uniform(0.0, 2.0))
    workers = _children(p.pid)
    p.send_signal(rng.choice([signal.SIGKILL, signal.SIGTERM, signal.SIGHUP]))
    try:
        p.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        pass
    deadline = time.time() + 10
    while time.time() < deadline and any(_alive(w) for w in workers):
        time.sleep(0.1)
    left = [w for w in workers if _alive(w)]
    for w in [*left, p.pid]:
        try:
            os.kill(w, signal.SIGKILL)
        except OSError:
            pass
    p.wait()
    return len(left)


def main(rounds: int = 20, seed: int = 0) -> dict:
    rng = random.Random(seed)
    root = Path(tempfile.mkdtemp(prefix="hqp-tpm-faults-"))
    out = root / "out"
    subprocess.run([*CMD, "--out", str(out), "--steps", "200"], check=True, stdout=subprocess.DEVNULL)
    counts = {"rounds": 0, "SIGINT": 0, "SIGTERM": 0, "SIGKILL": 0, "concurrent": 0, "partial_results": 0,
              "complete_result_lost": 0, "inconsistent": 0, "leftovers": 0, "fsize": 0, "untyped_errors": 0,
              "symlink": 0, "link_lost": 0, "sweep_kill": 0, "orphaned_workers": 0}
    link = root / "links" / "out"
    link.parent.mkdir()
    link.symlink_to(out, target_is_directory=True)
    for _ in range(rounds):
        counts["rounds"] += 1
        kind = rng.choice(["SIGINT", "SIGTERM", "SIGKILL", "concurrent", "fsize", "symlink", "sweep_kill"])
        counts[kind] += 1
        if kind == "sweep_kill":
            counts["orphaned_workers"] += sweep_kill(root, rng)
        elif kind == "fsize":
            p = subprocess.run([*CMD, "--out", str(out), "--steps", str(rng.randint(50, 3000))], capture_output=True,
                               text=True, preexec_fn=_limit_file_size(rng.randint(1_000, 60_000)))
            if p.returncode not in (0, 2) or "Traceback" in p.stderr or (p.returncode and "OutputError" not in
                                                                           _error_type(p.stderr)):
                counts["untyped_errors"] += 1
        elif kind == "symlink":
            subprocess.run([*CMD, "--out", str(link), "--steps", str(rng.randint(50, 500))], check=True,
                           stdout=subprocess.DEVNULL)
            if not link.is_symlink() or [q for q in link.parent.iterdir() if q.name.startswith(".")]:
                counts["link_lost"] += 1
        elif kind == "concurrent":
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
            shutil.rmtree(part)
        shutil.rmtree(root / "sweep", ignore_errors=True)
        stale = [q for q in root.iterdir() if q.name.startswith(".")]
        alive = [q for q in stale if kind != "SIGKILL"]
        counts["leftovers"] += len(alive)
        if kind == "SIGKILL" and stale:  # the next run must sweep the killed run's folder
            subprocess.run([*CMD, "--out", str(out), "--steps", "50"], check=True, stdout=subprocess.DEVNULL)
            counts["leftovers"] += sum(1 for q in root.iterdir() if q.name.startswith("."))
    return counts


def _error_type(stderr: str) -> str:
    """``OutputError`` when the message is the one of a write that failed for lack of room (exit code 2)."""
    return "OutputError" if "cannot write the result to" in stderr else stderr[-200:]


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    print(json.dumps(main(*args)))
    os._exit(0)
