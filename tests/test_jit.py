"""The jit layer (:mod:`hqp_tpm._jit`, issue 28 item 5): one switch, a cache that survives damage, read-only installs.

Each run is a subprocess (:data:`PROBE`: the robot kernels ``euclidean_step`` and ``velocity_box`` and, where
the test says, a small ``tpm_stacked`` solve through the compiled TPM kernel) with its own ``NUMBA_CACHE_DIR``,
warmed once for the module (the solve's kernels take ~15 s of CPU to compile cold; the robot kernels ~1 s).
"""

from __future__ import annotations

import ast
import importlib.util
import os
import shutil
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import hqp_tpm

#: the probe's numbers from the robot kernels (then, with ``solve``, x and the solvers' switch)
ROBOT = 13

pytestmark = pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="numba is not installed")

PACKAGE = Path(hqp_tpm.__file__).resolve().parent

#: A few kernel calls whose numbers are printed in full (``repr``); ``solve`` in argv: also a small TPM solve by the
#: compiled kernel (m > n: ``_past_rank``). It imports only what an application imports (no ``hqp_tpm._jit``).
PROBE = r"""
import sys
import numpy as np
from hqp_tpm.robot import _compiled as rc
out = []
e = np.array([1.0, -2.0, 0.5, 3.0])
dq, v_next = np.zeros(4), np.zeros(4)
rc.euclidean_step(e, e, 0.1 * e, 0.3, 2, dq, v_next)
out += dq.tolist() + v_next.tolist()
P = np.array([[-1.0, -2.0], [1.0, 2.0], [0.5, 0.7], [3.0, 4.0], [6.0, 8.0], [0.03, 0.04]])
idx = np.array([[0, 1], [0, 1]], dtype=np.int64)
lo, up = np.zeros(2), np.zeros(2)
out += [bool(rc.velocity_box(np.array([0.3, -1.9]), P, idx, 0.01, lo, up))] + lo.tolist() + up.tolist()
if "solve" in sys.argv:
    from hqp_tpm.solvers import _compiled
    from hqp_tpm.solvers.tpm import tpm_stacked
    J = np.sin(np.arange(63.0)).reshape(9, 7)
    out += tpm_stacked(J, np.cos(np.arange(9.0)), (3, 3, 3), 7).tolist() + [_compiled.ENABLED]
import numba  # noqa: E402  (imported by now when the kernels are on)
print(repr(out))
"""


def as_user(nobody: bool) -> list[str]:
    """The command prefix that runs a program as the unprivileged user ``nobody`` (when we are root; otherwise we
    already are an unprivileged user)."""
    if not nobody or os.geteuid() != 0:
        return []
    if shutil.which("setpriv") is None:
        pytest.skip("setpriv is not installed")
    return ["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups"]


def run(env_extra: dict, *args: str, cwd=None, pythonpath=None, as_nobody=False, drop_env=(), probe=PROBE):
    env = {k: v for k, v in os.environ.items() if k not in drop_env and not k.startswith("NUMBA_")}
    env["PYTHONPATH"] = str(pythonpath or PACKAGE.parent)
    env["OMP_NUM_THREADS"] = env["OPENBLAS_NUM_THREADS"] = "1"
    env.update(env_extra)
    return subprocess.run([*as_user(as_nobody), sys.executable, "-c", probe, *args], env=env,
                          cwd=cwd or tempfile.gettempdir(), capture_output=True, text=True, timeout=600)


def ok(result) -> str:
    assert result.returncode == 0, result.stderr[-3000:]
    return result.stdout


@pytest.fixture(scope="module")
def warm(tmp_path_factory):
    """A cache directory holding every kernel the probe (with the solve) uses, and the probe's output."""
    cache = tmp_path_factory.mktemp("numba_cache")
    first = run({"NUMBA_CACHE_DIR": str(cache)}, "solve")
    want = ok(first)
    again = run({"NUMBA_CACHE_DIR": str(cache)}, "solve")
    assert ok(again) == want and again.stderr == "", again.stderr   # from the cache: the same numbers, quiet
    return cache, want


def cache_files(cache: Path, suffix: str, names=("euclidean_step", "velocity_box")) -> list[Path]:
    """The probe's kernels' cache files of one kind (``.nbi`` index, ``.nbc`` data) under ``cache``."""
    return sorted(p for p in cache.rglob(f"*{suffix}") if any(f".{n}-" in p.name for n in names))


