"""The first run on a machine and short scripts (issue 29 item 3), each in a fresh process.

    python benchmarks/first_run.py [--steps 200] [--script-steps 1000] [--repeat 3] [--ab OLD_CHECKOUT]

1. ``hqp-tpm run lwr_relaxed --steps N`` with an empty numba cache (``NUMBA_CACHE_DIR`` a new temporary folder each
   time: every kernel the run uses is compiled), then on that cache (loaded), ``--repeat`` times each, interleaved:
   the process's CPU time (user + system, of the child; median, min, max), whether the compile notice was printed,
   and the run's ``compile_s``, ``wall_time_s`` and ``mean_step_us`` (metrics.json, medians: compiling is kept out
   of the last two).
2. A short script (iiwa 7, EE pose > posture, ``ctrl.step()``) on a cache of its own, once with that cache empty (its
   kernels compiled), then ``--repeat`` pairs of fresh processes, compiled (warm cache) and ``HQP_TPM_COMPILED=0``
   in turn: the process's CPU time (import, set-up, steps and exit), the CPU time of the first step (kernels loaded
   there) and :func:`hqp_tpm._jit.compile_seconds`; medians, and the median of the pairs' CPU ratio compiled /
   numpy (pairs: the ratio holds when the machine's speed drifts).

``--kernels``: where a cold run's CPU goes, kernel by kernel: ``--repeat`` more cold runs (of the other checkout and
this one in turn with ``--ab``), each with numba's ``numba:compile`` events listened to (numba imported first, then the
CLI run in that process): the thread CPU of each compile less the compiles it started (the kernels it calls, numba's
own numpy implementations), per function compiled; medians.

``--ab OLD_CHECKOUT`` (a directory with an earlier commit's files, ``git archive COMMIT | tar -x -C DIR``): also the
cold run of that checkout and of this one in turn, ``--repeat`` pairs, each with an empty cache of its own: process
CPU medians and the median of the pairs' ratio (the machine's load drifts; pairs run back to back).

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

import numpy as np  # noqa: E402

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

#: A cold ``hqp-tpm run`` in this process with numba's compile events listened to: per compiled function, the thread
#: CPU of its compiles less the compiles they started (argv: steps, output folder); one JSON line.
PROFILE = r"""
import collections, json, runpy, sys, time
from numba.core import event
stack, own, count = [], collections.defaultdict(float), collections.Counter()
class Compiles(event.Listener):
    def on_start(self, ev):
        f = getattr(ev.data.get("dispatcher"), "py_func", None)
        name = getattr(f, "__module__", "?") + "." + getattr(f, "__qualname__", "?")
        stack.append([name, time.thread_time(), 0.0])
    def on_end(self, ev):
        name, t0, inner = stack.pop()
        dt = time.thread_time() - t0
        own[name] += dt - inner
        count[name] += 1
        if stack:
            stack[-1][2] += dt
event.register("numba:compile", Compiles())
sys.argv = ["hqp-tpm", "run", "lwr_relaxed", "--steps", sys.argv[1], "--quiet", "--out", sys.argv[2]]
try:
    runpy.run_module("hqp_tpm.app.cli", run_name="__main__")
except SystemExit:
    pass
print(json.dumps({"own": own, "count": count, "process": time.process_time()}))
"""


def kernel_name(name: str) -> str:
    """A compiled function's name in the table: the package's kernels by module and name, numba's own numpy
    implementations (``np.empty``, ``np.dot``, ...) together."""
    return name.removeprefix("hqp_tpm.") if name.startswith("hqp_tpm.") else "numba's numpy implementations"


def child(cmd: list[str], env: dict[str, str], cwd=None) -> tuple[float, subprocess.CompletedProcess]:
    """Run ``cmd`` (in ``cwd``); the child's CPU seconds (user + system) and its result."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1800, check=False, cwd=cwd)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if out.returncode != 0:
        raise RuntimeError(f"{cmd} failed: {out.stderr[-2000:]}")
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), out


def median(values):
    return float(np.median(values)) if values else float("nan")


def spread(values, digits=2) -> str:
    """``median (min-max)`` of ``values``."""
    return f"{median(values):.{digits}f} ({min(values):.{digits}f}-{max(values):.{digits}f})"


