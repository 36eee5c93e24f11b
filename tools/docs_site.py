"""The generated parts of the documentation site, from the results files (never written by hand).

``render(markdown)`` replaces each ``<!-- generated: NAME -->`` marker by ``BLOCKS[NAME]()`` and each inline
``[[scenario.metric:format]]`` (optionally ``[[scenario.metric:format*scale]]``) by the value in
benchmarks/results/scenarios.json. tools/docs_hooks.py calls it for every page of ``make docs``;
tests/test_docs_numbers.py checks that the hand-written numbers of the pages come from results files.
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
SCENARIOS = RESULTS / "scenarios.json"

MARKER = re.compile(r"<!-- generated: ([a-z_]+) -->")
INLINE = re.compile(r"\[\[([a-z0-9_]+)\.([A-Za-z0-9_.> ]+?)(?::([^\]*]+))?(?:\*([0-9.e+-]+))?\]\]")


def scenarios() -> dict:
    return json.loads(SCENARIOS.read_text(encoding="utf-8"))["scenarios"]


def value(scenario: str, metric: str, fmt: str = "", scale: float = 1.0) -> str:
    """One number of benchmarks/results/scenarios.json, formatted (a missing one is an error, not a blank)."""
    runs = scenarios()
    if scenario not in runs or metric not in runs[scenario]:
        raise KeyError(f"benchmarks/results/scenarios.json has no {scenario}.{metric}")
    v = runs[scenario][metric]
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        v = v * scale if scale != 1.0 else v
        return format(v, fmt) if fmt else str(v)
    return str(v)


def _links_to_text(markdown: str) -> str:
    """Included results files link relative to their own folder: keep the text, name the target as code."""
    return re.sub(r"(?<!!)\[([^\]]+)\]\((?!https?://|#)([^)]+)\)", r"\1 (`\2`)", markdown)


def _demote(markdown: str, by: int = 1) -> str:
    return re.sub(r"^(#+) ", lambda m: "#" * (len(m.group(1)) + by) + " ", markdown, flags=re.M)


def include(name: str, by: int = 1) -> str:
    """A results file's Markdown inside a page: headings demoted, its images served from ``results/``."""
    path = RESULTS / name
    if not path.exists():
        return f"*`benchmarks/results/{name}` is missing: run the benchmark that writes it.*\n"
    text = _links_to_text(path.read_text(encoding="utf-8"))
    text = re.sub(r"!\[([^\]]*)\]\((?!https?://|/)([^)]+\.(?:png|svg|jpg))\)",
                  lambda m: f"![{m.group(1)}](results/{m.group(2)})" if (RESULTS / m.group(2)).is_file()
                  else f"*(figure `{m.group(2)}` is not in benchmarks/results)*", text)
    return _demote(text, by)


def result_images() -> list[Path]:
    """The figures the included results files show (the site serves them as ``results/NAME.png``)."""
    return sorted(p for ext in ("png", "svg", "jpg") for p in RESULTS.rglob(f"*.{ext}"))


def _num(text: str):
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def peers_summary() -> str:
    """Median µs per problem, phase and contender from benchmarks/results/peers.csv (whatever its columns)."""
    path = RESULTS / "peers.csv"
    if not path.exists():
        return "*`benchmarks/results/peers.csv` is missing: run `make bench-peers`.*\n"
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    if not rows or "problem" not in rows[0] or "contender" not in rows[0]:
        return "*`benchmarks/results/peers.csv` has no `problem`/`contender` columns; see the full report below.*\n"
    time_key = next((k for k in ("median_us", "us_median", "median") if k in rows[0]), None)
    ratio_key = next((k for k in ("ratio_median", "ratio") if k in rows[0]), None)
    phases = list(dict.fromkeys(r.get("phase", "") for r in rows))
    out = []
    for problem in dict.fromkeys(r["problem"] for r in rows):
        mine = [r for r in rows if r["problem"] == problem]
        out.append(f"**{problem}**\n")
        cols = [p for p in phases if any(r.get("phase", "") == p for r in mine)]
        out.append("| contender | " + " | ".join(c or "value" for c in cols) + " |")
        out.append("|---|" + "---|" * len(cols))
        for contender in dict.fromkeys(r["contender"] for r in mine):
            cells = []
            for c in cols:
                r = next((r for r in mine if r["contender"] == contender and r.get("phase", "") == c), None)
                t = _num(r.get(time_key)) if r and time_key else None
                q = _num(r.get(ratio_key)) if r and ratio_key else None
                if r is not None and t is None and _num(r.get("loop_ms")) is not None:
                    cells.append(f"{_num(r['loop_ms']):.4g} ms per loop")
                    continue
                cell = "—" if t is None else f"{t:.4g} µs"
                if q is not None:
                    cell += f" ({q:.2f}×)"
                env = (r or {}).get("env")
                cells.append(cell + (f" [{env}]" if env and t is not None else ""))
            out.append(f"| {contender} | " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out) + "\n"