def damage(path: Path, how: str) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2] if how == "truncate" else bytes(len(data)))


def test_a_notice_while_kernels_compile_once_and_none_from_the_cache(tmp_path):
    """An empty cache: numba compiles the probe's two kernels and one line says so (issue 29: the first run compiled
    for half a minute with no word); the same cache again: the kernels are loaded, no line. The notice goes to the
    writer a progress bar sets."""
    from hqp_tpm import _jit

    cold = run({"NUMBA_CACHE_DIR": str(tmp_path)})
    want = ok(cold)
    assert cold.stderr.splitlines() == [f"hqp_tpm: {_jit.COMPILING}"], cold.stderr
    warm_ = run({"NUMBA_CACHE_DIR": str(tmp_path)})
    assert ok(warm_) == want and warm_.stderr == "", warm_.stderr
    lines = []
    before = _jit.set_notice_writer(lines.append)
    try:
        _jit.notice("a  line")
    finally:
        _jit.set_notice_writer(before)
    assert lines == ["hqp_tpm: a line"]


@pytest.mark.parametrize("how", ["truncate", "zero"])
@pytest.mark.parametrize("suffix", [".nbi", ".nbc"])
def test_a_damaged_cache_file_is_discarded_and_rebuilt(warm, tmp_path, suffix, how):
    """Damaged index or data files (truncated, zeroed) of the kernels a run loads: the same numbers, at most one
    line on stderr, the files rebuilt whole, and the next run is clean (on main 0d7b885: UnpicklingError / EOFError,
    every run, until the cache is deleted by hand)."""
    cache, want = warm
    copy = tmp_path / "cache"
    shutil.copytree(cache, copy)
    hit = cache_files(copy, suffix)
    assert len(hit) >= 2, sorted(p.name for p in copy.rglob("*.nb?"))
    for p in hit:
        damage(p, how)
    damaged = run({"NUMBA_CACHE_DIR": str(copy)}, "solve")
    assert ok(damaged) == want
    assert len(damaged.stderr.splitlines()) <= 1, damaged.stderr
    for p in hit:  # rebuilt: there again, and numba reads it (next run quiet, same numbers)
        assert p.exists() and p.stat().st_size > 0 and p.read_bytes()[:1] == b"\x80"
    clean = run({"NUMBA_CACHE_DIR": str(copy)}, "solve")
    assert ok(clean) == want and clean.stderr == "", clean.stderr


@pytest.mark.slow  # (compiles the TPM kernel again: ~15 s of CPU)
def test_every_cache_file_damaged_at_once(warm, tmp_path):
    """Every index and data file of the cache damaged (alternately truncated and zeroed), the solver's too, and the
    list of files found whole: the same numbers with one notice, then a clean run."""
    cache, want = warm
    copy = tmp_path / "cache"
    shutil.copytree(cache, copy)
    files = sorted(p for p in copy.rglob("*.nb?") if p.suffix in (".nbi", ".nbc"))
    assert any("_past_rank" in p.name for p in files)
    for i, p in enumerate(files):
        damage(p, "truncate" if i % 2 else "zero")
    for listing in copy.rglob("checked.txt"):  # (the jit layer's list of files found whole: damaged too)
        listing.write_bytes(b"\xff\xfe" + bytes(64))
    damaged = run({"NUMBA_CACHE_DIR": str(copy)}, "solve")
    assert ok(damaged) == want
    assert len(damaged.stderr.splitlines()) == 1 and "damaged" in damaged.stderr, damaged.stderr
    clean = run({"NUMBA_CACHE_DIR": str(copy)}, "solve")
    assert ok(clean) == want and clean.stderr == "", clean.stderr


