"""Shared pieces of the benchmarks: machine and package description, statistics, CSV/Markdown output.

Every benchmark runs with one BLAS thread (:func:`one_blas_thread`; numpy and scipy each load their
own OpenBLAS, whose default threading stalls for milliseconds on small matrices on a busy machine)
and states the thread count it ran with. Times are per call, from ``time.perf_counter_ns``; only
ratios measured in the same run are compared.
"""

from __future__ import annotations

import csv
import datetime as _dt
import importlib.metadata
import os
import platform
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

#: Packages whose versions every result file states.
PACKAGES = ("numpy", "scipy", "pin", "coal", "qpsolvers", "proxsuite", "osqp", "daqp", "quadprog")

#: The qpsolvers backends the benchmarks compare (those installed are used).
QP_BACKENDS = ("proxqp", "osqp", "daqp", "quadprog")

BLAS_THREADS = 1


@contextmanager
def one_blas_thread():
    """All BLAS/OpenMP pools limited to :data:`BLAS_THREADS` (threadpoolctl) for the block.

    threadpoolctl limits only the libraries loaded when the block starts, so everything that
    brings its own BLAS or OpenMP (numpy, scipy, pinocchio, coal, the QP backends) is imported first.
    """
    from threadpoolctl import threadpool_limits

    load_native_libraries()
    with threadpool_limits(limits=BLAS_THREADS):
        yield


def load_native_libraries() -> None:
    """Import the packages that load BLAS/OpenMP libraries (so that a thread limit reaches them)."""
    import importlib

    for mod in ("numpy", "scipy.linalg", "scipy.sparse.linalg", "pinocchio", "coal", "qpsolvers", "proxsuite",
                "osqp", "daqp", "quadprog", "hqp_tpm.solvers"):
        try:
            importlib.import_module(mod)
        except ImportError:
            pass


def installed_qp_backends() -> list[str]:
    import qpsolvers

    return [b for b in QP_BACKENDS if b in qpsolvers.available_solvers]


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(pkg: str) -> str:
    try:
        return importlib.metadata.version(pkg)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def blas_threads() -> str:
    """Thread count of every loaded BLAS/OpenMP library, e.g. ``openblas=1, openblas=1, openmp=1``."""
    from threadpoolctl import threadpool_info

    return ", ".join(f"{i['internal_api']}={i['num_threads']}" for i in threadpool_info()) or "none loaded"


def environment() -> dict[str, str]:
    """Machine, Python, package versions and BLAS threads (call inside :func:`one_blas_thread`)."""
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count() or 0
    env = {
        "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": cpu_model(),
        "cores": f"{os.cpu_count()} (usable {usable})",
        "load average at start": " ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "?",
        "python": platform.python_version(),
        "platform": platform.platform(),
    }
    env.update({pkg: _version(pkg) for pkg in PACKAGES})
    env["BLAS threads"] = f"{BLAS_THREADS} (threadpoolctl: {blas_threads()})"
    env["host speed probe at start"] = host_probe()
    _START[id(env)] = (time.perf_counter(), time.process_time())
    return env


def host_probe() -> str:
    """How fast the host runs right now: the median time of a fixed workload (a Python loop and 20 numpy QRs of a
    38 x 27 matrix), the same in every run. Not a benchmark of hqp-tpm: this shared machine's speed swings by
    up to ~2x within minutes, and runs whose probes differ that much are not comparable in µs (ratios
    measured within one run are)."""
    A = np.random.default_rng(0).standard_normal((38, 27))

    def work():
        s = 0
        for i in range(2000):
            s += i * i
        for _ in range(20):
            np.linalg.qr(A)
        return s

    work()
    ts = []
    for _ in range(21):
        t0 = time.perf_counter_ns()
        work()
        ts.append(time.perf_counter_ns() - t0)
    return f"{sorted(ts)[10] / 1e3:.0f} µs (fixed workload, median of 21)"


_START: dict[int, tuple[float, float]] = {}


