"""The first run on a machine (issue 29 item 3): compiling kernels is said once and kept out of the step times.

The cold compile itself (a subprocess with an empty cache) is in ``tests/test_jit.py``
(``test_a_notice_while_kernels_compile_once_and_none_from_the_cache``); here the runner's accounting: a step during
which kernels are made (compiled, or loaded from the cache) adds its compile time to ``compile_s``, not to
``wall_time_s``, ``mean_step_us`` or the progress bar's rate, and the notice gets a line of its own beside the bar.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from hqp_tpm import Controller, Gains, Posture, Robot, Stack, _jit
from hqp_tpm.app import runner

COMPILE_S = 0.4  # the time the first step "compiles" for


@pytest.fixture
def compiling_controller(monkeypatch):
    """A controller whose first step spends :data:`COMPILE_S` in a (simulated) numba compile: the process's compile
    clock advances by that much and the compile notice is written, as the numba listener of hqp_tpm._jit does."""
    robot = Robot.load("iiwa7")
    Controller(robot, Stack.of(Posture(robot, np.zeros(robot.nv), Gains(1.0))), dt=1e-3).step()  # real kernels made
    ctrl = Controller(robot, Stack.of(Posture(robot, np.zeros(robot.nv), Gains(1.0))), dt=1e-3)
    clock = {"s": 0.0}
    real = _jit.compile_seconds  # (kernels a cold cache really compiles count too)
    monkeypatch.setattr(_jit, "compile_seconds", lambda: clock["s"] + real())
    step = ctrl.step

    def first_step_compiles(record=False):
        if ctrl.steps == 0:
            _jit.notice(_jit.COMPILING)
            time.sleep(COMPILE_S)
            clock["s"] += COMPILE_S
        return step(record)

    ctrl.step = first_step_compiles
    return ctrl


@pytest.mark.parametrize("progress", [False, True])
def test_compile_time_is_not_in_the_step_times(compiling_controller, progress, capsys):
    steps = 5
    capsys.readouterr()
    t0 = time.perf_counter()
    rec, timing = runner.run(compiling_controller, steps, progress=progress)
    elapsed = time.perf_counter() - t0
    rec.discard()
    assert timing["steps"] == steps and timing["compile_s"] >= COMPILE_S - 1e-9
    # before: the compile landed in both (mean_step_us >= COMPILE_S / steps = 80,000 µs)
    assert timing["wall_time_s"] <= elapsed - COMPILE_S
    assert timing["mean_step_us"] * steps * 1e-6 <= elapsed - COMPILE_S
    lines = [line.split("\r")[-1].strip() for line in capsys.readouterr().err.split("\n")]
    assert lines.count(f"hqp_tpm: {_jit.COMPILING}") == 1  # a line of its own (beside the bar when there is one)


def test_the_progress_bar_rate_leaves_the_compile_out(compiling_controller, monkeypatch):
    """The bar's elapsed time (its rate and ETA) leaves the compile out: ``1/18850 [00:24<129:33:38]`` before."""
    from tqdm import tqdm

    seen = []
    close = tqdm.close

    def record(bar):
        seen.append(bar.format_dict["elapsed"])
        close(bar)

    monkeypatch.setattr(tqdm, "close", record)
    rec, timing = runner.run(compiling_controller, 5, progress=True)
    rec.discard()
    assert seen and seen[0] < COMPILE_S / 2, seen


def test_the_application_layer_is_not_a_kernel_file():
    """The runner reads the compile clock of :mod:`hqp_tpm._jit`; that import does not make the application layer
    part of the kernel cache's key (an edit of the runner or the results would start a fresh, cold cache)."""
    files = [f.relative_to(_jit.PACKAGE).parts for f in _jit.kernel_files()]
    assert ("_jit.py",) in files and ("robot", "_compiled.py") in files
    assert not [f for f in files if f[0] == "app"], files
