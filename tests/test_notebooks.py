"""The analysis notebooks execute top to bottom (so they never rot) and are stored clean."""

import os
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def test_the_notebooks_exist():
    assert [p.name for p in NOTEBOOKS] == [
        "01_walkthrough.ipynb",
        "02_estimator_analysis.ipynb",
        "03_write_your_own_ekf.ipynb",
        "04_workbench.ipynb",
        "05_flight_log_replay.ipynb",
    ]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_is_stored_without_outputs(path):
    notebook = nbformat.read(path, as_version=4)
    nbformat.validate(notebook)
    for cell in notebook.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None, cell.source[:60]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_every_cell_that_flies_a_campaign_shows_its_progress(path):
    for cell in nbformat.read(path, as_version=4).cells:
        if cell.cell_type == "code" and any(word in cell.source for word in ("run_campaign(", '"tune"')):
            assert "progress=False" not in cell.source and '"--quiet"' not in cell.source, cell.source[:80]


@pytest.mark.notebook
@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_executes(path, tmp_path, monkeypatch):
    # The kernel is this interpreter (jupyter_client maps the "python3" spec to sys.executable)
    # and finds the package even when it is not installed; it runs in tmp_path (as in the
    # notebooks folder of a checkout) and writes its files into a folder of its own.
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    monkeypatch.setenv("QUAD_DRAKE_QUICK", "1")  # a notebook's campaigns and searches at their smallest
    notebook = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()  # raises CellExecutionError on any failing cell
    assert not list(tmp_path.iterdir())  # nothing written where it runs: into a folder it names
    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    assert any("image/png" in o.get("data", {}) for o in outputs)  # the plots were drawn
