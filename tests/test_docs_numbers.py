"""No number in the README or the documentation without a results file behind it.

Each hand-written page names the files its numbers come from in an HTML comment near the top,
``<!-- sources: benchmarks/results/scenarios.json, hqp_tpm/data/scenarios/*.toml -->`` (results files written by
the benchmarks and tools, the scenario files and code whose parameters a page quotes, or another page). Every
number in the page's prose (outside code blocks, inline code, links and the generated blocks
``<!-- generated: ... -->`` / ``[[scenario.metric]]``, which tools/docs_site.py fills from the results files) must
occur in one of those files, as written or rounded to the digits the page shows (also in mm for m, in % of a
fraction). Small counts (0-12), publication years, DOIs, equation, figure, section and algorithm numbers are not
checked.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Pages that are generated and checked against their generator by other tests (or are results files).
GENERATED = {"docs/metrics.md": "tests/test_docs.py::test_metrics_schema_doc_is_current",
             "docs/scenario_format.md": "tests/test_docs.py (generated from the parser)",
             "docs/sns_residual_gaps.md": "written by docs/sns_residual_gaps.py (a results file)"}

SOURCES = re.compile(r"<!-- sources: (.*?) -->", re.S)
NUMBER = re.compile(r"(?<![\w/.\-+])[-+−]?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:[eE][-+−]?\d+)?(?![\w])")
NUMBER_IN_SOURCE = re.compile(r"[-+]?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:[eE][-+]?\d+)?")
# references to the papers' own numbering, not quantities
EXEMPT_CONTEXT = re.compile(r"(?:\b(?:eqs?|Eqs?|Figs?|Sec|Secs|Table|Algorithm|issue|Issue|papers|step|steps|level|"
                            r"joint|Notebook|notebook|item|draw|version|pin|Python|v|vol|no|pp)\.?\s*$)")
YEAR = re.compile(r"^(?:19[5-9]\d|20[0-3]\d)$")  # publication years in citations


def pages() -> list[str]:
    names = ["README.md", "CONTRIBUTING.md"] + sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").rglob("*.md"))
    return [n for n in names if (ROOT / n).exists() and n not in GENERATED]


LIST_ITEM = re.compile(r"^\s*(?:[-*+]|\d+\.)\s")


def drop_indented_code(text: str) -> str:
    """Indented code blocks (4 spaces after a blank line, not inside a list item) blanked out."""
    out, in_code, in_list, prev_blank = [], False, False, True
    for line in text.split("\n"):
        blank = not line.strip()
        indented = line.startswith("    ") or line.startswith("\t")
        if in_code and (indented or blank):
            out.append("")
            continue
        in_code = False
        if indented and prev_blank and not in_list:
            in_code = True
            out.append("")
            continue
        if not blank:
            in_list = bool(LIST_ITEM.match(line)) or (in_list and line.startswith(" "))
        out.append(line)
        prev_blank = blank
    return "\n".join(out)


def prose(text: str) -> str:
    """The page without what is not prose: code, generated blocks, links' targets, HTML comments, images."""
    text = re.sub(r"```.*?```", " ", text, flags=re.S)
    text = drop_indented_code(text)
    text = re.sub(r"<!--.*?-->", " ", text, flags=re.S)
    text = re.sub(r"\[\[.*?\]\]", " ", text)
    text = re.sub(r"`[^`]*`", " ", text)
    text = re.sub(r"!\[[^\]]*\]\([^)]*\)", " ", text)
    text = re.sub(r"\]\([^)]*\)", "] ", text)
    text = re.sub(r"https?://\S+", " ", text)
    text = re.sub(r"\b10\.\d{4,}/\S+", " ", text)  # DOIs
    text = re.sub(r"\bpp\. \d+[–-]\d+", " ", text)  # page ranges of citations
    text = re.sub(r"\(\d+[a-z]?\)(?:\s*[–-]\s*\(\d+[a-z]?\))?", " ", text)  # equation numbers (28), (5)-(6)
    text = re.sub(r"\b\d+-D\b", " ", text)  # 1-D, 3-D
    return text


def to_float(token: str) -> float:
    return float(token.replace(",", "").replace("−", "-"))


def source_numbers(page: str, text: str) -> tuple[list[str], set[float]]:
    m = SOURCES.search(text)
    if m is None:
        return [], set()
    files = []
    for pattern in (s.strip() for s in m.group(1).split(",") if s.strip()):
        found = sorted(ROOT.glob(pattern))
        assert found, f"{page}: source {pattern!r} matches no file"
        files += found
    values = set()
    for f in files:
        for tok in NUMBER_IN_SOURCE.findall(f.read_text(encoding="utf-8", errors="replace")):
            try:
                values.add(abs(to_float(tok)))
            except ValueError:
                pass
    return [str(f.relative_to(ROOT)) for f in files], values


def decimals(token: str) -> int:
    mant = token.replace(",", "").lstrip("+-−").split("e")[0].split("E")[0]
    return len(mant.split(".")[1]) if "." in mant else 0


def matches(token: str, values: set[float]) -> bool:
    x = abs(to_float(token))
    if "e" in token.lower():  # 1e-9: the same value to the digits shown
        digits = decimals(token)
        return any(math.isclose(v, x, rel_tol=0.5 * 10 ** -digits + 1e-12) for v in values)
    d = decimals(token)
    half = 0.5 * 10 ** -d + 1e-12
    for scale in (1.0, 1e3, 1e-3, 100.0):  # as written, m <-> mm, a fraction in %
        for v in values:
            if abs(v * scale - x) <= half * (1 + 1e-9):
                return True
    return False


