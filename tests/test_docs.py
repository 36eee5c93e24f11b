"""The documentation is self-contained and generated parts are current: the README walkthrough runs as written,
the scenario field reference and the metrics schema match the code, and nothing points outside the repository."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def readme_block(heading: str, lang: str = "python") -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index(heading):]
    m = re.search(rf"```{lang}\n(.*?)```", section, re.S)
    assert m, f"no ```{lang} block after {heading!r}"
    return m.group(1)


def test_readme_controller_example_runs_as_written(tmp_path):
    code = readme_block("## Your first controller")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("Robot('iiwa7', nq=7, nv=7")
    assert lines[1] == "Stack('ee > pointing > posture', 3 levels)"
    errors = {ln.split()[0]: float(ln.split()[1]) for ln in lines[3:6]}
    assert errors["ee"] < 1e-3 and errors["pointing"] < 1e-3
    assert float(lines[-1]) < 1e-8  # the QP and the TPM give the same command


def test_readme_quick_start_commands_exist():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = readme.split("## Two commands", 1)[1].split("Other commands", 1)[0]
    commands = re.findall(r"^    (make \w+)", block, re.M)
    assert commands == ["make demo", "make test"]
    proc = subprocess.run(["make", "-n", "-C", str(ROOT), "demo", "test"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr


def test_readme_is_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").count("\n")
    assert lines <= 300, f"README.md has {lines} lines: move the material into docs/ pages"


# --- every code block of the README and of the documentation runs ----------------------------------------------

DOC_FILES = ["README.md", "CONTRIBUTING.md"] + sorted(
    str(p.relative_to(ROOT)) for p in (ROOT / "docs").rglob("*.md"))


def code_blocks(lang: str):
    """(file, index, code) of every fenced ``lang`` block of the README, CONTRIBUTING.md and docs/."""
    for name in DOC_FILES:
        path = ROOT / name
        if not path.exists():
            continue
        for i, m in enumerate(re.finditer(rf"^```{lang}\n(.*?)^```", path.read_text(encoding="utf-8"), re.S | re.M)):
            yield name, i, m.group(1)


PYTHON_BLOCKS = list(code_blocks("python"))


def test_the_docs_have_python_blocks():
    files = {name for name, _, _ in PYTHON_BLOCKS}
    assert {"README.md", "docs/getting_started.md", "docs/concepts.md", "docs/humanoids.md",
            "docs/testing.md"} <= files, files


@pytest.mark.slow
@pytest.mark.parametrize("name,index,code", PYTHON_BLOCKS, ids=[f"{n}[{i}]" for n, i, _ in PYTHON_BLOCKS])
def test_python_block_runs_as_written(name, index, code, tmp_path):
    """Each block alone, in a fresh interpreter, in an empty folder: self-contained, nothing defined elsewhere."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "MPLBACKEND": "Agg"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=tmp_path,
                          env=env)
    assert proc.returncode == 0, f"{name}, python block {index}:\n{proc.stderr[-3000:]}"


def shell_lines():
    """Command lines of the docs: fenced bash blocks and the README's indented blocks."""
    for name, _, code in code_blocks("bash"):
        for line in code.splitlines():
            yield name, line.split("#", 1)[0].strip()
    for line in re.findall(r"^    (\S.*)$", (ROOT / "README.md").read_text(encoding="utf-8"), re.M):
        yield "README.md", line.split("#", 1)[0].strip()


