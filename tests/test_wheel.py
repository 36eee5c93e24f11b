"""The wheel works outside the repository (issue 11, item 7), without its extras (issue 32, item 6).

A wheel is built from a copy of the sources (``pyproject.toml``, ``README.md``, ``hqp_tpm/``) with no
setuptools deprecation warning, and installed with ``--no-deps`` into two new virtual environments in a
temporary folder, used from another folder:

- ``base``: only the distributions the base install pulls in (the closure of ``[project] dependencies``):
  the library imports, loads robots, solves a stack and runs a scenario without figures; the application's
  packages (matplotlib, meshcat, tqdm) are not importable and ``hqp-tpm run`` names the extra to install;
- ``app``: the base plus the ``app`` extra: ``hqp-tpm list``, a 200-step ``hqp-tpm run lwr_relaxed``.

The environments reuse this interpreter's installed distributions (pinocchio, coal, ... are large): a folder
of links to the files of exactly the distributions of the closure, listed by one ``.pth`` file that also
replays their ``.pth`` files; never the editable install of ``hqp_tpm`` itself: ``hqp_tpm`` can only come
from the wheel, which the tests check (``hqp_tpm.__file__`` is inside the new environment, package data
included).

``HQP_TPM_WHEEL_SRC`` builds another source tree instead of this checkout (e.g. an older commit).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

SRC = Path(os.environ.get("HQP_TPM_WHEEL_SRC", Path(__file__).resolve().parents[1]))


def _run(args, cwd, env, timeout=600):
    out = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, f"{' '.join(map(str, args))} failed ({out.returncode}):\n{out.stdout}\n{out.stderr}"
    return out.stdout


def _closure(extras: tuple[str, ...]) -> set[str]:
    """Distributions (normalized names) a ``pip install hqp-tpm[extras]`` pulls in, from this environment's
    metadata (pyproject.toml for hqp-tpm itself)."""
    from importlib.metadata import PackageNotFoundError, distribution

    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib

    project = tomllib.loads((SRC / "pyproject.toml").read_text())["project"]
    todo = [(Requirement(r), "") for r in project["dependencies"]]
    todo += [(Requirement(r), "") for e in extras for r in project["optional-dependencies"][e]]
    seen: set[str] = set()
    while todo:
        req, extra = todo.pop()
        if req.marker is not None and not req.marker.evaluate({"extra": extra}):
            continue
        name = canonicalize_name(req.name)
        for wanted in sorted(req.extras):  # e.g. dask[distributed]
            todo += [(Requirement(r), wanted) for r in (distribution(name).requires or [])]
        if name in seen:
            continue
        seen.add(name)
        try:
            dist = distribution(name)
        except PackageNotFoundError:
            raise AssertionError(f"{name} (required by hqp-tpm{list(extras)}) is not installed here") from None
        todo += [(Requirement(r), "") for r in (dist.requires or [])]
    return seen


def _linked_site(folder: Path, extras: tuple[str, ...]) -> str:
    """Links in ``folder`` to the files of the distributions of the closure; the ``.pth`` text that adds them."""
    from importlib.metadata import distribution

    here = Path(sysconfig.get_paths()["purelib"]).resolve()
    folder.mkdir()
    pth = [str(folder)]
    for name in sorted(_closure(extras)):
        if name == "hqp-tpm":
            continue
        dist = distribution(name)
        for top in sorted({f.parts[0] for f in dist.files or () if f.parts and f.parts[0] != ".."}):
            src = Path(dist.locate_file(top)).resolve()
            if not src.exists() or not src.is_relative_to(here) or (folder / top).exists():
                continue
            (folder / top).symlink_to(src)
            if top.endswith(".pth"):
                for line in src.read_text().splitlines():
                    if line.strip() and not line.startswith("#"):
                        pth.append(line if line.startswith(("import ", "import\t")) else str((here / line).resolve()))
    return "\n".join(pth) + "\n"


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """(the wheel, the environment for subprocesses, the build's output)."""
    root = tmp_path_factory.mktemp("wheel")
    src = root / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(SRC / name, src / name)
    shutil.copytree(SRC / "hqp_tpm", src / "hqp_tpm", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "HQP_TPM_ROBOTS", "PYTHONHOME")}
    env.update(PIP_DISABLE_PIP_VERSION_CHECK="1", MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1")
    dist = root / "dist"
    log = _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-v", "-w", dist, src], cwd=root, env=env)
    wheels = list(dist.glob("hqp_tpm-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0], env, log


def _install(wheel, root: Path, extras: tuple[str, ...]):
    path, env, _ = wheel
    env_dir = root / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], root, env).strip())
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "-q", path], root, env)
    (site / "zz_test_dependencies.pth").write_text(_linked_site(root / "deps", extras))
    work = root / "elsewhere"
    work.mkdir()
    return env_dir, env, work


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory):
    """The wheel with its app extra: (venv folder, environment for subprocesses, a folder outside the checkout)."""
    env_dir, env, work = _install(wheel, tmp_path_factory.mktemp("app"), ("app",))
    return env_dir, {**env, "HQP_TPM_COMPILED": "0"}, work  # the kernels are compiled (once) in the base one


@pytest.fixture(scope="module")
def base(wheel, tmp_path_factory):
    """The wheel without extras."""
    return _install(wheel, tmp_path_factory.mktemp("base"), ())


