"""The MuJoCo plant's cost per control step, against the controller's own step (``[plant] kind = "mujoco"`` runs).

Per step of ``iiwa_mujoco`` (acceleration level: inverse dynamics), ``lwr_relaxed_mujoco`` (acceleration level,
Algorithm 1) and ``iiwa_comanipulation_mujoco`` (velocity level: joint impedance), in the loop a run closes:
the controller's step (its lean step where it has one, as ``hqp-tpm run``), the torque law (pinocchio ``rnea``
from the measured state), MuJoCo (``mj_step`` and the sensor sample) and handing the measurement to the
controller (``set_state``). Medians and p99 over ``--steps`` steps after ``--warmup``.

    python benchmarks/plant_step.py [--steps 2000] [--warmup 200] [--quick]

Writes ``benchmarks/results/plant_step.csv`` and ``plant_step.md``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make ``benchmarks`` importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import common  # noqa: E402
from benchmarks.common import fmt  # noqa: E402

SCENARIOS = ("iiwa_mujoco", "lwr_relaxed_mujoco", "iiwa_comanipulation_mujoco")
PARTS = ("controller step", "torque law", "MuJoCo step + sensors", "set_state")


def measure(name: str, steps: int, warmup: int) -> dict:
    from hqp_tpm.app import build, plant_run, scenario

    ctx = build.build_run(scenario.load(name))
    ctrl = ctx.controller
    plant = plant_run.build_plant(ctx)
    def step():
        return ctrl.step().command

    operator = ctx.scene.operator
    samples: dict[str, list] = {p: [] for p in PARTS}
    cpu: dict[str, list] = {p: [] for p in PARTS}
    for i in range(warmup + steps):
        w0, c0, x = common.timed(step)
        if operator is not None:
            plant.push(operator.fid, operator.force)
        w1, c1, tau = common.timed(plant.torque, x)
        w2, c2, _ = common.timed(plant.apply, tau)
        w3, c3, _ = common.timed(lambda: ctrl.set_state(*plant.measure()))
        if i >= warmup:
            for p, w, c in zip(PARTS, (w0, w1, w2, w3), (c0, c1, c2, c3), strict=True):
                samples[p].append(w)
                cpu[p].append(c)
    out = {"scenario": name, "level": ctx.scenario.level, "lean": ctrl.compiled(), "steps": steps}
    for p in PARTS:
        st = common.stats_us(samples[p], cpu[p])
        out[f"{p} median_us"], out[f"{p} p99_us"], out[f"{p} cpu_median_us"] = (st["median_us"], st["p99_us"],
                                                                                st["cpu_median_us"])
    plant_us = sum(out[f"{p} median_us"] for p in PARTS[1:])
    out["plant overhead median_us"] = plant_us
    out["plant / controller"] = plant_us / out["controller step median_us"]
    return out


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--warmup", type=int, default=200)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", type=Path, default=common.RESULTS)
    args = p.parse_args(argv)
    steps, warmup = (50, 10) if args.quick else (args.steps, args.warmup)
    with common.one_blas_thread():
        env = common.environment()
        import mujoco

        env["mujoco"] = mujoco.__version__
        env["settings"] = f"steps {steps}, warmup {warmup}"
        rows = [measure(name, steps, warmup) for name in SCENARIOS]
        common.close_environment(env)
    common.write_csv(args.out / "plant_step.csv", rows, env)
    table = common.md_table(
        ["scenario", "level", "controller step", "torque law", "MuJoCo + sensors", "set_state", "plant total",
         "plant / controller"],
        [[r["scenario"], r["level"], *(fmt(r[f"{p} median_us"]) for p in PARTS), fmt(r["plant overhead median_us"]),
          fmt(r["plant / controller"], 2)] for r in rows])
    body = (table + "\n\nMedian µs per control step (wall time; thread CPU medians in plant_step.csv), one BLAS "
            "thread. The plant's overhead is the torque law, MuJoCo and set_state; the controller step is the lean "
            "step where the scenario has one.")
    common.write_markdown(args.out / "plant_step.md", "MuJoCo plant: cost per control step", env,
                          [("Plant overhead per step", body)])
    print((args.out / "plant_step.md").read_text())
    return {"env": env, "rows": rows, "sections": [("Plant overhead per step", body)]}


if __name__ == "__main__":
    main()
