"""How far the SNS variants are from the lexicographic optimum: first-level residual gaps to the cascaded QP.

The cascaded QP with the hard box solves the first level to its box-constrained least-squares optimum,
so its first-level residual is a lower bound for SNS-TPM and the multi-task SNS (``tests/test_sns.py``
asserts it on every draw). This script reports by how much the SNS variants exceed it:

* on the random (stack, box) draws of the property tests (undamped, ``full_rank`` and ``any`` kinds);
* on the stacks of the ``romeo_sns_tpm`` scenario (every ``--every`` steps), level by level.

    python docs/sns_residual_gaps.py [--draws 2000] [--every 10] [--out docs/sns_residual_gaps.md]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the property tests' generator and residual

from test_sns import first_level_residual, lexicographic_qp, random_problem  # noqa: E402

from hqp_tpm.solvers import Level  # noqa: E402
from hqp_tpm.solvers.sns import sns, sns_tpm  # noqa: E402


def relative_gaps(draws: int, seed: int) -> dict[str, dict[str, np.ndarray]]:
    """Per kind: ``(r_variant - r_qp) / (1 + ||b_1||)`` for each SNS variant, one entry per draw."""
    rng = np.random.default_rng(seed)
    out = {}
    for kind in ("full_rank", "any"):
        gaps = {"sns_tpm": [], "sns": [], "qp_residual": []}
        for s in rng.integers(0, 2**32 - 1, draws):
            levels, lo, up, _ = random_problem(np.random.default_rng(int(s)), kind)
            first = levels[0] if isinstance(levels[0], Level) else Level(*levels[0])
            size = 1.0 + np.linalg.norm(first.b if first.is_equality else np.nan_to_num(
                np.concatenate([first.lower, first.upper]), posinf=0.0, neginf=0.0))
            rq = first_level_residual(first, lexicographic_qp(levels, lo, up))
            gaps["qp_residual"].append(rq / size)
            gaps["sns_tpm"].append((first_level_residual(first, sns_tpm(levels, lo, up)) - rq) / size)
            gaps["sns"].append((first_level_residual(first, sns(levels, lo, up)[0]) - rq) / size)
        out[kind] = {k: np.array(v) for k, v in gaps.items()}
    return out


def romeo_residuals(every: int) -> tuple[list[str], dict[str, np.ndarray]]:
    """Residual ``||J_i x - b_i||`` of every level on the romeo_sns_tpm stacks, per solver (steps x levels)."""
    from hqp_tpm.app import build, scenario

    ctrl = build.build(scenario.load("romeo_sns_tpm"))[1]
    names, res = None, {"sns_tpm": [], "sns": [], "qp": []}
    for i in range(scenario.load("romeo_sns_tpm").steps):
        step = ctrl.step()
        if i % every:
            continue
        lo, up = ctrl.box(ctrl.state, step.t)
        levels = step.levels
        names = [lv.name for lv in levels]
        for key, x in (("sns_tpm", sns_tpm(levels, lo, up, lambda_max=ctrl.lambda_max, eps=ctrl.eps)),
                       ("sns", sns(levels, lo, up, lambda_max=ctrl.lambda_max, eps=ctrl.eps)[0]),
                       ("qp", lexicographic_qp(levels, lo, up))):
            res[key].append([first_level_residual(lv, x) for lv in levels])
    return names, {k: np.array(v) for k, v in res.items()}


def fmt(x: float) -> str:
    return "0" if x == 0.0 else f"{x:.2e}"


def report(gaps, names, romeo, args) -> str:
    lines = ["# SNS variants vs the cascaded QP: first-level residual gaps", "",
             f"Command: `python docs/sns_residual_gaps.py --draws {args.draws} --every {args.every}`", "",
             "## Random (stack, box) draws of the property tests (undamped)", "",
             "Gap = (first-level residual of the SNS variant - the QP's) / (1 + ||b_1||). "
             "A draw *binds* when the gap exceeds 1e-9.", "",
             "| kind | variant | draws | QP residual > 0 | binds | median gap (binding) | 90th pct (binding) | "
             "max gap | min gap |", "|---|---|---|---|---|---|---|---|---|"]
    for kind, g in gaps.items():
        for variant in ("sns_tpm", "sns"):
            v = g[variant]
            binding = v[v > 1e-9]
            lines.append(f"| {kind} | {variant} | {v.size} | {np.mean(g['qp_residual'] > 1e-9):.0%} | "
                         f"{binding.size / v.size:.1%} | {fmt(np.median(binding)) if binding.size else '-'} | "
                         f"{fmt(np.percentile(binding, 90)) if binding.size else '-'} | {fmt(v.max())} | "
                         f"{fmt(v.min())} |")
    lines += ["", f"## romeo_sns_tpm stacks (every {args.every} steps, {romeo['qp'].shape[0]} stacks)", "",
              "Median and maximum residual ||J_i x - b_i|| per level (m/s, rad/s) of each solver on the same stack "
              "and box (velocity limits); the QP is lexicographic, SNS-TPM scales all tasks by one factor, "
              "the multi-task SNS scales each level by the least amount.", "",
              "| level | " + " | ".join(f"{k} median / max" for k in romeo) + " |",
              "|---|" + "---|" * len(romeo)]
    for i, name in enumerate(names):
        cells = [f"{fmt(np.median(r[:, i]))} / {fmt(r[:, i].max())}" for r in romeo.values()]
        lines.append(f"| {i + 1}: {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=2000, help="random draws per kind")
    ap.add_argument("--every", type=int, default=10, help="romeo_sns_tpm: one stack every N steps")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "sns_residual_gaps.md")
    args = ap.parse_args(argv)
    with threadpool_limits(1):
        gaps = relative_gaps(args.draws, args.seed)
        names, romeo = romeo_residuals(args.every)
    text = report(gaps, names, romeo, args)
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
