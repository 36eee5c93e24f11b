"""Step cost of the per-step account (``hqp-tpm run --explain``): off, account only, account and causes.

    python -m benchmarks.explain_cost [--steps 300] [--start 0.9] [SCENARIO ...]

Each scenario is built and stepped to ``--start`` seconds three times; from that state the same
``--steps`` steps are run through :func:`hqp_tpm.app.runner.run` (one BLAS thread): with no probe (what every run
and every benchmark does by default: the account is never computed), with the account only
(``Explainer(causes=False)``) and with the causes (``Explainer()``, the ``--explain`` default). The
numbers are mean wall-clock milliseconds per step, recording included.
"""

from __future__ import annotations

import argparse
import json
import time

DEFAULT = ("romeo_sns_tpm", "romeo_sns", "romeo_qp", "planar5_exact")


def measure(name: str, steps: int, start: float) -> dict:
    from threadpoolctl import threadpool_limits

    from hqp_tpm.app import build, runner, scenario
    from hqp_tpm.app.explain import Explainer

    sc = scenario.load(name)
    out = {"scenario": name, "start_s": start, "steps": steps}
    with threadpool_limits(limits=1):
        for label, causes in (("off", None), ("account", False), ("causes", True)):
            _, c, _, _ = build.build(sc)          # the same state each time: built and stepped anew
            for _ in range(int(round(start / sc.period))):
                c.step()
            out["solver"] = c.solver
            probes = [] if causes is None else [Explainer(c, causes=causes).probe]
            t0 = time.perf_counter()
            rec, _ = runner.run(c, steps, probes=probes)
            out[f"{label}_ms_per_step"] = round(1e3 * (time.perf_counter() - t0) / steps, 3)
            if causes:
                frac = rec.arrays()["explain_fraction"]
                out["steps_degraded"] = int((frac < 1 - 1e-6).any(axis=1).sum())
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenarios", nargs="*", default=list(DEFAULT))
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--start", type=float, default=0.9)
    args = p.parse_args(argv)
    for name in args.scenarios:
        print(json.dumps(measure(name, args.steps, args.start)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
