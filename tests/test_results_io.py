"""Results on disk are never lost or mixed, and memory does not grow with the run (issue 13, items 2-3).

Each test failed on the code before the fix (in-place writes, a shared temp name, no manifest, no partial
result on a signal, every step kept in Python lists)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hqp_tpm.app.cli import main, run_scenario

QUIET = ["--quiet", "--no-replay"]


def cli(*args) -> int:
    return main([*map(str, args)])


def files(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir()}


def leftovers(parent: Path) -> list[str]:
    return [p.name for p in parent.iterdir() if p.name.startswith(".")]


def test_out_is_a_file_is_refused_before_computing(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    t0 = time.perf_counter()
    assert cli("run", "planar5_exact", "--out", f, *QUIET) == 2
    assert time.perf_counter() - t0 < 20
    err = capsys.readouterr().err
    assert "is a file" in err and "Traceback" not in err
    assert f.read_text() == "x" and leftovers(tmp_path) == []


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX permissions")
def test_read_only_out_is_refused_before_computing(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        assert cli("run", "planar5_exact", "--out", ro, "--steps", 50, *QUIET) == 2
        assert "read-only" in capsys.readouterr().err
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)


def test_foreign_folder_needs_force(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("keep me")
    assert cli("run", "planar5_exact", "--out", out, "--steps", 20, "--no-figures", *QUIET) == 2
    assert "--force" in capsys.readouterr().err
    assert files(out) == {"thesis.tex"}
    assert cli("run", "planar5_exact", "--out", out, "--steps", 20, "--no-figures", "--force", *QUIET) == 0
    assert "thesis.tex" not in files(out) and "manifest.json" in files(out)


def test_manifest_and_no_stale_figures_of_another_scenario(tmp_path):
    out = tmp_path / "out"
    assert cli("run", "lwr_relaxed", "--out", out, "--steps", 30, *QUIET) == 0
    assert "pointing_error.png" in files(out)
    assert cli("run", "planar5_exact", "--out", out, "--steps", 30, *QUIET) == 0
    assert "pointing_error.png" not in files(out)  # lwr_relaxed's figure is gone with its run
    m = json.loads((out / "manifest.json").read_text())
    assert (m["tool"], m["scenario"], m["steps"], m["status"]) == ("hqp-tpm", "planar5_exact", 30, "complete")
    assert set(m["files"]) == files(out) - {"manifest.json"}
    assert leftovers(tmp_path) == []


def test_failure_while_writing_keeps_the_previous_result(tmp_path, monkeypatch):
    out = tmp_path / "out"
    assert cli("run", "planar5_exact", "--out", out, "--steps", 30, *QUIET) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    from hqp_tpm.app import figures

    def boom(*a, **k):
        raise KeyboardInterrupt  # a signal in the write phase

    monkeypatch.setattr(figures, "write_all", boom)
    with pytest.raises(KeyboardInterrupt):
        run_scenario("planar5_exact", out, steps=40, progress=False, replay=False)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert leftovers(tmp_path) == []


def _spawn(*args) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([sys.executable, "-m", "hqp_tpm.app.cli", *map(str, args)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_stepping(parent: Path, name: str, proc, timeout: float = 120.0) -> None:
    t0 = time.time()
    while time.time() - t0 < timeout:
        if list(parent.glob(f".{name}.hqp-tpm-*/.columns/t.npy")) or list(parent.glob(f"{name}*/t.npy")):
            return
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    raise AssertionError("the run did not start stepping")


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_while_stepping_saves_a_partial_run(tmp_path, sig, code):
    out = tmp_path / "out"
    assert cli("run", "planar5_exact", "--out", out, "--steps", 25, "--no-figures", *QUIET) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    proc = _spawn("run", "planar5_exact", "--out", out, "--steps", 2_000_000, "--no-figures", *QUIET)
    try:
        _wait_for_stepping(tmp_path, "out", proc)
        time.sleep(0.5)
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr
    assert len(stderr.strip().splitlines()) == 1 and "partial" in stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # the complete result is untouched
    part = tmp_path / "out.partial"
    m = json.loads((part / "manifest.json").read_text())
    assert m["status"] == "partial" and 0 < m["steps"] < 2_000_000
    t = np.load(part / "trajectory.npz")["t"]
    assert t.shape == (m["steps"],)
    assert json.loads((part / "metrics.json").read_text())["status"] == "partial"
    assert leftovers(tmp_path) == []


def test_concurrent_runs_into_one_folder_leave_one_consistent_result(tmp_path):
    out = tmp_path / "out"
    procs = [_spawn("run", name, "--out", out, "--steps", 300, "--no-figures", *QUIET)
             for name in ("planar5_exact", "planar5_approximate", "planar5_exact")]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
    m = json.loads((out / "manifest.json").read_text())
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"] == m["scenario"] and m["status"] == "complete"
    with np.load(out / "trajectory.npz") as z:
        assert z["q"].shape[0] == 300
    assert leftovers(tmp_path) == []


def test_recording_streams_to_npy_files(tmp_path):
    from hqp_tpm.app import runner

    rec = runner.Recording(["a", "b"], tmp_path / "rec")
    n = runner.CHUNK_ROWS * 2 + 17
    for i in range(n):
        rec.add(t=i * 1e-3, q=np.array([i, -i], dtype=float), stack="ee > pointing" if i % 3 else "ee")
        if i == runner.CHUNK_ROWS + 5:  # the first chunk is on disk, not in memory
            assert rec.columns["q"].rows == runner.CHUNK_ROWS and len(rec.columns["q"].buf) == 6
    rec.close()
    q = np.load(tmp_path / "rec" / "q.npy", mmap_mode="r")
    assert q.shape == (n, 2) and q[-1, 1] == -(n - 1)
    stack = np.load(tmp_path / "rec" / "stack.npy")
    assert stack[0] == "ee" and stack[1] == "ee > pointing" and stack.shape == (n,)
    assert set(rec.arrays()) == {"t", "q", "stack", "joint_names"}


RSS_SCRIPT = """
import resource, sys
from hqp_tpm.app.cli import run_scenario
run_scenario("planar5_exact", sys.argv[1], steps=int(sys.argv[2]), progress=False, replay=False, figures=False)
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def test_peak_memory_is_flat_in_the_number_of_steps(tmp_path):
    rss = []
    for steps in (4_000, 40_000):
        out = subprocess.run([sys.executable, "-c", RSS_SCRIPT, str(tmp_path / f"r{steps}"), str(steps)],
                             capture_output=True, text=True, timeout=600, check=True)
        rss.append(int(out.stdout.split()[-1]))
    assert rss[1] - rss[0] < 15_000, rss  # KB: today's lists grew by ~1 KB per step


