"""Bad input answered with a typed error that names the file and the field, before any work (issue 13, item 4).

Every test here failed on the code before the fix (a traceback, a silent acceptance or a hang)."""

import math
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from hqp_tpm.app import build, scenario, scenario_values
from hqp_tpm.app.cli import main
from hqp_tpm.errors import HqpTpmError, ScenarioError

BASE = textwrap.dedent("""
    [scenario]
    robot = "lwr4"
    level = "acceleration"
    period = 0.001
    duration = 0.01

    [initial]
    joints_deg = { lwr_joint_2 = 30.0 }

    [[tasks]]
    name = "ee"
    type = "frame_position"
    frame = "lwr_ee"
    kp = 40.0
    kd = 20.0
    target = [0.1, 0.5, 0.2]
""")


def write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def load_and_build(path):
    sc = scenario.load(path)
    return build.build(sc)


def test_base_file_runs(tmp_path):
    load_and_build(write(tmp_path, BASE))


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("duration = 0.01", 'duration = "9**9**9"', r"s\.toml\.scenario\.duration: .*exponent"),
        ("duration = 0.01", 'duration = "10.0**60 * 10.0**60"', r"scenario\.duration: .*too large"),
        ("duration = 0.01", 'duration = "1' + "0" * 190 + '"', r"scenario\.duration: .*too large"),
        ("duration = 0.01", 'duration = "__import__(\'os\')"', r"scenario\.duration: "),
        ("duration = 0.01", 'duration = "(1).__class__"', r"scenario\.duration: "),
        ("duration = 0.01", 'duration = "1/0"', r"scenario\.duration: .*division by zero"),
        ("duration = 0.01", "duration = 1e308", r"scenario\.duration: .*too large"),
        ("period = 0.001", "period = 1e-300", r"scenario\.duration: .*10,000,000 steps"),
        ("duration = 0.01", "duration = 1e6", r"scenario\.duration: .*10,000,000 steps"),
        ("duration = 0.01", "duration = 0.01\nlambda_max = -0.05", r"scenario\.lambda_max: must be >= 0"),
        ("duration = 0.01", "duration = 0.01\neps = nan", r"scenario\.eps: .*not finite"),
        ("duration = 0.01", "duration = 0.01\nnullspace_damping = -5", r"scenario\.nullspace_damping: must be >= 0"),
        ("lwr_joint_2 = 30.0", 'lwr_joint_2 = "thirty"', r"initial\.joints_deg\.lwr_joint_2: "),
        ("lwr_joint_2 = 30.0", "lwr_joint_2 = [30.0]", r"initial\.joints_deg\.lwr_joint_2: "),
        ("lwr_joint_2 = 30.0", "lwr_joint_2 = true", r"initial\.joints_deg\.lwr_joint_2: expected a number"),
        ("lwr_joint_2 = 30.0", "lwr_joint_2 = nan", r"initial\.joints_deg\.lwr_joint_2: nan is not finite"),
        ("lwr_joint_2 = 30.0", "lwr_joint_2 = inf", r"initial\.joints_deg\.lwr_joint_2: inf is not finite"),
        ("lwr_joint_2 = 30.0", "lwr_joint_2 = 3000.0", r"initial: joint 'lwr_joint_2' .* outside its limits"),
        ("joints_deg = { lwr_joint_2 = 30.0 }", "q = [0, 1e300, 0, 0, 0, 0, 0]", r"initial\.q\[1\]: .*too large"),
        ("joints_deg = { lwr_joint_2 = 30.0 }", "q = [0, 100, 0, 0, 0, 0, 0]",
         r"initial: joint 'lwr_joint_2' = 100 rad .* outside its limits"),
        ("kp = 40.0", "kp = 1e300", r"tasks\[0\]\.kp: .*too large"),
        ("duration = 0.01", 'duration = 0.01\nsolver = "tpm"\n[limits]\nvelocity = true',
         r"s\.toml\.limits: a hard joint box, which solver 'tpm' .*ignores; valid: .*sns_tpm"),
        ("duration = 0.01", 'duration = 0.01\n[limits]\nvelocity = true',
         r"limits: .*solver 'tpm' \(s\.toml\.scenario\.solver\)"),
    ],
)
def test_bad_field_is_a_scenario_error_naming_it(tmp_path, old, new, match):
    assert old in BASE
    path = write(tmp_path, BASE.replace(old, new))
    t0 = time.perf_counter()
    with pytest.raises(ScenarioError, match=match):
        load_and_build(path)
    assert time.perf_counter() - t0 < 5.0


