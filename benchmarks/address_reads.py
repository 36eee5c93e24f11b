"""What the fused lean step's arrays-by-address cost against numba's public ways of handing a kernel many arrays.

    python benchmarks/address_reads.py [--slots 4 12] [--calls 20000] [--rounds 7]

The fused step (:mod:`hqp_tpm.control._compiled_step`) takes five arguments whatever the stack; the matrices and
vectors it reads (pinocchio's views among them) are an address table in its int64 array, read through
:func:`hqp_tpm._jit.table_matrix` / ``table_vector`` (an ``inttoptr`` intrinsic and ``numba.carray``). The
alternatives without raw addresses: two ``numba.typed.List`` arguments (matrices, vectors) or two tuples (one
compiled specialization per slot count). Each kernel here reads ``slots`` matrices and ``2 slots`` vectors (two
entries of each) and writes their sum: the call's cost is numba's dispatch (typing and unboxing the arguments)
plus the reads. Reported: the median over rounds of the mean time per call, ns.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numba  # noqa: E402
import numpy as np  # noqa: E402
from numba.typed import List  # noqa: E402

from hqp_tpm import _jit  # noqa: E402

table_matrix, table_vector = _jit.address_readers()


@numba.njit(nogil=True)
def by_address(buf, ints, floats, q, v):
    s = 0.0
    for k in range(ints[2]):
        M = table_matrix(ints, k)
        a, b = table_vector(ints, 2 * k), table_vector(ints, 2 * k + 1)
        s += M[1, 2] + M[0, 0] + a[1] + b[2]
    buf[0] = s
    return 0


@numba.njit(nogil=True)
def by_containers(buf, ints, floats, mats, vecs, q, v):
    s = 0.0
    for k in range(ints[2]):
        M = mats[k]
        a, b = vecs[2 * k], vecs[2 * k + 1]
        s += M[1, 2] + M[0, 0] + a[1] + b[2]
    buf[0] = s
    return 0


def case(slots: int, calls: int, rounds: int) -> dict:
    rng = np.random.default_rng(0)
    mats = [rng.random((6, 30)) for _ in range(slots)]
    vecs = [rng.random(6) for _ in range(2 * slots)]
    head = 9
    ints = np.zeros(head + 3 * slots + 4 * slots, dtype=np.int64)
    ints[2], ints[7], ints[8] = slots, head, head + 3 * slots  # (the table offsets where Program keeps them)
    for i, a in enumerate(mats):
        ints[head + 3 * i: head + 3 * i + 3] = a.ctypes.data, a.shape[0], a.shape[1]
    for i, a in enumerate(vecs):
        at = head + 3 * slots + 2 * i
        ints[at: at + 2] = a.ctypes.data, a.shape[0]
    buf, floats, q, v = np.zeros(4), np.zeros(5), np.zeros(30), np.zeros(30)
    variants = {"address table": (by_address, (buf, ints, floats, q, v)),
                "typed List": (by_containers, (buf, ints, floats, List(mats), List(vecs), q, v)),
                "tuples": (by_containers, (buf, ints, floats, tuple(mats), tuple(vecs), q, v))}
    out, sums = {}, set()
    for name, (fn, args) in variants.items():
        fn(*args)
        sums.add(buf[0])
        per_round = []
        for _ in range(rounds):
            t = time.perf_counter()
            for _ in range(calls):
                fn(*args)
            per_round.append((time.perf_counter() - t) / calls * 1e9)
        out[name] = float(np.median(per_round))
    assert len(sums) == 1, sums  # the same numbers read every way
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--slots", type=int, nargs="+", default=[4, 12])
    ap.add_argument("--calls", type=int, default=20000)
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args()
    for slots in args.slots:
        res = case(slots, args.calls, args.rounds)
        print(f"{slots} matrices + {2 * slots} vectors: " + ", ".join(f"{k} {v:.0f} ns" for k, v in res.items()))


if __name__ == "__main__":
    main()
