"""Print the old README's LWR and Romeo tables from the runs of `make scenarios` (default folder: runs/).

    python docs/results_tables.py [RUNS_DIR]

The documentation's tables are generated instead (docs/reproductions.md, from benchmarks/results/scenarios.json,
which `python tools/scenario_results.py RUNS_DIR` writes).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from hqp_tpm.robot.model import Robot

LWR = ["lwr_relaxed", "lwr_velocity", "lwr_avoid3d", "lwr_point35_equality", "lwr_point35_inequality"]
ROMEO = ["romeo_tpm", "romeo_sns_tpm", "romeo_sns", "romeo_qp"]


def load(root: Path, name: str):
    m = json.loads((root / name / "metrics.json").read_text())
    d = np.load(root / name / "trajectory.npz")
    return m, d


def lwr_table(root: Path) -> str:
    rows = ["| run | max / RMS EE error [mm] | max pointing violation [deg] | min D_minimal [m] | min D_ee [m] | "
            "largest step of qdot [rad/s] | stack changes | wall time [s] |", "|---|---|---|---|---|---|---|---|"]
    for name in LWR:
        if not (root / name / "metrics.json").exists():
            continue
        m, _ = load(root, name)
        rows.append(f"| `{name}` | {1e3 * m['ee_error_max']:.1f} / {1e3 * m['ee_error_rms']:.1f} | "
                    f"{m.get('pointing_violation_max_deg', 0):.2f} | {m['d_minimal_min']:.4f} | {m['d_ee_min']:.4f} | "
                    f"{m['max_dq_jump']:.4f} | {m['stack_changes']} | {m['wall_time_s']:.1f} |")
    return "\n".join(rows)


def romeo_table(root: Path) -> str:
    v = Robot.load("romeo21").velocity_limits()
    rows = ["| run | CoM / left foot / left hand / right hand max error [mm] | right sole [mm] | min scale | "
            "steps with a joint over its velocity limit | max excess [rad/s] | mean step [us] |",
            "|---|---|---|---|---|---|---|"]
    for name in ROMEO:
        if not (root / name / "metrics.json").exists():
            continue
        m, d = load(root, name)
        excess = np.abs(d["dq"]) - v
        bad = int((excess > 1e-9).any(axis=1).sum())
        errs = " / ".join(f"{1e3 * m[f'error_{k}_max']:.1f}" for k in ("com", "left_foot", "left_hand", "right_hand"))
        rows.append(f"| `{name}` | {errs} | {1e3 * m['error_right_sole_position_max']:.2f} | "
                    f"{m.get('scale_min', 1.0):.3f} | {bad} of {int(m['steps'])} | {max(0.0, excess.max()):.3g} | "
                    f"{m['mean_step_us']:.0f} |")
    return "\n".join(rows)


if __name__ == "__main__":
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "runs")
    print(lwr_table(root))
    print()
    print(romeo_table(root))