def unbacked(page: str) -> list[str]:
    text = (ROOT / page).read_text(encoding="utf-8")
    _, values = source_numbers(page, text)
    body = prose(text)
    bad = []
    for m in NUMBER.finditer(body):
        tok = m.group(0)
        before = body[max(0, m.start() - 12):m.start()]
        if EXEMPT_CONTEXT.search(before):
            continue
        if "." not in tok and "e" not in tok.lower() and abs(to_float(tok)) <= 12:
            continue
        if YEAR.match(tok):
            continue
        if not values:
            bad.append(f"{page}: a number ({tok}) but no <!-- sources: ... --> comment naming the files it comes from")
        elif not matches(tok, values):
            line = body[:m.start()].count("\n") + 1
            bad.append(f"{page}:{line}: {tok}  (…{body[max(0, m.start() - 40):m.end() + 20]!r}…)")
    return bad


@pytest.mark.parametrize("page", pages())
def test_every_number_has_a_results_file(page):
    bad = unbacked(page)
    assert not bad, ("numbers not found in the page's <!-- sources: --> files (quote them from a results file, "
                     "generate them, or move the history to CHANGELOG.md):\n" + "\n".join(bad))


def test_the_checker_catches_an_unbacked_number(tmp_path, monkeypatch):
    page = tmp_path / "p.md"
    page.write_text("<!-- sources: pyproject.toml -->\nThe step takes 123.45 µs; `9.99` in code is fine; eq. (28).\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path, raising=False)
    (tmp_path / "pyproject.toml").write_text("x = 1.5\n")
    assert [b.split(": ")[1].split()[0] for b in unbacked("p.md")] == ["123.45"]
    page.write_text("<!-- sources: pyproject.toml -->\nThe ratio is 1.5 and 1,500 mm.\n")
    assert unbacked("p.md") == []
    page.write_text("<!-- sources: pyproject.toml -->\n- a list\n    - nested: 77.7 s\n\nText.\n\n    code 88.8\n")
    assert [b.split(": ")[1].split()[0] for b in unbacked("p.md")] == ["77.7"]


def test_the_reproductions_claims_hold_in_the_results_file():
    """docs/reproductions.md states these comparisons in words; they must hold in the numbers it is built from."""
    import json

    runs = json.loads((ROOT / "benchmarks" / "results" / "scenarios.json").read_text(encoding="utf-8"))["scenarios"]

    def g(name, key):
        return runs[name][key]

    eps1, d_m = 0.05, 0.2  # lwr_relaxed's policy.eps1, the planar scenarios' d_m (their TOML files)
    claims = {
        "acceleration level: smaller q-dot jumps": g("lwr_relaxed", "max_dq_jump") < g("lwr_velocity", "max_dq_jump"),
        "1-D avoidance: D_minimal below eps1 (not reproduced)": g("lwr_relaxed", "d_minimal_min") < eps1,
        "velocity level: D_minimal above eps1": g("lwr_velocity", "d_minimal_min") > eps1,
        "3-D avoidance comes closer": g("lwr_avoid3d", "d_minimal_min") < g("lwr_relaxed", "d_minimal_min"),
        "3-D avoidance: more stack changes": g("lwr_avoid3d", "stack_changes") > g("lwr_relaxed", "stack_changes"),
        "3-D avoidance: larger jumps": g("lwr_avoid3d", "max_dq_jump") > g("lwr_relaxed", "max_dq_jump"),
        "equality pointing in every stack": all("pointing" in k for k in runs["lwr_point35_equality"]
                                                 if k.startswith("time_in_stack_s.")),
        "inequality pointing leaves the stack": "time_in_stack_s.ee > avoid" in runs["lwr_point35_inequality"],
        "TPM exceeds the velocity limits": g("romeo_tpm", "velocity_limit_steps") > 0,
        "the boxed solvers never do": all(g(n, "velocity_limit_steps") == 0 for n in (
            "romeo_sns_tpm", "romeo_sns", "romeo_qp", "romeo_obstacles_sns_tpm", "romeo_obstacles_qp")),
        "SNS-TPM with the rate bound never scales": g("romeo_sns_tpm", "scale_min") == 1.0,
        "no distance below zero": all(g(n, k) > 0 for n in ("romeo_obstacles_sns_tpm", "romeo_obstacles_qp")
                                      for k in ("d_obstacle_min", "d_self_min")),
        "hierarchy keeps sigma_m higher": g("iiwa_comanipulation", "sigma_m_min") > g("iiwa_admittance", "sigma_m_min"),
        "admittance passes a joint limit, the hierarchy does not":
            g("iiwa_admittance", "joint_limit_margin_min") < 0 < g("iiwa_comanipulation", "joint_limit_margin_min"),
        "sigma_l not lower with the hierarchy": g("iiwa_comanipulation", "sigma_l_max") >= g("iiwa_admittance",
                                                                                             "sigma_l_max"),
        "exact avoidance above d_m": g("planar5_exact", "d_obstacle_min") > d_m,
        "approximate comes closer": g("planar5_approximate", "d_obstacle_min") < g("planar5_exact", "d_obstacle_min"),
        "transition smoother": g("planar5_transition", "max_dq_jump") < g("planar5_primary", "max_dq_jump"),
        "PWDLS closer than the transition": g("planar5_pwdls", "d_obstacle_min") < g("planar5_transition",
                                                                                     "d_obstacle_min"),
        "transition not closer than primary (not reproduced)": g("planar5_transition", "d_obstacle_min") > g(
            "planar5_primary", "d_obstacle_min"),
    }
    assert all(claims.values()), [k for k, v in claims.items() if not v]
