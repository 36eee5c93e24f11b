"""Scenario files: declarative task stacks in TOML (``hqp_tpm/data/scenarios/*.toml`` and users' own files).

A scenario names the robot, the initial state, obstacles, tasks with their parameters, the
policy that orders them, the solver, the level (velocity/acceleration), the period and the
duration. The format is documented in ``docs/scenario_format.md``; every error names the file, the
field and the valid choices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from hqp_tpm.app.scenario_values import Section
from hqp_tpm.data import scenarios_dir
from hqp_tpm.errors import HqpTpmError, ScenarioError, shown
from hqp_tpm.solvers.registry import ANALYTIC, BOXED, SOLVER_NAMES, check_solver_name

#: Folder of the shipped scenario files (package data ``hqp_tpm/data/scenarios/``).
SCENARIO_DIR = scenarios_dir()

LEVELS = {"velocity": 1, "acceleration": 2}

#: Most steps one run may take (10 million: 2.8 h at 1 kHz); a longer run is split into several.
MAX_STEPS = 10_000_000
#: Deepest nesting of arrays and tables in a scenario file (the shipped ones use 5); deeper is a damaged file.
MAX_DEPTH = 32


@dataclass
class Scenario:
    """A parsed scenario: plain data, built into robot/tasks/policy by :mod:`hqp_tpm.app.runner`."""

    name: str
    path: Path
    robot: str
    level: str
    solver: str
    period: float
    duration: float
    lambda_max: float
    eps: float
    nullspace_damping: float
    description: str
    initial: Section
    obstacles: list[Section]
    tasks: list[Section]
    policy: Section
    limits: Section | None
    raw: dict
    #: the ``[plant]`` section (:class:`hqp_tpm.app.scenario_plant.PlantConfig`: kinematic by default)
    plant: Any = None
    #: a run stops (DivergedError) when a joint velocity exceeds this multiple of its bound (context.py)
    velocity_bound: float = 1000.0  # (romeo_tpm, TPM ignoring the limits on purpose, reaches 143x)

    @property
    def order(self) -> int:
        return LEVELS[self.level]

    @property
    def steps(self) -> int:
        """Samples of ``t = 0 : T : duration`` (18,850 for 6 pi s at 1 ms)."""
        return int(math.floor(self.duration / self.period + 1e-9)) + 1


def check_steps(steps, where: str = "steps") -> int:
    """A step count asked for by a caller (``--steps``): an int in ``1 .. MAX_STEPS``."""
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)):
        raise ScenarioError(f"{where}: expected a whole number of steps, got {steps!r}")
    if not 1 <= steps <= MAX_STEPS:
        raise ScenarioError(f"{where}: {steps} is not in 1 .. {MAX_STEPS:,} (the bound of one run)")
    return int(steps)


def check_solver_choice(solver, where: str, cls: type[HqpTpmError] = ScenarioError) -> str:
    """``solver`` if it names a solver and, for ``qp:<backend>``, an installed backend (checked here, before any
    work, where the file and field or the command-line option ``where`` are known); else ``cls`` naming ``where``."""
    try:
        check_solver_name(solver)
    except Exception:
        raise cls(f"{where}: unknown solver {shown(solver)}; valid: {', '.join(SOLVER_NAMES)}") from None
    if solver.startswith("qp:"):
        from hqp_tpm.errors import SolverNotAvailableError
        from hqp_tpm.solvers.cascaded_qp import check_solver

        try:
            check_solver(solver[3:])
        except SolverNotAvailableError as exc:
            raise cls(f"{where}: {exc}") from None
    return solver


def resolve_path(spec: str | Path) -> Path:
    """``spec``: a path to a TOML file or the stem of a file in ``tasks/`` (also when a folder of that name, e.g. an
    earlier run's ``--out``, is in the working directory)."""
    p = Path(spec)
    if p.suffix == ".toml" or (p.exists() and not p.is_dir()):
        if not p.is_file():
            raise ScenarioError(f"scenario file not found: {str(p)!r}")
        return p
    candidate = SCENARIO_DIR / f"{spec}.toml"
    if candidate.is_file():
        return candidate
    known = sorted(f.stem for f in SCENARIO_DIR.glob("*.toml"))
    folder = f"{str(spec)!r} is a folder, not a scenario file; " if p.is_dir() else ""
    raise ScenarioError(f"{folder}unknown scenario {str(spec)!r}; scenarios in {SCENARIO_DIR}: {', '.join(known)}")


def check_nesting(data, where: str, limit: int = MAX_DEPTH) -> None:
    """Refuse arrays or tables nested deeper than ``limit`` (naming the first such field), before anything
    recursive (a copy, a message, the builders) meets them. Walks the data without recursion."""
    todo = [(data, where, 0)]
    while todo:
        node, at, depth = todo.pop()
        if depth > limit:
            raise ScenarioError(f"{at}: arrays or tables nested more than {limit} deep; a scenario field is a "
                                "number, a string, a list of numbers or a table")
        if isinstance(node, dict):
            todo += [(v, f"{at}.{k}", depth + 1) for k, v in node.items() if isinstance(v, (dict, list))]
        elif isinstance(node, list):
            todo += [(v, f"{at}[{i}]", depth + 1) for i, v in enumerate(node) if isinstance(v, (dict, list))]


def _deep_line(text: str, limit: int = MAX_DEPTH) -> str:
    """Where in TOML ``text`` brackets first nest deeper than ``limit``: ``"line N (key)"`` (a best effort that
    skips strings and comments), for a file too deeply nested for the TOML parser itself."""
    depth, quote, comment, line, start = 0, None, False, 1, 0
    for i, c in enumerate(text):
        if c == "\n":
            line, start, comment = line + 1, i + 1, False
        elif comment:
            continue
        elif quote:
            quote = None if c == quote else quote
        elif c in "\"'":
            quote = c
        elif c == "#":
            comment = True
        elif c in "[{":
            depth += 1
            if depth > limit:
                key = text[start:i].split("=", 1)[0].strip() if "=" in text[start:i] else ""
                return f"line {line}" + (f" (field {key!r})" if key else "")
        elif c in "]}":
            depth -= 1
    return "somewhere"


def merge(base: dict, over: dict) -> dict:
    """Deep merge for ``extends``: tables merge key by key; arrays of named tables merge by ``name``
    (a table with ``remove = true`` drops that entry); anything else is replaced."""
    out = dict(base)
    for key, value in over.items():
        old = out.get(key)
        if isinstance(old, dict) and isinstance(value, dict):
            out[key] = merge(old, value)
        elif (isinstance(old, list) and isinstance(value, list) and all(isinstance(x, dict) and "name" in x
                                                                        for x in [*old, *value])):
            items = {x["name"]: dict(x) for x in old}
            for x in value:
                if x.get("remove") is True:
                    items.pop(x["name"], None)
                else:
                    items[x["name"]] = merge(items.get(x["name"], {}), x)
            out[key] = list(items.values())
        else:
            out[key] = value
    return out


def read(path: Path, seen: tuple = ()) -> dict:
    """The file's TOML, with ``[scenario] extends = "other"`` resolved (the other file's stem or path)."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read the scenario file ({exc.strerror or exc})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ScenarioError(f"{path}: not UTF-8 text (byte {exc.start}, line {line}); save the file as UTF-8") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML ({exc})") from None
    except RecursionError:  # arrays or inline tables nested too deep for the parser
        raise ScenarioError(f"{path}: {_deep_line(text)}: arrays or tables nested more than {MAX_DEPTH} deep; a "
                            "scenario field is a number, a string, a list of numbers or a table") from None
    check_nesting(data, path.name)
    parent = data.get("scenario", {}).pop("extends", None) if isinstance(data.get("scenario"), dict) else None
    if parent is None:
        return data
    where = f"{path.name}.scenario.extends"
    if not isinstance(parent, str) or not parent:
        raise ScenarioError(f"{where}: expected the name or path of a scenario file, got {shown(parent)}")
    try:
        base_path = resolve_path(parent) if not Path(parent).suffix else path.parent / parent
    except ScenarioError as exc:
        raise ScenarioError(f"{where}: {exc}") from None
    if base_path.resolve() in seen:
        raise ScenarioError(f"{where}: cycle through {base_path.name}")
    try:
        base = read(base_path, (*seen, path.resolve()))
    except ScenarioError as exc:
        raise ScenarioError(f"{where} ({parent!r}): {exc}") from None
    base.get("scenario", {}).pop("name", None)
    base.get("scenario", {}).pop("description", None)
    return merge(base, data)


def load(spec: str | Path) -> Scenario:
    """Read and validate a scenario file (structure and scalar fields; tasks are built later)."""
    path = resolve_path(spec)
    return parse(read(path), path)


def _plant(sec: Section | None, period: float):
    """The ``[plant]`` section, checked (:func:`hqp_tpm.app.scenario_plant.plant_config`)."""
    from hqp_tpm.app.scenario_plant import plant_config

    return plant_config(sec, period)


def parse(data: dict, path: Path = Path("<memory>")) -> Scenario:
    check_nesting(data, path.name)
    top = Section(data, path.name)
    sc = top.table("scenario")
    solver = sc.string("solver", "tpm")
    check_solver_choice(solver, f"{sc.where}.solver")
    period = sc.number("period")
    if period <= 0:
        raise ScenarioError(f"{sc.where}.period: must be > 0, got {period}")
    duration = sc.number("duration")
    if duration < 0:
        raise ScenarioError(f"{sc.where}.duration: must be >= 0, got {duration}")
    if duration / period + 1 > MAX_STEPS:
        raise ScenarioError(f"{sc.where}.duration: duration / period = {duration:g} / {period:g} is more than "
                            f"{MAX_STEPS:,} steps, the bound of one run; use a longer period or a shorter "
                            "duration")
    damping = {"lambda_max": sc.number("lambda_max", 0.0), "eps": sc.number("eps", 0.0),
               "nullspace_damping": sc.number("nullspace_damping", 0.0)}
    for k, v in damping.items():
        if v < 0:
            raise ScenarioError(f"{sc.where}.{k}: must be >= 0, got {v}")
    out = Scenario(
        name=sc.string("name", path.stem), path=path, robot=sc.string("robot"),
        level=sc.string("level", choices=tuple(LEVELS)), solver=solver, period=period, duration=duration,
        **damping, description=sc.string("description", ""),
        initial=top.table("initial", None) or Section({}, f"{path.name}.initial"),
        obstacles=top.tables("obstacles"), tasks=top.tables("tasks"),
        policy=top.table("policy", None) or Section({"type": "fixed"}, f"{path.name}.policy"),
        limits=top.table("limits", None), raw=data,
        velocity_bound=sc.number("velocity_bound", 1000.0),
    )
    if not out.velocity_bound > 0:
        raise ScenarioError(f"{sc.where}.velocity_bound: must be > 0 (a multiple of the joint velocity "
                            f"limits), got {out.velocity_bound}")
    if out.limits is not None and solver in ANALYTIC:  # the analytic solvers ignore a box: say so, don't run
        raise ScenarioError(f"{out.limits.where}: a hard joint box, which solver {solver!r} ({sc.where}.solver) "
                            f"ignores; valid: a boxed solver ({', '.join(BOXED)}, qp, qp:<backend>), or no "
                            "[limits] section")
    out.plant = _plant(top.table("plant", None), period)
    sc.check_unused()
    top.check_unused()
    if not out.tasks:
        raise ScenarioError(f"{path.name}: no [[tasks]] given")
    names = [t.string("name") for t in out.tasks]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ScenarioError(f"{path.name}: task names must be unique, repeated: {', '.join(sorted(dup))}")
    return out
