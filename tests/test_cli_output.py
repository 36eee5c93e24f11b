"""What every subcommand prints (issue 32, item 6): output that ends with a newline, and ``--quiet`` quiet.

``--quiet`` prints nothing on success for the commands whose results are files (run, sweep); errors and
failed variants still go to stderr. ``campaign`` writes no file, so its result is still printed.
"""

import json

import pytest

from hqp_tpm.app.cli import main


@pytest.fixture(scope="module")
def explained_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "run"
    assert main(["run", "planar5_exact", "--steps", "20", "--out", str(out), "--quiet", "--explain", "--no-replay",
                 "--no-figures"]) == 0
    return out


def _printed(capsys, argv, code=0):
    capsys.readouterr()
    assert main(argv) == code
    return capsys.readouterr()


@pytest.mark.parametrize("kind", ["run", "explain", "explain-no-account", "list", "list-names", "sweep",
                                  "campaign-replay"])
def test_every_output_ends_with_a_newline(kind, explained_run, tmp_path, capsys):
    argv = {"run": ["run", "planar5_exact", "--steps", "10", "--out", str(tmp_path / "r"), "--no-replay",
                    "--no-figures"],
            "explain": ["explain", str(explained_run), "--t", "0.01"],
            "explain-no-account": None,
            "list": ["list"], "list-names": ["list", "--names"],
            "sweep": ["sweep", "planar5_exact", "--set", "policy.d_m=0.15,0.25", "--steps", "5", "--workers", "0",
                      "--out", str(tmp_path / "s")],
            "campaign-replay": ["campaign", "sns", "--replay", "3"]}[kind]
    if argv is None:  # a run recorded without --explain: explain says so, after the step it can show
        assert main(["run", "planar5_exact", "--steps", "10", "--out", str(tmp_path / "n"), "--quiet",
                     "--no-replay", "--no-figures"]) == 0
        argv = ["explain", str(tmp_path / "n"), "--t", "0.005"]
    out = _printed(capsys, argv).out
    assert out and out.endswith("\n") and not out.endswith("\n\n"), repr(out[-80:])


def test_quiet_is_quiet_on_every_subcommand(tmp_path, capsys):
    """0d7b885: ``run --quiet`` printed the metrics; 7f723e3: ``sweep --quiet`` printed its summary line."""
    printed = _printed(capsys, ["run", "planar5_exact", "--steps", "10", "--out", str(tmp_path / "r"), "--quiet"])
    assert printed.out == "" and printed.err == ""
    printed = _printed(capsys, ["sweep", "planar5_exact", "--set", "policy.d_m=0.15,0.25", "--steps", "5",
                                "--workers", "0", "--out", str(tmp_path / "s"), "--quiet"])
    assert printed.out == "" and printed.err == "", printed
    assert len((tmp_path / "s" / "summary.csv").read_text().splitlines()) == 3
    printed = _printed(capsys, ["campaign", "sns", "--draws", "4", "--chunk", "2", "--workers", "0", "--quiet"])
    assert printed.err == "" and json.loads(printed.out)["draws"] == 4  # the result: no file holds it


def test_quiet_sweep_still_reports_failed_variants(tmp_path, capsys):
    printed = _printed(capsys, ["sweep", "planar5_exact", "--set", "policy.d_m=-1.0", "--steps", "5", "--workers", "0",
                                "--out", str(tmp_path / "s"), "--quiet"], code=1)  # (a misspelt field: no run at all)
    assert printed.out == ""
    assert "1 of 1 variants failed" in printed.err and "summary.md" in printed.err


def test_quiet_keeps_the_first_run_compile_notice_quiet(tmp_path, capsys, monkeypatch):
    """42742a8: the first run's "compiling kernels" notice went to stderr under ``--quiet`` (on a machine whose numba
    cache lacked a kernel the run calls); a run without ``--quiet`` still prints it."""
    from hqp_tpm import _jit
    from hqp_tpm.app import cli

    real = cli.run_scenario

    def compiling_run(*args, **kwargs):  # what numba's first compile of a kernel does during the run
        _jit.notice(_jit.COMPILING)
        return real(*args, **kwargs)

    monkeypatch.setattr(cli, "run_scenario", compiling_run)
    printed = _printed(capsys, ["run", "planar5_exact", "--steps", "5", "--out", str(tmp_path / "q"), "--quiet"])
    assert printed.out == "" and printed.err == ""
    printed = _printed(capsys, ["run", "planar5_exact", "--steps", "5", "--out", str(tmp_path / "l"), "--no-replay",
                                "--no-figures"])
    assert _jit.COMPILING in printed.err
