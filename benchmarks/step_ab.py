"""The side-by-side benchmark's hqp-tpm step (``benchmarks.peers.contenders.Hqp.step``: moved targets assigned,
``ctrl.set_state``, ``ctrl.compute()``) of two checkouts in ONE process, interleaved per configuration.

    OMP_NUM_THREADS=1 python benchmarks/step_ab.py OLD_CHECKOUT [NEW_CHECKOUT]

``OLD_CHECKOUT``: a directory with an earlier commit's files (``mkdir old && git archive 42742a8 | tar -x -C old``);
``NEW_CHECKOUT``: default this one. Each checkout's package and benchmark modules are imported in turn (the first
import's modules dropped from ``sys.modules`` before the second: both stay loaded). The iiwa problems (EE pose >
posture: ``tpm`` and ``sns_tpm`` at velocity level, ``tpm`` at acceleration level), 20 configurations, 2 x REPEATS
(env, default 300) steps each; per-step thread CPU time (``CLOCK=wall``: ``perf_counter``), median and p99.

When the checkouts' kernels differ, give the run an empty numba cache (``NUMBA_CACHE_DIR=$(mktemp -d)``; both
compile, ~2 min): with both loaded from their disk caches in one process, the newer checkout's step crashed (a heap
corruption, "corrupted size vs. prev_size"; one checkout's cached callee linked into the other's kernel, it seems).
"""
import importlib
import os
import sys
import time
from pathlib import Path

import numpy as np


def load(root):
    for k in [k for k in sys.modules if k.split(".")[0] in ("hqp_tpm", "benchmarks")]:
        del sys.modules[k]
    sys.path.insert(0, root)
    pkg = importlib.import_module("hqp_tpm")  # (now: the benchmark modules import it lazily, after root is gone)
    if not Path(pkg.__file__).resolve().is_relative_to(Path(root).resolve()):
        raise SystemExit(f"hqp_tpm imported from {pkg.__file__}, not from {root}")
    P = importlib.import_module("benchmarks.peers.problems")
    C = importlib.import_module("benchmarks.peers.contenders")
    sys.path.remove(root)
    robot = P.load_robot(P.IIWA)
    out = {}
    for name, order, solver in [("tpm", 1, "tpm"), ("sns_tpm", 1, "sns_tpm"), ("acc", 2, "tpm")]:
        prob = P.iiwa_problem(robot, order, n=20)
        hs = []
        for cfg in prob.configs:
            h = C.Hqp(robot, prob, solver)
            h.setup(cfg)
            for _ in range(200):
                h.step()
            hs.append(h)
        out[name] = hs
    return out

versions = {"old": load(sys.argv[1]),
            "new": load(sys.argv[2] if len(sys.argv) > 2 else str(Path(__file__).resolve().parents[1]))}
clock = time.thread_time_ns if os.environ.get("CLOCK", "cpu") == "cpu" else time.perf_counter_ns
R = int(os.environ.get("REPEATS", "300"))
res = {v: {p: [] for p in versions[v]} for v in versions}
for _ in range(2):
    for p in versions["old"]:
        for k in range(20):
            for v in (("old", "new") if k % 2 else ("new", "old")):
                h = versions[v][p][k]
                step = h.step
                ts = res[v][p]
                for _ in range(R):
                    a = clock()
                    step()
                    ts.append(clock() - a)
print(f"per-step {'thread CPU' if clock is time.thread_time_ns else 'wall'} us, 20 configs x {2*R} steps, interleaved")
for p in versions["old"]:
    o, n = np.array(res["old"][p]) / 1000, np.array(res["new"][p]) / 1000
    print(f"{p:8s} old median {np.median(o):6.2f} p99 {np.percentile(o, 99):6.2f} | new median {np.median(n):6.2f} "
          f"p99 {np.percentile(n, 99):6.2f} | new/old {np.median(n)/np.median(o):.2f}")
