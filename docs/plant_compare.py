"""The README's first controller at acceleration level, kinematic vs on the MuJoCo plant: EE error over time.

    python docs/plant_compare.py [--out docs/img/plant_iiwa_ee_error.png] [--runs DIR]

Runs ``iiwa_first_controller`` (the controller integrates its own qdd), ``iiwa_mujoco`` (torques by inverse
dynamics into MuJoCo) and ``iiwa_mujoco`` with armature 0.01 kg m² and joint damping 0.1 N m s/rad that the
controller does not model, each 4 s (4,001 steps, a few seconds), and plots the norm of the EE position error
of the three. Prints the error at the last step and the largest of each run.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from hqp_tpm.app import scenario
from hqp_tpm.app.cli import run_scenario

ROOT = Path(__file__).resolve().parents[1]

RUNS = (("iiwa_first_controller", None, "kinematic (perfect integration)"),
        ("iiwa_mujoco", None, "MuJoCo, inverse dynamics"),
        ("iiwa_mujoco", {"armature": 0.01, "damping": 0.1}, "MuJoCo + armature 0.01, damping 0.1 (unmodelled)"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs/img/plant_iiwa_ee_error.png")
    ap.add_argument("--runs", type=Path, default=None, help="keep the runs in this folder (default: a temporary one)")
    args = ap.parse_args()
    fig = Figure(figsize=(8, 3.6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(111)
    with tempfile.TemporaryDirectory() as tmp:
        base = args.runs or Path(tmp)
        for i, (name, extra, label) in enumerate(RUNS):
            path = scenario.resolve_path(name)
            data = scenario.read(path)
            if extra:
                data["plant"] = {**data["plant"], **extra}
            sc = scenario.parse(data, path)
            out = base / f"{name}_{i}"
            run_scenario(sc, out, progress=False, figures=False, replay=False, force=True)
            z = np.load(out / "trajectory.npz")
            e = 1e3 * np.linalg.norm(z["ee_error"], axis=1)
            print(f"{label}: EE error at the last step {e[-1]:.4f} mm, largest {e.max():.3f} mm "
                  f"(at t = {z['t'][e.argmax()]:.3f} s), largest after 1 s {e[z['t'] >= 1.0].max():.4f} mm")
            ax.semilogy(z["t"], e, label=label, lw=1.2)
    ax.set_ylim(5e-3, 30.0)  # (the error starts at 0: the circle starts at the EE)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("EE position error [mm]")
    ax.set_title("iiwa, EE circle > 10° cone > posture at acceleration level (TPM)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
