"""papers/003 Figs. 5-7 from two runs: the switching hierarchy (blue) and the admittance baseline (red).

    hqp-tpm run iiwa_comanipulation --out runs/iiwa_comanipulation
    hqp-tpm run iiwa_admittance --out runs/iiwa_admittance
    python docs/comanipulation_compare.py [runs] [--out docs/img/iiwa_comanipulation_vs_admittance.png]

Prints the numbers of both runs (the interaction window is 0.5-12 s: from the operator's first touch
until the admittance run has reached its last marker).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from hqp_tpm.app.figures import comanipulation

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("runs", nargs="?", type=Path, default=ROOT / "runs")
    ap.add_argument("--out", type=Path, default=ROOT / "docs/img/iiwa_comanipulation_vs_admittance.png")
    args = ap.parse_args()
    runs = {}
    for stem, label in (("iiwa_comanipulation", "hierarchy (switching)"), ("iiwa_admittance", "admittance")):
        runs[label] = dict(np.load(args.runs / stem / "trajectory.npz"))
        m = json.loads((args.runs / stem / "metrics.json").read_text())
        a = runs[label]
        w = (a["t"] >= 0.5) & (a["t"] <= 12.0)
        print(f"{stem}: sigma_m min {m['sigma_m_min']:.3f}, mean (0.5-12 s) {a['sigma_m'][w].mean():.3f}, "
              f"below 1.5 for {m['sigma_m_below_threshold_s']:.2f} s; sigma_l max {m['sigma_l_max']:.4f}, "
              f"mean (0.5-12 s) {a['sigma_l'][w].mean():.4f}; max |q_i - q_i*| {m['joint_deviation_max']:.3f} rad, "
              f"closest to a limit {m['joint_limit_margin_min']:.4f} rad; markers reached {m['markers_reached']}, "
              f"given up {m['markers_skipped']}; largest qd step {m['max_dq_jump']:.3f} rad/s")
    comanipulation(args.out, runs, title="papers/003 Figs. 5-7: hierarchy vs admittance (iiwa 7)")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
