"""A run's result does not depend on what the process did before it (issue 12, point 9).

ProxQP's dense backend (AVX2 build) returned last-bit different solutions for bit-equal inputs depending on
where the heap had placed its work buffers; romeo_qp then differed between two fresh processes from step 5
on, and after step ~1,040 by up to 8 rad/s. The cascade now calls ProxQP's sparse backend (see
``SPARSE_CALL`` in :mod:`hqp_tpm.solvers.cascaded_qp`); these tests compare bit for bit.
"""

import subprocess
import sys

import numpy as np
import pytest

#: Runs scenarios one after the other in a fresh process through the Python API (no thread limit) and
#: saves their float columns: ``python -c SCENARIOS out.npz name:steps ...``. With the lean step, as the CLI: the
#: lean rows' rotation error (robot._compiled.log3) rounds within a few ulps of pinocchio's, which the rate-bounded
#: romeo_qp (its sole error no longer ~0) shows from step 181 (4e-13 rad/s) when compared with ctrl.step().
SCENARIOS = """
import sys
import numpy as np
from hqp_tpm.app import build, runner, scenario
arrays = {}
for item in sys.argv[2:]:
    name, steps = item.split(":")
    ctx = build.build_run(scenario.load(name))
    rec, _ = runner.run(ctx.controller, int(steps))  # (the CLI's path: the compiled step)
    arrays.update({f"{name}/{k}": v for k, v in rec.load().items() if v.dtype.kind == "f"})
np.savez(sys.argv[1], **arrays)
"""

#: Solves random boxed stacks with the cascaded QP (proxqp) and prints a hash of every solution's bits.
STACKS = """
import hashlib
import numpy as np
from hqp_tpm.solvers import cascaded_qp
from hqp_tpm.testing.stacks import box_for, random_stack
rng = np.random.default_rng(7)
digest = hashlib.sha256()
for _ in range(40):
    n = int(rng.integers(6, 14))
    levels = random_stack(rng, n, [int(rng.integers(1, 4)) for _ in range(3)])
    x_free = cascaded_qp(levels, "proxqp")
    lo, up = box_for(rng, x_free, n)
    digest.update(cascaded_qp(levels, "proxqp", lower=lo, upper=up).tobytes())
print(digest.hexdigest())
"""

QP_STEPS, SNS_STEPS = 300, 150


def _fresh(script: str, *args: str) -> str:
    out = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


def _differences(a: dict, b: dict, prefix: str) -> dict:
    """Per column of ``prefix``: the first step where ``a`` and ``b`` differ and by how much (empty: bit-equal)."""
    diff = {}
    for key in (k for k in a if k.startswith(prefix)):
        x, y = a[key], b[key]
        assert x.shape == y.shape, key
        rows = np.flatnonzero((x != y).reshape(len(x), -1).any(axis=1))
        if rows.size:
            diff[key] = (int(rows[0]), float(np.abs(x - y).max()))
    return diff


@pytest.mark.slow
def test_cascaded_qp_same_bits_in_fresh_processes():
    """40 random boxed stacks solved in four fresh processes: the same bits every time."""
    digests = {_fresh(STACKS).strip() for _ in range(4)}
    assert len(digests) == 1, digests


@pytest.fixture(scope="module")
def both_orders(tmp_path_factory):
    """romeo_sns_tpm then romeo_qp in one fresh process, romeo_qp then romeo_sns_tpm in another."""
    folder = tmp_path_factory.mktemp("orders")
    runs = {}
    for label, order in (("sns_first", ("romeo_sns_tpm", "romeo_qp")), ("qp_first", ("romeo_qp", "romeo_sns_tpm"))):
        steps = {"romeo_qp": QP_STEPS, "romeo_sns_tpm": SNS_STEPS}
        _fresh(SCENARIOS, str(folder / f"{label}.npz"), *(f"{name}:{steps[name]}" for name in order))
        with np.load(folder / f"{label}.npz") as data:
            runs[label] = dict(data)
    return runs