@pytest.fixture
def read_only_install():
    """A copy of the package in a directory nobody may write to (readable by everyone), removed after."""
    root = Path(tempfile.mkdtemp(prefix="hqp_tpm_ro_"))
    site = root / "site"
    shutil.copytree(PACKAGE, site / "hqp_tpm", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for p in [site, *site.rglob("*")]:
        p.chmod(0o555 if p.is_dir() else 0o444)
    root.chmod(0o755)
    yield site
    for p in [site, *site.rglob("*")]:
        p.chmod(stat.S_IRWXU)
    shutil.rmtree(root)


def test_a_read_only_install_without_a_cache_directory_compiles_in_memory(warm, read_only_install):
    """The package read-only, run by an unprivileged user whose home does not exist and without NUMBA_CACHE_DIR:
    the same numbers, at most a one-line notice, nothing written (on main 0d7b885: RuntimeError "no locator
    available" at import of hqp_tpm.robot._compiled)."""
    _, want = warm
    got = run({"HOME": "/nonexistent"}, pythonpath=read_only_install, cwd=read_only_install, as_nobody=True,
              drop_env=("XDG_CACHE_HOME",))
    assert ast.literal_eval(ok(got)) == ast.literal_eval(want)[:ROBOT]
    assert len(got.stderr.splitlines()) <= 1, got.stderr
    assert not list(read_only_install.rglob("__pycache__"))


def test_switched_off_the_same_numbers_without_numba(warm, read_only_install):
    """``HQP_TPM_COMPILED=0``: the same numbers from the same kernel source run as Python (the solve by the numpy
    path, equal to 1e-12), numba never imported, no notice, nothing written, even from a read-only install run by an
    unprivileged user (on main 0d7b885 that import already fails: the robot kernels were made with numba's cache
    whatever the switch)."""
    _, want = warm
    probe = PROBE.replace("import numba  # noqa: E402  (imported by now when the kernels are on)",
                          "assert 'numba' not in sys.modules, 'numba imported'")
    got = run({"HOME": "/nonexistent", "HQP_TPM_COMPILED": "0"}, "solve", pythonpath=read_only_install,
              cwd=read_only_install, as_nobody=True, drop_env=("XDG_CACHE_HOME",), probe=probe)
    out = ok(got)
    assert got.stderr == ""
    have, ref = ast.literal_eval(out), ast.literal_eval(want)
    assert have[-1] is False and ref[-1] is True  # (the solvers' switch off here, on in the warm runs)
    assert have[:ROBOT] == ref[:ROBOT]  # the robot kernels' numbers: the same source, run as Python
    assert max(abs(a - b) for a, b in zip(have[ROBOT:-1], ref[ROBOT:-1], strict=True)) <= 1e-12


def test_switched_on_later_compiles_then(warm):
    """Off at import (``HQP_TPM_COMPILED=0``), then turned on by either module's name: the kernel modules are
    compiled then (numba's dispatchers in place of the plain functions), with the same numbers."""
    cache, want = warm
    probe = PROBE.replace("out = []", "out = []\nassert 'numba' not in sys.modules and not rc.ENABLED\n"
                          "from hqp_tpm.solvers import _compiled as sc\nsc.ENABLED = True\n"
                          "assert rc.ENABLED and type(rc.euclidean_step).__name__ == 'CPUDispatcher'")
    got = run({"NUMBA_CACHE_DIR": str(cache), "HQP_TPM_COMPILED": "0"}, "solve", probe=probe)
    assert ok(got) == want and got.stderr == "", got.stderr

#: The first kernel call of a process (``euclidean_step``) watched: the collections the cyclic garbage collector
#: started meanwhile, its switch after, whether numba's import froze the objects alive then, which of numba's compiler
#: modules had been imported by then, the kernel's numbers, and the young objects left uncollected after. ``off`` in
#: argv: the program switched the collector off itself.
LOAD = r"""
import gc, sys
import numpy as np
started, watching = [], [False]
gc.callbacks.append(lambda phase, info: watching[0] and phase == "start" and started.append(info["generation"]))
from hqp_tpm.robot import _compiled as rc
frozen = gc.get_freeze_count()
if "off" in sys.argv:
    gc.disable()
e = np.array([1.0, -2.0, 0.5, 3.0])
dq, v_next = np.zeros(4), np.zeros(4)
watching[0] = True
rc.euclidean_step(e, e, 0.1 * e, 0.3, 2, dq, v_next)
watching[0] = False
compiler = [m for m in ("numba.np.linalg", "numba.np.arraymath", "numba.typed.typeddict") if m in sys.modules]
print(repr([started, gc.isenabled(), frozen > 0, compiler, dq.tolist() + v_next.tolist(), gc.get_count()[0]]))
"""


@pytest.mark.parametrize("collector", ["on", "off"])
def test_a_warm_process_loads_its_kernels_without_numba_s_compiler(warm, collector):
    """Issue 29 (a 1,000-step script ran slower compiled than with ``HQP_TPM_COMPILED=0`` on main 312f146): a kernel
    loaded from the cache imports none of what numba's compiler needs (on 312f146 numba refreshed its typing and
    lowering registries first: numpy's and linalg's implementations, typed containers, ...); the cyclic garbage
    collector runs no full collection while it loads (a few young ones; ~100 on 312f146) and is switched back as the
    program had it; the objects alive after numba's import are frozen (no collection walks them again); the numbers
    are the compiled kernel's."""
    cache, want = warm
    started, enabled, frozen, compiler, numbers, _ = ast.literal_eval(
        ok(run({"NUMBA_CACHE_DIR": str(cache)}, collector, probe=LOAD)).strip().splitlines()[-1])
    assert compiler == []
    assert 2 not in started and len(started) <= 5  # (on 312f146: ~100, one full; young ones outside numba's lock)
    assert enabled is (collector == "on")
    assert frozen
    assert numbers == ast.literal_eval(want)[:8]


def test_compiling_pauses_the_collector_and_switches_it_back(tmp_path):
    """An empty cache: while numba compiles the kernel the collector is paused (its compiler makes and drops millions
    of objects: ~15 % of a first run's CPU went to ~100 collections per kernel on main 312f146), one collection
    after, inside the compile's time (none of its objects left for the caller's next steps to collect), and the
    collector on again;
    the same numbers as loaded from the cache later."""
    cold = ast.literal_eval(ok(run({"NUMBA_CACHE_DIR": str(tmp_path)}, probe=LOAD)).strip().splitlines()[-1])
    assert len(cold[0]) <= 5 and cold[1] is True  # (on 312f146: ~110; here the one after the compile, and young
    # ones outside numba's lock)
    assert cold[5] < 700  # (the compile's objects were collected in it: none left for the caller's next steps)
    warm_ = ast.literal_eval(ok(run({"NUMBA_CACHE_DIR": str(tmp_path)}, probe=LOAD)).strip().splitlines()[-1])
    assert warm_[4] == cold[4]


def test_one_switch():
    """The solvers' and the robot's ``ENABLED`` are one switch (main 0d7b885 had two, set apart)."""
    from hqp_tpm import _jit
    from hqp_tpm.robot import _compiled as robot_compiled
    from hqp_tpm.solvers import _compiled as solvers_compiled

    before = _jit.ENABLED
    try:
        for value in (False, True, False):
            solvers_compiled.ENABLED = value
            assert robot_compiled.ENABLED is _jit.ENABLED is (value and _jit.AVAILABLE)
            robot_compiled.ENABLED = not value
            assert solvers_compiled.ENABLED is _jit.ENABLED is ((not value) and _jit.AVAILABLE)
    finally:
        _jit.ENABLED = before


def test_the_cache_key_follows_every_kernel_file_and_the_constants_they_import(tmp_path):
    """Every module that uses the jit layer (and the package modules it imports names from: compiled-in constants) is
    in the cache key, so a cached kernel never holds an earlier version of a kernel it calls; any change to one of
    them changes the key."""
    from hqp_tpm import _jit

    files = {str(p.relative_to(PACKAGE)) for p in _jit.kernel_files()}
    users = {str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py") if _jit._IMPORTS_JIT.search(p.read_text())
             and p.relative_to(PACKAGE).parts[0] != "app"}  # (the application reads the compile clock: no kernel)
    assert {"solvers/_compiled.py", "solvers/_compiled_sns.py", "control/_compiled_step.py", "robot/_compiled.py",
            "geometry/_compiled.py", "tasks/_compiled_rows.py", "solvers/levels.py", "solvers/damping.py"} <= files
    assert users <= files
    key = "import sys; from hqp_tpm import _jit; print(_jit.source_key())"
    site = tmp_path / "site"
    shutil.copytree(PACKAGE, site / "hqp_tpm", ignore=shutil.ignore_patterns("__pycache__"))
    keys = []
    for edit in (None, "solvers/levels.py", "solvers/_compiled.py", "README-not-a-kernel"):
        if edit and (site / "hqp_tpm" / edit).exists():
            with open(site / "hqp_tpm" / edit, "a") as f:
                f.write("\n# edited\n")
        elif edit:
            (site / "hqp_tpm" / "app" / "unrelated_note.py").write_text("X = 1\n")
        out = subprocess.run([sys.executable, "-c", key], env={**os.environ, "PYTHONPATH": str(site)},
                             cwd=tmp_path, capture_output=True, text=True, check=True)
        keys.append(out.stdout.strip())
    assert keys[0] != keys[1] != keys[2] and keys[2] == keys[3]  # (an unrelated module: the same key)



def test_earlier_cache_directories_are_pruned(tmp_path):
    """:data:`~hqp_tpm._jit.KEEP` cache directories stay, the current one and the most recently used others (and any
    used in the last hour: another checkout sharing ``NUMBA_CACHE_DIR``); older ones of earlier sources go."""
    import time

    from hqp_tpm import _jit

    now = time.time()
    ages = {"numba-a": 10, "numba-b": 20, "numba-c": 30, "numba-d": 40, "numba-e": 50, "numba-f": 0.1}  # hours
    for name, hours in ages.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "x.nbi").write_bytes(b"")
        os.utime(tmp_path / name, (now - 3600 * hours, now - 3600 * hours))
    (tmp_path / "numba-current").mkdir()
    _jit._prune(tmp_path / "numba-current")
    kept = sorted(p.name for p in tmp_path.iterdir())
    assert kept == ["numba-a", "numba-b", "numba-current", "numba-f"], kept  # f, a, b: the 3 most recent others

