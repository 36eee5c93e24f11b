"""Every notebook in notebooks/ runs top to bottom and shows its plots (shortened runs via HQP_TPM_NOTEBOOK_STEPS)."""

import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def plotting_cell(cell) -> bool:
    """A code cell that shows a matplotlib figure."""
    return cell.cell_type == "code" and "plt.show()" in cell.source


def test_notebooks_are_stored_without_outputs():
    assert NOTEBOOKS
    for path in NOTEBOOKS:
        nb = nbformat.read(path, as_version=4)
        for cell in nb.cells:
            if cell.cell_type == "code":
                assert not cell.outputs and cell.execution_count is None, (
                    f"{path.name}: outputs not stripped (python notebooks/strip_outputs.py)")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs_and_shows_every_plot(path, monkeypatch):
    monkeypatch.setenv("HQP_TPM_NOTEBOOK_STEPS", os.environ.get("HQP_TPM_NOTEBOOK_STEPS", "1500"))
    # the kernel's own default (inline) backend, as in Jupyter: an Agg backend here would hide lost plots
    monkeypatch.delenv("MPLBACKEND", raising=False)
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors
    for i, cell in enumerate(nb.cells):
        if plotting_cell(cell):
            images = [o for o in cell.outputs if "image/png" in o.get("data", {})]
            assert images, f"{path.name}, cell {i}: the plot was not shown (no image/png output)"
