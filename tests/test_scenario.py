"""Scenario files: every shipped file loads and builds; bad files give errors naming the field."""

import textwrap
from pathlib import Path

import numpy as np
import pytest

from hqp_tpm.app import build, scenario
from hqp_tpm.errors import ScenarioError

SHIPPED = sorted(p.stem for p in scenario.SCENARIO_DIR.glob("*.toml"))

BASE = textwrap.dedent("""
    [scenario]
    robot = "lwr4"
    level = "acceleration"
    period = 0.001
    duration = 0.01

    [[tasks]]
    name = "ee"
    type = "frame_position"
    frame = "lwr_ee"
    kp = 40.0
    kd = 20.0
    target = [0.1, 0.5, 0.2]
""")


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "s.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scenarios_build_and_step(name):
    sc = scenario.load(name)
    robot, ctrl, tasks, policy = build.build(sc)
    for _ in range(3):
        ctrl.step()
    assert np.isfinite(ctrl.q).all()


def test_lwr_relaxed_has_the_papers_numbers():
    sc = scenario.load("lwr_relaxed")
    assert sc.steps == 18_850
    assert sc.order == 2 and sc.solver == "tpm"
    assert (sc.lambda_max, sc.eps, sc.nullspace_damping) == (0.05, 0.1, 5.0)


def test_extends_merges_tasks_by_name():
    sc = scenario.load("lwr_point35_equality")
    pointing = next(t for t in sc.tasks if t.data["name"] == "pointing")
    assert pointing.data["alpha_d_deg"] == 35.0 and pointing.data["inequality"] is False
    assert pointing.data["kp"] == 5.0  # inherited
    assert len(sc.policy.data["control_points"]) == 8


def test_minimal_file_runs(tmp_path):
    sc = scenario.load(write(tmp_path, BASE))
    _, ctrl, _, _ = build.build(sc)
    assert sc.steps == 11
    ctrl.step()


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda s: s.replace('type = "frame_position"', 'type = "frame_positon"'),
         r"tasks\[0\]\.type: unknown task type 'frame_positon'; valid types: .*frame_position"),
        (lambda s: s.replace('frame = "lwr_ee"\n', ""), r"tasks\[0\]: missing field 'frame'"),
        (lambda s: s.replace("target = [0.1, 0.5, 0.2]", "target = [0.1, 0.5]"),
         r"tasks\[0\]\.target: expected 3 numbers, got 2"),
        (lambda s: s.replace('level = "acceleration"', 'level = "jerk"'),
         r"scenario\.level: 'jerk' is not one of 'velocity', 'acceleration'"),
        (lambda s: s.replace("period = 0.001", "period = -1"), r"scenario\.period: must be > 0"),
        (lambda s: s.replace('robot = "lwr4"\n', ""), r"scenario: missing field 'robot'"),
        (lambda s: s.replace("kd = 20.0", "kd = 20.0\nkdd = 3"), r"tasks\[0\]: unknown field\(s\) 'kdd'"),
        (lambda s: s.replace('frame = "lwr_ee"', 'frame = "lwr_eee"'), r"unknown frame 'lwr_eee'.*'lwr_ee'"),
        (lambda s: s.replace("period = 0.001", 'period = 0.001\nsolver = "magic"'),
         r"scenario\.solver: unknown solver 'magic'; valid: tpm"),
        (lambda s: s + '\n[policy]\ntype = "fixed"\nlevels = ["ee", "nope"]\n', r"levels\[1\]: unknown task 'nope'"),
        (lambda s: s.replace("duration = 0.01", 'duration = "6*pie"'), r"scenario\.duration"),
        (lambda s: s + '\n[initial]\nq = [0, 0, 0]\n', r"initial\.q: expected 7 numbers, got 3"),
        (lambda s: s + '\n[[obstacles]]\nname = "o"\ntype = "cube"\n', r"obstacles\[0\]\.type: 'cube' is not one of"),
    ],
)
def test_bad_files_name_the_field(tmp_path, edit, match):
    with pytest.raises(ScenarioError, match=match):
        sc = scenario.load(write(tmp_path, edit(BASE)))
        build.build(sc)


def test_unknown_scenario_lists_the_known_ones():
    with pytest.raises(ScenarioError, match="unknown scenario 'nope'.*lwr_relaxed"):
        scenario.load("nope")
    with pytest.raises(ScenarioError, match="not found"):
        scenario.load("missing/file.toml")


def test_invalid_toml(tmp_path):
    with pytest.raises(ScenarioError, match="not valid TOML"):
        scenario.load(write(tmp_path, "[scenario\nrobot ="))


def test_cli_list_names_every_scenario_with_its_description(capsys):
    from hqp_tpm.app.cli import main
    from hqp_tpm.app.scenario import SCENARIO_DIR, load

    assert main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    files = sorted(SCENARIO_DIR.glob("*.toml"))
    assert len(lines) == len(files)
    for line, f in zip(lines, files, strict=True):
        name, _, description = line.partition(" ")
        assert name == f.stem and description.strip() == load(f).description != ""