# -- the fused step's reads of pinocchio's memory by address: verified against pinocchio's API, else its API -----
@pytest.fixture(scope="module")
def robots():
    sys.path.insert(0, str(PACKAGE.parent))  # the repository root: ``benchmarks``
    from benchmarks.peers import problems as P

    return [P.load_robot(P.ROMEO), P.load_robot(P.IIWA)]


def test_pinocchio_memory_read_by_address_is_pinocchio_s_api(robots):
    """Every frame of Romeo and the iiwa: the views the fused step reads and writes by address are pinocchio's storage
    (taken before an update, they hold its values after) and the kernels on them are pinocchio's API to the bit, so
    the state hands them out (with this pinocchio)."""
    from hqp_tpm.robot.state import State, verify_source

    for robot in robots:
        model, st = robot.model, State(robot)
        for fid in range(1, model.nframes):
            assert verify_source(model, "jacobian", fid) and verify_source(model, "placement", fid), \
                model.frames[fid].name
        assert st.frame_jacobian_source(model.nframes - 1) is not None
        assert st.frame_placement_source(model.nframes - 1) is not None


@pytest.mark.parametrize("what", ["frame_jacobian", "frame_placement"])
def test_a_kernel_that_is_not_pinocchio_s_api_is_not_used(robots, what, monkeypatch):
    """A frame kernel one ulp away from pinocchio's API (as another pinocchio's arithmetic or memory layout would
    be): the state hands out no source for the fused step (None: the tasks call pinocchio's API every step). On main
    0d7b885 nothing compared them: the sources were handed out."""
    import numpy as np

    from hqp_tpm.robot import _compiled
    from hqp_tpm.robot.state import State

    kernel = getattr(_compiled, what)

    def off_by_an_ulp(*args):
        kernel(*args)
        out = args[-1]
        out[...] = np.nextafter(out, np.inf)

    robot = robots[1]
    fid = robot.model.nframes - 1
    assert getattr(State(robot), f"{what}_source")(fid) is not None
    monkeypatch.setattr(_compiled, what, off_by_an_ulp)
    assert getattr(State(robot), f"{what}_source")(fid) is None


