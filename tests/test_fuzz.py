"""Fuzz: scenario files mutated as a careless user would, and solver inputs (issue 13, item 5).

Derandomized (fixed seeds). Every outcome must be a clean result or a typed error (:class:`HqpTpmError`) that
names the file and the field, within a time limit, and the output folder must never be left inconsistent.

``HQP_TPM_FUZZ=N`` multiplies the number of cases (default 1: 240 scenario mutants, 600 solver calls), e.g.
``HQP_TPM_FUZZ=20 pytest tests/test_fuzz.py -s`` for a long campaign; ``-s`` prints the counts.
"""

from __future__ import annotations

import copy
import json
import math
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from hqp_tpm.app import scenario
from hqp_tpm.app.cli import run_scenario
from hqp_tpm.errors import HqpTpmError

SCALE = max(1, int(os.environ.get("HQP_TPM_FUZZ", "1")))
SCENARIO_CASES = 240 * SCALE
SOLVER_CASES = 600 * SCALE
#: A case taking longer than this is a hang (s); generous for a loaded 2-core machine.
TIME_LIMIT = 60.0
BASES = ("lwr_relaxed", "planar5_exact", "iiwa_comanipulation", "planar5_dmp")
STEPS = 5


class Hang(BaseException):
    pass


def _alarm(signum, frame):
    raise Hang


def limited(fn, seconds: float = TIME_LIMIT):
    """Run ``fn()`` under a wall-clock limit (SIGALRM): a :class:`Hang` when it is exceeded."""
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        return fn()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


# ------------------------------------------------------------------------------------------ TOML writer
def _key(k: str) -> str:
    return k if k and all(c.isalnum() or c in "-_" for c in k) else json.dumps(k)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def dump_toml(data: dict) -> str:
    lines = []
    for k, v in data.items():
        if not isinstance(v, (dict, list)) or (isinstance(v, list) and not all(isinstance(x, dict) for x in v)):
            lines.append(f"{_key(k)} = {_value(v)}")
    for k, v in data.items():
        if isinstance(v, dict):
            lines.append(f"\n[{_key(k)}]")
            lines += [f"{_key(a)} = {_value(b)}" for a, b in v.items()]
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for item in v:
                lines.append(f"\n[[{_key(k)}]]")
                lines += [f"{_key(a)} = {_value(b)}" for a, b in item.items()]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------ mutations
def base_data(name: str) -> dict:
    data = scenario.read(scenario.resolve_path(name))
    data["scenario"]["duration"] = 0.02
    data["scenario"].pop("name", None)
    return data