def speed() -> str:
    return ("### Medians per problem (from `benchmarks/results/peers.csv`)\n\n"
            "Wall-time medians over the configurations; in brackets the ratio to hqp-tpm `tpm` at the same "
            "configuration in the same process, and the environment (pinocchio version) it was measured in.\n\n"
            + peers_summary() + "\n### The full report (`benchmarks/results/peers.md`)\n\n" + include("peers.md", 2))


def bench() -> str:
    return include("summary.md", 2)


def first_call() -> str:
    return include("first_call.md", 2)


def guarantees() -> str:
    """The table of hqp_tpm.testing.tolerances.GUARANTEES."""
    from hqp_tpm.testing.tolerances import BASE_RTOL, COND_FACTOR, GUARANTEES, OTHER_QP_RTOL

    out = ["| relation | tolerance (relative) | on which stacks | cond up to | scales | tests |",
           "|---|---|---|---|---|---|"]
    for g in GUARANTEES:
        out.append(f"| {g.relation} | {g.rtol:.1e} | {g.stacks} | {g.cond_max:.0e} | "
                   f"{g.scales[0]:g} … {g.scales[1]:g} | `{g.tests}` |")
    out += ["", "Base accuracy per solver on a well-conditioned stack (`BASE_RTOL`); the tolerance between two solvers "
            f"is `max(base, {COND_FACTOR:g} eps cond)`, any other QP backend `{OTHER_QP_RTOL:g}`:", "",
            "| solver | base relative accuracy |", "|---|---|"]
    out += [f"| `{k}` | {v:g} |" for k, v in BASE_RTOL.items()]
    return "\n".join(out) + "\n"


def _table(header: list[str], rows: list[list[str]]) -> str:
    return "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
                      *("| " + " | ".join(r) + " |" for r in rows)]) + "\n"


def _f(m: dict, key: str, fmt: str, scale: float = 1.0, missing: str = "—") -> str:
    v = m.get(key)
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return missing
    return format(v * scale if scale != 1.0 else v, fmt)


def _runs(names):
    runs = scenarios()
    return [(n, runs[n]) for n in names if n in runs]


def lwr_table() -> str:
    rows = [[f"`{n}`", f"{_f(m, 'ee_error_max', '.1f', 1e3)} / {_f(m, 'ee_error_rms', '.1f', 1e3)}",
             _f(m, "pointing_violation_max_deg", ".2f"), _f(m, "d_minimal_min", ".4f"), _f(m, "d_ee_min", ".4f"),
             _f(m, "max_dq_jump", ".4f"), _f(m, "stack_changes", "d")]
            for n, m in _runs(["lwr_relaxed", "lwr_velocity", "lwr_avoid3d", "lwr_point35_equality",
                               "lwr_point35_inequality", "lwr_tracking"])]
    return _table(["run", "max / RMS EE error [mm]", "max pointing violation [deg]", "min D_minimal [m]",
                   "min D_ee [m]", "largest step of q̇ [rad/s]", "stack changes"], rows)


def romeo_table() -> str:
    rows = []
    for n, m in _runs(["romeo_tpm", "romeo_sns_tpm", "romeo_sns", "romeo_qp"]):
        errs = " / ".join(_f(m, f"error_{k}_max", ".1f", 1e3) for k in ("com", "left_foot", "left_hand", "right_hand"))
        rows.append([f"`{n}`", errs, _f(m, "error_right_sole_position_max", ".2f", 1e3), _f(m, "scale_min", ".3f", 1,
                                                                                          "1.000"),
                     f"{_f(m, 'velocity_limit_steps', 'd')} of {_f(m, 'steps', 'd')}",
                     _f(m, "velocity_limit_excess_max", ".3g")])
    return _table(["run", "CoM / left foot / left hand / right hand max error [mm]", "right sole [mm]", "min scale",
                   "steps with a joint over its velocity limit", "max excess [rad/s]"], rows)


def obstacles_table() -> str:
    rows = []
    for n, m in _runs(["romeo_obstacles_sns_tpm", "romeo_obstacles_qp"]):
        rows.append([f"`{n}`", _f(m, "d_obstacle_min", ".3f"), _f(m, "d_self_min", ".4f"),
                     f"{_f(m, 'velocity_limit_steps', 'd')} of {_f(m, 'steps', 'd')}",
                     " / ".join(_f(m, f"error_{k}_max", ".1f", 1e3)
                                for k in ("com", "left_foot", "right_sole_position")),
                     " / ".join(f"{_f(m, f'error_{k}_max', '.0f', 1e3)} ({_f(m, f'error_{k}_rms', '.0f', 1e3)})"
                                for k in ("left_hand", "right_hand")),
                     _f(m, "scale_min", ".2g")])
    return _table(["run", "min robot–obstacle distance [m]", "min self distance [m]",
                   "steps with a joint over its velocity limit", "CoM / left foot / right sole max error [mm]",
                   "left / right hand max (RMS) error [mm]", "min scale"], rows)


