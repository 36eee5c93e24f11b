"""A scenario file's values: arithmetic strings (``"6*pi"``), numbers, vectors and :class:`Section`, a table read
field by field with the path its errors name (:mod:`hqp_tpm.app.scenario` parses a file with them)."""

from __future__ import annotations

import ast
import math
import operator
from dataclasses import dataclass, field
from typing import Any

from hqp_tpm.errors import ScenarioError, shown

#: Largest magnitude of any number in a scenario file (gains, positions, times): beyond it a value is a typo.
MAX_ABS = 1e9
#: Longest arithmetic string (``"6*pi"``) and the largest exponent ``**`` accepts.
MAX_EXPR_CHARS = 200
MAX_EXPONENT = 64
_BINOPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
           ast.Pow: operator.pow}
_UNARY = {ast.UAdd: operator.pos, ast.USub: operator.neg}
_NAMES = {"pi": math.pi}


def _evaluate(node: ast.AST, where: str, text: str) -> float:
    """Float arithmetic on a parsed expression: numbers, ``pi``, ``+ - * / **`` and parentheses only."""
    if isinstance(node, ast.Expression):
        return _evaluate(node.body, where, text)
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        try:
            return float(node.value)
        except OverflowError:
            raise ScenarioError(f"{where}: {text!r}: the number is too large") from None
    if isinstance(node, ast.Name) and node.id in _NAMES:
        return _NAMES[node.id]
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        return _UNARY[type(node.op)](_evaluate(node.operand, where, text))
    if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
        a, b = _evaluate(node.left, where, text), _evaluate(node.right, where, text)
        if isinstance(node.op, ast.Pow) and abs(b) > MAX_EXPONENT:
            raise ScenarioError(f"{where}: {text!r}: exponent {b:g} is larger than {MAX_EXPONENT}")
        try:
            out = _BINOPS[type(node.op)](a, b)
        except ZeroDivisionError:
            raise ScenarioError(f"{where}: {text!r}: division by zero") from None
        except OverflowError:
            raise ScenarioError(f"{where}: {text!r}: the result is too large") from None
        if isinstance(out, complex):
            raise ScenarioError(f"{where}: {text!r}: the result is not a real number")
        return out
    raise ScenarioError(f"{where}: {text!r}: only numbers, pi, + - * / ** and parentheses are allowed")


def expression(text: str, where: str) -> float:
    """The value of a tiny arithmetic string such as ``"6*pi"`` or ``"1/3"`` (no names but ``pi``, no calls)."""
    if len(text) > MAX_EXPR_CHARS:
        raise ScenarioError(f"{where}: expression longer than {MAX_EXPR_CHARS} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError):
        raise ScenarioError(f"{where}: cannot read {text!r} as a number or an expression like '6*pi'") from None
    return _evaluate(tree, where, text)


def number(value: Any, where: str) -> float:
    """A finite float of magnitude <= :data:`MAX_ABS` from a number or a tiny arithmetic string (``"6*pi"``)."""
    if isinstance(value, bool):
        raise ScenarioError(f"{where}: expected a number, got {shown(value)}")
    if isinstance(value, int):
        out = float(value) if abs(value) <= MAX_ABS else math.inf
    elif isinstance(value, float):
        out = value
    elif isinstance(value, str):
        out = expression(value, where)
    else:
        raise ScenarioError(f"{where}: expected a number or an expression like '6*pi', got {shown(value)}")
    if not math.isfinite(out):
        raise ScenarioError(f"{where}: {value!r} is not finite")
    if abs(out) > MAX_ABS:
        raise ScenarioError(f"{where}: {value!r} is too large (|value| must be <= {MAX_ABS:g})")
    return out


def vector(value: Any, where: str, dim: int | None = None) -> list[float]:
    """A list of floats, optionally of a given length."""
    if not isinstance(value, (list, tuple)):
        raise ScenarioError(f"{where}: expected a list of numbers, got {shown(value)}")
    out = [number(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if dim is not None and len(out) != dim:
        raise ScenarioError(f"{where}: expected {dim} numbers, got {len(out)}")
    return out


@dataclass
class Section:
    """A table of the file with the path used in error messages; fields are read and checked."""

    data: dict
    where: str
    used: set = field(default_factory=set)

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key: str, default: Any = ...) -> Any:
        self.used.add(key)
        if key not in self.data:
            if default is ...:
                raise ScenarioError(f"{self.where}: missing field {key!r}")
            return default
        return self.data[key]

    def number(self, key: str, default: Any = ...) -> float:
        v = self.raw(key, default)
        return v if v is None or (default is not ... and v is default) else number(v, f"{self.where}.{key}")

    def vector(self, key: str, dim: int | None = None, default: Any = ...) -> list[float] | None:
        v = self.raw(key, default)
        return v if v is None or (default is not ... and v is default) else vector(v, f"{self.where}.{key}", dim)

    def string(self, key: str, default: Any = ..., choices=None) -> str:
        v = self.raw(key, default)
        if v is None or (default is not ... and v is default):
            return v
        if not isinstance(v, str):
            raise ScenarioError(f"{self.where}.{key}: expected a string, got {shown(v)}")
        if choices is not None and v not in choices:
            raise ScenarioError(f"{self.where}.{key}: {shown(v)} is not one of {', '.join(map(repr, choices))}")
        return v

    def boolean(self, key: str, default: Any = ...) -> bool:
        v = self.raw(key, default)
        if not isinstance(v, bool):
            raise ScenarioError(f"{self.where}.{key}: expected true or false, got {shown(v)}")
        return v

    def table(self, key: str, default: Any = ...) -> Section | None:
        v = self.raw(key, default)
        if v is None or (default is not ... and v is default):
            return v
        if not isinstance(v, dict):
            raise ScenarioError(f"{self.where}.{key}: expected a table, got {shown(v)}")
        return Section(v, f"{self.where}.{key}")

    def tables(self, key: str) -> list[Section]:
        v = self.raw(key, [])
        if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
            raise ScenarioError(f"{self.where}.{key}: expected an array of tables ([[{key}]])")
        return [Section(x, f"{self.where}.{key}[{i}]") for i, x in enumerate(v)]

    def check_unused(self) -> None:
        """Unknown fields are errors: a typo must not be silently ignored."""
        extra = sorted(set(self.data) - self.used)
        if extra:
            raise ScenarioError(f"{self.where}: unknown field(s) {', '.join(map(repr, extra))}; known fields: "
                                f"{', '.join(map(repr, sorted(self.used)))}")
