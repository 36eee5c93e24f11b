"""Merge the per-environment results of ``run.py`` into ``benchmarks/results/peers.md`` and ``peers.csv``.

    python benchmarks/peers/report.py [--dir benchmarks/results/peers]

Ratios are contender time / hqp-tpm ``tpm`` time, per configuration, measured in the same process
(so a ratio never mixes environments); the summary table takes pink from the pin 4 environment,
PlaCo from the pin 3.8 one and TSID from the pin 3.4 one, and names the environment of every cell.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks import common  # noqa: E402

ENV_ORDER = ("pin4", "pin38", "pin34")
SUMMARY_COLUMNS = (  # (column title, contender, environments to take it from, in order of preference)
    ("hqp-tpm `tpm`", "hqp-tpm tpm", ("pin4", "pin34", "pin38")),
    ("hqp-tpm `sns_tpm`", "hqp-tpm sns_tpm", ("pin4", "pin34", "pin38")),
    ("hqp-tpm cascaded QP (daqp)", "hqp-tpm qp:daqp", ("pin4", "pin34", "pin38")),
    ("pink 4.4 (weighted QP, daqp)", "pink", ("pin4", "pin38")),
    ("pink + limits", "pink + limits", ("pin4", "pin38")),
    ("pink, top as constraint", "pink, top as constraint", ("pin4", "pin38")),
    ("PlaCo 0.10 (hard > soft)", "PlaCo", ("pin38",)),
    ("PlaCo + limits", "PlaCo + limits", ("pin38",)),
    ("TSID 1.7 (HQP)", "TSID", ("pin34",)),
)
SUMMARY_ROWS = (
    ("iiwa_vel", "step", "iiwa 7, EE pose (6) > posture (7), velocity level: step (state in, targets moved, "
     "kinematics, rows, solve)"),
    ("iiwa_vel", "rows_solve", "same: rows + solve at a state already fed in (PlaCo's `solve`)"),
    ("iiwa_vel", "solve", "same: solver alone on built matrices"),
    ("romeo_vel", "step", "Romeo 27 nv, sole > CoM > foot > left hand > right hand > posture, lambda_max 0.05, "
     "eps 0.1, kp 100: step"),
    ("romeo_vel", "rows_solve", "same: rows + solve"),
    ("romeo_vel", "solve", "same: solver alone"),
    ("iiwa_acc", "step", "iiwa, acceleration level, EE priority 0 + posture: step"),
    ("iiwa_acc", "solve", "same: solver alone"),
    ("iiwa_circle_vel", "loop", "2,000-step closed loop, iiwa circle, velocity level"),
    ("iiwa_circle_acc", "loop", "2,000-step closed loop, iiwa circle, acceleration level"),
)
#: The headline: hqp-tpm's time over the reference peer's, measured in the peer's environment (issue 29's table).
HEADLINE = (  # (problem, phase, title)
    ("iiwa_vel", "step", "iiwa 7, EE pose > posture: step (state fed in, targets moved)"),
    ("iiwa_vel", "rows_solve", "iiwa 7: rows + solve (PlaCo: its `solve`, which builds its task matrices)"),
    ("romeo_vel", "step", "Romeo 27 nv, 6 levels, the library's damping and gains: step"),
    ("romeo_vel", "rows_solve", "Romeo: rows + solve (PlaCo: its `solve`)"),
    ("iiwa_circle_vel", "loop", "iiwa circle, velocity level, closed loop (per step)"),
    ("iiwa_acc", "step", "iiwa, acceleration level: step (state fed in, targets moved)"),
    ("iiwa_acc", "solve", "iiwa, acceleration level: solver alone"),
    ("iiwa_circle_acc", "loop", "iiwa circle, acceleration level, closed loop (per step)"),
)


def headline(index: dict) -> tuple[str, list[dict]]:
    """The table of hqp-tpm ``tpm`` and ``sns_tpm`` against the reference peer (median and p99 ratios, thread CPU
    time; loops: wall time per step) and its rows (for the CSV)."""
    head = ["problem", "against", "`tpm` median / p99", "`sns_tpm` median / p99", "µs: `tpm` / `sns_tpm` / peer"]
    body, out = [], []
    for prob, phase, title in HEADLINE:
        cells = {}
        for solver in ("tpm", "sns_tpm"):
            r = next((index[k] for k in index if k[1:] == (prob, phase, f"hqp-tpm {solver}")
                      and index[k].get("vs_peer")), None)
            if r is not None:
                cells[solver] = r
        if not cells:
            continue
        peer = next(iter(cells.values()))["vs_peer"]
        env = next(iter(cells.values()))["env"]
        peer_row = index.get((env, prob, phase, peer))
        key = "median_us" if phase == "loop" else "cpu_median_us"   # (a loop's steps are timed in CPU time)
        us = [f(num(cells[s], key), 1) if s in cells else "–" for s in ("tpm", "sns_tpm")]
        us.append(f(num(peer_row, key), 1) if peer_row else "–")
        body.append([title, f"{peer} [{env}]",
                     *[f"{num(cells[s], 'vs_ratio_median'):.2f}× / {num(cells[s], 'vs_ratio_p99'):.2f}×"
                       if s in cells else "–" for s in ("tpm", "sns_tpm")], " / ".join(us)])
        for s, r in cells.items():
            out.append({"problem": prob, "phase": phase, "solver": s, "against": peer, "env": env,
                        "ratio_median": num(r, "vs_ratio_median"), "ratio_p99": num(r, "vs_ratio_p99")})
    return common.md_table(head, body), out


def read(path: Path) -> tuple[dict[str, str], list[dict]]:
    env, lines = {}, []
    for line in path.read_text().splitlines():
        if line.startswith("# "):
            k, _, v = line[2:].partition(": ")
            env[k] = v
        else:
            lines.append(line)
    return env, list(csv.DictReader(lines))


def num(r: dict, k: str) -> float:
    try:
        return float(r.get(k, "") or "nan")
    except ValueError:
        return math.nan


def f(x: float, d: int = 2) -> str:
    if not math.isfinite(x):
        return "–"
    if abs(x) >= 100:
        return f"{x:,.0f}"
    if abs(x) >= 10:
        return f"{x:.1f}"
    return f"{x:.{d}f}"


def g(x: float) -> str:
    return "–" if not math.isfinite(x) else f"{x:.1e}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", type=Path, default=common.RESULTS / "peers")
    ap.add_argument("--out", type=Path, default=common.RESULTS)
    args = ap.parse_args(argv)
    envs, rows = {}, []
    for name in ENV_ORDER:
        p = args.dir / f"{name}.csv"
        if p.is_file():
            envs[name], r = read(p)
            rows += r
    if not rows:
        print(f"no results in {args.dir}", file=sys.stderr)
        return 1
    index = {(r["env"], r["problem"], r["phase"], r["contender"]): r for r in rows}

    # summary --------------------------------------------------------------------------------
    head = ["problem", *[c[0] for c in SUMMARY_COLUMNS]]
    body = []
    for prob, phase, title in SUMMARY_ROWS:
        cells, any_ = [title], False
        for _, cont, prefs in SUMMARY_COLUMNS:
            r = next((index[(e, prob, phase, cont)] for e in prefs if (e, prob, phase, cont) in index), None)
            if r is None:
                cells.append("—")
                continue
            any_ = True
            ratio = num(r, "ratio_median")
            if not math.isfinite(ratio):
                cells.append(f"failed ({r.get('failed', '')[:60]})")
                continue
            cpu = num(r, "cpu_ratio_median")
            extra = [f"CPU {cpu:.2f}"] if math.isfinite(cpu) else []
            if math.isfinite(num(r, "ratio_p99")):
                extra.append(f"p99 {num(r, 'ratio_p99'):.2f}")
            cell = f"{ratio:.2f}" + (f" ({'; '.join(extra)})" if extra else "")
            cell += f" · {f(num(r, 'median_us'), 1)} µs [{r['env']}]"
            fc = int(num(r, "failed_configs")) if math.isfinite(num(r, "failed_configs")) else 0
            if fc:
                cell += f" · failed on {fc} configs"
            cells.append(cell)
        if any_:
            body.append(cells)
    summary = common.md_table(head, body)
    top, _ = headline(index)

    # quality --------------------------------------------------------------------------------
    qhead = ["env", "problem", "contender", "top-level residual, own formulation (median / max)",
             "vs hqp-tpm's level `J1 x - b1` (median / max)", "relative (median)", "box violation max (rad/s)",
             "configs/steps violating", "failed configs", "EE tracking RMS / max (mm)"]
    qbody = []
    for r in rows:
        scenario = r["problem"].startswith(("lwr", "romeo_obs"))
        if r["phase"] not in ("step", "loop") or not r.get("ratio_median") or scenario:
            continue
        viol_n = int(num(r, "box_violated_configs")) if math.isfinite(num(r, "box_violated_configs")) else -1
        track = (f"{f(num(r, 'tracking_rms_mm'))} / {f(num(r, 'tracking_max_mm'))}"
                 if math.isfinite(num(r, "tracking_rms_mm")) else "")
        qbody.append([r["env"], r["problem"], r["contender"],
                      f"{g(num(r, 'own_top_residual_median'))} / {g(num(r, 'own_top_residual_max'))}"
                      if math.isfinite(num(r, "own_top_residual_median")) else "",
                      f"{g(num(r, 'top_residual_median'))} / {g(num(r, 'top_residual_max'))}"
                      if math.isfinite(num(r, "top_residual_median")) else "",
                      g(num(r, "top_residual_rel_median")), g(num(r, "box_violation_max")),
                      str(viol_n) if viol_n >= 0 else "n/a", r.get("failed_configs", "") or "0", track])
    quality = common.md_table(qhead, qbody)

    # all rows -------------------------------------------------------------------------------
    dhead = ["env", "pin", "problem", "phase", "contender", "n", "median µs", "p99 µs (all calls)",
             "p99 µs (config medians)", "CPU µs median", "ratio median", "ratio p99", "CPU-time ratio median",
             "loop ms", "failed"]
    dbody = [[r["env"], r["pin"], r["problem"], r["phase"], r["contender"], r.get("configs", ""),
              f(num(r, "median_us"), 1), f(num(r, "p99_us"), 1), f(num(r, "p99_cfg_us"), 1),
              f(num(r, "cpu_median_us"), 1), f(num(r, "ratio_median")), f(num(r, "ratio_p99")),
              f(num(r, "cpu_ratio_median")),
              f(num(r, "loop_ms"), 1), (r.get("failed", "") or "")[:80]] for r in rows
             if not r["problem"].startswith(("lwr", "romeo_obs"))]
    detail = common.md_table(dhead, dbody)

    shead = ["env", "scenario", "solver", "steps timed", "median µs", "p99 µs"]
    sbody = [[r["env"], r["problem"], r["contender"], r.get("configs", ""), f(num(r, "median_us"), 1),
              f(num(r, "p99_us"), 1)] for r in rows if r["problem"].startswith(("lwr", "romeo_obs"))]
    scen = common.md_table(shead, sbody)

    keys = ["date", "cpu", "cores", "load average at start", "load average at end", "host speed probe at start",
            "host speed probe at end", "CPU share of this process",
            "python", "hqp-tpm", "pin", "pin-pink", "placo", "tsid", "daqp", "qpsolvers", "numpy", "scipy",
            "eigenpy", "coal", "BLAS threads"]
    ehead = ["", *envs.keys()]
    ebody = [[k, *[envs[e].get(k, "") for e in envs]] for k in keys]
    environ = common.md_table(ehead, ebody)

    text = "\n".join([
        "# hqp-tpm side by side with pink, PlaCo and TSID",
        "",
        "Written by `make bench-peers` (`benchmarks/peers/`, see `benchmarks/README.md`). One process per",
        "virtual environment (each peer pins its own pinocchio); in each process the contenders are",
        "interleaved configuration by configuration, one BLAS thread. **Ratios** are the contender's time",
        "divided by hqp-tpm `tpm`'s at the same configuration in the same process (median over 200",
        "configurations; in brackets the same ratio of thread CPU times, which leaves out the time other",
        "processes took the core for, and the wall-time ratio's 99th percentile); µs are wall-time medians",
        "over configurations of the median of the repeats; the environment ([pin4] = pin 4.x, [pin38] =",
        "pin 3.8.0, [pin34] = pin 3.4.0) says where a cell was measured. Closed loops: ratio of whole-loop",
        "times (median of the interleaved rounds), µs per step. Absolute times depend on the machine's",
        "load (below); compare ratios.",
        "",
        "## hqp-tpm against the reference peer (higher than 1: hqp-tpm is slower)",
        "",
        "hqp-tpm's time divided by PlaCo's with velocity limits (velocity level, in the PlaCo environment) or",
        "TSID's (acceleration level), both measured in one process, interleaved. Median: the median over the 200",
        "configurations of the ratio of thread CPU time medians at each configuration; p99: the 99th percentile of",
        "all of hqp-tpm's timed calls over the peer's (tail against tail). Loops: thread CPU time per step. A step",
        "is: the state fed in (`ctrl.set_state(q)`; PlaCo `state.q = q; update_kinematics()`; TSID",
        "`computeProblemData(t, q, v)`), the targets assigned again (they move every call), then the command",
        "(`ctrl.compute()`; PlaCo `solve()`; TSID's solver).",
        "",
        top,
        "",
        "## Time relative to hqp-tpm `tpm` (lower is faster)",
        "",
        summary,
        "",
        "## Quality of the commands (same configurations)",
        "",
        "Top-level residual (EE pose / right sole; velocity or acceleration units): in the contender's own",
        "formulation of that task (pink: `|J dq + gain e| / dt` with its `log6` error; PlaCo's targets and",
        "TSID's world-aligned errors are set up to equal hqp-tpm's), and against hqp-tpm's first level",
        "`|J1 x - b1|` at the same configuration (for pink this includes the difference between its `log6`",
        "error and hqp-tpm's position + rotation-vector error, a few %). A hierarchy solves it exactly (up",
        "to rounding) unless a joint box binds; a weighted QP trades it against the lower levels.",
        "Box violation: largest `|x_j| - v_max_j` over joints of the",
        "URDF velocity limits (velocity level only). Tracking: EE position error to the circle over the loop.",
        "",
        quality,
        "",
        "## hqp-tpm scenario steps (no peer equivalent)",
        "",
        scen,
        "",
        "## All rows",
        "",
        detail,
        "",
        "## Environments",
        "",
        environ,
        "",
    ])
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "peers.md").write_text(text)
    keys_all: list[str] = []
    for r in rows:
        keys_all += [k for k in r if k not in keys_all]
    with open(args.out / "peers.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys_all)
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {args.out / 'peers.md'} and peers.csv", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
