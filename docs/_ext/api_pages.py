"""A Sphinx extension: sphinx-autoapi's page sources keep their time stamps while they keep their text.

sphinx-autoapi writes the source of every API page under ``docs/api/`` (``autoapi_keep_files``)
whenever it reads the package again, that is whenever a module's text changed; Sphinx then sees
every API page as changed (its source is newer than its last reading) and reads all 135 again.
Around autoapi's run (both on ``builder-inited``), this extension gives each source that autoapi
wrote with the same text back the time stamp it had, so Sphinx reads again only the pages whose
text changed, and removes the sources autoapi no longer writes (a module that was deleted or
renamed), which would otherwise stay pages of the manual.
"""

import os
from pathlib import Path

UNWRITTEN_NS = 0  # the time stamp every kept source gets before autoapi runs: "not written yet"


def _sources(app):
    root = Path(app.srcdir, app.config.autoapi_root)
    return [path for path in root.rglob("*") if path.is_file()] if root.is_dir() else []


def _before_autoapi(app):
    app.api_sources_kept = {}
    for path in _sources(app):
        app.api_sources_kept[path] = (path.read_bytes(), path.stat().st_mtime_ns)
        os.utime(path, ns=(UNWRITTEN_NS, UNWRITTEN_NS))


def _after_autoapi(app):
    kept = app.api_sources_kept
    written = {path for path in _sources(app) if path.stat().st_mtime_ns != UNWRITTEN_NS}
    for path, (text, mtime_ns) in kept.items():
        if not written:  # the package's files are as autoapi last read them: it wrote nothing
            os.utime(path, ns=(mtime_ns, mtime_ns))
        elif path not in written:
            path.unlink()
        elif path.read_bytes() == text:
            os.utime(path, ns=(mtime_ns, mtime_ns))


def setup(app):
    app.connect("builder-inited", _before_autoapi, priority=400)  # autoapi's run_autoapi: 500
    app.connect("builder-inited", _after_autoapi, priority=600)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
