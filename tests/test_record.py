"""Results from Python (issue 32, item 4): ``hqp_tpm.record`` writes the folder ``hqp-tpm run`` writes.

Failed on 0d7b885: there was no public call (``hqp_tpm.record`` did not exist; notebooks imported the CLI's
``run_scenario``) and ``StepResult``'s docstring did not say what ``levels`` holds.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import hqp_tpm
from hqp_tpm import Controller, FramePosition, Gains, Harmonic, Posture, Robot
from hqp_tpm.app.cli import main
from hqp_tpm.errors import ParameterError


def _controller():
    robot = Robot.load("lwr4")
    ee = FramePosition(robot, "lwr_ee", Harmonic(relative=True, center=[0, 0, 0], cos_amplitude=[0, 0, 0],
                                                         sin_amplitude=[0.0, 0.05, 0.0], omega=2.0), Gains(kp=10.0),
                       name="ee")
    q0 = robot.configuration({"lwr_joint_1": 0.3, "lwr_joint_3": 0.4, "lwr_joint_4": 1.2})
    return Controller(robot, [ee, Posture(robot, q0)], order=1, dt=0.01, solver="tpm", q0=q0)


def test_record_a_controller_writes_the_clis_folder(tmp_path):
    summary = hqp_tpm.record(_controller(), tmp_path / "mine", steps=40, name="mine")
    out = tmp_path / "mine"
    assert summary["out"] == str(out)
    names = {p.name for p in out.iterdir()}
    assert {"trajectory.npz", "metrics.json", "manifest.json", "replay.html", "joint_velocities.png",
            "task_errors.png"} <= names, names
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"] == "mine" and metrics["steps"] == 40 and metrics["status"] == "complete"
    assert metrics["ee_error_max"] < 1e-2
    with np.load(out / "trajectory.npz") as npz:
        assert npz["q"].shape == (40, 7) and {"error_ee", "error_posture", "t", "dq"} <= set(npz.files)
        np.testing.assert_allclose(npz["t"], 0.01 * np.arange(40), atol=1e-12)
    # the same keys as a scenario run of the command line
    assert main(["run", "planar5_exact", "--steps", "10", "--out", str(tmp_path / "cli"), "--quiet"]) == 0
    cli_names = {p.name for p in (tmp_path / "cli").iterdir()}
    assert {"trajectory.npz", "metrics.json", "manifest.json", "replay.html"} <= cli_names & names


def test_record_a_scenario_by_name(tmp_path):
    summary = hqp_tpm.record("planar5_exact", tmp_path / "p", steps=10, figures=False, replay=False)
    assert summary["scenario"] == "planar5_exact" and summary["steps"] == 10
    assert {p.name for p in (tmp_path / "p").iterdir()} == {"trajectory.npz", "metrics.json", "manifest.json"}


def test_record_checks_its_arguments(tmp_path):
    with pytest.raises(ParameterError, match="steps is required"):
        hqp_tpm.record(_controller(), tmp_path / "x")
    robot = Robot.load("lwr4")
    twins = [Posture(robot, name="p"), Posture(robot, name="p")]
    with pytest.raises(ParameterError, match="two tasks are named 'p'"):
        hqp_tpm.record(Controller(robot, [twins[0], twins[1]], order=1, dt=0.01), tmp_path / "y", steps=3)
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_step_result_documents_levels():
    doc = hqp_tpm.StepResult.__doc__
    for word in ("``levels``", "Level", "highest", "assert_solvers_agree", "``command``", "``box``"):
        assert word in doc, word


def test_trajectory_npz_stores_each_array_once(tmp_path):
    """0d7b885 stored ``error_ee`` and ``ee_error``, ``error_pointing`` and ``pointing_error`` bit for bit twice."""
    assert main(["run", "lwr_relaxed", "--steps", "30", "--out", str(tmp_path / "r"), "--quiet", "--no-figures",
                 "--no-replay"]) == 0
    with np.load(tmp_path / "r" / "trajectory.npz") as npz:
        keys = set(npz.files)
        assert {"error_ee", "error_pointing"} <= keys and not {"ee_error", "pointing_error"} & keys, keys
        errors = {k: npz[k].tobytes() for k in keys if "error" in k}
    assert len(set(errors.values())) == len(errors)
    metrics = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert "ee_error_max" in metrics and "pointing_violation_max_deg" in metrics  # the summary still reads them


def test_quiet_prints_nothing(tmp_path, capsys):
    assert main(["run", "planar5_exact", "--steps", "10", "--out", str(tmp_path / "q"), "--quiet"]) == 0
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""
    assert (tmp_path / "q" / "metrics.json").is_file()


@pytest.mark.parametrize("command", [[], ["run"], ["list"], ["explain"], ["sweep"], ["campaign"]])
def test_help_is_plain_text(command, capsys):
    with pytest.raises(SystemExit):
        main([*command, "--help"])
    text = capsys.readouterr().out
    assert "usage: hqp-tpm" in text and "``" not in text and ":class:" not in text


def test_notebooks_use_the_public_call_not_cli_internals():
    from pathlib import Path

    notebooks = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
    assert notebooks
    for path in notebooks:
        text = path.read_text()
        assert "hqp_tpm.app.cli" not in text and "run_scenario" not in text, path.name
    assert sum("from hqp_tpm import record" in p.read_text() for p in notebooks) >= 3


def test_the_readme_names_the_notebook_command_and_it_runs(tmp_path):
    """0d7b885's README had no command to run the notebooks. The one it gives now runs (on the first notebook)."""
    import os
    import shlex
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    lines = [ln.strip() for ln in (root / "README.md").read_text().splitlines() if "jupyter nbconvert" in ln]
    assert len(lines) == 1 and lines[0].endswith("notebooks/*.ipynb"), lines
    args = shlex.split(lines[0])
    assert args[0] == ".venv/bin/jupyter"
    args = [sys.executable, "-m", "jupyter", *args[1:-1], str(root / "notebooks" / "01_compose_a_stack.ipynb")]
    args[args.index("runs/notebooks")] = str(tmp_path)
    env = {**os.environ, "HQP_TPM_NOTEBOOK_STEPS": "300", "MPLBACKEND": "Agg"}
    out = subprocess.run(args, capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    assert (tmp_path / "01_compose_a_stack.ipynb").is_file()


def test_notebook_02_embeds_the_replay_without_ipythons_iframe_warning():
    """0d7b885's notebook 02 printed IPython's "Consider using IPython.display.IFrame instead" warning."""
    import warnings
    from pathlib import Path

    import nbformat
    from IPython.display import HTML

    nb = nbformat.read(Path(__file__).resolve().parents[1] / "notebooks" / "02_relaxed_constraints.ipynb", 4)
    line = next(ln for c in nb.cells if c.cell_type == "code" for ln in c.source.splitlines() if "HTML(" in ln)
    shown = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        eval(line, {"HTML": HTML, "display": shown.append, "html": '<p class="x">replay</p>'})  # noqa: S307
    assert "srcdoc=" in shown[0].data and "&quot;x&quot;" in shown[0].data