@pytest.mark.slow
@pytest.mark.parametrize("name", ["romeo_qp", "romeo_sns_tpm"])
def test_scenarios_in_both_orders_are_bit_equal(both_orders, name):
    """Each scenario gives the same bits whichever ran first in its process (and in two fresh processes)."""
    assert _differences(both_orders["sns_first"], both_orders["qp_first"], f"{name}/") == {}


@pytest.mark.slow
def test_romeo_qp_here_equals_fresh_processes(both_orders, tmp_path):
    """romeo_qp through the CLI path in this (long-lived) test process equals the fresh processes' runs."""
    from hqp_tpm.app.cli import run_scenario

    run_scenario("romeo_qp", tmp_path / "qp", steps=QP_STEPS, progress=False, figures=False, replay=False)
    with np.load(tmp_path / "qp" / "trajectory.npz") as data:
        here = {f"romeo_qp/{k}": data[k] for k in ("t", "q", "dq", "ddq")}
    fresh = {k: both_orders["qp_first"][k] for k in here}
    assert _differences(here, fresh, "romeo_qp/") == {}


#: romeo_qp step 1,277, level 4 as handed to the backend: one variable, 18 rows (a row and its negation
#: each), feasible on [-0.1111, 0.0973]. ProxQP's sparse backend called it primally infeasible with every
#: setting, its infeasibility tolerance at 1e-12 included.
STEP_1277_ROWS = np.array([-0.0018582212914387446, -0.0005823647454605409, -0.0020316028889268583,
                           -0.0010507653104449386, 0.002708404714628721, 0.0016306457706601642,
                           -0.002337726539841158, 14.325454215366548, -35.49090127299444])
STEP_1277_H = np.array([2.365353540845648, 2.3492290924602814, 2.376906011599466, 2.4686163702585935,
                        1.9610566000124403, 2.030497787855671, 0.6884558813334665, 2.808704790383639,
                        3.9456893410810854, 1.8146464591543516, 1.830770907539718, 1.803093988400534,
                        1.7113836297414062, 2.23894339998756, 2.1695022121443293, 2.3115441186665335,
                        1.5912952096163615, 3.454310658918915])


@pytest.mark.parametrize("solver", ["proxqp", "daqp", "quadprog"])
def test_romeo_qp_step_1277_level_is_solved(solver):
    """The level on which ProxQP gave up at step 1,277 of romeo_qp: solved, at the end of its interval."""
    import qpsolvers

    from hqp_tpm.solvers.cascaded_qp import _attempts, _Cascade
    if solver not in qpsolvers.available_solvers:
        pytest.skip(f"{solver} not installed")
    G = np.concatenate([STEP_1277_ROWS, -STEP_1277_ROWS])[:, None]
    ends = STEP_1277_H / G[:, 0]
    interval = (ends[G[:, 0] < 0].max(), ends[G[:, 0] > 0].min())
    P, q = np.array([[4.66205685955924]]), np.array([14.423486275168113])
    assert interval[0] < 0.0 < interval[1] and -q[0] / P[0, 0] < interval[0]  # feasible; optimum at the lower end
    c = _Cascade(np.zeros(1), np.eye(1), np.zeros((0, 1)), np.zeros(0), solver, _attempts(solver, {}))
    v, mult = c.backend(P, q, G, STEP_1277_H, np.zeros((0, 1)), np.zeros(0), "level 4")
    assert abs(v[0] - interval[0]) <= 1e-9
    assert (G @ v <= STEP_1277_H + 1e-10).all() and (mult >= -1e-9).all()


def test_csc_is_scipys():
    """The CSC matrices handed to ProxQP's sparse backend are SciPy's conversion, entry for entry."""
    from scipy import sparse

    from hqp_tpm.solvers.cascaded_qp import _csc

    rng = np.random.default_rng(3)
    for shape in [(1, 1), (5, 3), (3, 7), (42, 16)]:
        M = rng.standard_normal(shape) * (rng.random(shape) < 0.4)
        M[:, 0] = 0.0  # an empty column
        mine, scipys = _csc(M), sparse.csc_matrix(M)
        for attr in ("data", "indices", "indptr"):
            assert np.array_equal(getattr(mine, attr), getattr(scipys, attr)), (shape, attr)
        assert mine.shape == scipys.shape and np.array_equal(mine.toarray(), M)
