"""Sweeps and campaigns: many runs of one scenario (or many property draws), on local processes or on Dask.

``hqp-tpm sweep SCENARIO --set FIELD=v1,v2 ... [--random N --seed S FIELD=lo:hi ...] [--solver a,b]``
runs every variant (the grid of the ``--set`` values, crossed with ``N`` random draws of the ranges and with
the solvers) as one ``hqp-tpm run`` each, into ``OUT/<variant>/`` (the layout of ``hqp-tpm run``, with its
manifest), and writes ``OUT/summary.csv``, ``OUT/summary.md`` and ``OUT/sweep.png`` (chosen metrics against
the varied fields). Re-running the same sweep skips the variants whose results are complete. A variant that
fails records its typed error in the table; the sweep goes on.

Executors (one code path: anything with the ``concurrent.futures.Executor`` interface):
local worker processes by default (``--workers N``; ``--workers 0`` runs in this process),
``--scheduler tcp://HOST:PORT`` an existing Dask cluster (``dask.distributed``), ``--cluster local:N`` a Dask
``LocalCluster`` of N worker processes started for the sweep. Dask is optional: ``pip install 'hqp-tpm[dask]'``.

Fields are dotted paths into the scenario file: ``policy.eps1``, ``scenario.period``, ``tasks.ee.kp``
(arrays of tables by ``name``), ``obstacles[0].center`` (or by index). Values are TOML values:
``--set policy.eps1=0.03,0.05`` or ``--set obstacles.o1.center=[0.1,0.5,0.1],[0.1,0.5,0.2]``; a range is
``lo:hi`` (numbers or lists of numbers, drawn uniformly per element).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import copy
import csv
import hashlib
import itertools
import json
import math
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from hqp_tpm.errors import HqpTpmError, OutputError, ScenarioError, SweepError, elide
from hqp_tpm.solvers.registry import ANALYTIC, BOXED

SWEEP_FILE = "sweep.json"
#: Seconds to wait for a Dask scheduler given by --scheduler.
CONNECT_TIMEOUT = 30
#: Metrics shown in summary.md and the figure when none are asked for (those the runs have).
DEFAULT_METRICS = ("d_minimal_min", "d_ee_min", "ee_error_rms", "ee_error_max_settled", "pointing_violation_max_deg",
                   "d_obstacle_min", "scale_min", "sigma_m_min", "wall_time_s")


# ------------------------------------------------------------------------------------------ fields
def _tokens(path: str) -> list:
    """``"obstacles[0].center"`` -> ``["obstacles", 0, "center"]``."""
    out: list = []
    for part in path.split("."):
        if not part:
            raise SweepError(f"field {path!r}: empty part")
        name, *idx = part.split("[")
        if name:
            out.append(name)
        for i in idx:
            if not i.endswith("]") or not i[:-1].lstrip("-").isdigit():
                raise SweepError(f"field {path!r}: bad index [{i}")
            out.append(int(i[:-1]))
    return out


def set_field(data: dict, path: str, value) -> None:
    """Replace the field ``path`` of scenario ``data`` by ``value`` (arrays of tables: by index or ``name``)."""
    toks = _tokens(path)
    node = data
    for k, tok in enumerate(toks):
        last = k == len(toks) - 1
        where = ".".join(map(str, toks[:k])) or "the file"
        if isinstance(node, list):
            if isinstance(tok, int):
                if not -len(node) <= tok < len(node):
                    raise SweepError(f"field {path!r}: {where} has {len(node)} entries, no [{tok}]")
                idx = tok
            else:
                names = [x.get("name") for x in node if isinstance(x, dict)]
                if tok not in names:
                    raise SweepError(f"field {path!r}: no entry named {tok!r} in {where}; names: "
                                     f"{', '.join(map(repr, names))}")
                idx = names.index(tok)
            if last:
                node[idx] = value
            else:
                node = node[idx]
        elif isinstance(node, dict):
            if isinstance(tok, int):
                raise SweepError(f"field {path!r}: {where} is a table, not an array")
            if last:
                node[tok] = value
            else:
                node = node.setdefault(tok, {})
        else:
            raise SweepError(f"field {path!r}: {where} is a value, not a table")


def _split(text: str, sep: str) -> list[str]:
    """Split at ``sep`` outside brackets, braces and quotes."""
    out, depth, cur, quote = [], 0, "", None
    for c in text:
        if quote:
            quote = None if c == quote else quote
        elif c in "\"'":
            quote = c
        elif c in "[{":
            depth += 1
        elif c in "]}":
            depth -= 1
        elif c == sep and depth == 0:
            out.append(cur)
            cur = ""
            continue
        cur += c
    out.append(cur)
    return [x.strip() for x in out]


def parse_value(text: str):
    """A TOML value (``0.05``, ``[0.1, 0.5, 0.1]``, ``"x"``, ``true``); a bare word is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text
    except RecursionError:
        raise SweepError(f"value {elide(text, 200)!r}: arrays nested too deep") from None


