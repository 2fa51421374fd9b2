"""The analysis notebooks execute top to bottom (so they never rot) and are stored clean.

An execution is shared with the manual's build (docs/_ext/executed_notebooks.py): `make docs`
executes each notebook in its quick mode and keeps it, and this test reads that execution when it
ran exactly this notebook, package, scenarios/ and interpreter; anything else executes it here."""

import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
sys.path.insert(0, str(ROOT / "docs" / "_ext"))
import executed_notebooks  # noqa: E402


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
def test_notebook_executes(path):
    # Executed in its quick mode by this interpreter's kernel in an empty folder (as in the
    # notebooks folder of a checkout), or that execution as kept for exactly this code.
    notebook = executed_notebooks.executed(path)  # raises CellExecutionError on any failing cell
    # Nothing written where it ran: it writes into a folder it names.
    assert notebook.metadata[executed_notebooks.METADATA]["files_left"] == []
    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    assert any("image/png" in o.get("data", {}) for o in outputs)  # the plots were drawn


def _tree(root):
    """A checkout-shaped folder: a notebook, a package module (with a compiled cache beside it)
    and a scenario."""
    (root / "quad_drake" / "__pycache__").mkdir(parents=True)
    (root / "scenarios").mkdir()
    (root / "quad_drake" / "model.py").write_text("GAIN = 1\n")
    (root / "quad_drake" / "__pycache__" / "model.cpython-311.pyc").write_bytes(b"1")
    (root / "scenarios" / "01.yaml").write_text("end_time: 1\n")
    notebook = root / "a.ipynb"
    nbformat.write(nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("print(1)")]), notebook)
    return notebook


def test_an_execution_is_kept_only_for_the_code_it_ran(tmp_path):
    notebook = _tree(tmp_path)
    key = executed_notebooks.execution_key(notebook, tmp_path, interpreter="python A")
    assert executed_notebooks.execution_key(notebook, tmp_path, interpreter="python A") == key
    (tmp_path / "quad_drake" / "__pycache__" / "model.cpython-311.pyc").write_bytes(b"2")
    assert executed_notebooks.execution_key(notebook, tmp_path, interpreter="python A") == key
    assert executed_notebooks.execution_key(notebook, tmp_path, interpreter="python B") != key
    for changed in (tmp_path / "quad_drake" / "model.py", tmp_path / "scenarios" / "01.yaml", notebook):
        original = changed.read_bytes()
        changed.write_bytes(original + b"\n")
        assert executed_notebooks.execution_key(notebook, tmp_path, interpreter="python A") != key, changed
        changed.write_bytes(original)
    (tmp_path / "quad_drake" / "new.py").write_text("")
    assert executed_notebooks.execution_key(notebook, tmp_path, interpreter="python A") != key


def test_a_notebook_is_executed_once_per_key(tmp_path, monkeypatch):
    notebook = _tree(tmp_path)
    runs = []

    def execute(path):
        runs.append(path)
        node = nbformat.read(path, as_version=4)
        node.metadata[executed_notebooks.METADATA] = {"seconds": 0.0, "files_left": []}
        return node

    monkeypatch.setattr(executed_notebooks, "execute", execute)
    monkeypatch.setattr(executed_notebooks, "ROOT", tmp_path)
    monkeypatch.setattr(executed_notebooks, "interpreter_key", lambda: "python A")
    store = tmp_path / "store"
    first = executed_notebooks.executed(notebook, store)
    assert executed_notebooks.executed(notebook, store) == first and len(runs) == 1
    (tmp_path / "quad_drake" / "model.py").write_text("GAIN = 2\n")
    executed_notebooks.executed(notebook, store)
    assert len(runs) == 2 and len(list(store.glob("*.ipynb"))) == 1


def test_the_test_and_docs_tools_are_not_part_of_the_key():
    # CI's `make docs` and then `make test` (which installs pytest, ruff, dask...) share executions.
    names = executed_notebooks.runtime_distributions()
    assert {"drake", "numpy", "numba", "matplotlib", "ipykernel"} <= set(names)
    assert not {"pytest", "ruff", "sphinx", "myst-nb", "distributed"} & set(names)