def close_environment(env: dict[str, str]) -> None:
    """Add the load at the end and this process's CPU share since :func:`environment` (contention check).

    A CPU share well below 100 % means other processes took the cores part of the time: medians
    are then somewhat and 99th percentiles much higher than on an idle machine.
    """
    wall0, cpu0 = _START.pop(id(env), (None, None))
    if hasattr(os, "getloadavg"):
        env["load average at end"] = " ".join(f"{x:.2f}" for x in os.getloadavg())
    env["host speed probe at end"] = host_probe()
    if wall0 is not None:
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        env["CPU share of this process"] = f"{100 * cpu / wall:.0f} % of {wall:.0f} s wall"


def stats_us(samples_ns, cpu_ns=None) -> dict[str, float]:
    """Median, 99th percentile, mean and count of per-call wall times in ns, in µs; with ``cpu_ns`` also
    the median and p99 of the calls' thread CPU times (``cpu_median_us``, ``cpu_p99_us``)."""
    a = np.asarray(samples_ns, dtype=float) / 1e3
    nan = float("nan")
    if a.size == 0:
        out = {"median_us": nan, "p99_us": nan, "mean_us": nan, "count": 0}
    else:
        out = {"median_us": float(np.median(a)), "p99_us": float(np.percentile(a, 99)), "mean_us": float(a.mean()),
               "count": int(a.size)}
    if cpu_ns is not None:
        c = np.asarray(cpu_ns, dtype=float) / 1e3
        out["cpu_median_us"] = float(np.median(c)) if c.size else nan
        out["cpu_p99_us"] = float(np.percentile(c, 99)) if c.size else nan
    return out


def timed(fn: Callable, *args, **kwargs):
    """``(wall ns, thread CPU ns, fn(*args, **kwargs))``.

    On a shared machine the wall time includes the slices other processes take the core for
    (a few ms each); the thread CPU time does not.
    """
    c0 = time.thread_time_ns()
    t0 = time.perf_counter_ns()
    out = fn(*args, **kwargs)
    t1 = time.perf_counter_ns()
    return t1 - t0, time.thread_time_ns() - c0, out


def rel_err(a, b) -> float:
    """``max|a - b| / max(1, max|b|)``."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.abs(a - b).max(initial=0.0) / max(1.0, np.abs(b).max(initial=0.0)))


@dataclass
class Target:
    """A stated performance target, the measured figure and whether it is met."""

    name: str
    goal: str
    measured: str
    met: bool

    def row(self) -> list[str]:
        return [self.name, self.goal, self.measured, "**met**" if self.met else "**missed**"]


def fmt(x: float, digits: int = 1) -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "–"
    if abs(x) >= 1000:
        return f"{x:,.0f}"
    return f"{x:.{digits}f}"


def md_table(header: Sequence[str], rows: Iterable[Sequence]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def env_markdown(env: dict[str, str]) -> str:
    return md_table(["", ""], [[k, v] for k, v in env.items()])


def targets_markdown(targets: Sequence[Target]) -> str:
    return md_table(["target", "goal", "measured (this run)", ""], [t.row() for t in targets])


def write_csv(path: Path, rows: Sequence[dict], env: dict[str, str]) -> None:
    """Rows as CSV; the environment as leading ``# key: value`` lines (``pandas.read_csv(comment="#")``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with open(path, "w", newline="") as fh:
        for k, v in env.items():
            fh.write(f"# {k}: {v}\n")
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})


def write_markdown(path: Path, title: str, env: dict[str, str], sections: Sequence[tuple[str, str]],
                   argv: Sequence[str] | None = None) -> None:
    """``argv``: the command's arguments as shown (default ``sys.argv``; a caller shows a local path as a name)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    shown = [Path(sys.executable).name, *(sys.argv if argv is None else argv)]
    parts = [f"# {title}", "", f"Command: `{' '.join(shown)}`", "",
             "## Environment", "", env_markdown(env), ""]
    for heading, body in sections:
        parts += [f"## {heading}", "", body.rstrip(), ""]
    path.write_text("\n".join(parts))


def progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)
