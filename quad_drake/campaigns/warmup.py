"""Compile every numba kernel into the on-disk cache at once (``quad-drake warmup``).

numba compiles a kernel the first time it is called with a given set of argument types
(``kernels/jit.py``), so without a warm-up the first flight of each new estimator, sensor, fleet or
campaign pays for the kernels it is the first to call (11-14 s each time). :func:`warm_up` flies
every bundled scenario for :data:`WARMUP_TIME` s as a one-run campaign and as a fleet campaign
of two runs, in this process: the bundled scenarios use every estimator, sensor model and fault
path, so every kernel is called with the argument types a later run passes it (per vehicle and
batched), the campaigns' NEES and bound kernels included: a later process flies any of them,
longer, with other seeds or fleet sizes, without compiling (tested).
"""

import sys
import time

from ..kernels import jit
from ..running import catalog

WARMUP_TIME = 0.3
"""s flown per scenario: past the first sample of every sensor (GPS at 0.1 s, the barometer and
the magnetometer sooner) and so through every update of every estimator."""
VARIANTS = (("24_mag3_disturbance", ("vehicles.0.estimator={kind: ekf7}",)),)
"""(bundled scenario, overrides) flown besides the bundled scenarios: the configurations whose
kernels no bundled scenario calls (the EKF7's heading from a 3-axis magnetometer)."""


def warm_up(progress=None) -> tuple[int, float]:
    """Fly every bundled scenario and the VARIANTS for WARMUP_TIME s, each as a one-run campaign
    and as a fleet campaign of two runs, in this process; `progress(text)` is called before each.
    (scenarios flown, s spent compiling: 0 when every kernel was already in the cache)."""
    from .campaign import run_campaign

    compiled = jit.compile_seconds()
    flights = [(name, ()) for name in catalog.bundled_scenarios()] + list(VARIANTS)
    for name, overrides in flights:
        if progress is not None:
            progress(" ".join((name, *overrides)))
        scenario = catalog.load(name, None, [*overrides, f"end_time={WARMUP_TIME}"])
        run_campaign(scenario, 1, progress=False)
        run_campaign(scenario, 2, progress=False, fleet_batch=2)
    return len(flights), jit.compile_seconds() - compiled


def warm_up_command(stream=sys.stdout) -> int:
    """``quad-drake warmup``: warm up, then print what it compiled."""
    start = time.perf_counter()
    flown, seconds = warm_up(lambda name: print(f"warming up: {name}", file=stream, flush=True))
    print(
        f"flew {flown} scenarios for {WARMUP_TIME:g} s each in {time.perf_counter() - start:.1f} s; "
        + (
            f"numba compiled kernels for {seconds:.1f} s into its cache"
            if seconds > 0
            else "every kernel was already in numba's cache"
        ),
        file=stream,
    )
    print("every kernel a flight uses is in the cache: runs, campaigns and fleets start at once", file=stream)
    return 0
