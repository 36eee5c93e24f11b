"""Solver timing on random stacks: the TPM paper's Figs. 1-2 (time against l and against n).

Methods: ``tpm``, ``nullspace``, ``sns_tpm`` (with a box that binds: ``|x_j| <= 0.7 max|x_tpm|``)
from :mod:`hqp_tpm.solvers`, and ``cascaded_qp(levels, solver=b)`` for every installed backend
``b`` among proxqp, osqp, daqp, quadprog. Stacks (``benchmarks/stacks.py``): l = 1..10 tasks of
3 rows at n = 30, and n = 20..300 (step 20) at l = 5, independent full-rank and dependent/conflicting.
Every draw is a new stack, solved by all methods in rotating order (same stack, same moment),
so the ratios are measured under the same conditions. The QPs run on the first ``--qp-draws``
draws of each point, and on a coarser n grid (``--qp-n-step``).

    python benchmarks/solvers.py [--draws 200] [--qp-draws 30] [--qp-n-step 40] [--quick]

Writes ``benchmarks/results/solvers.csv``, ``solvers.md``, ``solvers_vs_l.png``, ``solvers_vs_n.png``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

if __package__ in (None, ""):  # run as a script: make ``benchmarks`` importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import common, stacks  # noqa: E402
from benchmarks.common import Target, fmt  # noqa: E402

L_RANGE = tuple(range(1, 11))
N_FIXED = 30
N_RANGE = tuple(range(20, 301, 20))
L_FIXED = 5
ANALYTIC = ("tpm", "nullspace", "sns_tpm")
EQUAL_TOL = 1e-9


def _methods(qp_backends):
    from hqp_tpm.solvers import cascaded_qp, nullspace, sns_tpm, tpm

    fns = {
        "tpm": lambda lv, box: tpm(lv),
        "nullspace": lambda lv, box: nullspace(lv),
        "sns_tpm": lambda lv, box: sns_tpm(lv, box[0], box[1], return_info=True),
    }
    for b in qp_backends:
        fns[f"qp:{b}"] = lambda lv, box, b=b: cascaded_qp(lv, solver=b)
    return fns


def measure_point(kind: str, l: int, n: int, draws: int, qp_draws: int, qp_backends, rng, warmup: int = 3):
    """Time every method on ``draws`` stacks of one (kind, l, n); one row per method."""
    fns = _methods(qp_backends)
    names = list(fns)
    times = {m: [] for m in names}
    cpu = {m: [] for m in names}
    err = {m: 0.0 for m in names}
    failures = {m: 0 for m in names}
    sns_scaled = sns_sat = sns_iter = 0
    for d in range(-warmup, draws):
        levels = stacks.stack(kind, rng, l, n)
        x_ref = fns["tpm"](levels, None)
        box = stacks.binding_box(x_ref)
        use = [m for m in names if not m.startswith("qp:") or d < qp_draws]
        k = d % len(use) if d >= 0 else 0
        for m in use[k:] + use[:k]:                    # rotate the order from draw to draw
            try:
                dt, dc, out = common.timed(fns[m], levels, box)
            except Exception:  # a QP backend that gives up: count it, do not time it
                failures[m] += d >= 0
                continue
            if d < 0:
                continue
            times[m].append(dt)
            cpu[m].append(dc)
            if m == "sns_tpm":
                x, info = out
                sns_scaled += info.scale < 1.0
                sns_sat += len(info.saturated)
                sns_iter += info.iterations
            elif m != "tpm":
                err[m] = max(err[m], common.rel_err(out, x_ref))
    rows = []
    for m in names:
        st = common.stats_us(times[m], cpu[m])
        row = {"kind": kind, "l": l, "n": n, "method": m, "draws": st["count"], "median_us": st["median_us"],
               "p99_us": st["p99_us"], "mean_us": st["mean_us"], "cpu_median_us": st["cpu_median_us"],
               "cpu_p99_us": st["cpu_p99_us"], "max_rel_diff_vs_tpm": "",
               "failures": failures[m], "sns_scaled_fraction": "", "sns_mean_saturated": "",
               "sns_mean_iterations": ""}
        if m not in ("tpm", "sns_tpm") and st["count"]:
            row["max_rel_diff_vs_tpm"] = err[m]
        if m == "sns_tpm" and st["count"]:
            c = st["count"]
            row.update(sns_scaled_fraction=sns_scaled / c, sns_mean_saturated=sns_sat / c,
                       sns_mean_iterations=sns_iter / c)
        rows.append(row)
    return rows


def sweep(args, qp_backends) -> list[dict]:
    rng = np.random.default_rng(args.seed)
    rows = []
    points = [("l", kind, l, N_FIXED) for kind in stacks.KINDS for l in args.l_range]
    points += [("n", kind, L_FIXED, n) for kind in stacks.KINDS for n in args.n_range]
    qp_n = set(range(args.n_range[0], args.n_range[-1] + 1, args.qp_n_step)) | {args.n_range[-1]}
    for i, (axis, kind, l, n) in enumerate(points):
        qp_draws = args.qp_draws if axis == "l" or n in qp_n else 0
        common.progress(f"  solvers [{i + 1}/{len(points)}] {kind} l={l} n={n}")
        for row in measure_point(kind, l, n, args.draws, qp_draws, qp_backends, rng):
            rows.append({"sweep": axis, **row})
    return rows


def _find(rows, sweep_axis, kind, l, n, method):
    for r in rows:
        if (r["sweep"], r["kind"], r["l"], r["n"], r["method"]) == (sweep_axis, kind, l, n, method):
            return r
    return None


def ratio(rows, sweep_axis, kind, l, n, num="nullspace", den="tpm", key="median_us") -> float:
    """``num``'s median over ``den``'s (wall time; ``key="cpu_median_us"`` for thread CPU time)."""
    a, b = _find(rows, sweep_axis, kind, l, n, num), _find(rows, sweep_axis, kind, l, n, den)
    if not a or not b or not a["draws"] or not b["draws"]:
        return float("nan")
    return a[key] / b[key]


def targets(rows, l_max: int, n_max: int) -> list[Target]:
    """A ratio target is met only if both the wall-time and the thread-CPU-time medians meet it."""
    out = []
    for kind in stacks.KINDS:
        r10 = ratio(rows, "l", kind, l_max, N_FIXED)
        c10 = ratio(rows, "l", kind, l_max, N_FIXED, key="cpu_median_us")
        e10 = _find(rows, "l", kind, l_max, N_FIXED, "nullspace")["max_rel_diff_vs_tpm"]
        out.append(Target(f"tpm vs nullspace, l={l_max} n={N_FIXED}, {kind}", "tpm faster (ratio > 1), equal to 1e-9",
                          f"nullspace/tpm = {r10:.2f}× (CPU time {c10:.2f}×), max rel. diff {e10:.1e}",
                          min(r10, c10) > 1.0 and e10 <= EQUAL_TOL))
        r300 = ratio(rows, "n", kind, L_FIXED, n_max)
        c300 = ratio(rows, "n", kind, L_FIXED, n_max, key="cpu_median_us")
        e300 = _find(rows, "n", kind, L_FIXED, n_max, "nullspace")["max_rel_diff_vs_tpm"]
        out.append(Target(f"tpm vs nullspace, l={L_FIXED} n={n_max}, {kind}", "≥ 10× faster, equal to 1e-9",
                          f"nullspace/tpm = {r300:.1f}× (CPU time {c300:.1f}×), max rel. diff {e300:.1e}",
                          min(r300, c300) >= 10.0 and e300 <= EQUAL_TOL))
    return out


def _sweep_table(rows, axis, kind, methods) -> str:
    var = "l" if axis == "l" else "n"
    keys = sorted({r[var] for r in rows if r["sweep"] == axis and r["kind"] == kind})
    table = []
    for v in keys:
        line = [v]
        for m in methods:
            r = next(r for r in rows if r["sweep"] == axis and r["kind"] == kind and r[var] == v and r["method"] == m)
            line.append(f"{fmt(r['median_us'])} / {fmt(r['p99_us'])}" if r["draws"] else "–")
        nt = ratio(rows, axis, kind, *((v, N_FIXED) if axis == "l" else (L_FIXED, v)))
        line.append(f"{nt:.2f}")
        table.append(line)
    return common.md_table([var, *methods, "nullspace/tpm"], table)


def _errors_table(rows, methods) -> str:
    out = []
    for m in methods:
        errs = [r["max_rel_diff_vs_tpm"] for r in rows if r["method"] == m and r["max_rel_diff_vs_tpm"] != ""]
        fails = sum(r["failures"] for r in rows if r["method"] == m)
        out.append([m, f"{max(errs):.1e}" if errs else "–", fails])
    return common.md_table(["method", "max rel. diff to tpm (all points)", "failed solves"], out)


def _sns_table(rows) -> str:
    out = []
    for r in rows:
        if r["method"] == "sns_tpm" and ((r["sweep"] == "l" and r["l"] in (1, 5, 10)) or
                                         (r["sweep"] == "n" and r["n"] in (20, 100, 200, 300))):
            out.append([r["kind"], r["l"], r["n"], f"{r['sns_scaled_fraction']:.2f}",
                        f"{r['sns_mean_saturated']:.1f}", f"{r['sns_mean_iterations']:.1f}"])
    return common.md_table(["kind", "l", "n", "fraction scaled (s < 1)", "mean saturated joints",
                            "mean iterations"], out)


def plot(rows, methods, path_l: Path, path_n: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = dict(zip(methods, plt.rcParams["axes.prop_cycle"].by_key()["color"] * 3, strict=False))
    for axis, path in (("l", path_l), ("n", path_n)):
        var = axis
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
        for ax, kind in zip(axes, stacks.KINDS, strict=True):
            for m in methods:
                sel = sorted((r for r in rows if r["sweep"] == axis and r["kind"] == kind and r["method"] == m
                              and r["draws"]), key=lambda r: r[var])
                if not sel:
                    continue
                xs = [r[var] for r in sel]
                ax.semilogy(xs, [r["median_us"] for r in sel], "o-", color=colors[m], label=f"{m} median", ms=3)
                ax.semilogy(xs, [r["p99_us"] for r in sel], "--", color=colors[m], lw=0.8, alpha=0.8)
            fixed = f"n = {N_FIXED}" if axis == "l" else f"l = {L_FIXED}"
            ax.set_title(f"{kind} stacks, {fixed} (dashed: 99th percentile)")
            ax.set_xlabel("number of tasks l (3 rows each)" if axis == "l" else "number of joints n")
            ax.grid(True, which="both", alpha=0.3)
        axes[0].set_ylabel("time per solve [µs]")
        axes[1].legend(fontsize=8, loc="best")
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--draws", type=int, default=200, help="stacks per point for the analytic solvers (paper: 1000)")
    p.add_argument("--qp-draws", type=int, default=30, help="stacks per point for the cascaded QPs")
    p.add_argument("--qp-n-step", type=int, default=40, help="n grid step of the QPs in the n sweep")
    p.add_argument("--qp", default="all", help="comma-separated QP backends, 'all' (installed) or 'none'")
    p.add_argument("--seed", type=int, default=20160101)
    p.add_argument("--out", type=Path, default=common.RESULTS)
    p.add_argument("--quick", action="store_true", help="smoke test: few draws, few points")
    args = p.parse_args(argv)
    args.l_range, args.n_range = L_RANGE, N_RANGE
    if args.quick:
        args.draws, args.qp_draws, args.qp_n_step = 5, 2, 140
        args.n_range = (20, 160, 300)
    return args


def main(argv=None) -> dict:
    args = parse(argv)
    with common.one_blas_thread():
        env = common.environment()
        installed = common.installed_qp_backends()
        qp = installed if args.qp == "all" else [] if args.qp == "none" else [b for b in args.qp.split(",") if b]
        missing = [b for b in qp if b not in installed]
        if missing:
            raise SystemExit(f"QP backends not installed: {missing}; installed: {installed}")
        env["draws per point"] = (f"{args.draws} (analytic), {args.qp_draws} (QP; n grid step {args.qp_n_step}), "
                                  f"seed {args.seed}")
        rows = sweep(args, qp)
        common.close_environment(env)
    methods = [*ANALYTIC, *(f"qp:{b}" for b in qp)]
    l_max, n_max = args.l_range[-1], args.n_range[-1]
    tg = targets(rows, l_max, n_max)
    args.out.mkdir(parents=True, exist_ok=True)
    common.write_csv(args.out / "solvers.csv", rows, env)
    plot(rows, methods, args.out / "solvers_vs_l.png", args.out / "solvers_vs_n.png")
    ratios = []
    for kind in stacks.KINDS:
        for axis, l, n in (("l", l_max, N_FIXED), ("n", L_FIXED, n_max)):
            ratios.append([kind, l, n, *(f"{ratio(rows, axis, kind, l, n, num=m):.2f} "
                                         f"({ratio(rows, axis, kind, l, n, num=m, key='cpu_median_us'):.2f})"
                                         for m in methods[1:])])
    sections = [
        ("Targets", common.targets_markdown(tg)),
        ("Ratios to tpm (median / median, same run; in parentheses: of the thread CPU times)",
         common.md_table(["kind", "l", "n", *(f"{m}/tpm" for m in methods[1:])], ratios)),
    ]
    for kind in stacks.KINDS:
        sections.append((f"Time against l at n = {N_FIXED}, {kind} stacks: median / p99 µs",
                         _sweep_table(rows, "l", kind, methods)))
    for kind in stacks.KINDS:
        sections.append((f"Time against n at l = {L_FIXED}, {kind} stacks: median / p99 µs",
                         _sweep_table(rows, "n", kind, methods)))
    sections += [("Agreement and failures", _errors_table(rows, methods[1:])),
                 ("SNS-TPM with the binding box |x_j| ≤ 0.7 max|x_tpm|", _sns_table(rows)),
                 ("Figures", "![time against l](solvers_vs_l.png)\n\n![time against n](solvers_vs_n.png)")]
    common.write_markdown(args.out / "solvers.md", "Solver timing (TPM paper Figs. 1–2)", env, sections)
    common.progress(f"wrote {args.out}/solvers.csv, solvers.md, solvers_vs_l.png, solvers_vs_n.png")
    return {"env": env, "rows": rows, "targets": tg, "sections": sections}


if __name__ == "__main__":
    main()
