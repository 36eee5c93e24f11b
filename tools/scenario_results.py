"""Collect the papers' scenario runs into one results file the documentation quotes and its tests read.

    hqp-tpm run SCENARIO --out RUNS/SCENARIO ...      (or `make scenarios`, RUNS = runs)
    python tools/scenario_results.py RUNS [--out benchmarks/results/scenarios.json]

Per scenario: its ``metrics.json`` (numbers, flattened: ``time_in_stack_s.ee > pointing``), and, for the Romeo
runs, the steps with a joint over its URDF velocity limit and the largest excess (from ``trajectory.npz``).
The reproduction tables of docs/reproductions.md are generated from this file (tools/docs_site.py).
"""

from __future__ import annotations

import argparse
import json
import subprocess
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

SCENARIOS = ["lwr_relaxed", "lwr_velocity", "lwr_avoid3d", "lwr_point35_equality", "lwr_point35_inequality",
             "lwr_tracking", "romeo_tpm", "romeo_sns_tpm", "romeo_sns", "romeo_qp", "romeo_obstacles_sns_tpm",
             "romeo_obstacles_qp", "iiwa_comanipulation", "iiwa_admittance", "planar5_exact", "planar5_approximate",
             "planar5_two_obstacles", "planar5_primary", "planar5_transition", "planar5_pwdls", "planar5_dmp",
             "iiwa_first_controller", "iiwa_mujoco", "lwr_relaxed_mujoco", "iiwa_comanipulation_mujoco",
             "romeo_standing", "talos_sns_tpm"]


def flatten(obj, prefix=""):
    """The numbers (and strings) of a metrics dict, nested keys joined by dots."""
    out = {}
    for key, value in obj.items():
        name = f"{prefix}{key}"
        if key == "units":
            continue
        if isinstance(value, dict):
            out.update(flatten(value, name + "."))
        elif isinstance(value, (int, float, str, bool)) or value is None:
            out[name] = value
    return out


def collect(runs: Path) -> dict:
    from hqp_tpm.robot.model import Robot

    result = {}
    vlim = None
    for name in SCENARIOS:
        path = runs / name / "metrics.json"
        if not path.exists():
            continue
        m = flatten(json.loads(path.read_text()))
        if name.startswith("romeo_") and name != "romeo_standing":
            vlim = Robot.load("romeo21").velocity_limits() if vlim is None else vlim
            dq = np.load(runs / name / "trajectory.npz")["dq"]
            excess = np.abs(dq) - vlim
            m["velocity_limit_steps"] = int((excess > 1e-9).any(axis=1).sum())
            m["velocity_limit_excess_max"] = float(max(0.0, excess.max()))
        result[name] = m
    return result


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", type=Path)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "scenarios.json")
    args = p.parse_args(argv)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    doc = {"written_by": "python tools/scenario_results.py " + str(args.runs.name),
           "runs": "hqp-tpm run SCENARIO --no-figures --no-replay --quiet (one BLAS thread)",
           "code": commit.stdout.strip(), "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
           "scenarios": collect(args.runs)}
    args.out.write_text(json.dumps(doc, indent=1, sort_keys=False) + "\n", encoding="utf-8")
    print(f"wrote {args.out} ({len(doc['scenarios'])} scenarios)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
