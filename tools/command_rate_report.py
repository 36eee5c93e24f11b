"""Issue 31, item 1, done-when: the command-rate bound on the three boxed Romeo scenarios, measured.

For ``romeo_sns_tpm``, ``romeo_sns`` (multi-task SNS) and ``romeo_qp`` (the cascaded QP), each with the command-rate
box (``[limits] command_rate = true``, the shipped default) and with papers/002's box (``command_rate = false``),
runs the whole scenario (``hqp-tpm run``, lean step) and writes what the issue asks for into
``tests/data/command_rate_results.json`` (``tests/test_command_rate_results.py`` reads it):

* ``max_change``: the largest change of an actuated joint's command between two 1 ms steps (rad/s; the bound is
  ``acceleration_limit * period`` = 0.05, +1e-9), and the number of steps beyond it;
* ``velocity_violations`` / ``position_violations``: (step, joint) pairs beyond the URDF limits (+1e-9);
* the task errors: max and RMS of each task's error norm (m, rad), as ``metrics.json`` gives them;
* ``prefix_max_change``: ``max_change`` over the first ``PREFIX`` steps (the test recomputes it);
* ``chatter`` (sign changes of the command's rate per joint and second, largest joint) and the wall time;
* ``left_leg``: the same largest change and steps beyond over the left leg's joints (``L{Hip,Knee,Ankle}*``);
* ``left_foot_error_max_t``: when the left foot's error is largest (s), and ``legs_max_abs_dq_there`` the legs'
  largest ``|qdot|`` at that step (rad/s);
* ``saturated_median`` / ``saturated_max`` (joints at a bound of the box per step) and ``scale_min`` (the SNS
  scale factor), where the solver records them.

Usage: ``PYTHONPATH=$PWD python tools/command_rate_report.py [--out DIR [--reuse]]`` (DIR keeps the runs).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "tests" / "data" / "command_rate_results.json"
SCENARIOS = ("romeo_sns_tpm", "romeo_sns", "romeo_qp")
TOL = 1e-9
#: the first steps whose largest change is also recorded (a test recomputes it: the file is this code's)
PREFIX = 300


def variant(name: str, rate: bool):
    """The shipped scenario with ``[limits] command_rate`` set (parsed, named as the file with the box)."""
    from hqp_tpm.app import scenario

    data = scenario.read(scenario.resolve_path(name))
    data["limits"]["command_rate"] = rate
    return scenario.parse(data, Path(f"{name}[command_rate={str(rate).lower()}]"))


def measure(run_dir: Path, name: str, rate: bool) -> dict:
    """The numbers of one run folder (module doc)."""
    from hqp_tpm.app.build import build_run

    lim = build_run(variant(name, rate)).limits
    cols, a_dt = lim.cols, float(lim.a_max.max() * lim.dt)
    traj = np.load(run_dir / "trajectory.npz")
    metrics = json.loads((run_dir / "metrics.json").read_text())
    dq, qa = traj["dq"][:, cols], traj["q"][:, lim.qidx]
    change = np.abs(np.diff(dq, axis=0))
    lo, up = lim.robot.position_limits()
    pos_viol = int(((qa < lo[cols] - TOL) | (qa > up[cols] + TOL)).sum())
    v_lim = lim.robot.velocity_limits()[cols]
    names = [str(n) for n in traj["joint_names"]]
    leg = [i for i, n in enumerate(names) if n[1:].startswith(("Hip", "Knee", "Ankle"))]
    left = [i for i, n in enumerate(names) if n.startswith(("LHip", "LKnee", "LAnkle"))]
    left_change = np.abs(np.diff(traj["dq"][:, left], axis=0))
    foot = np.linalg.norm(traj["error_left_foot"], axis=1)
    at = int(foot.argmax())
    solver = {}
    if "saturated" in traj.files:
        sat = traj["saturated"][:, cols].sum(axis=1)
        solver.update(saturated_median=float(np.median(sat)), saturated_max=int(sat.max()))
    if "scale" in traj.files:
        solver["scale_min"] = float(traj["scale"].min())
    errors = {k: v for k, v in metrics.items() if k.startswith("error_") and (k.endswith("_max") or k.endswith("_rms"))}
    return {
        "scenario": name, "command_rate": rate, "steps": int(dq.shape[0]), "bound": a_dt,
        "max_change": float(change.max()),
        "prefix_steps": PREFIX, "prefix_max_change": float(change[:PREFIX - 1].max()),
        "steps_beyond": int((change > a_dt + TOL).any(axis=1).sum()),
        "velocity_violations": int((np.abs(dq) > v_lim + TOL).sum()), "position_violations": pos_viol,
        "max_abs_dq": float(np.abs(dq).max()), "chatter": metrics.get("chatter"),
        "errors": errors, "wall_time_s": round(metrics["wall_time_s"], 1),
        "left_leg": {"max_change": float(left_change.max()),
                     "steps_beyond": int((left_change > a_dt + TOL).any(axis=1).sum())},
        "left_foot_error_max_t": float(traj["t"][at]),
        "legs_max_abs_dq_there": float(np.abs(traj["dq"][at, leg]).max()),
        **solver,
    }


def main(argv=None) -> None:
    from hqp_tpm.app.cli import run_scenario

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="keep the runs here (default: a temporary folder)")
    ap.add_argument("--reuse", action="store_true", help="measure the complete runs already in --out, run the rest")
    args = ap.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="command_rate_"))
    rows = []
    for name in SCENARIOS:
        for rate in (True, False):
            d = out / f"{name}_{'rate' if rate else 'paper'}"
            if not (args.reuse and (d / "metrics.json").is_file()):
                run_scenario(variant(name, rate), d, progress=False, figures=False, replay=False, force=True)
            rows.append(measure(d, name, rate))
            print(json.dumps(rows[-1]))
    RESULTS.write_text(json.dumps({
        "command": "PYTHONPATH=$PWD python tools/command_rate_report.py",
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "runs": rows}, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