#: A wide stack (m <= n, every pivot regular) through the public solver, then which of the solvers' kernels numba
#: compiled: their signature counts.
WIDE = r"""
import numpy as np
from hqp_tpm.solvers import _compiled
from hqp_tpm.solvers.tpm import tpm_stacked
J = np.random.default_rng(3).normal(size=(5, 7))
x = tpm_stacked(J, np.cos(np.arange(5.0)), (3, 2), 7)
print(repr([x.tolist(), len(_compiled._general.signatures), len(_compiled._past_rank.signatures),
            len(_compiled._recursion.signatures)]))
"""


def test_a_first_solve_compiles_only_the_branch_it_takes(tmp_path):
    """Issue 29 (first run): a process's first TPM solve on an ``m <= n`` stack compiles the general path's kernel
    only, not the ``m > n`` shortcut's nor the recursion's (on main 42742a8 one kernel held all three: ~24 s of CPU
    for a first solve), and gives the Python source's numbers (1e-12, as tests/test_compiled.py)."""
    from hqp_tpm.solvers.tpm import tpm_stacked

    cold = run({"NUMBA_CACHE_DIR": str(tmp_path)}, probe=WIDE)
    x, general, past_rank, recursion = ast.literal_eval(ok(cold).strip().splitlines()[-1])
    assert (general, past_rank, recursion) == (1, 0, 0)
    J = np.random.default_rng(3).normal(size=(5, 7))
    from hqp_tpm import _jit

    on = _jit.ENABLED
    _jit.set_enabled(False)
    try:
        want = tpm_stacked(J, np.cos(np.arange(5.0)), (3, 2), 7)
    finally:
        _jit.set_enabled(on)
    np.testing.assert_allclose(x, want, rtol=1e-12, atol=1e-15)


