"""Package data: the robot descriptions (``robots/``) and the scenario files (``scenarios/``).

Read them through :func:`robots_dir` and :func:`scenarios_dir` (``importlib.resources``), so they are
found the same way in a checkout, an editable install and an installed wheel.
"""

from __future__ import annotations

import os
from importlib.resources import files
from pathlib import Path


def _dir(name: str) -> Path:
    # Installed packages live on the file system (pinocchio needs real paths), so the resource is a Path.
    return Path(str(files(__name__) / name))


def robots_dir() -> Path:
    """Folder of the shipped robot descriptions (override with the ``HQP_TPM_ROBOTS`` variable)."""
    env = os.environ.get("HQP_TPM_ROBOTS")
    return Path(env) if env else _dir("robots")


def scenarios_dir() -> Path:
    """Folder of the shipped scenario files."""
    return _dir("scenarios")