def _numeric(v) -> bool:
    return (isinstance(v, (int, float)) and not isinstance(v, bool)) or (
        isinstance(v, list) and bool(v) and all(_numeric(x) and not isinstance(x, list) for x in v))


def parse_assignment(text: str) -> tuple[str, list | None, tuple | None]:
    """``FIELD=v1,v2`` -> (field, [v1, v2], None); ``FIELD=lo:hi`` -> (field, None, (lo, hi))."""
    if "=" not in text:
        raise SweepError(f"{text!r}: expected FIELD=v1,v2,... or FIELD=lo:hi")
    name, _, rhs = text.partition("=")
    name = name.strip()
    _tokens(name)
    parts = _split(rhs, ":")
    if len(parts) == 2:
        lo, hi = parse_value(parts[0]), parse_value(parts[1])
        if _numeric(lo) and _numeric(hi):
            if isinstance(lo, list) != isinstance(hi, list) or (isinstance(lo, list) and len(lo) != len(hi)):
                raise SweepError(f"{name}: range {rhs!r}: both ends must be numbers or lists of one length")
            return name, None, (lo, hi)
    values = [parse_value(x) for x in _split(rhs, ",") if x != ""]
    if not values:
        raise SweepError(f"{name}: no values given")
    return name, values, None


# ------------------------------------------------------------------------------------------ variants
@dataclass(frozen=True)
class Variant:
    """One run of a sweep: the scenario with ``overrides`` (field -> value) and maybe another solver."""

    name: str
    overrides: dict = field(default_factory=dict)
    solver: str | None = None

    @property
    def key(self) -> str:
        """A digest of what the variant runs (resuming compares it with the manifest's)."""
        text = json.dumps({"overrides": self.overrides, "solver": self.solver}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def make_variants(grid: dict[str, list], ranges: dict[str, tuple], n_random: int = 0, seed: int = 0,
                  solvers=(None,)) -> list[Variant]:
    """The grid of ``grid`` values x ``n_random`` uniform draws of ``ranges`` (seeded) x ``solvers``."""
    import numpy as np

    if ranges and n_random <= 0:
        raise SweepError("ranges (FIELD=lo:hi) need --random N")
    rng = np.random.default_rng(seed)
    draws: list[dict] = [{}]
    if n_random > 0:
        draws = []
        for _ in range(n_random):
            d = {}
            for name, (lo, hi) in ranges.items():
                a, b = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
                x = a + (b - a) * rng.random(a.shape)
                d[name] = x.tolist() if x.ndim else float(x)
            draws.append(d)
    combos = list(itertools.product(*[[(k, v) for v in vals] for k, vals in grid.items()]))
    out = []
    for solver in solvers:
        for combo in combos:
            for d in draws:
                out.append(Variant(f"v{len(out):03d}", {**dict(combo), **d}, solver))
    return out


# ------------------------------------------------------------------------------------------ one job
@dataclass
class Job:
    """What a worker needs for one variant (pickles: plain data)."""

    variant: Variant
    base: dict
    label: str
    out: str
    steps: int | None = None
    figures: bool = False


def variant_scenario(base: dict, label: str, variant: Variant):
    """The variant's parsed scenario (validated like a file named ``<label>[<variant>]``)."""
    from hqp_tpm.app import scenario

    data = copy.deepcopy(base)
    for name, value in variant.overrides.items():
        try:
            set_field(data, name, copy.deepcopy(value))
        except SweepError as exc:
            raise SweepError(f"{label}[{variant.name}]: {exc}") from None
    return scenario.parse(data, Path(f"{label}[{variant.name}]"))


def _scalars(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if isinstance(v, (int, float, str)) or v is None}


def run_job(job: Job) -> dict:
    """Run one variant; returns its row (never raises for a failing variant: the error is in the row)."""
    from hqp_tpm.app.run_scenario import run_scenario

    v = job.variant
    row: dict = {"variant": v.name, "status": "error", "error": "", "error_type": ""}
    t0 = time.perf_counter()
    try:
        sc = variant_scenario(job.base, job.label, v)
        summary = run_scenario(sc, Path(job.out), solver=v.solver, steps=job.steps, progress=False,
                               figures=job.figures, replay=False,
                               manifest={"variant": {"name": v.name, "overrides": v.overrides, "solver": v.solver,
                                                     "key": v.key}})
        row.update(_scalars(summary))
        row["error"] = ""
    except HqpTpmError as exc:
        row.update(error=str(exc), error_type=type(exc).__name__)
    except Exception as exc:  # noqa: BLE001 - a crash of one variant is recorded, not fatal
        row.update(error=f"{exc} ({traceback.format_exc(limit=3).splitlines()[-1]})", error_type=type(exc).__name__)
    row["variant_wall_s"] = time.perf_counter() - t0
    return row


# ------------------------------------------------------------------------------------------ executors
class InlineExecutor(cf.Executor):
    """Runs each call at submit time, in this process (``--workers 0``; handy for debugging)."""

    def submit(self, fn, /, *args, **kwargs):
        fut: cf.Future = cf.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001
            fut.set_exception(exc)
        return fut


@contextlib.contextmanager
def executor(workers: int | None = None, scheduler: str | None = None, cluster: str | None = None):
    """A ``concurrent.futures.Executor``: local processes, an existing Dask cluster or a Dask LocalCluster."""
    if scheduler and cluster:
        raise SweepError("--scheduler and --cluster exclude each other")
    if scheduler or cluster:
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise SweepError("Dask is not installed: pip install 'hqp-tpm[dask]' (dask[distributed])") from None
        lc = None
        if cluster:
            kind, _, n = cluster.partition(":")
            if kind != "local" or (n and not n.isdigit()) or n == "0":
                raise SweepError(f"--cluster {cluster!r}: expected local:N (N worker processes)")
            lc = LocalCluster(n_workers=int(n or 2), threads_per_worker=1, processes=True, dashboard_address=None)
            client = Client(lc)
        else:
            try:
                client = Client(scheduler, timeout=CONNECT_TIMEOUT)
            except OSError as exc:
                raise SweepError(f"--scheduler {scheduler!r}: cannot connect ({exc})") from None
        try:
            yield client.get_executor(pure=False)
        finally:
            client.close()
            if lc is not None:
                lc.close()
        return
    n = (os.cpu_count() or 1) if workers is None else int(workers)
    if n < 0:
        raise SweepError(f"--workers {n}: must be >= 0")
    if n == 0:
        yield InlineExecutor()
        return
    ex = cf.ProcessPoolExecutor(max_workers=n, initializer=watch_parent, initargs=(os.getpid(),))
    try:
        yield ex
    except BaseException:  # interrupted (a signal): the workers end now, not after their current variant
        stop_workers(ex)
        raise
    ex.shutdown(wait=True)


#: Seconds between two checks of a worker that the sweep process is still there (where PR_SET_PDEATHSIG is not).
WATCH_PERIOD = 1.0


def watch_parent(parent: int) -> None:
    """Worker initializer: the worker ends when the sweep process ``parent`` ends, whatever ended it (``kill -9``
    included), instead of waiting forever on its job pipe. Linux: ``prctl(PR_SET_PDEATHSIG, SIGKILL)``; every
    platform: a daemon thread that checks the parent every :data:`WATCH_PERIOD` seconds."""
    direct = os.getppid() == parent  # not so under the forkserver start method
    if direct and sys.platform == "linux":
        import ctypes

        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
        if os.getppid() != parent:  # the parent died before prctl took effect
            os._exit(1)

    from hqp_tpm.app.results import pid_alive

    def watch() -> None:
        while True:
            time.sleep(WATCH_PERIOD)
            if (os.getppid() != parent) if direct else not pid_alive(parent):
                os._exit(1)

    threading.Thread(target=watch, name="hqp-tpm-watch-parent", daemon=True).start()


def stop_workers(ex: cf.ProcessPoolExecutor, timeout: float = 5.0) -> None:
    """End the worker processes of ``ex`` at once (SIGTERM, then SIGKILL after ``timeout`` s)."""
    procs = multiprocessing.active_children()  # the pool's workers (this process starts no other children)
    ex.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    deadline = time.monotonic() + timeout
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(max(0.0, deadline - time.monotonic()))
            if p.is_alive():
                p.kill()
                p.join(1.0)


def map_unordered(ex: cf.Executor, fn, items, on_result=None) -> list:
    """``fn(item)`` for every item through ``ex``; results in the order of ``items``."""
    futures = {ex.submit(fn, item): i for i, item in enumerate(items)}
    out: list = [None] * len(futures)
    try:
        for fut in cf.as_completed(futures):
            i = futures[fut]
            out[i] = fut.result()
            if on_result is not None:
                on_result(out[i])
    except BaseException:  # interrupted: what has not started does not start
        for fut in futures:
            fut.cancel()
        raise
    return out


# ------------------------------------------------------------------------------------------ a sweep
def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list):
        return "[" + ", ".join(_cell(x) for x in v) + "]"
    return "" if v is None else str(v)