def comanipulation_table() -> str:
    keys = [("σ_m min", "sigma_m_min", ".3f"), ("time with σ_m below 1.5 [s]", "sigma_m_below_threshold_s", ".2f"),
            ("σ_m mean", "sigma_m_mean", ".3f"), ("σ_l max", "sigma_l_max", ".4f"),
            ("largest |q_i − q_i*| [rad]", "joint_deviation_max", ".3f"),
            ("closest approach to a joint limit [rad]", "joint_limit_margin_min", "+.3f"),
            ("largest step of q̇ [rad/s]", "max_dq_jump", ".3f")]
    runs = dict(_runs(["iiwa_comanipulation", "iiwa_admittance"]))
    rows = [[label] + [_f(runs.get(n, {}), key, fmt) for n in ("iiwa_comanipulation", "iiwa_admittance")]
            for label, key, fmt in keys]
    return _table(["", "hierarchy (`iiwa_comanipulation`)", "admittance (`iiwa_admittance`)"], rows)


def planar_table() -> str:
    rows = [[f"`{n}`", _f(m, "d_obstacle_min", ".4f"),
             f"{_f(m, 'ee_error_max', '.2g')} / {_f(m, 'ee_error_max_settled', '.2g')}", _f(m, "max_dq_jump", ".2g"),
             _f(m, "time_below_d_m_s", ".3f")]
            for n, m in _runs(["planar5_exact", "planar5_approximate", "planar5_two_obstacles", "planar5_primary",
                               "planar5_transition", "planar5_pwdls", "planar5_dmp"])]
    return _table(["run", "min link–obstacle distance [m]", "EE error max / settled max [m]",
                   "largest step of q̇ [rad/s]", "time below d_m [s]"], rows)


def plant_table() -> str:
    """Each plant scenario beside its kinematic twin."""
    pairs = [("iiwa_first_controller", "iiwa_mujoco"), ("lwr_relaxed", "lwr_relaxed_mujoco"),
             ("iiwa_comanipulation", "iiwa_comanipulation_mujoco")]
    runs = scenarios()
    rows = []
    for kin, sim in pairs:
        for n in (kin, sim):
            m = runs.get(n)
            if m is None:
                continue
            ee = (f"{_f(m, 'ee_error_max', '.1f', 1e3)} / {_f(m, 'ee_error_rms', '.1f', 1e3)}" if "ee_error_max" in m
                  else f"{_f(m, 'error_position_max', '.1f', 1e3)} / {_f(m, 'error_position_rms', '.1f', 1e3)}")
            rows.append([f"`{n}`", str(m.get("plant", "—")), ee, _f(m, "d_minimal_min", ".4f"),
                         _f(m, "sigma_m_min", ".3f"), _f(m, "joint_limit_margin_min", ".3f"), _f(m, "tau_max", ".1f")])
    return _table(["run", "plant", "EE position error max / RMS [mm]", "min D_minimal [m]", "σ_m min",
                   "closest to a joint limit [rad]", "largest torque [N m]"], rows)


def scenarios_source() -> str:
    doc = json.loads(SCENARIOS.read_text(encoding="utf-8"))
    return (f"*Generated from `benchmarks/results/scenarios.json` ({doc['date']}, code {doc['code']}; "
            f"runs: `{doc['runs']}`, collected by `{doc['written_by']}`).*\n")


BLOCKS = {"speed": speed, "bench": bench, "first_call": first_call, "guarantees": guarantees,
          "lwr_table": lwr_table, "romeo_table": romeo_table, "obstacles_table": obstacles_table,
          "comanipulation_table": comanipulation_table, "planar_table": planar_table, "plant_table": plant_table,
          "scenarios_source": scenarios_source}


ROLE = re.compile(r":(?:class|func|meth|data|mod|attr|exc|obj|py:\w+):(?=<code>)")


def plain_roles(html: str) -> str:
    """``:class:<code>~hqp_tpm.a.B</code>`` (a Sphinx role left in rendered HTML) as ``<code>B</code>``."""
    html = ROLE.sub("", html)
    return re.sub(r"<code>~(?:[\w]+\.)*([\w]+)</code>", r"<code>\1</code>", html)


def render(markdown: str) -> str:
    def block(m):
        name = m.group(1)
        if name not in BLOCKS:
            raise KeyError(f"unknown generated block {name!r}; known: {', '.join(sorted(BLOCKS))}")
        return BLOCKS[name]()

    markdown = MARKER.sub(block, markdown)
    return INLINE.sub(lambda m: value(m.group(1), m.group(2), m.group(3) or "", float(m.group(4) or 1.0)), markdown)
