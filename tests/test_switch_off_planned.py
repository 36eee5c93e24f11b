"""``HQP_TPM_COMPILED=0`` holds for the planned step too (issue 29: the same source runs as plain Python without
numba): a run whose task rows the planned step writes (``lwr_relaxed``) imports no numba and makes no kernel. On
main 82bfea4 and 894a51a it did (the rows' program asked ``hqp_tpm.solvers._compiled._sizes``, which compiled the
kernels whatever the switch)."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CODE = r"""
import sys
from hqp_tpm.app.cli import main
from hqp_tpm.solvers import _compiled
code = main(["run", "lwr_relaxed", "--steps", "3", "--out", sys.argv[1], "--quiet"])
print(code, "numba" in sys.modules, _compiled._READY)
"""


def test_switched_off_run_imports_no_numba(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(HQP_TPM_COMPILED="0", NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", CODE, str(tmp_path / "run")], env=env, capture_output=True,
                         text=True, timeout=600, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-3:] == ["0", "False", "False"], out.stdout + out.stderr[-2000:]
    assert not (tmp_path / "cache").exists()  # nothing compiled, nothing written
