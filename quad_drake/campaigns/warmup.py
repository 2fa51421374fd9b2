"""Compile every numba kernel into the on-disk cache at once (``quad-drake warmup``).

numba compiles a kernel the first time it is called with a given set of argument types
(``kernels/jit.py``), so without a warm-up the first flight of each new estimator, sensor, fleet or
campaign pays for the kernels it is the first to call (11-14 s each time). :func:`warm_up` flies
every bundled scenario for :data:`WARMUP_TIME` s as a one-run campaign and as a fleet campaign
of two runs, in this process: the bundled scenarios use every estimator, sensor model and fault
path, so every kernel is called with the argument types a later run passes it (per vehicle and
batched), the campaigns' NEES and bound kernels included: a later process flies any of them,
longer, with other seeds or fleet sizes, without compiling (tested).

A warm-up leaves a stamp beside numba's cache (:data:`STAMP_NAME`, one per Python: numba's and
Python's versions, the machine and the SHA-256 of every source file a kernel is compiled from,
the files numba keys its cache by); a later warm-up whose stamp still matches flies nothing,
since every kernel is in the cache already (``--force`` flies anyway).
"""

import hashlib
import json
import platform
import sys
import time
from pathlib import Path

import numba

from ..kernels import jit
from ..running import catalog

WARMUP_TIME = 0.3
"""s flown per scenario: past the first sample of every sensor (GPS at 0.1 s, the barometer and
the magnetometer sooner) and so through every update of every estimator."""
VARIANTS = (("24_mag3_disturbance", ("vehicles.0.estimator={kind: ekf7}",)),)
"""(bundled scenario, overrides) flown besides the bundled scenarios: the configurations whose
kernels no bundled scenario calls (the EKF7's heading from a 3-axis magnetometer)."""


STAMP_NAME = f"quad_drake-warmup.{sys.implementation.cache_tag}.json"
"""The warm-up's stamp, in :func:`quad_drake.kernels.jit.cache_stamp_dir`: one per Python (numba
caches per Python too), so two Pythons on one checkout keep each its own."""


def cache_stamp(sources) -> dict:
    """What the kernels in numba's cache depend on: the package's folder, numba's and Python's
    versions, the machine, and {path: SHA-256} of each of the `sources` (kernel source files);
    OSError if one is unreadable."""
    return {
        "package": str(Path(__file__).resolve().parents[1]),
        "numba": numba.__version__,
        "python": sys.version,
        "machine": platform.machine(),
        "sources": {path: hashlib.sha256(Path(path).read_bytes()).hexdigest() for path in sorted(sources)},
    }


def stamp_is_current(path) -> bool:
    """True when the stamp at `path` names kernel sources that are all unchanged, on this numba,
    Python and machine: every kernel the warm-up compiled is then still in the cache."""
    try:
        saved = json.loads(Path(path).read_text())
        return bool(saved["sources"]) and saved == cache_stamp(saved["sources"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return False


def _stamp_path():
    folder = jit.cache_stamp_dir()
    return None if folder is None else Path(folder) / STAMP_NAME


def warm_up(progress=None, force=False) -> tuple[int, float]:
    """Fly every bundled scenario and the VARIANTS for WARMUP_TIME s, each as a one-run campaign
    and as a fleet campaign of two runs, in this process; `progress(text)` is called before each.
    Nothing is flown when an earlier warm-up's stamp is current (:func:`stamp_is_current`) unless
    `force`. (scenarios flown, s spent compiling: 0 when every kernel was already in the cache)."""
    from .campaign import run_campaign

    stamp = _stamp_path()
    if not force and stamp is not None and stamp_is_current(stamp):
        return 0, 0.0
    compiled = jit.compile_seconds()
    flights = [(name, ()) for name in catalog.bundled_scenarios()] + list(VARIANTS)
    for name, overrides in flights:
        if progress is not None:
            progress(" ".join((name, *overrides)))
        scenario = catalog.load(name, None, [*overrides, f"end_time={WARMUP_TIME}"])
        run_campaign(scenario, 1, progress=False)
        run_campaign(scenario, 2, progress=False, fleet_batch=2)
    stamp = _stamp_path()  # numba may have moved to the fallback cache while compiling
    if stamp is not None and not jit.uncached():
        try:
            stamp.write_text(json.dumps(cache_stamp(jit.KERNEL_SOURCES), indent=1))
        except OSError:
            pass  # no stamp: the next warm-up flies again
    return len(flights), jit.compile_seconds() - compiled


def warm_up_command(stream=sys.stdout, force=False) -> int:
    """``quad-drake warmup [--force]``: warm up, then print what it compiled."""
    start = time.perf_counter()
    flown, seconds = warm_up(lambda name: print(f"warming up: {name}", file=stream, flush=True), force)
    if flown == 0:
        done = (
            "every kernel was compiled by an earlier warm-up of these kernel sources (numba "
            f"{numba.__version__}): nothing to fly (`quad-drake warmup --force` flies anyway)"
        )
    else:
        took = time.perf_counter() - start
        done = f"flew {flown} scenarios for {WARMUP_TIME:g} s each in {took:.1f} s; " + (
            f"numba compiled kernels for {seconds:.1f} s into its cache"
            if seconds > 0
            else "every kernel was already in numba's cache"
        )
    print(done, file=stream)
    print("every kernel a flight uses is in the cache: runs, campaigns and fleets start at once", file=stream)
    return 0
