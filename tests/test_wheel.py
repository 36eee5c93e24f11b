"""The wheel works outside the repository (issue 11, item 7).

A wheel is built from a copy of the sources (``pyproject.toml``, ``README.md``, ``hqp_tpm/``), installed
with ``--no-deps`` into a new virtual environment in a temporary folder, and used from another folder:
``hqp-tpm list``, a 200-step ``hqp-tpm run lwr_relaxed`` and ``Robot.load('romeo21')``.

The new environment reuses this interpreter's installed dependencies (pinocchio, coal, ... are large)
through one ``.pth`` file that lists this environment's ``site-packages`` and replays its ``.pth`` files,
except the editable-install hook of ``hqp_tpm`` itself: ``hqp_tpm`` can only come from the wheel, which
the test checks (``hqp_tpm.__file__`` is inside the new environment, package data included).

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


def _dependencies_pth(site_packages: Path) -> str:
    """A ``.pth`` adding this environment's packages, without any editable install of hqp_tpm."""
    here = Path(sysconfig.get_paths()["purelib"])
    lines = [str(here)]
    for pth in sorted(here.glob("*.pth")):
        if pth.name.startswith("__editable__") or "hqp_tpm" in pth.name or "hqp-tpm" in pth.name:
            continue
        for line in pth.read_text().splitlines():
            if not line.strip() or line.startswith("#"):
                continue
            lines.append(line if line.startswith(("import ", "import\t")) else str((here / line).resolve()))
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(venv folder, environment for subprocesses, a working folder outside the checkout)."""
    root = tmp_path_factory.mktemp("wheel")
    src = root / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(SRC / name, src / name)
    shutil.copytree(SRC / "hqp_tpm", src / "hqp_tpm", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "HQP_TPM_ROBOTS", "PYTHONHOME")}
    env.update(PIP_DISABLE_PIP_VERSION_CHECK="1", MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1")
    dist = root / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", dist, src], cwd=root, env=env)
    wheels = list(dist.glob("hqp_tpm-*.whl"))
    assert len(wheels) == 1, wheels

    env_dir = root / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], root, env).strip())
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "-q", wheels[0]], root, env)
    (site / "zz_test_dependencies.pth").write_text(_dependencies_pth(site))
    work = root / "elsewhere"
    work.mkdir()
    return env_dir, env, work


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


def test_robot_load_romeo21(installed):
    env_dir, env, work = installed
    code = "import hqp_tpm; r = hqp_tpm.Robot.load('romeo21'); print(hqp_tpm.__file__, r.model.nq)"
    path, nq = _run([env_dir / "bin" / "python", "-c", code], work, env).split()
    assert Path(path).resolve().is_relative_to(env_dir.resolve()) and int(nq) == 28  # 21 joints + free flyer
