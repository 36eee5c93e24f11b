"""The ``app`` extra: what the command line, the figures and the viewer need beyond the library.

``pip install hqp-tpm`` installs the library (robots, tasks, solvers, controller, scenario files); the
figures (matplotlib), ``replay.html`` and the live viewer (meshcat, u-msgpack-python) and the progress bar
(tqdm) come with ``pip install 'hqp-tpm[app]'``. :func:`require` names what is missing before any work.
"""

from __future__ import annotations

import importlib.util

from hqp_tpm.errors import ExtraNotInstalledError

#: feature -> the modules it imports and their pip names (all in the ``app`` extra of pyproject.toml)
FEATURES = {
    "figures": {"matplotlib": "matplotlib"},
    "replay": {"meshcat": "meshcat", "umsgpack": "u-msgpack-python"},
    "viewer": {"meshcat": "meshcat", "umsgpack": "u-msgpack-python"},
    "progress": {"tqdm": "tqdm"},
}


def missing(*features: str) -> list[str]:
    """The pip names of the modules ``features`` need that are not installed."""
    out = []
    for feature in features:
        for module, dist in FEATURES[feature].items():
            if importlib.util.find_spec(module) is None and dist not in out:
                out.append(dist)
    return out


def require(*features: str, what: str = "this run") -> None:
    """Raise :class:`~hqp_tpm.errors.ExtraNotInstalledError` if a module of ``features`` is not installed."""
    absent = missing(*features)
    if absent:
        raise ExtraNotInstalledError(
            f"{what} needs {', '.join(features)}: {', '.join(absent)} not installed; install the app extra: "
            "pip install 'hqp-tpm[app]' (or turn them off: figures=False, replay=False, progress=False; "
            "on the command line --no-figures --no-replay --quiet)")