def _paths(node, prefix=()):
    """Every (path, value) in the nested data, tables and arrays included."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield (*prefix, k), v
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield (*prefix, i), v
            yield from _paths(v, (*prefix, i))


BAD_VALUES = ["abc", "", "9**9**9", "1/0", "__import__('os')", "2**0.5**-1", "pi*pi*1e300", True, False, 0, -1,
              -1.5, 1e300, -1e300, 1e-300, float("nan"), float("inf"), float("-inf"), [], [1.0], ["x", "y"],
              [float("nan")] * 3, {}, {"type": "harmonic"}, 10**30, 3, 0.0, 5e5, "6*pi", [0.0, 0.0, 0.0]]


def mutate(data: dict, rng: np.random.Generator) -> tuple[dict, str]:
    """One to three random edits; returns the mutant and a description."""
    out = copy.deepcopy(data)
    what = []
    for _ in range(int(rng.integers(1, 4))):
        paths = list(_paths(out))
        path, value = paths[int(rng.integers(len(paths)))]
        parent = out
        for p in path[:-1]:
            parent = parent[p]
        key = path[-1]
        kind = rng.integers(6)
        if kind == 0 and isinstance(parent, dict):
            del parent[key]
            what.append(f"del {path}")
        elif kind == 1 and isinstance(parent, dict):
            parent[f"{key}_x"] = 1.0
            what.append(f"add {path}_x")
        elif kind == 2 and isinstance(value, (int, float)) and not isinstance(value, bool):
            parent[key] = float(value) * float(rng.choice([-1.0, 1e6, 1e-9, 0.0, 1e12]))
            what.append(f"scale {path}")
        elif kind == 3 and isinstance(value, list) and value:
            parent[key] = value[:-1] if rng.random() < 0.5 else [*value, value[-1]]
            what.append(f"resize {path}")
        else:
            bad = BAD_VALUES[int(rng.integers(len(BAD_VALUES)))]
            parent[key] = copy.deepcopy(bad)
            what.append(f"set {path} = {bad!r}")
    return out, "; ".join(what)


def folder_consistent(out: Path) -> bool:
    """No output, or a folder whose manifest, files, metrics and trajectory agree."""
    if not out.exists():
        return True
    man = json.loads((out / "manifest.json").read_text())
    names = {p.name for p in out.iterdir()} - {"manifest.json"}
    if set(man["files"]) != names:
        return False
    metrics = json.loads((out / "metrics.json").read_text(),
                         parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    with np.load(out / "trajectory.npz") as z:
        n = z["t"].shape[0]
    return n == man["steps"] == metrics["steps"] and man["status"] in ("complete", "partial")


def test_scenario_mutation_fuzz(tmp_path, capsys):
    rng = np.random.default_rng(20261130)
    counts = {"inputs": 0, "clean": 0, "typed_errors": 0, "tracebacks": 0, "hangs": 0, "inconsistent": 0,
              "unnamed": 0}
    problems = []
    bases = {name: base_data(name) for name in BASES}
    for i in range(SCENARIO_CASES):
        name = BASES[i % len(BASES)]
        data, what = mutate(bases[name], rng)
        path = tmp_path / f"fuzz{i}.toml"
        if rng.random() < 0.05:  # byte-level damage now and then: truncation or invalid UTF-8
            raw = dump_toml(data).encode()
            raw = raw[: int(rng.integers(len(raw)))] if rng.random() < 0.5 else raw + b"\n# \xff\xfe\n"
            path.write_bytes(raw)
        else:
            try:
                path.write_text(dump_toml(data))
            except (TypeError, ValueError):
                continue
        out = tmp_path / "runs" / f"out{i}"
        counts["inputs"] += 1
        t0 = time.perf_counter()
        try:
            limited(lambda p=path, o=out: run_scenario(p, o, steps=STEPS, progress=False, figures=False,
                                                       replay=False))
            counts["clean"] += 1
        except HqpTpmError as exc:
            counts["typed_errors"] += 1
            if path.name not in str(exc) and "--steps" not in str(exc):
                counts["unnamed"] += 1
                problems.append(f"{what}: error without the file named: {exc}")
        except Hang:
            counts["hangs"] += 1
            problems.append(f"{what}: no answer after {TIME_LIMIT} s")
        except Exception as exc:  # noqa: BLE001 - the point of the fuzz
            counts["tracebacks"] += 1
            problems.append(f"{what}: {type(exc).__name__}: {exc}")
        if time.perf_counter() - t0 > TIME_LIMIT:
            counts["hangs"] += 1
        try:
            if not folder_consistent(out):
                raise ValueError("mismatch")
        except (OSError, ValueError, KeyError) as exc:
            counts["inconsistent"] += 1
            problems.append(f"{what}: inconsistent output folder ({exc})")
        leftover = [p.name for p in (tmp_path / "runs").glob(".*")] if (tmp_path / "runs").exists() else []
        if leftover:
            counts["inconsistent"] += 1
            problems.append(f"{what}: temporary folders left: {leftover}")
    with capsys.disabled():
        print(f"\nscenario fuzz: {json.dumps(counts)}")
    assert not problems, "\n".join(problems[:20])
    assert counts["typed_errors"] > counts["inputs"] // 3 and counts["clean"] > 0


# ------------------------------------------------------------------------------------------ solvers
SOLVERS = ("tpm", "nullspace", "sns_tpm", "sns", "qp", "qp:daqp")
SPECIAL = [np.nan, np.inf, -np.inf, 1e300, -1e300, 1e-300, 0.0]


def _spoil(a: np.ndarray, rng) -> np.ndarray:
    a = np.array(a, dtype=float)
    if a.size and rng.random() < 0.5:
        a.flat[int(rng.integers(a.size))] = SPECIAL[int(rng.integers(len(SPECIAL)))]
    return a


def solver_case(rng) -> tuple[str, list, int, dict, str]:
    n = int(rng.integers(1, 9))
    levels = []
    what = []
    for _ in range(int(rng.integers(0, 4))):
        m = int(rng.integers(0, 5))
        J = rng.standard_normal((m, n)) * 10.0 ** rng.integers(-8, 4)
        if rng.random() < 0.3 and m > 1:
            J[-1] = J[0]  # dependent rows
        b = rng.standard_normal(m)
        r = rng.random()
        if r < 0.15:
            J = _spoil(J, rng)
            what.append("J spoiled")
        elif r < 0.3:
            b = _spoil(b, rng)
            what.append("b spoiled")
        elif r < 0.36:
            J = J[:, : max(n - 1, 0)]
            what.append("J columns")
        elif r < 0.42:
            b = b[:-1] if m else np.ones(1)
            what.append("b rows")
        levels.append((J, b))
    kw: dict = {}
    r = rng.random()
    if r < 0.15:
        kw["x0"] = _spoil(rng.standard_normal(n), rng)
    elif r < 0.2:
        kw["x0"] = rng.standard_normal(n + 1)
    elif r < 0.3:
        kw["x0"] = rng.standard_normal(n)
    if rng.random() < 0.5:
        lo = -rng.random(n) * 2
        up = rng.random(n) * 2
        r = rng.random()
        if r < 0.1:
            lo, up = up, lo - 1.0
        elif r < 0.2:
            lo = _spoil(lo, rng)
        elif r < 0.25:
            up = up[:-1]
        kw["box"] = (lo, up)
    if rng.random() < 0.5:
        kw["lambda_max"] = float(rng.choice([0.05, 0.0, -0.1, np.nan, np.inf, 1.0]))
        kw["eps"] = float(rng.choice([0.1, 0.0, -1.0, np.nan, 0.5]))
    solver = SOLVERS[int(rng.integers(len(SOLVERS)))]
    return solver, levels, n, kw, f"{solver} n={n} {what} {sorted(kw)}"


def test_solver_input_fuzz(capsys):
    from hqp_tpm.solvers.registry import solve

    rng = np.random.default_rng(13)
    counts = {"inputs": 0, "clean": 0, "typed_errors": 0, "tracebacks": 0, "hangs": 0, "non_finite": 0}
    problems = []
    for _ in range(SOLVER_CASES):
        solver, levels, n, kw, what = solver_case(rng)
        counts["inputs"] += 1
        try:
            x, _ = limited(lambda s=solver, lv=levels, nn=n, k=kw: solve(s, lv, nn, **k), 30.0)
            if np.shape(x) != (n,) or not np.isfinite(x).all():
                counts["non_finite"] += 1
                problems.append(f"{what}: returned {x!r}")
            else:
                counts["clean"] += 1
        except HqpTpmError:
            counts["typed_errors"] += 1
        except Hang:
            counts["hangs"] += 1
            problems.append(f"{what}: no answer after 30 s")
        except Exception as exc:  # noqa: BLE001
            counts["tracebacks"] += 1
            problems.append(f"{what}: {type(exc).__name__}: {exc}")
    with capsys.disabled():
        print(f"\nsolver fuzz: {json.dumps(counts)}")
    assert not problems, "\n".join(problems[:20])


@pytest.mark.parametrize("name", BASES)
def test_fuzz_bases_run_clean(tmp_path, name):
    path = tmp_path / "base.toml"
    path.write_text(dump_toml(base_data(name)))
    assert tomllib.loads(path.read_text())
    s = run_scenario(path, tmp_path / "out", steps=STEPS, progress=False, figures=False, replay=False)
    assert s["status"] == "complete" and folder_consistent(tmp_path / "out")


# ------------------------------------------------------------------------------------------ hostile mutants
#: The kinds of the held-out campaign of issue 31, each applied to every base (deep and huge at random fields).
HOSTILE = ("deep", "huge", "repeat_level", "inside", "negative_radius", "qp_backend", "extends", "symlink_out")
DEEP = "__hqp_tpm_deep__"
#: The longest error message a user should get (characters).
LONGEST_MESSAGE = 2_000


def hostile(data: dict, kind: str, rng: np.random.Generator) -> tuple[str, str]:
    """The TOML text of ``data`` with one hostile edit of ``kind``, and a description."""
    out = copy.deepcopy(data)
    tasks = [t["name"] for t in out.get("tasks", [])]
    obstacles = out.get("obstacles", [])
    what = kind
    if kind in ("deep", "huge"):
        paths = [p for p, v in _paths(out) if not isinstance(v, (dict, list)) or kind == "huge"]
        path = paths[int(rng.integers(len(paths)))]
        parent = out
        for p in path[:-1]:
            parent = parent[p]
        if kind == "deep":
            depth = int(rng.choice([40, 400, 3000]))
            parent[path[-1]] = DEEP
            what = f"{path} nested {depth} deep"
            return dump_toml(out).replace(json.dumps(DEEP), "[" * depth + "]" * depth), what
        parent[path[-1]] = [0.5] * 200_000
        what = f"{path} = 200,000 numbers"
    elif kind == "repeat_level":
        out["policy"] = {"type": "fixed", "levels": [tasks[0], tasks[0]]}
    elif kind == "inside" and obstacles:
        obstacles[0].update(type="sphere", center=[0.0, 0.0, 0.0], radius=50.0)
        for k in ("half_extents", "a", "b", "velocity"):
            obstacles[0].pop(k, None)
    elif kind == "negative_radius" and obstacles:
        obstacles[0]["radius"] = -0.1
    elif kind == "qp_backend":
        out["scenario"]["solver"] = "qp:no_such_backend"
    elif kind == "extends":
        out["scenario"]["extends"] = "no_such_parent"
    return dump_toml(out), what


def test_hostile_mutants(tmp_path, capsys):
    """Deep nesting, huge lists, a repeated level, an obstacle holding the robot, a negative radius, an unknown QP
    backend, a missing parent, a symbolic-link ``--out``: a clean result or a typed error naming the file, a
    message of at most 2,000 characters (``hqp_tpm.errors.MAX_MESSAGE``), no folder left behind."""
    rng = np.random.default_rng(31)
    counts = {"inputs": 0, "clean": 0, "typed_errors": 0, "problems": 0}
    problems = []
    bases = {name: base_data(name) for name in BASES}
    runs, real = tmp_path / "runs", tmp_path / "real"
    runs.mkdir()
    for i in range(SCALE):
        for name in BASES:
            for kind in HOSTILE:
                text, what = hostile(bases[name], kind, rng)
                what = f"{name}: {what}"
                path = tmp_path / f"hostile{i}_{name}_{kind}.toml"
                path.write_text(text)
                out = runs / f"out_{name}_{kind}_{i}"
                if kind == "symlink_out":
                    target = real / out.name
                    target.mkdir(parents=True)
                    out.symlink_to(target, target_is_directory=True)
                counts["inputs"] += 1
                try:
                    limited(lambda p=path, o=out: run_scenario(p, o, steps=STEPS, progress=False, figures=False,
                                                               replay=False))
                    counts["clean"] += 1
                except HqpTpmError as exc:
                    counts["typed_errors"] += 1
                    if path.name not in str(exc):
                        problems.append(f"{what}: error without the file named: {str(exc)[:300]}")
                    if len(str(exc)) > LONGEST_MESSAGE:
                        problems.append(f"{what}: a message of {len(str(exc))} characters")
                except Hang:
                    problems.append(f"{what}: no answer after {TIME_LIMIT} s")
                except Exception as exc:  # noqa: BLE001 - the point of the fuzz
                    problems.append(f"{what}: {type(exc).__name__}: {str(exc)[:300]}")
                if kind == "symlink_out":
                    if not out.is_symlink():
                        problems.append(f"{what}: the link --out was replaced")
                    out = real / out.name
                try:
                    if out.exists() and any(out.iterdir()) and not folder_consistent(out):
                        raise ValueError("mismatch")
                except (OSError, ValueError, KeyError) as exc:
                    problems.append(f"{what}: inconsistent output folder ({exc})")
                left = [p.name for d in (runs, real) if d.exists() for p in d.iterdir() if p.name.startswith(".")]
                if left:
                    problems.append(f"{what}: entries left behind: {left}")
    counts["problems"] = len(problems)
    with capsys.disabled():
        print(f"\nhostile mutants: {json.dumps(counts)}")
    assert not problems, "\n".join(problems[:20])
    assert counts["typed_errors"] >= counts["inputs"] // 2 and counts["clean"] > 0
