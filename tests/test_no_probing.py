"""No attribute probing in the app and control layers: what they need is handed over explicitly (the
:class:`~hqp_tpm.control.policy.Policy` contract, :class:`~hqp_tpm.app.context.RunContext`,
:class:`~hqp_tpm.control.policy.SceneItems`, the :class:`~hqp_tpm.tasks.base.Task` base attributes).

The source is read with ``ast``: a call of ``getattr``/``hasattr`` (or ``inspect.signature``, probing a
callable's parameters) anywhere in ``hqp_tpm/app`` or ``hqp_tpm/control`` fails, unless it is in
:data:`ALLOWED` with its reason.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import hqp_tpm

ROOT = Path(hqp_tpm.__file__).parent
PACKAGES = ("app", "control")
PROBES = {"getattr", "hasattr", "signature"}

#: (module path relative to hqp_tpm, call source) -> why this probe must stay. Keep it short.
ALLOWED: dict[tuple[str, str], str] = {}


def probes(path: Path) -> list[tuple[int, str]]:
    """(line, source) of every ``getattr``/``hasattr``/``signature`` call in the module at ``path``."""
    text = path.read_text()
    out = []
    for node in ast.walk(ast.parse(text, str(path))):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
        if name in PROBES:
            out.append((node.lineno, ast.get_source_segment(text, node)))
    return sorted(out)


MODULES = sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_attribute_probing(path):
    rel = str(path.relative_to(ROOT))
    found = [(line, src) for line, src in probes(path) if (rel, src) not in ALLOWED]
    assert not found, (f"{rel} probes attributes instead of using the written contract: "
                       + "; ".join(f"line {line}: {src}" for line, src in found))


def test_the_scan_finds_probes(tmp_path):
    """The scan is not vacuous: it sees plain, attribute and nested calls."""
    src = tmp_path / "m.py"
    src.write_text("import inspect\nx = getattr(a, 'b', None)\nif hasattr(a, 'c'):\n    pass\n"
                   "y = [builtins.getattr(a, 'd')]\nz = inspect.signature(f)\n")
    assert [line for line, _ in probes(src)] == [2, 3, 5, 6]
    assert MODULES and all(any(p.parent.name == pkg for p in MODULES) for pkg in PACKAGES)


def test_allow_list_entries_still_exist():
    """An allowed probe that is gone must leave the allow-list too."""
    present = {(str(p.relative_to(ROOT)), src) for p in MODULES for _, src in probes(p)}
    assert set(ALLOWED) <= present, set(ALLOWED) - present