def test_shell_commands_name_existing_subcommands_options_and_targets():
    """Cheap checks of every documented command: `hqp-tpm SUB --option` exists (its --help), `make X` is a target."""
    uses: dict[str, set[str]] = {}
    targets = set()
    scenarios = set()
    for _, line in shell_lines():
        words = line.replace(".venv/bin/", "").split()
        if len(words) >= 2 and words[0] == "hqp-tpm":
            uses.setdefault(words[1], set()).update(w.split("=")[0] for w in words[2:] if w.startswith("--"))
            if words[1] in ("run", "sweep") and len(words) > 2 and re.fullmatch(r"[a-z0-9_]+", words[2]):
                scenarios.add(words[2])
        if len(words) >= 2 and words[0] == "make":
            targets.add(words[1])
    assert {"run", "list", "explain", "sweep", "campaign"} <= set(uses), sorted(uses)
    for sub, options in sorted(uses.items()):
        proc = subprocess.run([sys.executable, "-m", "hqp_tpm.app.cli", sub, "--help"], capture_output=True,
                              text=True, timeout=120, cwd=ROOT)
        assert proc.returncode == 0, f"hqp-tpm {sub}: {proc.stderr[-500:]}"
        missing = {o for o in options if o not in proc.stdout}
        assert not missing, f"hqp-tpm {sub} has no option {sorted(missing)} (documented)"
    listed = subprocess.run([sys.executable, "-m", "hqp_tpm.app.cli", "list", "--names"], capture_output=True,
                            text=True, timeout=120, cwd=ROOT)
    assert listed.returncode == 0, listed.stderr
    assert len(scenarios) >= 5 and scenarios <= set(listed.stdout.split()), scenarios - set(listed.stdout.split())
    assert {"demo", "test", "docs"} <= targets, targets
    proc = subprocess.run(["make", "-n", "-C", str(ROOT), *sorted(targets)], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr


def test_scenario_field_reference_is_generated_from_the_parser():
    from hqp_tpm.app.scenario_reference import BEGIN, END, fields, reference

    doc = (ROOT / "docs" / "scenario_format.md").read_text(encoding="utf-8")
    block = doc[doc.index(BEGIN):doc.index(END) + len(END)] + "\n"
    assert block == reference(), "docs/scenario_format.md is stale: python -m hqp_tpm.app.scenario_reference --write"
    documented = set(re.findall(r"^\| `([a-z_0-9]+)` \|", block, re.M))
    parsed = {f.name for f in fields()}
    assert parsed <= documented, parsed - documented
    for must in ("position", "velocity", "acceleration_limit", "velocity_scale", "phase", "value", "alpha_d_deg"):
        assert must in documented


def test_shipped_scenarios_use_documented_fields_only():
    import tomllib

    from hqp_tpm.app.scenario import SCENARIO_DIR
    from hqp_tpm.app.scenario_reference import fields

    documented = {f.name for f in fields()} | {"extends", "remove"}

    def keys(obj):
        if isinstance(obj, dict):
            for k, v in obj.items():
                yield k
                yield from keys(v) if k not in ("joints_deg",) else ()
        elif isinstance(obj, list):
            for v in obj:
                yield from keys(v)

    for path in sorted(SCENARIO_DIR.glob("*.toml")):
        unknown = set(keys(tomllib.loads(path.read_text()))) - documented
        assert not unknown, f"{path.name}: {unknown}"
    doc = (ROOT / "docs" / "scenario_format.md").read_text(encoding="utf-8")
    for path in SCENARIO_DIR.glob("*.toml"):
        assert f"`{path.stem}`" in doc, f"scenario {path.stem} is not described in docs/scenario_format.md"


def test_metrics_schema_doc_is_current():
    from hqp_tpm.app.results import metrics_doc

    assert (ROOT / "docs" / "metrics.md").read_text(encoding="utf-8") == metrics_doc(), (
        "docs/metrics.md is stale: python -m hqp_tpm.app.results > docs/metrics.md")


def tracked_text_files():
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True)
    if out.returncode != 0:
        pytest.skip("not a git checkout")
    for name in out.stdout.splitlines():
        path = ROOT / name
        if path.suffix in (".png", ".npz", ".ipynb") or not path.is_file():
            continue
        try:
            yield name, path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue


def test_nothing_points_outside_the_repository():
    pattern = re.compile(r"\.\./shared|/work/|/home/\w|shared/(?:papers|reference|notes)/|/tmp/[A-Za-z]")
    bad = [f"{name}:{text[:m.start()].count(chr(10)) + 1}: {m.group(0)}"
           for name, text in tracked_text_files() if name != "tests/test_docs.py"
           for m in pattern.finditer(text)]
    assert not bad, bad


def test_papers_are_cited_with_dois():
    text = (ROOT / "docs" / "papers.md").read_text(encoding="utf-8")
    for doi in ("10.1109/LRA.2020.3004771", "10.1007/978-3-319-14705-5_5"):
        assert doi in text
    assert "docs/papers.md" in (ROOT / "README.md").read_text(encoding="utf-8")


def test_crosscheck_is_explained_in_help_and_docs():
    from hqp_tpm.app.cli import CROSSCHECK_HELP
    from hqp_tpm.app.results import METRICS

    page = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    for key in ("crosscheck_max_diff", "crosscheck_max_diff_same_problem", "crosscheck_steps_different_problems"):
        assert key in METRICS and key in CROSSCHECK_HELP and f"`{key}`" in page


def test_commit_message_checker():
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        from check_commit_message import MAX_SUBJECT, problems
    finally:
        sys.path.pop(0)
    assert problems("Fix the box\n\nevidence: 0 of 100 outside") == []
    assert problems("x" * (MAX_SUBJECT + 1)) == [f"subject has {MAX_SUBJECT + 1} characters (at most {MAX_SUBJECT})"]
    assert problems("Subject\nbody at once") == ["no blank line between the subject and the body"]
    assert problems("# only a comment\n") == ["empty subject"]


def test_generated_speed_page_survives_a_new_report_format(tmp_path, monkeypatch):
    """tools/docs_site.py takes whatever `make bench-peers` writes: other columns, links, figures, no CSV."""
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import docs_site
    finally:
        sys.path.pop(0)
    (tmp_path / "peers").mkdir()
    (tmp_path / "peers" / "fig.png").write_bytes(b"png")
    (tmp_path / "peers.md").write_text("# Peers\n\nSee [the notes](../README.md).\n\n"
                                       "![a](peers/fig.png) ![b](gone.png)\n")
    (tmp_path / "peers.csv").write_text("problem,phase,contender,median_us,ratio_median,env\n"
                                        "iiwa,step,hqp-tpm tpm,30.5,1,pin4\niiwa,step,PlaCo,6.0,0.2,pin38\n")
    monkeypatch.setattr(docs_site, "RESULTS", tmp_path)
    page = docs_site.speed()
    assert "30.5 µs (1.00×) [pin4]" in page and "6 µs (0.20×) [pin38]" in page
    assert "## Peers" in page and "the notes (`../README.md`)" in page
    assert "![a](results/peers/fig.png)" in page and "gone.png` is not in benchmarks/results" in page
    assert [p.name for p in docs_site.result_images()] == ["fig.png"]
    (tmp_path / "peers.csv").write_text("case,time\nx,1\n")
    assert "no `problem`/`contender` columns" in docs_site.speed()
    (tmp_path / "peers.csv").unlink()
    assert "peers.csv` is missing" in docs_site.speed()
