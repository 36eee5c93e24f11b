"""The reasons of xfail and skip marks read on their own: no commit hashes (issue 32, item 6).

0d7b885 had ``xfail(reason="... undamped, main 37dff08")``: a hash says nothing to a reader of the test report.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

TESTS = Path(__file__).resolve().parent
HASH = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")
MARKS = {"xfail", "skip", "skipif", "importorskip"}


def _reasons(path: Path):
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Call):
            name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
            if name in MARKS:
                for arg in [*node.args, *(k.value for k in node.keywords)]:
                    for sub in ast.walk(arg):
                        if isinstance(sub, ast.Constant) and isinstance(sub.value, str):
                            yield node.lineno, sub.value


def test_the_hash_pattern_finds_a_hash():
    assert HASH.search("undamped, main 37dff08") and not HASH.search("numba is not installed; 1234567 steps")


def test_no_commit_hash_in_xfail_or_skip_reasons():
    found = [f"{p.name}:{line}: {text!r}" for p in sorted(TESTS.rglob("*.py")) for line, text in _reasons(p)
             if HASH.search(text)]
    assert not found, "\n".join(found)
