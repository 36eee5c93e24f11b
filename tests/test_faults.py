"""The faults of issue 31, item 3, each answered (every test here failed on main at 0d7b885).

Disk full / file-size limit, a killed sweep's workers, deep nesting, a symbolic-link ``--out``, megabyte
messages, a repeated level, a robot inside an obstacle, typed errors without the file, two sweeps in one folder,
one SIGTERM for ``--viz`` and the Dask trust note."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hqp_tpm import errors
from hqp_tpm.app import build, scenario, sweep
from hqp_tpm.app.cli import main, run_scenario
from hqp_tpm.data import scenarios_dir
from hqp_tpm.errors import HqpTpmError, OutputError, ScenarioError, SolverFailedError, SweepError

RUN = {"progress": False, "figures": False, "replay": False}


def shipped(name: str) -> str:
    return (scenarios_dir() / f"{name}.toml").read_text()


def write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def snapshot(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


# ------------------------------------------------------------------------------------------ messages, nesting
def test_a_huge_list_gives_a_short_message_naming_file_and_field(tmp_path):
    text = shipped("iiwa_comanipulation")
    marker = "markers = [[0.74, -0.2, 0.25]"
    assert marker in text
    path = write(tmp_path, text.replace(marker, "markers = [[" + ", ".join(["0.5"] * 200_000) + "]"))
    with pytest.raises(ScenarioError) as err:
        build.build(scenario.load(path))
    msg = str(err.value)
    assert len(msg) < 1000, len(msg)  # 1.2 MB before
    assert "s.toml.policy.operator.markers[0]" in msg and "(200000 items)" in msg
    # any typed error: the message is capped, its middle elided
    long = ScenarioError("x" * 1_000_000)
    assert len(str(long)) <= errors.MAX_MESSAGE and "characters elided" in str(long)


@pytest.mark.parametrize("depth", [40, 300, 5000])
def test_deeply_nested_arrays_are_a_scenario_error_naming_file_and_field(tmp_path, depth):
    text = shipped("planar5_exact").replace("center = [1.0, -1.2, 0.0]", "center = " + "[" * depth + "]" * depth)
    path = write(tmp_path, text)
    t0 = time.perf_counter()
    with pytest.raises(ScenarioError, match=r"s\.toml.*(obstacles\[0\]\.center|field 'center').*nested more than"):
        run_scenario(path, tmp_path / "out", steps=5, **RUN)  # RecursionError before (5000), or a huge message
    assert time.perf_counter() - t0 < 10
    assert not (tmp_path / "out").exists() and hidden(tmp_path) == []


def test_deep_sweep_values_are_typed_errors():
    with pytest.raises(SweepError, match="nested too deep"):
        sweep.parse_assignment("policy.d_m=" + "[" * 5000 + "]" * 5000)
    _, values, _ = sweep.parse_assignment("obstacles.o1.center=" + "[" * 60 + "]" * 60)
    base = scenario.read(scenario.resolve_path("planar5_exact"))
    v = sweep.Variant("v000", {"obstacles.o1.center": values[0]})
    with pytest.raises(ScenarioError, match=r"planar5_exact\[v000\]\.obstacles\[0\]\.center.*nested"):
        sweep.variant_scenario(base, "planar5_exact", v)


# ------------------------------------------------------------------------------------------ named errors
PLANAR_HOLD = """
[scenario]
robot = "planar5"
level = "velocity"
solver = "tpm"
period = 0.001
duration = 0.05
[initial]
q_deg = [-30.0, 25.0, 25.0, 25.0, 20.0]
[[tasks]]
name = "ee"
type = "frame_position"
frame = "planar5_ee"
axes = "xy"
[[tasks]]
name = "post"
type = "posture"
[policy]
type = "fixed"
levels = ["ee", "ee"]
"""


def test_a_repeated_level_is_named(tmp_path):
    # before: "Hold trajectory used before start(): the run did not initialise it", at the first step
    with pytest.raises(ScenarioError, match=r"s\.toml\.policy\.levels\[1\]: task 'ee' is repeated \(already in "
                                            r"levels\[0\]\)"):
        run_scenario(write(tmp_path, PLANAR_HOLD), tmp_path / "out", steps=5, **RUN)
    text = PLANAR_HOLD.replace('["ee", "ee"]', '["ee", ["post"], "post"]')
    with pytest.raises(ScenarioError, match=r"levels\[2\]: task 'post' is repeated \(already in levels\[1\]\)"):
        build.build(scenario.load(write(tmp_path, text)))


def test_a_robot_inside_an_obstacle_is_a_modelling_error(tmp_path):
    text = shipped("planar5_exact")
    inside = text.replace("center = [1.0, -1.2, 0.0]", "center = [1.0, 0.5, 0.0]").replace("radius = 0.2",
                                                                                           "radius = 5.0")
    # before: "ok", d_obstacle = -4.3 m, alpha_v = inf recorded, |dq| up to 405 rad/s
    with pytest.raises(ScenarioError, match=r"s\.toml\.obstacles\[0\] \('o1'\): the robot starts entirely inside "
                                            r"it .*distance -4\.\d+ m"):
        run_scenario(write(tmp_path, inside), tmp_path / "out", steps=5, **RUN)
    # a link touching the obstacle is not refused: the avoidance pushes it out (alpha_v held at d_b, finite)
    touching = text.replace("center = [1.0, -1.2, 0.0]", "center = [1.0, -0.25, 0.0]")
    s = run_scenario(write(tmp_path, touching, "t.toml"), tmp_path / "t", steps=20, **RUN)
    assert s["d_obstacle_min"] < 0.0
    with np.load(tmp_path / "t" / "trajectory.npz") as z:
        assert np.isfinite(z["alpha_v"]).all() and z["alpha_v"].max() > 0


@pytest.mark.parametrize(("old", "new", "match"), [
    ("radius = 0.2", "radius = -0.2", r"s\.toml\.obstacles\[0\]\.radius \(sphere\): .*radius must be >= 0"),
    ('solver = "tpm"', 'solver = "qp:nonexistent"', r"s\.toml\.scenario\.solver: unknown QP backend 'nonexistent'"),
    ('name = "planar5_exact"', 'name = "x"\nextends = "no_such_parent"',
     r"s\.toml\.scenario\.extends: unknown scenario 'no_such_parent'"),
    ('name = "planar5_exact"', 'name = "x"\nextends = "missing.toml"',
     r"s\.toml\.scenario\.extends \('missing\.toml'\): .*missing\.toml"),
])
def test_typed_errors_name_the_file_and_the_field(tmp_path, old, new, match):
    text = shipped("planar5_exact")
    assert old in text
    with pytest.raises(HqpTpmError, match=match):
        run_scenario(write(tmp_path, text.replace(old, new, 1)), tmp_path / "out", steps=5, **RUN)


def test_an_error_at_step_time_names_the_file_and_the_step(tmp_path, monkeypatch):
    from hqp_tpm.control.controller import Controller

    calls = [0]
    step = Controller.step

    def failing(self, record=False):
        calls[0] += 1
        if calls[0] == 4:
            raise SolverFailedError("the solver gave up")
        return step(self, record)

    monkeypatch.setattr(Controller, "step", failing)
    path = write(tmp_path, shipped("planar5_exact"))
    with pytest.raises(SolverFailedError, match=r"^s\.toml, step 4 \(t = 0\.003 s\): the solver gave up") as err:
        run_scenario(path, tmp_path / "out", steps=10, **RUN)
    assert err.value.partial_result is not None


# ------------------------------------------------------------------------------------------ --out
def test_symlinked_out_is_followed_and_nothing_is_left_behind(tmp_path):
    real, links = tmp_path / "real", tmp_path / "links"
    links.mkdir()
    link = links / "out"
    run_scenario("planar5_exact", real, steps=10, **RUN)
    link.symlink_to(real, target_is_directory=True)
    stale = links / ".out.hqp-tpm-999999999-abcd"  # what the old code left: the link swapped away, never removed
    stale.symlink_to(real, target_is_directory=True)
    s = run_scenario("planar5_exact", link, steps=20, **RUN)
    assert link.is_symlink() and os.readlink(link) == str(real)  # before: the link replaced by a folder
    assert Path(s["out"]) == real and json.loads((real / "manifest.json").read_text())["steps"] == 20
    assert hidden(links) == [] and hidden(tmp_path) == []
    assert real.is_dir() and not real.is_symlink()  # the stale link is gone, not what it pointed to
    dangling = links / "dangling"
    dangling.symlink_to(tmp_path / "nowhere")
    with pytest.raises(OutputError, match="symbolic link .*does not exist"):
        run_scenario("planar5_exact", dangling, steps=5, **RUN)
    assert not (tmp_path / "nowhere").exists() and hidden(links) == []


# ------------------------------------------------------------------------------------------ disk full
@pytest.fixture
def file_size_limit():
    """``ulimit -f`` in this process (Python ignores SIGXFSZ: a write past the limit fails with EFBIG)."""
    resource = pytest.importorskip("resource")
    old = resource.getrlimit(resource.RLIMIT_FSIZE)

    def limit(nbytes: int) -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, old[1]))

    yield limit
    resource.setrlimit(resource.RLIMIT_FSIZE, old)


@pytest.mark.skipif(sys.platform == "win32", reason="RLIMIT_FSIZE")
@pytest.mark.parametrize(("limit", "steps", "replay"), [(200_000, 30, True), (6_000, 400, False)])
def test_a_file_size_limit_is_an_output_error_and_the_previous_result_survives(tmp_path, file_size_limit, capsys,
                                                                                limit, steps, replay):
    out = tmp_path / "out"
    run_scenario("planar5_exact", out, steps=10, **RUN)
    before = snapshot(out)
    file_size_limit(limit)  # 200 kB: the replay (~900 kB) fails; 6 kB: a recorded column fails while stepping
    with pytest.raises(OutputError, match=r"cannot write the result to '.*out': a file grew beyond the file-size "
                                          r"limit") as err:
        run_scenario("planar5_exact", out, steps=steps, **{**RUN, "replay": replay})
    assert isinstance(err.value, OSError)
    args = ["run", "planar5_exact", "--out", str(out), "--steps", str(steps), "--quiet", "--no-figures"]
    assert main(args + ([] if replay else ["--no-replay"])) == 2
    stderr = capsys.readouterr().err
    assert "file-size limit" in stderr and "Traceback" not in stderr
    assert snapshot(out) == before and hidden(tmp_path) == []


@pytest.mark.skipif(not sys.platform.startswith("linux") or os.geteuid() != 0, reason="mounting a tmpfs: Linux, root")
def test_a_full_disk_is_an_output_error(tmp_path):
    disk = tmp_path / "small"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=600k", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("tmpfs cannot be mounted here")
    try:
        out = disk / "out"
        run_scenario("planar5_exact", out, steps=10, **RUN)
        before = snapshot(out)
        with pytest.raises(OutputError, match="no space left on the device") as err:
            run_scenario("planar5_exact", out, steps=30, **{**RUN, "replay": True})
        del err  # its traceback holds the run's memory-mapped columns (files on the tmpfs)
        assert snapshot(out) == before and hidden(disk) == []
    finally:
        import gc

        gc.collect()
        if subprocess.run(["umount", str(disk)], capture_output=True).returncode:
            subprocess.run(["umount", "-l", str(disk)], check=False)  # detached now, freed when unused


# ------------------------------------------------------------------------------------------ sweeps
def _children(pid: int) -> list[int]:
    out = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                stat = (p / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(p.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_no_sweep_worker_outlives_its_sweep(tmp_path, sig):
    out = tmp_path / "sw"
    cmd = [sys.executable, "-m", "hqp_tpm.app.cli", "sweep", "planar5_exact", "--set", "policy.d_m=0.15,0.25",
           "--steps", "5000000", "--workers", "2", "--out", str(out), "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    workers: list[int] = []
    try:
        t0 = time.time()
        while time.time() - t0 < 120 and not list(out.glob(".v00*.hqp-tpm-*/.columns/t.npy")):
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.1)
        workers = _children(proc.pid)
        assert workers, "no worker process found"
        proc.send_signal(sig)
        # before: the workers kept running (kill -9), blocked on their pipe and holding stdout/stderr open
        proc.communicate(timeout=10)  # EOF on both pipes: no worker holds them
        deadline = time.time() + 10
        while time.time() < deadline and any(_alive(w) for w in workers):
            time.sleep(0.1)
        assert not [w for w in workers if _alive(w)], "a worker outlived the sweep"
    finally:
        for w in [*workers, proc.pid]:
            try:
                os.kill(w, signal.SIGKILL)
            except OSError:
                pass
        proc.wait()
    if sig == signal.SIGTERM:
        assert proc.returncode == 143 and hidden(out) == []


def test_a_second_sweep_does_not_replace_a_different_one(tmp_path):
    out = tmp_path / "sw"
    first = sweep.run_sweep("planar5_exact", out, grid={"policy.d_m": [0.15, 0.25]}, steps=10, progress=False,
                            workers=0)
    assert [r["status"] for r in first] == ["complete", "complete"]
    summary = (out / "summary.csv").read_bytes()
    for kw in ({"grid": {"policy.d_i": [0.35]}, "steps": 10}, {"grid": {"policy.d_m": [0.15, 0.25]}, "steps": 12}):
        with pytest.raises(OutputError, match="holds a different sweep .*--force"):
            sweep.run_sweep("planar5_exact", out, progress=False, workers=0, **kw)
        assert (out / "summary.csv").read_bytes() == summary  # before: silently replaced
    again = sweep.run_sweep("planar5_exact", out, grid={"policy.d_m": [0.15, 0.25]}, steps=10, progress=False,
                            workers=0)
    assert all(r.get("resumed") for r in again)  # the same sweep resumes
    forced = sweep.run_sweep("planar5_exact", out, grid={"policy.d_i": [0.35]}, steps=12, progress=False,
                             workers=0, force=True)
    assert [r["steps"] for r in forced] == [12] and not forced[0].get("resumed")
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ["v000"]  # the other sweep's v001 is gone
    assert main(["sweep", "planar5_exact", "--set", "policy.d_m=0.2", "--steps", "10", "--workers", "0", "--out",
                 str(out), "--quiet"]) == 2


def test_the_scheduler_option_says_it_must_be_trusted(capsys):
    with pytest.raises(SystemExit):
        main(["sweep", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert re.search(r"--scheduler tcp://HOST:PORT .*trusted only: Dask unpickles", text)
    readme = " ".join((Path(__file__).parents[1] / "README.md").read_text().split())
    assert "use `--scheduler` only with a cluster you trust" in readme


# ------------------------------------------------------------------------------------------ --viz
@pytest.mark.parametrize("when", ["after", "during"])
def test_one_sigterm_ends_viz(tmp_path, when):
    out = tmp_path / "out"
    steps = "50" if when == "after" else "5000000"
    cmd = [sys.executable, "-m", "hqp_tpm.app.cli", "run", "planar5_exact", "--steps", steps, "--viz",
           "--no-figures", "--no-replay", "--quiet", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        if when == "after":
            for line in proc.stdout:
                if "press Ctrl-C" in line:
                    break
        else:
            t0 = time.time()
            while time.time() - t0 < 120 and not list(tmp_path.glob(".out.hqp-tpm-*/.columns/t.npy")):
                assert proc.poll() is None
                time.sleep(0.1)
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)  # before: ignored after the run (or the viewer kept up after a partial
        proc.wait(timeout=15)  # run), a second one was needed
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    manifest = json.loads((out.with_name("out") / "manifest.json").read_text())
    assert (proc.returncode, manifest["status"]) == ((0, "complete") if when == "after" else (143, "partial"))