def run_sweep(spec, out: Path, *, grid: dict | None = None, ranges: dict | None = None, n_random: int = 0,
              seed: int = 0, solvers=(None,), steps: int | None = None, workers: int | None = None,
              scheduler: str | None = None, cluster: str | None = None, metrics=None, figures: bool = False,
              force: bool = False, progress: bool = True) -> list[dict]:
    """Run a sweep (see the module doc); returns the summary rows, one per variant, in variant order."""
    from hqp_tpm.app import results, scenario

    grid, ranges = dict(grid or {}), dict(ranges or {})
    path = scenario.resolve_path(spec)
    label = path.stem
    base = scenario.read(path)
    variants = make_variants(grid, ranges, n_random, seed, tuple(solvers) or (None,))
    fields = [*grid, *ranges]
    if steps is not None:
        steps = scenario.check_steps(steps, "--steps")
    for name in fields:  # a field that resolves in no variant is a mistake in the sweep itself: say so at once
        try:
            set_field(copy.deepcopy(base), name, 0.0)
        except SweepError as exc:
            raise SweepError(f"{label}: {exc}") from None
    if not variants:
        raise SweepError(f"{label}: no variants (a field with no values: {', '.join(fields)})")
    try:  # the first variant's file: a misspelt field (a table set_field created) is refused before any work
        first = variant_scenario(base, label, variants[0])
        boxless = [s for s in solvers if s in ANALYTIC] if first.limits is not None else []
        if boxless:
            raise ScenarioError(f"--solver {boxless[0]!r} ignores the hard joint box of {first.limits.where}; "
                                f"valid: a boxed solver ({', '.join(BOXED)}, qp, qp:<backend>)")
    except ScenarioError as exc:
        raise SweepError(f"{exc} (in the first variant, {variants[0].name}: "
                         f"{', '.join(f'{k}={v!r}' for k, v in variants[0].overrides.items())}); nothing was run") \
            from None
    out = Path(out).absolute()
    definition = {"scenario": label, "scenario_file": str(path), "grid": grid, "ranges": ranges,
                  "random": n_random, "seed": seed, "solvers": list(solvers), "steps": steps,
                  "variants": [{"name": v.name, "overrides": v.overrides, "solver": v.solver, "key": v.key}
                               for v in variants]}
    if out.exists():
        if not out.is_dir():
            raise OutputError(f"sweep output {str(out)!r} is a file")
        if any(out.iterdir()) and not (out / SWEEP_FILE).is_file() and not force:
            raise OutputError(f"sweep output {str(out)!r} is not empty and holds no sweep ({SWEEP_FILE}); choose "
                              "another --out or pass --force")
        _claim(out, definition, force)
    out.mkdir(parents=True, exist_ok=True)
    results.write_text(out / SWEEP_FILE, json.dumps(definition, indent=2) + "\n")
    rows: dict[str, dict] = {}
    jobs = []
    for v in variants:
        folder = out / v.name
        man = results.read_manifest(folder)
        if man is not None and man.get("status") == "complete" and man.get("variant", {}).get("key") == v.key:
            m = json.loads((folder / "metrics.json").read_text())
            rows[v.name] = {"variant": v.name, "status": "complete", "error": "", "error_type": "", **_scalars(m),
                            "resumed": True}
        else:
            jobs.append(Job(v, base, label, str(folder), steps, figures))
    done = [0]

    def report(row):
        done[0] += 1
        if progress:
            state = row["status"] if not row.get("error") else f"error: {row['error_type']}"
            print(f"sweep {label}: {done[0]}/{len(jobs)} {row['variant']} {state}", file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    if jobs:
        try:
            with executor(workers, scheduler, cluster) as ex:
                for row in map_unordered(ex, run_job, jobs, report):
                    rows[row["variant"]] = row
        except BaseException:  # the temporary folders of the variants the ended workers were writing
            for job in jobs:
                results.remove_stale(out, job.variant.name)
            raise
    wall = time.perf_counter() - t0
    table = []
    for v in variants:
        row = {"variant": v.name, **{f: v.overrides.get(f) for f in fields}}
        if len(set(solvers)) > 1 or any(s is not None for s in solvers):
            row["solver"] = v.solver
        r = rows[v.name]
        row.update({k: val for k, val in r.items() if k not in row})
        table.append(row)
    write_summary(out, table, fields, metrics)
    meta = {"wall_time_s": wall, "variants": len(variants), "run": len(jobs), "resumed": len(variants) - len(jobs),
            "failed": sum(1 for r in table if r.get("error")),
            "executor": (f"dask {scheduler}" if scheduler else f"dask LocalCluster {cluster}" if cluster
                         else f"processes ({workers if workers is not None else os.cpu_count()})")}
    results.write_text(out / "sweep_run.json", json.dumps(meta, indent=2) + "\n")
    return table


#: What makes two sweeps the same sweep (``sweep.json``): the rest of the file follows from these.
SAME_SWEEP = ("scenario", "scenario_file", "grid", "ranges", "random", "seed", "solvers", "steps")
#: Files a sweep writes into its folder besides the variants' folders.
SWEEP_FILES = (SWEEP_FILE, "sweep_run.json", "summary.csv", "summary.md", "sweep.png")


def _claim(out: Path, definition: dict, force: bool) -> None:
    """A folder holding another sweep (its ``sweep.json`` differs in :data:`SAME_SWEEP`) is refused, unless
    ``force``: then that sweep's files and variant folders are removed first (the same sweep is resumed)."""
    from hqp_tpm.app import results

    try:
        old = json.loads((out / SWEEP_FILE).read_text(encoding="utf-8"))
    except FileNotFoundError:
        return
    except (OSError, ValueError):
        old = {}
    new = json.loads(json.dumps(definition))
    if not isinstance(old, dict):
        old = {}

    def same_file(a, b) -> bool:
        return a == b or (isinstance(a, str) and isinstance(b, str) and Path(a).resolve() == Path(b).resolve())

    differ = [k for k in SAME_SWEEP if not (same_file(old.get(k), new[k]) if k == "scenario_file"
                                            else old.get(k) == new[k])]
    if not differ:
        return
    if not force:
        what = "; ".join(f"{k}: {_cell(old.get(k))} there, {_cell(new[k])} now" for k in differ)
        raise OutputError(elide(f"sweep output {str(out)!r} holds a different sweep ({what}); choose another --out, "
                                "or pass --force to replace it"))
    import shutil

    for v in old.get("variants", []) if isinstance(old.get("variants"), list) else []:
        name = v.get("name") if isinstance(v, dict) else None
        folder = out / name if isinstance(name, str) and name and "/" not in name and name not in (".", "..") \
            else None
        if folder is not None and folder.is_dir() and not folder.is_symlink() and (
                results.read_manifest(folder) is not None or not any(folder.iterdir())):
            shutil.rmtree(folder)
    for f in SWEEP_FILES:
        (out / f).unlink(missing_ok=True)


def _chosen(table: list[dict], metrics) -> list[str]:
    have = {k for r in table for k, v in r.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
    if metrics:
        return [m for m in metrics if m in have] or list(metrics)
    return [m for m in DEFAULT_METRICS if m in have]


def write_summary(out: Path, table: list[dict], fields: list[str], metrics=None) -> None:
    """``summary.csv`` (every column), ``summary.md`` (fields, status, chosen metrics) and ``sweep.png``."""
    from hqp_tpm.app import results

    cols: list[str] = []
    for r in table:
        cols += [k for k in r if k not in cols]
    lines = []
    import io

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in table:
        w.writerow([_cell(r.get(c)) for c in cols])
    results.write_text(out / "summary.csv", buf.getvalue())
    chosen = _chosen(table, metrics)
    head = ["variant", *fields, *(["solver"] if "solver" in cols else []), "status", *chosen, "error"]
    lines = ["| " + " | ".join(f"`{h}`" if h in fields else h for h in head) + " |",
             "|" + "---|" * len(head)]
    for r in table:
        cells = [_cell(r.get(h)).replace("|", "\\|").replace("\n", " ") for h in head]
        lines.append("| " + " | ".join(cells) + " |")
    results.write_text(out / "summary.md", "\n".join(lines) + "\n")
    if chosen and fields:
        try:
            figure(out / "sweep.png", table, fields, chosen)
        except Exception as exc:  # noqa: BLE001 - a figure must not lose the table
            print(f"hqp-tpm: sweep figure not written ({exc})", file=sys.stderr)


def _axis_value(v):
    if isinstance(v, list):
        return float(v[-1]) if v and _numeric(v) else math.nan  # a vector: its last element
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return float(v)
    return math.nan


#: Metrics of the table that say how long a run took, not how it went: not plotted.
TIMING_METRICS = ("wall_time_s", "mean_step_us", "compile_s")


def _unit(table: list[dict], metric: str) -> str:
    """The unit of ``metric``: from the runs' ``units`` (metrics.json), else from the metrics schema."""
    from hqp_tpm.app.results import METRICS, schema_key

    for r in table:
        units = r.get("units")
        if isinstance(units, dict) and metric in units:
            return str(units[metric])
    key = schema_key(metric)
    return METRICS[key][0] if key is not None else ""


#: Units shown with an SI prefix when a metric's values are small (``ee_error_rms`` of 6.1e-3 m: 6.1 mm).
PREFIXED_UNITS = ("m", "rad", "s", "N", "m/s", "rad/s")


def scaled_unit(unit: str, values) -> tuple[float, str]:
    """``(factor, unit)``: the values times ``factor`` read in ``unit`` with at most 3 digits before the point and
    not below 0.1 (m -> mm or µm; units outside :data:`PREFIXED_UNITS` unchanged)."""
    import numpy as np

    v = np.abs(np.asarray(values, dtype=float))
    v = v[np.isfinite(v) & (v > 0)]
    if unit not in PREFIXED_UNITS or not len(v) or v.max() >= 0.1:
        return 1.0, unit
    if v.max() >= 1e-4:
        return 1e3, "m" + unit
    return 1e6, "µ" + unit


def figure(path: Path, table: list[dict], fields: list[str], metrics: list[str], title: str = ""):
    """Each chosen metric (rows, with its unit, SI-prefixed when small: :func:`scaled_unit`) against each varied
    field (columns), coloured by another varied field when there is one (its values in a legend above the
    column; the colour groups side by side at each grid value, so equal results stay visible); failed variants
    as red crosses at the bottom. Timing metrics (:data:`TIMING_METRICS`) are left out; plain tick labels (no
    offset, no multiplier). Returns the figure."""
    import textwrap

    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator, ScalarFormatter

    metrics = [m for m in metrics if m not in TIMING_METRICS] or list(metrics)
    width = 3.6 * len(fields) + 1.2
    fig, axes = plt.subplots(len(metrics), len(fields), figsize=(width, 2.6 * len(metrics) + 1.2), squeeze=False)
    ok = [not r.get("error") for r in table]
    for j, f in enumerate(fields):
        xs = np.array([_axis_value(r.get(f)) for r in table], dtype=float)
        finite = xs[np.isfinite(xs)]
        span = float(np.ptp(finite)) if len(finite) else 0.0
        other = next((g for g in fields if g != f), None)
        groups = {"": list(range(len(table)))}
        if other is not None:
            groups = {}
            for k, r in enumerate(table):
                groups.setdefault(_cell(r.get(other)), []).append(k)
        for i, m in enumerate(metrics):
            ax = axes[i, j]
            ys = np.array([r.get(m) if isinstance(r.get(m), (int, float)) else math.nan for r in table], dtype=float)
            factor, unit = scaled_unit(_unit(table, m), ys[np.array(ok, dtype=bool)] if any(ok) else ys)
            for c, (value, idx) in enumerate(groups.items()):
                idx = [k for k in idx if ok[k]]
                label = f"{other} = {value}" if other is not None else None
                dodge = (c - (len(groups) - 1) / 2.0) * 0.025 * span  # side by side at each grid value
                ax.plot(xs[idx] + dodge, factor * ys[idx], "o", ms=5, mfc=f"C{c % 10}", mec="k", mew=0.4, ls="none",
                        label=label)
            bad = [x for x, k in zip(xs, ok, strict=True) if not k]
            if bad:
                ax.plot(bad, [ax.get_ylim()[0]] * len(bad), "rx", ms=6, label="failed")
            for axis in (ax.xaxis, ax.yaxis):
                fmt = ScalarFormatter(useOffset=False)
                fmt.set_scientific(False)
                axis.set_major_formatter(fmt)
                axis.set_major_locator(MaxNLocator(5))
            ax.tick_params(labelsize=7)
            ax.tick_params(axis="x", labelrotation=30)
            ax.grid(True, lw=0.3, alpha=0.6)
            if i == len(metrics) - 1:
                ax.set_xlabel(f + (" (last element)" if any(isinstance(r.get(f), list) for r in table) else ""),
                              fontsize=8)
            if j == 0:  # the same metric (and factor) along the row
                ax.set_ylabel(f"{m} [{unit}]" if unit else m, fontsize=8)
            if i == 0 and (other is not None or bad):
                ax.legend(fontsize=7, loc="lower left", bbox_to_anchor=(0.0, 1.02), frameon=False, borderaxespad=0.0,
                          ncol=min(3, len(groups) + bool(bad)), handletextpad=0.2, columnspacing=0.8)
    what = ", ".join(metrics) if len(metrics) <= 2 else f"{len(metrics)} metrics (rows)"
    default = f"sweep: {what} against {', '.join(fields)}" + (" (colour: the other field)" if len(fields) > 1 else "")
    fig.suptitle(textwrap.fill(title or default, width=int(11 * width)), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return fig


# ------------------------------------------------------------------------------------------ campaigns
CAMPAIGNS = ("sns",)


def sns_draw(seed: int, index: int) -> list[str]:
    """The SNS properties on draw ``index`` of campaign ``seed``; returns the names of those that fail."""
    import numpy as np

    from hqp_tpm.errors import SolverFailedError
    from hqp_tpm.solvers.cascaded_qp import cascaded_qp
    from hqp_tpm.solvers.levels import Level
    from hqp_tpm.solvers.random_stacks import random_problem  # the SNS draws of the library's tests
    from hqp_tpm.solvers.sns import sns, sns_tpm, sns_tpm_reference

    kind = ("full_rank", "any", "damped")[index % 3]
    rng = np.random.default_rng([seed, index])
    levels, lo, up, damping = random_problem(rng, kind)

    def in_box(x, tol=1e-9):
        s = 1.0 + np.maximum(np.abs(np.nan_to_num(lo, neginf=0.0)), np.abs(np.nan_to_num(up, posinf=0.0)))
        return bool(((x >= lo - tol * s) & (x <= up + tol * s)).all())

    def residual(level, x):
        lv = level if isinstance(level, Level) else Level(*level)
        y = lv.J @ x
        if lv.is_equality:
            return float(np.linalg.norm(y - lv.b))
        return float(np.linalg.norm(np.maximum(0.0, np.maximum(lv.lower - y, y - lv.upper))))

    failed = []
    x, info = sns_tpm(levels, lo, up, return_info=True, **damping)
    xr, info_r = sns_tpm_reference(levels, lo, up, return_info=True, **damping)
    xs, _, sinfo = sns(levels, lo, up, return_info=True, **damping)
    if not (info.feasible and in_box(x) and in_box(xr) and in_box(xs) and not sinfo.clipped):
        failed.append("box")
    rel = np.linalg.norm(x - xr) / max(1.0, np.linalg.norm(xr))
    if info.saturated != info_r.saturated or abs(info.scale - info_r.scale) >= 1e-9 or rel >= 1e-9:
        failed.append("fast_equals_reference")
    if not damping:
        try:
            xq = cascaded_qp(levels, solver="proxqp", lower=lo, upper=up)
        except SolverFailedError:
            xq = cascaded_qp(levels, solver="daqp", lower=lo, upper=up)
        rq = residual(levels[0], xq)
        J1 = levels[0].J if isinstance(levels[0], Level) else levels[0][0]
        for xx in (sns_tpm(levels, lo, up), sns(levels, lo, up)[0]):
            if rq > residual(levels[0], xx) + 1e-7 * (1.0 + np.abs(J1).max()) * (1.0 + np.abs(xx).max()):
                failed.append("qp_first_level_residual")
                break
    return failed


def campaign_chunk(task: tuple) -> dict:
    """Draws ``start .. start + count - 1`` of a campaign: counts per property and the failing draws."""
    from threadpoolctl import threadpool_limits

    kind, seed, start, count = task
    fails: dict[str, list[int]] = {}
    errors: list[str] = []
    with threadpool_limits(1):
        for i in range(start, start + count):
            try:
                for prop in sns_draw(seed, i):
                    fails.setdefault(prop, []).append(i)
            except Exception as exc:  # noqa: BLE001 - recorded with its draw
                errors.append(f"draw {i}: {type(exc).__name__}: {exc}")
    return {"draws": count, "failed": fails, "errors": errors}


def run_campaign(kind: str, draws: int, *, seed: int = 0, chunk: int = 500, workers: int | None = None,
                 scheduler: str | None = None, cluster: str | None = None, progress: bool = True) -> dict:
    """Run ``draws`` property draws of campaign ``kind`` through an executor; replay one draw with
    :func:`sns_draw` ``(seed, index)`` (``hqp-tpm campaign sns --replay INDEX --seed S``)."""
    if kind not in CAMPAIGNS:
        raise SweepError(f"unknown campaign {kind!r}; campaigns: {', '.join(CAMPAIGNS)}")
    if draws < 1 or chunk < 1:
        raise SweepError("--draws and --chunk must be >= 1")
    tasks = [(kind, seed, s, min(chunk, draws - s)) for s in range(0, draws, chunk)]
    total: dict = {"campaign": kind, "seed": seed, "draws": 0, "failed": {}, "errors": []}
    t0 = time.perf_counter()

    def report(r):
        total["draws"] += r["draws"]
        if progress:
            print(f"campaign {kind}: {total['draws']}/{draws} draws", file=sys.stderr, flush=True)

    with executor(workers, scheduler, cluster) as ex:
        for r in map_unordered(ex, campaign_chunk, tasks, report):
            for prop, idx in r["failed"].items():
                total["failed"].setdefault(prop, []).extend(idx)
            total["errors"] += r["errors"]
    total["wall_time_s"] = time.perf_counter() - t0
    total["properties"] = ["box", "fast_equals_reference", "qp_first_level_residual"]
    return total
