"""The first run on a machine and short scripts (issue 29 item 3), each in a fresh process.

    python benchmarks/first_run.py [--steps 200] [--script-steps 1000]

1. ``hqp-tpm run lwr_relaxed --steps N`` with an empty numba cache (``NUMBA_CACHE_DIR`` a new temporary folder:
   every kernel the run uses is compiled), then again on that cache (loaded): the process's CPU time (user +
   system, of the child), whether the compile notice was printed, and the run's ``compile_s``, ``wall_time_s`` and
   ``mean_step_us`` (metrics.json: compiling is kept out of the last two).
2. A warm process's kernel load: a short script (iiwa 7, EE pose > posture, ``ctrl.step()``) on a cache of its own,
   first empty (its kernels compiled), then warm: the CPU time of its first step (kernels compiled or loaded there)
   and :func:`hqp_tpm._jit.compile_seconds`.
3. The same script for ``--script-steps`` steps with the kernels on and with ``HQP_TPM_COMPILED=0``: the process's
   CPU time (import, set-up and steps), the numbers a user of a short script sees.

Writes ``benchmarks/results/first_run.md``. Absolute times depend on the machine's load (stated).
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import common  # noqa: E402

SCRIPT = r"""
import sys, time
t0 = time.process_time()
import numpy as np
import pinocchio as pin
from hqp_tpm import Controller, FramePose, Gains, Posture, Robot, Stack, _jit
robot = Robot.load("iiwa7")
q0 = np.array([0.0, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0])
data = robot.model.createData()
pin.framesForwardKinematics(robot.model, data, q0)
M = data.oMf[robot.frame_id("iiwa_ee")].copy()
M.translation[0] += 0.05
ctrl = Controller(robot, Stack.of(FramePose(robot, "iiwa_ee", M, Gains(10.0)), Posture(robot, q0, Gains(1.0))),
                  dt=1e-3, q0=q0)
t1 = time.process_time()
ctrl.step()
t2 = time.process_time()
for _ in range(int(sys.argv[1]) - 1):
    ctrl.step()
t3 = time.process_time()
print({"setup_cpu_s": t1 - t0, "first_step_cpu_s": t2 - t1, "steps_cpu_s": t3 - t1,
       "kernels_s": _jit.compile_seconds(), "compiled": bool(_jit.ENABLED)})
"""


def child(cmd: list[str], env: dict[str, str]) -> tuple[float, subprocess.CompletedProcess]:
    """Run ``cmd``; the child's CPU seconds (user + system) and its result."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1800, check=False)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if out.returncode != 0:
        raise RuntimeError(f"{cmd} failed: {out.stderr[-2000:]}")
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--script-steps", type=int, default=1000)
    ap.add_argument("--out", type=Path, default=common.RESULTS / "first_run.md")
    args = ap.parse_args(argv)
    env0 = common.environment()
    base = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != "HQP_TPM_COMPILED"}
    base["PYTHONPATH"] = str(common.ROOT) + os.pathsep + base.get("PYTHONPATH", "")
    base["OMP_NUM_THREADS"] = base["OPENBLAS_NUM_THREADS"] = "1"
    rows_run, rows_script = [], []
    with tempfile.TemporaryDirectory(prefix="hqp-tpm-first-run-") as tmp:
        env = {**base, "NUMBA_CACHE_DIR": str(Path(tmp) / "cache")}
        for what in ("cold (empty cache)", "warm (same cache)"):
            common.progress(f"run lwr_relaxed, {what}")
            out = Path(tmp) / what.split()[0]
            cpu, res = child([sys.executable, "-m", "hqp_tpm.app.cli", "run", "lwr_relaxed", "--steps",
                              str(args.steps), "--out", str(out), "--quiet"], env)
            m = json.loads((out / "metrics.json").read_text())
            rows_run.append([what, f"{cpu:.1f}", "yes" if "compiling kernels" in res.stderr else "no",
                             f"{m.get('compile_s', float('nan')):.2f}", f"{m['wall_time_s']:.3f}",
                             f"{m['mean_step_us']:.0f}"])
        script_env = {**base, "NUMBA_CACHE_DIR": str(Path(tmp) / "script-cache")}  # (its own kernels: lean step)
        for what, extra in (("compiled (empty cache)", {}), ("compiled (warm cache)", {}),
                            ("HQP_TPM_COMPILED=0", {"HQP_TPM_COMPILED": "0"})):
            common.progress(f"{args.script_steps}-step script, {what}")
            cpu, res = child([sys.executable, "-c", SCRIPT, str(args.script_steps)], {**script_env, **extra})
            r = ast.literal_eval(res.stdout.strip().splitlines()[-1])
            rows_script.append([what, f"{cpu:.2f}", f"{r['setup_cpu_s']:.2f}", f"{r['first_step_cpu_s']:.3f}",
                                f"{r['kernels_s']:.3f}", f"{r['steps_cpu_s']:.3f}"])
    common.close_environment(env0)
    run_table = common.md_table([f"`hqp-tpm run lwr_relaxed --steps {args.steps}`", "process CPU s",
                                 "compile notice", "compile_s", "wall_time_s", "mean_step_us"], rows_run)
    script_table = common.md_table([f"{args.script_steps}-step script (iiwa 7, `ctrl.step()`)", "process CPU s",
                                    "import + set-up CPU s", "first step CPU s (kernels made)",
                                    "kernels made, wall s", "steps CPU s"], rows_script)
    common.write_markdown(args.out, "The first run and short scripts", env0, [
        ("The first run (fresh processes, `NUMBA_CACHE_DIR` a new empty folder, then the same again)", run_table),
        ("A short script, kernels on (warm cache) and off", script_table),
    ])
    common.progress(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
