"""Output folders: checks done before any work starts, atomic file writes, a lock for what
concurrent invocations share."""

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ..config.errors import ConfigError


def check_output_dir(path, option="--out") -> Path:
    """Path of a usable output folder: an existing writable folder, or a new one whose parent
    is an existing writable folder (created later by whoever writes). Raises ConfigError (one
    line naming `option`) for a file, a missing parent or a folder that cannot be written.
    Leaves nothing behind."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{option} {path}: exists and is not a folder")
    probe_in = path if path.is_dir() else path.absolute().parent
    if not path.is_dir() and not probe_in.is_dir():
        raise ConfigError(f"{option} {path}: parent folder {probe_in} does not exist")
    try:  # os.access says yes to root even on a read-only mount: write and remove a file
        with tempfile.TemporaryFile(dir=probe_in):
            pass
    except OSError as e:
        raise ConfigError(f"{option} {path}: cannot write in {probe_in} ({os.strerror(e.errno)})") from None
    return path


def remove_stale(folder, patterns) -> None:
    """Delete the files of `folder` matching any glob pattern of `patterns` (what an earlier
    result left there that the one being written would not replace)."""
    for pattern in patterns:
        for stale in Path(folder).glob(pattern):
            stale.unlink()


def is_result_folder(folder) -> bool:
    """True when `folder` holds a run's or a campaign's results (a summary.json that is an
    object with a ``kind``, or a logs.npz): a folder to write results beside, not into."""
    folder = Path(folder)
    if (folder / "logs.npz").is_file():
        return True
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(summary, dict) and "kind" in summary


@contextlib.contextmanager
def atomic_path(path) -> Iterator[Path]:
    """Yield a temporary path beside `path` (same folder, same suffix, a hidden name) to write the
    whole file to; when the block ends without an exception, rename it over `path` (``os.replace``,
    atomic on one file system), else delete it. A full disk, a crash or Ctrl-C while writing so
    leaves the earlier `path` (or none), never a torn file."""
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    temporary = Path(name)
    try:
        yield temporary
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(temporary, 0o666 & ~umask)  # mkstemp's 0600: the mode a plain open() would give
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def write_text_atomic(path, text) -> Path:
    """Write `text` (UTF-8) to `path` through :func:`atomic_path`; returns the path."""
    with atomic_path(path) as temporary:
        temporary.write_text(text, encoding="utf-8")
    return Path(path)


def write_binary_atomic(path, write) -> Path:
    """Call ``write(file)`` on a binary file object whose content then replaces `path` whole
    (:func:`atomic_path`); returns the path. For ``np.savez_compressed``, ``figure.savefig``."""
    with atomic_path(path) as temporary, open(temporary, "wb") as f:
        write(f)
    return Path(path)


LOCK_NAME = ".quad_drake.lock"
"""The lock file in an output folder (:func:`locked`)."""


@contextlib.contextmanager
def locked(folder) -> Iterator[None]:
    """Hold an exclusive advisory lock on output folder `folder` (``fcntl.flock`` of its
    LOCK_NAME file; made with the folder when missing) while choosing and writing what several
    invocations share there (a run folder's name, index.html). Without ``fcntl`` (Windows) it
    does not lock."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # pragma: no cover (not POSIX)
        yield
        return
    with open(folder / LOCK_NAME, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)