def test_metrics_in_blocks_equal_whole_column_metrics(tmp_path, monkeypatch):
    """metrics() reads the columns in blocks: with one block its numbers are those of the whole-column formulas
    (checked here for the jumps, errors, pointing violation and stacks), with blocks of 37 rows the same except the
    RMS values (summation order: 1e-14 relative)."""
    from hqp_tpm.app import results, runner
    from hqp_tpm.app.build import build_run
    from hqp_tpm.app.scenario import load

    ctx = build_run(load("lwr_relaxed"))
    rec, timing = runner.run(ctx.controller, 2500, probes=ctx.probes(),
                             recording=runner.Recording(ctx.robot.joint_names, tmp_path / "rec"))
    arrays = rec.load()
    results.standard_aliases(arrays, ctx.tasks)
    one = results.metrics(arrays, timing, ctx.tasks)
    dq, ee, t = np.asarray(arrays["dq"]), np.linalg.norm(arrays["ee_error"], axis=1), np.asarray(arrays["t"])
    jumps = np.abs(np.diff(dq, axis=0)).max(axis=1)
    assert one["max_dq_jump"] == jumps.max() and one["max_dq_jump_step"] == jumps.argmax() + 1
    assert one["ee_error_rms"] == np.sqrt(np.mean(ee**2)) and one["ee_error_max_settled"] == ee[t >= 2.0].max()
    p = np.clip(np.cos(np.deg2rad(5.0)) - np.asarray(arrays["pointing_error"]), -1.0, 1.0)
    assert one["pointing_violation_max_deg"] == max(0.0, np.rad2deg(np.arccos(p).max() - np.deg2rad(5.0)))
    stack = np.asarray(arrays["stack"])
    assert one["stack_changes"] == int((stack[1:] != stack[:-1]).sum()) > 0
    monkeypatch.setattr(results, "BLOCK_ROWS", 37)
    many = results.metrics(arrays, timing, ctx.tasks)
    assert many.keys() == one.keys()
    for k in one:
        if k.endswith(("_rms", "_rms_settled")):
            assert many[k] == pytest.approx(one[k], rel=1e-14, abs=0), k
        else:
            assert many[k] == one[k], k


def test_blocks_of_a_memory_mapped_column_and_of_its_views(tmp_path):
    from hqp_tpm.app.results import blocks

    a = np.arange(60.0).reshape(20, 3)
    np.save(tmp_path / "a.npy", a)
    m = np.load(tmp_path / "a.npy", mmap_mode="r")
    for view, expect in ((m, a), (m[::-1], a[::-1]), (m[:, 1:], a[:, 1:]), (m[5:], a[5:]), (a, a)):
        got = [b for _, b in blocks(view, rows=6)]
        assert all(type(b) is np.ndarray for b in got)
        np.testing.assert_array_equal(np.concatenate(got), expect)
        over = list(blocks(view, rows=6, overlap=1))
        assert [i for i, _ in over] == list(range(0, len(expect), 6))
        np.testing.assert_array_equal(over[1][1], expect[5:12])


def test_crosscheck_on_no_same_problem_step_is_no_agreement():
    """42742a8: a run whose every step had a binding box one solver ignores (romeo_sns_tpm ``--crosscheck``) wrote
    ``crosscheck_max_diff_same_problem: 0.0``, a maximum over no step that reads as agreement; now null, with why."""
    from hqp_tpm.app.results import dumps, metrics

    n = 5
    arrays = {"t": np.arange(n) * 1e-3, "dq": np.zeros((n, 2)), "stack": np.zeros(n, dtype=np.int64),
              "crosscheck_diff": np.full(n, 0.3), "crosscheck_same_problem": np.zeros(n)}
    data = json.loads(dumps(metrics(arrays, {}, {})))
    assert data["crosscheck_max_diff_same_problem"] is None
    assert "no step" in data["crosscheck_max_diff_same_problem_reason"]
    assert data["crosscheck_steps_different_problems"] == n and data["crosscheck_max_diff"] == 0.3
    arrays["crosscheck_same_problem"][2] = 1.0  # one step solved the same problem: its difference
    data = json.loads(dumps(metrics(arrays, {}, {})))
    assert data["crosscheck_max_diff_same_problem"] == 0.3 and data["crosscheck_steps_different_problems"] == n - 1