#: The planned step's task programs (a frame position at order 1 with its Jacobian in the kernel and at order 2, a
#: posture) written once each, then a rows program with a rotation error run through the same kernel; which of the
#: kernels only the fused step's rows call numba compiled (their signature counts), and the statuses.
TASK_ROWS = r"""
import numpy as np
from hqp_tpm import Gains, Robot
from hqp_tpm.control import _compiled_step as cs
from hqp_tpm.control._task_rows import TaskProgram
from hqp_tpm.references.trajectories import Harmonic
from hqp_tpm.robot import _compiled as rc
from hqp_tpm.robot.state import State
from hqp_tpm.tasks.frame_position import FramePosition
from hqp_tpm.tasks.posture import Posture
robot = Robot.load("iiwa7")
n = robot.nv
st = State(robot)
st.update(robot.neutral() + 0.3, np.full(n, 0.2), 0.1)
circle = Harmonic(center=np.array([0.1, 0.6, -0.2]), cos_amplitude=np.array([0.2, 0.0, 0.3]),
                  sin_amplitude=np.array([0.0, -0.1, 0.05]), omega=1.7)
written = []
for order in (1, 2):
    for task in (FramePosition(robot, "iiwa_ee", circle, Gains(7.0, 3.0)), Posture(robot, None, Gains(2.0, 1.0))):
        task.start(st)
        J, b = np.full((task.dim, n), np.nan), np.full(task.dim, np.nan)
        TaskProgram.of(task, st, order, J, b)(0.1)
        written.append(bool(np.isfinite(J).all() and np.isfinite(b).all()))
fid = robot.frame_id("iiwa_ee")
p, R = st.frame_views(fid)
prog = cs.Program(6, n, (6,), 1, 0.0, 0.0, False, solve=cs.ROWS)
prog.add_frame(0, range(6), range(3), 1.0, 0.0, x=p, jacobian=(*st.frame_jacobian_source(fid), p),
               rotation=(R.T, np.eye(3)))
prog.build()
buf = np.zeros(prog.buffer_size(6, n, cs.ROWS))
status = int(cs.rows_writer()(buf, prog.ints, prog.floats, st.q, st.v)[0])
print(repr([written, status == cs.NONFINITE_ROWS, [len(k.signatures) for k in (
    rc.rotation_error, rc.log3, rc.frame_placement, rc.frame_jdot_qdot, rc.frame_jacobian)]]))
"""


def test_task_programs_compile_only_the_rows_they_write(tmp_path):
    """Issue 29 (first run): the planned step's task programs never compute a rotation error, a frame placement or
    ``Jdot qd`` in the kernel (:class:`~hqp_tpm.control._task_rows.TaskProgram`), so their rows kernel
    (:func:`hqp_tpm._jit.variant` of the fused step's) compiles none of those kernels (on 56091bc it compiled all
    four: ~1.2 s of CPU of the cold ``hqp-tpm run lwr_relaxed``); the frame Jacobian it computes at velocity level is
    compiled. A program that asks for a rotation error after all gets non-finite rows from it, not wrong numbers (the
    bits of the rows: ``tests/test_task_rows.py``)."""
    written, nonfinite, signatures = ast.literal_eval(ok(run({"NUMBA_CACHE_DIR": str(tmp_path)},
                                                             probe=TASK_ROWS)).strip().splitlines()[-1])
    assert signatures == [0, 0, 0, 0, 1]
    assert written == [True] * 4 and nonfinite
