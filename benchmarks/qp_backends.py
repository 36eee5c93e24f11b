"""QP backends on random boxed cascades: failures, disagreements and CPU time per level.

Draws the boxed stacks of the library's public builders and strategies (:mod:`hqp_tpm.testing.stacks`,
:mod:`hqp_tpm.testing.strategies`), each in other units (scale ``c``), and solves every one with
:func:`hqp_tpm.solvers.cascaded_qp` for each installed backend. Families:

* ``full_rank``, ``any``, ``damped``: :func:`~hqp_tpm.testing.stacks.random_problem` (the SNS draws; box
  containing 0, 5 % infinite sides, 3 % locked joints); ``excluded``: ``any`` with
  :func:`~hqp_tpm.testing.stacks.box_without_zero`;
* ``near``: :func:`~hqp_tpm.testing.stacks.nearly_dependent_stack` (cond up to ``--max-cond``) with a
  :func:`~hqp_tpm.testing.stacks.box_for` box (binds);
* ``strategies``: ``boxed_stacks(stacks(conflict=0.3, inequality=0.3, max_cond=1e3), box=any|binds,
  zero=inside|excluded)`` drawn by hypothesis (derandomized).

Units: a draw is solved as drawn (``c = 1``) or with ``(c J, c b)`` (``units=J``, same solution) or with
``b``, the inequality bounds and the box times ``c`` (``units=b``, solution times ``c``), ``c`` in
``--scales``. For each draw and backend: a typed failure (:class:`~hqp_tpm.errors.SolverFailedError`,
budget errors counted apart) or an untyped exception; a box violation beyond 1e-9 relative; residuals
lexicographically worse than the best backend's (level by level, beyond 1e-7 of ``max|J| max|x| + max|target|``);
the solution more than ``--rtol`` (relative, osqp ``--osqp-rtol``) from the majority of the backends
(the largest group within that tolerance of each other, at least two; ``--backends`` may add e.g. the
interior-point ``clarabel`` as a voter); the CPU time of each level (this process's). Each backend runs
alone (``fallback=()``); with ``--fallback`` the cascade's automatic fallback is on and the draws where
another backend solved a level are counted (``fell_back``). Writes ``qp_backends.md`` and
``qp_backends.json`` (failing and disagreeing draws, replayable: family, index, units, scale)::

    .venv/bin/python benchmarks/qp_backends.py --draws 300        # per family and unit scale
    .venv/bin/python benchmarks/qp_backends.py --replay near:17:J:1e6
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

if __package__ in (None, ""):  # run as a script
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import RESULTS, env_markdown, environment, md_table, one_blas_thread

FAMILIES = ("full_rank", "any", "damped", "excluded", "near", "strategies")
BACKENDS = ("proxqp", "daqp", "osqp", "quadprog")
SCALES = (1e-6, 1e-3, 1e3, 1e6)


def draw(family: str, i: int, max_cond: float, strategy_cases: list):
    """``(levels, lower, upper, damping)`` of draw ``i`` of ``family`` (replayable from ``(family, i)``)."""
    from hqp_tpm.solvers import tpm
    from hqp_tpm.testing.stacks import box_for, box_without_zero, nearly_dependent_stack, random_problem

    rng = np.random.default_rng([FAMILIES.index(family), i])
    if family in ("full_rank", "any", "damped"):
        return random_problem(rng, family)
    if family == "excluded":
        levels, lo, up, damping = random_problem(rng, "any")
        return (levels, *box_without_zero(rng, lo, up), damping)
    if family == "near":
        levels, _ = nearly_dependent_stack(rng, max_cond)
        n = levels[0][0].shape[1]
        return (levels, *box_for(rng, tpm(levels), n), {})
    case = strategy_cases[i % len(strategy_cases)]
    return case.levels, case.box[0], case.box[1], case.damping


def strategy_cases(count: int) -> list:
    """``count`` boxed cases drawn by hypothesis from the public strategies (derandomized: the same each run)."""
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import strategies as st

    from hqp_tpm.testing.strategies import boxed_stacks, stacks

    out: list = []
    kinds = st.sampled_from([("any", "inside"), ("binds", "inside"), ("any", "excluded"), ("binds", "excluded")])

    @settings(max_examples=count, database=None, derandomize=True, phases=[Phase.generate], deadline=None,
              suppress_health_check=list(HealthCheck))
    @given(st.data())
    def collect(data):
        box, zero = data.draw(kinds)
        out.append(data.draw(boxed_stacks(stacks(conflict=0.3, inequality=0.3, max_cond=1e3), box=box, zero=zero)))

    collect()
    return out


def in_units(levels, lo, up, units: str, c: float):
    """The draw in other units: ``J`` scales J and b (same solution), ``b`` scales b, bounds and box (x times c)."""
    from hqp_tpm.solvers import Level
    from hqp_tpm.solvers.levels import as_levels

    n = lo.size
    if units == "1":
        return levels, lo, up
    out = []
    for lv in as_levels(levels, n):
        if units == "J":
            J, f = c * lv.J, c
        else:
            J, f = lv.J, c
        if lv.is_equality:
            out.append(Level(J, f * lv.b))
        else:
            out.append(Level(J, lower=f * lv.lower, upper=f * lv.upper))
    if units == "b":
        return out, c * lo, c * up
    return out, lo, up


class LevelClock:
    """CPU seconds of each level of the cascades solved while it is installed (wraps ``_Cascade.start_level``)."""

    def __init__(self):
        import importlib

        module = importlib.import_module("hqp_tpm.solvers.cascaded_qp")

        self.cls = module._Cascade
        self.original = self.cls.start_level
        self.marks: list[float] = []

    def __enter__(self):
        clock = self

        def start_level(cascade):
            clock.marks.append(time.process_time())
            clock.original(cascade)

        self.cls.start_level = start_level
        return self

    def __exit__(self, *exc):
        self.cls.start_level = self.original

    def levels(self) -> list[float]:
        t = [*self.marks, time.process_time()]
        self.marks = []
        return list(np.diff(t))


def solve_all(levels, lo, up, damping, backends, clock, fallback=()):
    """Per backend: ``{"x", "res", "error", "kind", "times", "fallbacks"}`` (``fallback=()``: the backend alone)."""
    import inspect

    from hqp_tpm.errors import SolverBudgetError, SolverFailedError
    from hqp_tpm.solvers.cascaded_qp import cascaded_qp

    extra = {"fallback": fallback} if "fallback" in inspect.signature(cascaded_qp).parameters else {}  # old checkouts
    out = {}
    for s in backends:
        r = {"x": None, "res": None, "error": None, "kind": "ok", "fallbacks": ()}
        clock.levels()
        try:
            x, info = cascaded_qp(levels, s, lower=lo, upper=up, return_info=True, **extra, **damping)
            r["x"], r["res"], r["fallbacks"] = x, info.residuals, getattr(info, "fallbacks", ())
        except SolverBudgetError as e:
            r["kind"], r["error"] = "budget", str(e)
        except SolverFailedError as e:
            r["kind"], r["error"] = "failed", str(e)
        except Exception as e:  # noqa: BLE001 - an untyped error is what we count
            r["kind"], r["error"] = "untyped", f"{type(e).__name__}: {e}"
        r["times"] = clock.levels()
        out[s] = r
    return out


def majority(xs: dict, rtol: dict) -> tuple[list[str], np.ndarray | None]:
    """The largest group of backends whose solutions agree pairwise within their tolerances (>= 2), and its first x."""
    names = [s for s, x in xs.items() if x is not None]
    best: list[str] = []
    for a in names:
        group = [b for b in names if rel_diff(xs[a], xs[b]) <= max(rtol[a], rtol[b])]
        if len(group) > len(best):
            best = group
    if len(best) < 2:
        return [], None
    return best, xs[best[0]]


def rel_diff(a, b) -> float:
    return float(np.abs(a - b).max() / max(1.0, np.abs(a).max(), np.abs(b).max()))


def lex_worse(res: np.ndarray, best: np.ndarray, scale: np.ndarray) -> bool:
    """``res`` lexicographically worse than ``best`` beyond the KKT tolerance (1e-7 of each level's scale)."""
    for r, b, s in zip(res, best, scale, strict=True):
        if abs(r - b) > 1e-7 * s:
            return r > b
    return False


def level_scale(levels, x_norm: float, n: int) -> np.ndarray:
    """Per level, the size its residual is measured against: ``max|J| max|x| + max|target|`` (unit-free)."""
    from hqp_tpm.solvers.levels import as_levels

    out = []
    for lv in as_levels(levels, n):
        t = np.concatenate([np.atleast_1d(lv.b) if lv.is_equality else np.concatenate([lv.lower, lv.upper])])
        t = t[np.isfinite(t)]
        out.append(np.abs(lv.J).max() * x_norm + np.abs(t).max(initial=0.0) + 1e-300)
    return np.array(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--draws", type=int, default=150, help="draws per family and units (default 150)")
    p.add_argument("--families", default=",".join(FAMILIES))
    p.add_argument("--backends", default=",".join(BACKENDS))
    p.add_argument("--scales", default=",".join(f"{c:g}" for c in SCALES))
    p.add_argument("--units", default="1,J,b", help="1 (as drawn), J (c J, c b), b (c b, c box)")
    p.add_argument("--max-cond", type=float, default=1e10, help="cond(J) bound of the 'near' family")
    p.add_argument("--rtol", type=float, default=1e-6)
    p.add_argument("--osqp-rtol", type=float, default=1e-5)
    p.add_argument("--fallback", action="store_true", help="the cascade's default fallback backends on "
                   "(counted in 'fell_back'); default: each backend alone")
    p.add_argument("--replay", default=None, help="family:index:units:scale of one draw, printed per backend")
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--tag", default="", help="suffix of the output file names")
    p.add_argument("--quick", action="store_true", help="smoke test: 5 draws")
    a = p.parse_args(argv)
    import qpsolvers

    backends = [s for s in a.backends.split(",") if s in qpsolvers.available_solvers]
    voters = backends
    rtol = defaultdict(lambda: a.rtol, {"osqp": a.osqp_rtol})
    draws = 5 if a.quick else a.draws
    scales = [float(c) for c in a.scales.split(",")]
    families = a.families.split(",")
    fallback: tuple = ()
    if a.fallback:
        from hqp_tpm.solvers.cascaded_qp import FALLBACK as fallback
    cases = strategy_cases(max(draws, 1)) if "strategies" in families or (a.replay or "").startswith("strat") else []

    with one_blas_thread(), LevelClock() as clock:
        if a.replay:
            fam, i, units, c = a.replay.split(":")
            lv, lo, up, dmp = draw(fam, int(i), a.max_cond, cases)
            lv, lo, up = in_units(lv, lo, up, units, float(c))
            for s, r in solve_all(lv, lo, up, dmp, voters, clock, fallback).items():
                print(s, r["kind"], r["error"] or "", "levels CPU s:", np.round(r["times"], 4),
                      "x:", None if r["x"] is None else np.array2string(r["x"], precision=6))
            return 0
        stats = {s: defaultdict(lambda: defaultdict(int)) for s in voters}
        times = {s: [] for s in voters}
        bad: list[dict] = []
        t0 = time.process_time()
        for fam in families:
            for units in a.units.split(","):
                for i in range(draws):
                    c = 1.0 if units == "1" else scales[i % len(scales)]
                    lv, lo, up, dmp = draw(fam, i, a.max_cond, cases)
                    lv, lo, up = in_units(lv, lo, up, units, c)
                    n = lo.size
                    res = solve_all(lv, lo, up, dmp, voters, clock, fallback)
                    xs = {s: r["x"] for s, r in res.items()}
                    group, xm = majority(xs, rtol)
                    ok = [s for s in voters if xs[s] is not None]
                    xn = max((float(np.abs(xs[s]).max()) for s in ok), default=0.0)
                    sc = level_scale(lv, xn, n)
                    best = None
                    for s in ok:
                        if best is None or lex_worse(best, res[s]["res"], sc):
                            best = res[s]["res"]
                    key = f"{fam}:{units}"
                    for s, r in res.items():
                        st = stats[s][key]
                        st["draws"] += 1
                        times[s].extend(r["times"])
                        st["max_level_s"] = max(st["max_level_s"], max(r["times"], default=0.0))
                        flags = []
                        if r["fallbacks"]:
                            st["fell_back"] += 1
                            flags.append("fell_back")
                        if r["kind"] != "ok":
                            st[r["kind"]] += 1
                            flags.append(r["kind"])
                        else:
                            x = r["x"]
                            tol_box = 1e-9 * (1.0 + np.abs(np.nan_to_num(np.concatenate([lo, up]),
                                                                         posinf=0, neginf=0)).max())
                            if ((x < lo - tol_box) | (x > up + tol_box)).any():
                                st["box"] += 1
                                flags.append("box")
                            if lex_worse(r["res"], best, sc):
                                st["lex_worse"] += 1
                                flags.append("lex_worse")
                            if xm is None:
                                st["no_majority"] += 1
                            elif s not in group and rel_diff(x, xm) > rtol[s]:
                                st["disagree"] += 1
                                flags.append("disagree")
                        if flags:
                            bad.append({"draw": f"{fam}:{i}:{units}:{c:g}", "backend": s, "flags": flags,
                                        "error": r["error"], "diff": None if xm is None or r["x"] is None
                                        else rel_diff(r["x"], xm), "level_s": r["times"]})
            print(f"{fam} done, {time.process_time() - t0:.0f} s CPU", flush=True)
    env = environment()
    cols = ["draws", "failed", "budget", "untyped", "fell_back", "box", "lex_worse", "disagree", "no_majority"]
    rows = []
    for s in voters:
        for key, st in stats[s].items():
            rows.append([s, key, *[st[k] for k in cols], f"{st['max_level_s']:.3f}"])
        tot = defaultdict(int)
        for st in stats[s].values():
            for k in cols:
                tot[k] += st[k]
        t = np.array(times[s])
        fails = tot["failed"] + tot["budget"] + tot["untyped"]
        rows.append([f"**{s}**", "all", *[tot[k] for k in cols],
                     f"{t.max():.3f} (p99 {np.percentile(t, 99) * 1e3:.1f} ms, fail rate "
                     f"{100 * fails / max(tot['draws'], 1):.2f} %)"])
    table = md_table(["backend", "family:units", *cols, "max CPU s per level"], rows)
    cmd = "python benchmarks/qp_backends.py " + " ".join(sys.argv[1:] if argv is None else argv)
    text = (f"# QP backends on random boxed cascades\n\n`{cmd}`\n\n{env_markdown(env)}\n\n{table}\n\n"
            f"Units J/b cycle through scales {scales}. Total CPU {time.process_time() - t0:.0f} s.\n")
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / f"qp_backends{a.tag}.md").write_text(text)
    (a.out / f"qp_backends{a.tag}.json").write_text(json.dumps(bad, indent=1, default=float))
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
