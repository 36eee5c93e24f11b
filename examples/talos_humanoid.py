"""A floating-base humanoid in Python: Talos, feet > CoM > hands > posture, joint limits, SNS-TPM.

Kinematic only (no dynamics, no contacts): both soles are the top level, so they stay put. The same stack as
the shipped scenario ``talos_sns_tpm`` (``hqp-tpm run talos_sns_tpm``). Run from the repository root:

    python examples/talos_humanoid.py [--steps 800] [--out runs/talos_python]

It writes the folder ``hqp-tpm run`` writes (trajectory.npz, metrics.json, figures, replay.html); without
the ``app`` extra installed pass ``--no-files`` to only run and print the errors.
"""

from __future__ import annotations

import argparse

import numpy as np

import hqp_tpm
from hqp_tpm import CenterOfMass, Controller, FramePose, FramePosition, Gains, Harmonic, JointLimits, Posture, Robot


def build(dt: float = 0.005) -> Controller:
    robot = Robot.load("talos")  # example-robot-data: 32 joints on a free-flyer base
    q0 = robot.reference("half_sitting")  # its SRDF's pose (robot.references lists the names)
    k = Gains(kp=20.0)
    feet = (FramePose(robot, "left_sole_link", None, k, name="left_foot"),
            FramePose(robot, "right_sole_link", None, k, name="right_foot"))
    com = CenterOfMass(robot, None, k, axes="xy", name="com")
    circle = dict(relative=True, center=[0.1, 0.0, 0.0], cos_amplitude=[-0.1, 0.0, 0.0], omega=np.pi)
    hands = (FramePosition(robot, "gripper_left_base_link", Harmonic(**circle, sin_amplitude=[0.0, 0.0, 0.15]), k,
                           name="left_hand"),
             FramePosition(robot, "gripper_right_base_link", Harmonic(**circle, sin_amplitude=[0.0, 0.0, -0.15]), k,
                           name="right_hand"))
    posture = Posture(robot, q0, Gains(kp=5.0))  # a full q: the task reads its 32 joint angles from it
    box = JointLimits(robot, order=1, dt=dt)  # position (one step ahead) and velocity limits
    return Controller(robot, [feet, com, hands, posture], order=1, dt=dt, solver="sns_tpm", box=box, q0=q0)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=801)
    p.add_argument("--out", default="runs/talos_python")
    p.add_argument("--no-files", action="store_true", help="run only; write nothing")
    args = p.parse_args(argv)
    ctrl = build()
    if args.no_files:
        for _ in range(args.steps):
            ctrl.step()
        errors = {t.name: float(np.linalg.norm(t.tracking_error(ctrl.state, ctrl.state.t))) for t in ctrl.tasks()}
    else:
        summary = hqp_tpm.record(ctrl, args.out, steps=args.steps, name="talos_python", force=True)
        errors = {k: v for k, v in summary.items() if k.startswith("error_") and k.endswith("_max")}
        print(f"wrote {summary['out']}")
    for key, value in errors.items():
        print(f"{key}: {value:.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
