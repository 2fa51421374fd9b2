"""Checks on a folder results will be written to, done before any work starts."""

import os
import tempfile
from pathlib import Path

from .config import ConfigError


def check_output_dir(path, option="--out"):
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


def remove_stale(folder, patterns):
    """Delete the files of `folder` matching any glob pattern of `patterns` (what an earlier
    result left there that the one being written would not replace)."""
    for pattern in patterns:
        for stale in Path(folder).glob(pattern):
            stale.unlink()
