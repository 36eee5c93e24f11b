"""Import cost of hqp-tpm, measured with ``python -X importtime`` (one source tree or two, in one run).

    python tools/import_times.py [--repeat 7] SRC [SRC ...]

Each ``SRC`` is a source root (a checkout or ``git archive`` of some commit); it is put first on
``PYTHONPATH``, so one interpreter (with the dependencies installed) measures every tree. The runs are
interleaved and the median and the minimum over ``--repeat`` runs are printed per statement, in milliseconds: the
cumulative import time of the ``hqp_tpm`` modules (what ``-X importtime`` attributes to them, third-party
modules they pull in included), the CPU time (user + system) of the whole process minus that of
``python -c pass`` (steadier than wall time on a busy machine), and which heavy optional modules ended up
in ``sys.modules``.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile

#: The last one preloads numpy and scipy.linalg (not counted): what the package itself adds on top of them.
STATEMENTS = ("import hqp_tpm", "import hqp_tpm.solvers", "import numpy, scipy.linalg; import hqp_tpm.solvers")
HEAVY = ("qpsolvers", "matplotlib", "meshcat", "example_robot_data", "tqdm", "scipy.spatial", "osqp", "proxsuite")


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def cpu_time(src: str, code: str) -> float:
    """CPU seconds (user + system) of ``python -c code`` with ``src`` first on the path."""
    env = {**os.environ, "PYTHONPATH": src}
    with tempfile.TemporaryDirectory() as cwd:
        before = _cpu()
        subprocess.run([sys.executable, "-c", code], env=env, cwd=cwd, check=True)
        return _cpu() - before


def measure(src: str, statement: str) -> tuple[float, list[str]]:
    """Cumulative microseconds of the top-level ``hqp_tpm*`` imports of ``statement``, and the heavy modules loaded."""
    env = {**os.environ, "PYTHONPATH": src}
    probe = f"{statement}\nimport sys\nprint([m for m in {HEAVY!r} if m in sys.modules])"
    with tempfile.TemporaryDirectory() as cwd:  # not the checkout: the import must come from SRC
        out = subprocess.run([sys.executable, "-X", "importtime", "-c", probe], env=env, cwd=cwd,
                             capture_output=True, text=True, check=True)
    total = 0
    for line in out.stderr.splitlines():
        if not line.startswith("import time:") or "cumulative" in line:
            continue
        _, cumulative, name = (s.rstrip() for s in line[len("import time:"):].split("|"))
        if name.startswith("  "):  # nested (deeper indent): counted in its top-level parent
            continue
        name = name.strip()
        if name == "hqp_tpm" or name.startswith("hqp_tpm."):
            total += int(cumulative)
    return total, eval(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("src", nargs="+")
    p.add_argument("--repeat", type=int, default=7)
    args = p.parse_args(argv)
    for statement in STATEMENTS:
        times = {src: [] for src in args.src}
        cpu = {src: [] for src in args.src}
        heavy = {}
        for _ in range(args.repeat):
            for src in args.src:
                us, heavy[src] = measure(src, statement)
                times[src].append(us)
                cpu[src].append(1000 * (cpu_time(src, statement) - cpu_time(src, "pass")))
        med = {src: statistics.median(t) / 1000 for src, t in times.items()}
        low = {src: min(t) / 1000 for src, t in times.items()}
        print(f"{statement}")
        for src in args.src:
            ratio = ""
            if src != args.src[0]:
                first = args.src[0]
                ratio = f"  first/this: {med[first] / med[src]:.1f}x (median), {low[first] / low[src]:.1f}x (min)"
            c, c0 = statistics.median(cpu[src]), statistics.median(cpu[args.src[0]])
            c_ratio = f" (first/this {c0 / c:.1f}x)" if src != args.src[0] and c else ""
            print(f"  {src}: -X importtime median {med[src]:7.1f} ms, min {low[src]:7.1f} ms{ratio}; "
                  f"CPU time median {c:7.1f} ms{c_ratio}; heavy modules loaded: {', '.join(heavy[src]) or 'none'}")


if __name__ == "__main__":
    main()