def checkout_name(path: Path) -> str:
    """The other checkout as the results file names it: its commit (a git checkout) or its folder's name (no local
    paths in the repository's files)."""
    proc = subprocess.run(["git", "-C", str(path), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return f"commit `{proc.stdout.strip()}`" if proc.returncode == 0 else f"`{path.name}` (a copy)"


def shown_argv(args) -> list[str]:
    """``sys.argv`` with the other checkout's path shown as ``OLD_CHECKOUT``."""
    return ["OLD_CHECKOUT" if args.ab is not None and a == str(args.ab) else a for a in sys.argv]


def kernel_table(kernels: dict[str, list[dict]], ab: bool) -> str:
    """Per compiled function (:func:`kernel_name`), the median over the runs of its own compile CPU (a run that did
    not compile it counts 0); then all compiles and the process CPU of those runs."""
    sides = ("old", "new") if ab else ("new",)
    grouped = {sd: [] for sd in sides}  # per side, per run: {name: seconds}
    for sd in sides:
        for run in kernels[sd]:
            g: dict[str, float] = {}
            for name, sec in run["own"].items():
                g[kernel_name(name)] = g.get(kernel_name(name), 0.0) + sec
            grouped[sd].append(g)
    names = {name for sd in sides for g in grouped[sd] for name in g}
    per = {name: {sd: median([g.get(name, 0.0) for g in grouped[sd]]) for sd in sides} for name in names}
    rows = [[f"`{name}`"] + [f"{per[name][sd]:.2f}" if per[name][sd] else "-" for sd in sides]
            for name in sorted(names, key=lambda k: -max(per[k].values()))]
    rows.append(["all compiles"] + [f"{median([sum(r['own'].values()) for r in kernels[sd]]):.2f}" for sd in sides])
    rows.append(["process CPU of these runs"] + [f"{median([r['process'] for r in kernels[sd]]):.2f}" for sd in sides])
    return common.md_table(["compiled function", *(f"{sd}: own compile CPU s" for sd in sides)], rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--script-steps", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=3, help="cold and warm runs, and script pairs (medians)")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "first_run.md")
    ap.add_argument("--ab", type=Path, metavar="OLD_CHECKOUT", help="cold runs of that checkout and this one in turn")
    ap.add_argument("--kernels", action="store_true", help="also the cold run's compile CPU kernel by kernel")
    args = ap.parse_args(argv)
    env0 = common.environment()
    base = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != "HQP_TPM_COMPILED"}
    base["PYTHONPATH"] = str(common.ROOT) + os.pathsep + base.get("PYTHONPATH", "")
    base["OMP_NUM_THREADS"] = base["OPENBLAS_NUM_THREADS"] = "1"
    runs = {"cold (empty cache)": [], "warm (same cache)": []}
    pairs = {"old": [], "new": []}
    with tempfile.TemporaryDirectory(prefix="hqp-tpm-first-run-") as tmp:
        for i in range(args.repeat if args.ab else 0):  # cold runs of the old checkout and this one, in turn
            for which, root in (("old", args.ab.resolve()), ("new", common.ROOT)):
                common.progress(f"cold run A/B, {which} ({root}), {i + 1}/{args.repeat}")
                env = {**base, "NUMBA_CACHE_DIR": str(Path(tmp) / f"ab-{which}{i}"),
                       "PYTHONPATH": str(root) + os.pathsep + os.environ.get("PYTHONPATH", "")}
                pairs[which].append(child([sys.executable, "-m", "hqp_tpm.app.cli", "run", "lwr_relaxed", "--steps",
                                           str(args.steps), "--quiet", "--out", str(Path(tmp) / f"ab{which}{i}")],
                                          env, cwd=root)[0])  # (python -m puts the working directory first)
        kernels: dict[str, list[dict]] = {"old": [], "new": []}
        for i in range(args.repeat if args.kernels else 0):  # the cold run's compiles, kernel by kernel
            for which, root in ((("old", args.ab.resolve()),) if args.ab else ()) + (("new", common.ROOT),):
                common.progress(f"cold run, compiles kernel by kernel, {which}, {i + 1}/{args.repeat}")
                env = {**base, "NUMBA_CACHE_DIR": str(Path(tmp) / f"k-{which}{i}"),
                       "PYTHONPATH": str(root) + os.pathsep + os.environ.get("PYTHONPATH", "")}
                res = child([sys.executable, "-c", PROFILE, str(args.steps), str(Path(tmp) / f"k{which}{i}")], env,
                            cwd=root)[1]
                kernels[which].append(json.loads(res.stdout.strip().splitlines()[-1]))
        for i in range(args.repeat):
            env = {**base, "NUMBA_CACHE_DIR": str(Path(tmp) / f"cache{i}")}
            for what in runs:
                common.progress(f"run lwr_relaxed, {what}, {i + 1}/{args.repeat}")
                out = Path(tmp) / f"{what.split()[0]}{i}"
                cpu, res = child([sys.executable, "-m", "hqp_tpm.app.cli", "run", "lwr_relaxed", "--steps",
                                  str(args.steps), "--out", str(out)], env)  # (not --quiet: its notice)
                m = json.loads((out / "metrics.json").read_text())
                runs[what].append((cpu, "compiling kernels" in res.stderr, m.get("compile_s", float("nan")),
                                   m["wall_time_s"], m["mean_step_us"]))
        script_env = {**base, "NUMBA_CACHE_DIR": str(Path(tmp) / "script-cache")}  # (its own kernels: lean step)
        common.progress(f"{args.script_steps}-step script, compiled (empty cache)")
        script = {"compiled (empty cache)": [child([sys.executable, "-c", SCRIPT, str(args.script_steps)],
                                                   script_env)],
                  "compiled (warm cache)": [], "HQP_TPM_COMPILED=0": []}
        for i in range(args.repeat):
            for what, extra in (("compiled (warm cache)", {}), ("HQP_TPM_COMPILED=0", {"HQP_TPM_COMPILED": "0"})):
                common.progress(f"{args.script_steps}-step script, {what}, {i + 1}/{args.repeat}")
                script[what].append(child([sys.executable, "-c", SCRIPT, str(args.script_steps)],
                                          {**script_env, **extra}))
    common.close_environment(env0)
    rows_run = [[what, spread([r[0] for r in rs], 1), "yes" if all(r[1] for r in rs) else
                 ("no" if not any(r[1] for r in rs) else "some"), f"{median([r[2] for r in rs]):.2f}",
                 f"{median([r[3] for r in rs]):.3f}", f"{median([r[4] for r in rs]):.0f}"] for what, rs in runs.items()]
    rows_script = []
    for what, results in script.items():
        parsed = [(cpu, ast.literal_eval(res.stdout.strip().splitlines()[-1])) for cpu, res in results]
        rows_script.append([what, spread([c for c, _ in parsed]),
                            f"{median([r['setup_cpu_s'] for _, r in parsed]):.2f}",
                            f"{median([r['first_step_cpu_s'] for _, r in parsed]):.3f}",
                            f"{median([r['kernels_s'] for _, r in parsed]):.3f}",
                            f"{median([r['steps_cpu_s'] for _, r in parsed]):.3f}"])
    ratios = [a[0] / b[0] for a, b in zip(script["compiled (warm cache)"], script["HQP_TPM_COMPILED=0"],
                                                  strict=True)]
    run_table = common.md_table([f"`hqp-tpm run lwr_relaxed --steps {args.steps}`",
                                 f"process CPU s, median (min-max) of {args.repeat}", "compile notice",
                                 "compile_s", "wall_time_s", "mean_step_us"], rows_run)
    script_table = common.md_table([f"{args.script_steps}-step script (iiwa 7, `ctrl.step()`)",
                                    "process CPU s, median (min-max)", "import + set-up CPU s",
                                    "first step CPU s (kernels made)", "kernels made, wall s", "steps CPU s"],
                                   rows_script)
    script_table += (f"\n\nCompiled (warm cache) / `HQP_TPM_COMPILED=0`, process CPU, pair by pair ({len(ratios)} "
                     f"pairs, run in turn): median {median(ratios):.2f} (min {min(ratios):.2f}, max "
                     f"{max(ratios):.2f}).")
    sections = []
    if args.ab:
        ratios_ab = [b / a for a, b in zip(pairs["old"], pairs["new"], strict=True)]
        ab_table = common.md_table([f"`hqp-tpm run lwr_relaxed --steps {args.steps}`, cold",
                                    f"process CPU s, median (min-max) of {args.repeat}"],
                                   [[f"old: {checkout_name(args.ab)}", spread(pairs["old"])], ["new: this checkout",
                                                                                  spread(pairs["new"])]])
        ab_table += (f"\n\nNew / old, pair by pair: median {median(ratios_ab):.3f} (min {min(ratios_ab):.3f}, max "
                     f"{max(ratios_ab):.3f}).")
        sections.append((f"Cold runs of two checkouts in turn ({args.repeat} pairs, each an empty cache)", ab_table))
    if args.kernels:
        sections.append((f"Where a cold run's compile CPU goes (`--kernels`: {args.repeat} cold runs each, numba's "
                         "compile events; medians)", kernel_table(kernels, bool(args.ab))))
    common.write_markdown(args.out, "The first run and short scripts", env0, sections + [
        (f"The first run (fresh processes, `NUMBA_CACHE_DIR` a new empty folder, then the same again; {args.repeat} "
         "times each)", run_table),
        ("A short script, kernels on (warm cache) and off (medians; the empty-cache row: one run)", script_table),
    ], argv=shown_argv(args))
    common.progress(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
