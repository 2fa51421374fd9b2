"""numba's ``njit`` with its on-disk cache wherever a cache directory can be written.

numba caches a compiled function next to its module (``__pycache__``), or in the user's cache
directory (``~/.cache/numba``) when the package is read-only, or in ``$NUMBA_CACHE_DIR`` when
that is set. Where none of them can be written (a read-only install run by a user whose home
is read-only too), ``numba.njit(cache=True)`` raises at decoration, that is, at the import of
the module that holds the kernel. :func:`njit_cached` then caches under the temporary directory
(:func:`fallback_cache_dir`), and where even that fails it compiles without a cache (the
kernels compile again in every process, about 15 s) and warns once.

numba's cache files are pickles, and the temporary directory is shared: the fallback directory
is used only when it is this user's own and no one else can write in it
(:func:`private_directory`), so another user cannot plant code in it.

A kernel compiles the first time it is called (per argument types), so each estimator, sensor,
fleet or campaign flown first after an install or an upgrade compiles the kernels it is the
first to use; ``quad-drake warmup`` (``quad_drake.warmup``) compiles them all at once. A process
that compiles says so once on a terminal's stderr (:class:`CompileNotice`), so that the pause
of about 15 s is not taken for a hang.
"""

import getpass
import os
import stat
import sys
import tempfile
import time
import types
import warnings
from collections.abc import Callable

import numba
from numba.core import event

_warned = False
COMPILE_NOTICE = (
    "quad-drake: compiling the numba kernels this flight is the first to use into the on-disk cache "
    "(up to about 15 s; `quad-drake warmup` compiles every kernel once) ..."
)


class CompileNotice(event.Listener):
    """numba's ``numba:compile`` event (a kernel not found in the cache is being compiled): the
    first one of the process for a quad_drake kernel (not another library's or the user's own)
    prints :data:`COMPILE_NOTICE` on stderr when stderr is a terminal (a log or a test's
    capture gets nothing)."""

    def __init__(self):
        self.shown = False
        self.seconds = 0.0  # s, spent compiling so far in this process (outermost compilations)
        self._depth, self._start = 0, 0.0

    def on_start(self, compile_event) -> None:
        self._depth += 1
        if self._depth == 1:
            self._start = time.perf_counter()
        if self.shown or sys.stderr is None or not sys.stderr.isatty():
            return
        module = getattr(compile_event.data["dispatcher"].py_func, "__module__", None) or ""
        if module.partition(".")[0] == __name__.partition(".")[0]:
            self.shown = True
            print(COMPILE_NOTICE, file=sys.stderr, flush=True)

    def on_end(self, compile_event) -> None:
        self._depth -= 1
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._start


def compile_seconds() -> float:
    """s spent by numba compiling (any kernel, not loading from the cache) in this process so
    far: what a flight subtracts from its wall time (``simulation.run``)."""
    return compile_notice.seconds


compile_notice = CompileNotice()
event.register("numba:compile", compile_notice)


def fallback_cache_dir() -> str:
    """The cache directory used where numba has none: ``<tmp>/quad_drake-numba-<user>``, one per
    user: the numeric user id where the platform has one (a container may run an id that has no
    name), else the login name; ``tempfile.gettempdir()`` honours ``$TMPDIR``."""
    user = os.getuid() if hasattr(os, "getuid") else getpass.getuser()
    return os.path.join(tempfile.gettempdir(), f"quad_drake-numba-{user}")


def private_directory(path) -> bool:
    """Make `path` a directory (mode 0o700) unless it exists; True when it is then a real
    directory (not a link) owned by this user that neither its group nor others can write."""
    try:
        os.makedirs(path, mode=0o700, exist_ok=True)
        status = os.lstat(path)
    except OSError:
        return False
    owned = not hasattr(os, "getuid") or status.st_uid == os.getuid()
    return stat.S_ISDIR(status.st_mode) and owned and not status.st_mode & (stat.S_IWGRP | stat.S_IWOTH)


KERNEL_SOURCES: set[str] = set()
"""The source files of every function :func:`njit_cached` has compiled in this process: the files
numba keys its cache by (it compiles a kernel again when its file changes)."""


def cache_stamp_dir() -> str | None:
    """Where a note about this process's kernel cache may be kept beside numba's own files:
    ``$NUMBA_CACHE_DIR`` (or the fallback) when numba caches there, else the package's
    ``kernels/__pycache__`` when it can be written; None where neither is known."""
    if numba.config.CACHE_DIR:
        return numba.config.CACHE_DIR
    folder = os.path.join(os.path.dirname(os.path.abspath(__file__)), "__pycache__")
    return folder if os.path.isdir(folder) and os.access(folder, os.W_OK) else None


def uncached() -> bool:
    """True when a kernel of this process could not be cached (:func:`njit_cached` warned)."""
    return _warned


def njit_cached(function) -> Callable:
    """``numba.njit(cache=True)(function)``, cached under :func:`fallback_cache_dir` where numba
    can write none of its own cache directories, and uncached (one warning per process) where
    that cannot be written either or is not private (:func:`private_directory`). numba decides
    whether a cache can be written (it raises RuntimeError at decoration when it cannot);
    compiling stays lazy (on first call)."""
    global _warned
    KERNEL_SOURCES.add(os.path.abspath(function.__code__.co_filename))
    try:
        return numba.njit(cache=True)(function)
    except RuntimeError:
        pass
    if numba.config.CACHE_DIR:  # the user's NUMBA_CACHE_DIR (or the fallback, set before) failed
        tried = f"NUMBA_CACHE_DIR={numba.config.CACHE_DIR} is not usable"
    else:
        fallback = fallback_cache_dir()
        if private_directory(fallback):
            numba.config.CACHE_DIR = fallback  # for this kernel and the next ones
            try:
                return numba.njit(cache=True)(function)
            except RuntimeError:
                pass
        tried = (
            f"the package's __pycache__, the user cache and {fallback} are not usable (the last "
            "must be a directory of this user's that no one else can write)"
        )
    if not _warned:
        _warned = True
        warnings.warn(
            f"quad-drake: numba cannot cache its compiled kernels: {tried}. They compile again in "
            "every process (about 15 s); set NUMBA_CACHE_DIR to a directory this user can write.",
            RuntimeWarning,
            stacklevel=2,
        )
    return numba.njit(function)


def compiled(function, **callees) -> Callable:
    """The scalar `function`'s own code compiled by numba (nopython, cached on disk), with the
    module globals it calls replaced by their compiled forms `callees`."""
    namespace = dict(function.__globals__, **callees)
    return njit_cached(types.FunctionType(function.__code__, namespace, function.__name__))
