"""The notebooks of ``notebooks/``, executed once per version of what they run, for the manual and
the tests alike.

``make docs`` renders each notebook with its outputs (the gallery: myst-nb with its own execution
off) and ``tests/test_notebooks.py`` checks that each one runs cleanly; both take the executed copy
from :func:`executed`. A notebook is executed in its quick mode (``QUAD_DRAKE_QUICK=1``: every
campaign and search at its smallest) by this interpreter's Jupyter kernel, in a new empty folder
(which must stay empty: a notebook writes into a folder of its own), and the executed copy is kept
under ``docs/_build/notebooks/``. It is reused only while its key is unchanged: the notebook, every
file of the package and of ``scenarios/``, the interpreter (path and version) and the version of
every distribution the package and the kernel run on (not the test and docs tools). Any change
runs the notebook again, so neither the manual nor the tests ever show the result of other code;
CI's ``make docs`` executes the notebooks once and its ``make test`` on the same Python reads
them. Delete ``docs/_build/notebooks/`` to force a new run.

Used by ``docs/conf.py`` (as a Sphinx extension, on ``builder-inited``) and by the tests.
"""

import contextlib
import fcntl
import hashlib
import importlib.metadata
import os
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import nbclient
import nbformat
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOKS = ROOT / "notebooks"
STORE = ROOT / "docs" / "_build" / "notebooks"
GALLERY = ROOT / "docs" / "gallery"
SOURCES = ("quad_drake", "scenarios")  # what a notebook imports and flies, besides itself
QUICK_ENVIRONMENT = {"QUAD_DRAKE_QUICK": "1"}
TIMEOUT_S = 900  # per cell
METADATA = "quad_drake_execution"  # the executed copy's notebook metadata: key, seconds, files left


def runtime_distributions():
    """The distributions the package runs on: its dependencies in pyproject.toml (no extras), the
    Jupyter kernel (ipykernel) and everything they require, installed ones only, sorted names.
    (Not the test and docs tools: installing them must not invalidate an execution.)"""
    with open(ROOT / "pyproject.toml", "rb") as file:
        pending = [*tomllib.load(file)["project"]["dependencies"], "ipykernel"]
    names = set()
    while pending:
        requirement = Requirement(pending.pop())
        if requirement.marker is not None and not requirement.marker.evaluate({"extra": ""}):
            continue
        name = canonicalize_name(requirement.name)
        if name in names:
            continue
        try:
            pending += importlib.metadata.requires(name) or []
        except importlib.metadata.PackageNotFoundError:
            continue
        names.add(name)
    return sorted(names)


def interpreter_key():
    """What the kernel runs on: this interpreter's path and version, and the version of each of
    :func:`runtime_distributions` (drake, numpy, numba, ...)."""
    versions = [f"{name}=={importlib.metadata.version(name)}" for name in runtime_distributions()]
    return "\n".join([sys.executable, sys.version, *versions])


def execution_key(notebook, root=None, interpreter=None):
    """SHA-256 (hex) of everything an execution of `notebook` depends on: its bytes, every file
    under the SOURCES of `root` (this checkout unless given; path and bytes, ``__pycache__`` left
    out), the interpreter (:func:`interpreter_key` unless given) and the quick mode's environment."""
    root = Path(root if root is not None else ROOT)
    digest = hashlib.sha256(Path(notebook).read_bytes())
    for folder in SOURCES:
        for path in sorted((root / folder).rglob("*")):
            if path.is_file() and "__pycache__" not in path.parts:
                digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    digest.update((interpreter if interpreter is not None else interpreter_key()).encode())
    digest.update(repr(sorted(QUICK_ENVIRONMENT.items())).encode())
    return digest.hexdigest()


@contextlib.contextmanager
def _environment(values):
    """os.environ updated with `values` inside the block (a kernel inherits it), then restored."""
    saved = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def execute(notebook):
    """`notebook` (a path) executed top to bottom in its quick mode in a new empty folder, by this
    interpreter's kernel, with this checkout first on PYTHONPATH; its metadata[METADATA] holds
    ``seconds`` and ``files_left`` (what it left in that folder, sorted names). Raises
    nbclient's CellExecutionError on a failing cell."""
    node = nbformat.read(notebook, as_version=4)
    python_path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    with (
        tempfile.TemporaryDirectory(prefix="notebook_") as folder,
        _environment(QUICK_ENVIRONMENT | {"PYTHONPATH": python_path}),
    ):
        client = nbclient.NotebookClient(
            node, timeout=TIMEOUT_S, kernel_name="python3", resources={"metadata": {"path": folder}}
        )
        start = time.perf_counter()
        client.execute()
        seconds = time.perf_counter() - start
        left = sorted(p.name for p in Path(folder).iterdir())
    node.metadata[METADATA] = {"seconds": round(seconds, 1), "files_left": left}
    return node


def executed(notebook, store=STORE):
    """`notebook` (a path) executed (see :func:`execute`): the copy kept in `store` when its
    :func:`execution_key` matches, else a new execution, then kept there. One process at a time
    per notebook and interpreter (a file lock), so parallel callers execute it once."""
    notebook = Path(notebook)
    key = execution_key(notebook)
    store = Path(store)
    store.mkdir(parents=True, exist_ok=True)
    interpreter = hashlib.sha256(sys.executable.encode()).hexdigest()[:12]
    kept = store / f"{notebook.stem}.{interpreter}.ipynb"
    with open(store / f"{kept.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if kept.is_file():
            node = nbformat.read(kept, as_version=4)
            if node.metadata.get(METADATA, {}).get("key") == key:
                return node
        node = execute(notebook)
        node.metadata[METADATA]["key"] = key
        partial = kept.with_suffix(".partial")
        nbformat.write(node, partial)
        os.replace(partial, kept)
        return node


def write_gallery(app=None):
    """docs/gallery/: every notebook of notebooks/ executed (:func:`executed`), each file
    rewritten only when it changed (Sphinx then re-reads only that page); stale ones removed."""
    GALLERY.mkdir(parents=True, exist_ok=True)
    names = set()
    for notebook in sorted(NOTEBOOKS.glob("*.ipynb")):
        names.add(notebook.name)
        text = nbformat.writes(executed(notebook))
        page = GALLERY / notebook.name
        if not page.is_file() or page.read_text(encoding="utf-8") != text:
            page.write_text(text, encoding="utf-8")
    for stale in GALLERY.glob("*.ipynb"):
        if stale.name not in names:
            stale.unlink()


def setup(app):
    """The Sphinx extension: the gallery written before Sphinx looks for its pages."""
    app.connect("builder-inited", write_gallery)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