def test_the_build_has_no_deprecation_warning(wheel):
    """0d7b885's ``license = {text = ...}`` made setuptools warn three times per build (builds stop in 2027)."""
    log = wheel[2]
    assert "Successfully built" in log or "Saved" in log, log[-2000:]
    for word in ("DeprecationWarning", "BuildBackendWarning", "deprecated", "2027"):
        assert word not in log, log[max(0, log.find(word) - 800): log.find(word) + 800]


def test_base_install_has_no_application_packages(base):
    env_dir, env, work = base
    code = ("import importlib.util as u; print(*[m for m in ('matplotlib', 'meshcat', 'umsgpack', 'tqdm', "
            "'fast_simplification', 'numpy', 'pinocchio', 'coal', 'scipy', 'numba', 'qpsolvers', 'proxsuite', 'daqp') "
            "if u.find_spec(m)])")
    found = _run([env_dir / "bin" / "python", "-c", code], work, env).split()
    assert found == ["numpy", "pinocchio", "coal", "scipy", "numba", "qpsolvers", "proxsuite", "daqp"], found


def test_base_install_imports_and_solves_a_stack(base):
    env_dir, env, work = base
    code = """
import numpy as np
import hqp_tpm
from hqp_tpm import Controller, FramePosition, Gains, JointLimits, Posture, Robot
robot = Robot.load("romeo21")
q0 = robot.neutral()
hand = FramePosition(robot, "l_gripper", None, Gains(kp=10.0), name="hand")
ctrl = Controller(robot, [hand, Posture(robot)], order=1, dt=0.01, solver="tpm", q0=q0)
for _ in range(5):
    res = ctrl.step()
assert np.isfinite(res.command).all() and len(res.levels) == 2
x, _ = hqp_tpm.solve("qp", res.levels, robot.nv, box=JointLimits(robot, order=1, dt=0.01)(ctrl.state, ctrl.t))
assert np.isfinite(x).all()
s = hqp_tpm.record("planar5_exact", "run", steps=20, figures=False, replay=False)
print(hqp_tpm.__file__, s["steps"])
"""
    path, steps = _run([env_dir / "bin" / "python", "-c", code], work, env).split()
    assert Path(path).resolve().is_relative_to(env_dir.resolve()) and int(steps) == 20
    assert (work / "run" / "trajectory.npz").is_file() and not (work / "run" / "replay.html").exists()


def test_base_install_cli_names_the_app_extra(base):
    env_dir, env, work = base
    out = subprocess.run([env_dir / "bin" / "hqp-tpm", "run", "planar5_exact", "--steps", "5", "--out", "r"],
                         cwd=work, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 2 and "pip install 'hqp-tpm[app]'" in out.stderr, out.stdout + out.stderr
    assert not (work / "r").exists()


def test_package_comes_from_the_wheel(installed):
    env_dir, env, work = installed
    code = ("import hqp_tpm, hqp_tpm.data as d; print(hqp_tpm.__file__); print(d.robots_dir()); "
            "print(d.scenarios_dir()); print(hqp_tpm.__version__)")
    out = _run([env_dir / "bin" / "python", "-c", code], work, env).split()
    for path in out[:3]:
        assert Path(path).resolve().is_relative_to(env_dir.resolve()), out
    assert (Path(out[1]) / "kuka_lwr4" / "lwr4.urdf").is_file() and (Path(out[2]) / "lwr_relaxed.toml").is_file()
    assert _run([env_dir / "bin" / "hqp-tpm", "--version"], work, env).split()[-1] == out[3]


def test_cli_list(installed):
    env_dir, env, work = installed
    out = _run([env_dir / "bin" / "hqp-tpm", "list"], work, env)
    assert "lwr_relaxed" in out and "romeo_sns_tpm" in out


def test_cli_run_lwr_relaxed(installed):
    env_dir, env, work = installed
    _run([env_dir / "bin" / "hqp-tpm", "run", "lwr_relaxed", "--steps", "200", "--out", "run"], work, env)
    with np.load(work / "run" / "trajectory.npz") as npz:
        assert npz["q"].shape[0] >= 200 and np.all(np.isfinite(npz["q"]))


def test_app_extra_draws_decimated_meshes(installed):
    """The viewer's mesh decimation (fast-simplification, in the app extra) works from the installed wheel."""
    env_dir, env, work = installed
    code = """
import numpy as np
from hqp_tpm.app.viewer_scene import decimate
u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 80), np.linspace(0, np.pi, 60))
V = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], axis=-1).reshape(-1, 3)
i = np.arange(80 * 60).reshape(60, 80)
F = np.concatenate([np.stack([i[:-1, :-1], i[1:, :-1], i[1:, 1:]], -1).reshape(-1, 3),
                    np.stack([i[:-1, :-1], i[1:, 1:], i[:-1, 1:]], -1).reshape(-1, 3)])
W, G = decimate(V, F, 500)
print(len(G), float(np.abs(np.linalg.norm(W, axis=1) - 1).max()))
"""
    n, err = _run([env_dir / "bin" / "python", "-c", code], work, env).split()
    assert 0 < int(n) <= 500 and float(err) < 0.1


def test_robot_load_romeo21(installed):
    env_dir, env, work = installed
    code = "import hqp_tpm; r = hqp_tpm.Robot.load('romeo21'); print(hqp_tpm.__file__, r.model.nq)"
    path, nq = _run([env_dir / "bin" / "python", "-c", code], work, env).split()
    assert Path(path).resolve().is_relative_to(env_dir.resolve()) and int(nq) == 28  # 21 joints + free flyer