def test_expressions_still_work(tmp_path):
    for text, value in [("6*pi", 6 * math.pi), ("2*pi/3", 2 * math.pi / 3), ("-1e-3", -1e-3), ("2**-3", 0.125),
                        ("(1+2)*3", 9.0), (" 1 / 4 ", 0.25)]:
        assert scenario_values.number(text, "x") == pytest.approx(value, rel=1e-15)


def test_power_tower_is_refused_at_once():
    t0 = time.perf_counter()
    with pytest.raises(ScenarioError, match="f.g"):
        scenario_values.number("9**9**9", "f.g")
    assert time.perf_counter() - t0 < 1.0


def test_non_utf8_file_names_the_file(tmp_path):
    p = tmp_path / "latin1.toml"
    p.write_bytes(BASE.replace("[scenario]", "# caf\xe9\n[scenario]").encode("latin-1"))
    with pytest.raises(ScenarioError, match=r"latin1\.toml: not UTF-8"):
        scenario.load(p)


def test_eps1_above_eps2_names_the_field(tmp_path):
    text = (scenario.SCENARIO_DIR / "lwr_relaxed.toml").read_text().replace("eps1 = 0.05", "eps1 = 0.2")
    with pytest.raises(ScenarioError, match=r"policy\.eps1: need 0 < eps1 < eps2"):
        load_and_build(write(tmp_path, text, "lwr.toml"))


def test_library_errors_are_hqp_tpm_errors():
    from hqp_tpm.control.controller import Controller
    from hqp_tpm.policies.algorithm1 import Thresholds
    from hqp_tpm.references.line import Line
    from hqp_tpm.tasks.base import Gains

    for call in (lambda: Thresholds(0.2, 0.1), lambda: Gains(kp=-1.0),
                 lambda: Line(start_point=[0.0], end_point=[1.0], v_max=0.0),
                 lambda: Controller(None, [], order=3), lambda: Controller(None, [], dt=0.0)):
        with pytest.raises(HqpTpmError):
            call()
        with pytest.raises(ValueError):  # the builtin base is kept
            call()


@pytest.mark.parametrize("kw", [{"lambda_max": -0.1}, {"lambda_max": float("nan")}, {"eps": -1.0},
                                {"nullspace_damping": float("nan")}, {"nullspace_damping": -5.0}])
def test_controller_refuses_bad_damping(kw):
    from hqp_tpm.control.controller import Controller
    from hqp_tpm.robot.model import Robot
    from hqp_tpm.tasks import Posture

    robot = Robot.load("lwr4")
    name = next(iter(kw))
    with pytest.raises(HqpTpmError, match=name):
        Controller(robot, [Posture(robot)], **kw)  # (an empty stack is refused: tests/test_user_mistakes.py)


@pytest.mark.parametrize("solver", ["tpm", "nullspace", "qp"])
@pytest.mark.parametrize("bad", [{"x0": [np.nan, 0.0, 0.0]}, {"x0": [1.0, 2.0]}, {"lambda_max": -1.0},
                                 {"eps": float("nan")}])
def test_solvers_check_x0_and_damping(solver, bad):
    from hqp_tpm.solvers.registry import solve

    J = np.array([[1.0, 0.0, 0.0]])
    t0 = time.perf_counter()
    with pytest.raises(HqpTpmError, match=next(iter(bad))):
        solve(solver, [(J, np.array([1.0]))], 3, **bad)
    assert time.perf_counter() - t0 < 5.0


@pytest.mark.parametrize("steps", ["0", "-5"])
def test_cli_steps_must_be_positive(tmp_path, capsys, steps):
    path = write(tmp_path, BASE)
    code = main(["run", str(path), "--out", str(tmp_path / "o"), "--steps", steps, "--quiet", "--no-figures",
                 "--no-replay"])
    assert code == 2
    err = capsys.readouterr().err
    assert "--steps" in err and "1 .. 10,000,000" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_metrics_json_is_strict(tmp_path):
    import json

    from hqp_tpm.app import results

    arrays = {"t": np.array([0.0, 0.001]), "dq": np.array([[0.0], [np.inf]]), "stack": np.array(["a", "a"]),
              "d_minimal": np.array([np.nan, np.nan])}
    summary = {"scenario": "x", **results.metrics(arrays, {"wall_time_s": 1.0}, {})}
    results.write(tmp_path, arrays, summary)
    text = (tmp_path / "metrics.json").read_text()
    data = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    assert data["max_abs_dq"] is None and "not finite" in data["max_abs_dq_reason"]


def test_list_into_a_closed_pipe_is_quiet(tmp_path):
    import subprocess
    import sys

    proc = subprocess.run(f"{sys.executable} -m hqp_tpm.app.cli list | head -1", shell=True, capture_output=True,
                          text=True, timeout=120)
    assert proc.stdout.count("\n") == 1
    assert "Traceback" not in proc.stderr and "BrokenPipeError" not in proc.stderr
