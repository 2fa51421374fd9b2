"""What a run will cost before it starts, and the rule that refuses an absurd one.

A run keeps every logged signal of every vehicle at the 5 ms log period in memory (Drake's
logger, then the arrays of :func:`quad_drake.running.simulation.read_logs`). Its memory is estimated as
``end_time / LOG_PERIOD`` samples x the vehicles' logged values x 8 bytes x
:data:`LOG_COPIES`; its wall time as ``end_time x vehicles x`` :data:`WALL_PER_SIMULATED_S`.

The rule (:func:`check_memory`): a run, or the runs a campaign holds at once (one per worker;
a fleet batch's summaries per worker), whose estimate exceeds :data:`MEMORY_SHARE` of the
machine's physical memory is refused with the estimate, before anything flies
(``ConfigError``: one line, exit 2). :func:`cost_warnings` gives the lines the command line
prints for a run it will fly anyway: above :data:`WARN_BYTES` of memory or
:data:`WARN_WALL_S` of wall time.
"""

import math
import os

from ..config.errors import ConfigError
from ..conventions import LOG_PERIOD
from ..judging.signals import vehicle_log_widths

LOG_COPIES = 2.1
"""Bytes held per logged value over 8: the logger's copy, the read-back arrays and the derived
signals; 11_gps_update's run grows by 0.42 MB per simulated second against 0.20 MB of logged
values (126 values per sample)."""
WALL_PER_SIMULATED_S = 0.15
"""s of wall time per simulated second and vehicle on the 2-core reference machine (11 flies at
about 7x real time; README's scenario table)."""
MEMORY_SHARE = 0.5
"""Share of the physical memory a run (or the runs held at once) may be estimated to take."""
WARN_BYTES = 1 << 30
"""Memory estimate above which the command line says what a run will take (1 GiB)."""
WARN_WALL_S = 600.0
"""Wall-time estimate (s) above which the command line says what a run will take."""
FALLBACK_MEMORY = 8 << 30
"""Physical memory assumed where the platform does not tell (8 GiB)."""


def physical_memory() -> int:
    """Bytes of physical memory (``os.sysconf``), or :data:`FALLBACK_MEMORY`."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return FALLBACK_MEMORY


def logged_values(scenario) -> int:
    """Values logged per sample over the scenario's vehicles."""
    return sum(sum(vehicle_log_widths(vehicle).values()) for vehicle in scenario.vehicles)


def run_bytes(scenario) -> float:
    """Estimated bytes one run of `scenario` holds (a float: inf for an absurd end_time)."""
    return scenario.end_time / LOG_PERIOD * logged_values(scenario) * 8.0 * LOG_COPIES


def run_wall_s(scenario) -> float:
    """Estimated wall time of one run, s."""
    return scenario.end_time * len(scenario.vehicles) * WALL_PER_SIMULATED_S


def size_text(nbytes) -> str:
    """``1.2 GiB``-style text of a byte count (``inf`` as such)."""
    if not math.isfinite(nbytes):
        return "an unbounded amount"
    for unit, scale in (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{nbytes / 1024:.3g} KiB"


def check_memory(nbytes, what, fix) -> None:
    """ConfigError (one line: `what` would take the estimate, the limit, then `fix`) when
    `nbytes` exceeds MEMORY_SHARE of the physical memory."""
    limit = MEMORY_SHARE * physical_memory()
    if not nbytes <= limit:
        raise ConfigError(
            f"{what} would take about {size_text(nbytes)} of memory, more than half of this machine's "
            f"{size_text(physical_memory())}; {fix}"
        )


def check_run(scenario, at_once=1) -> None:
    """Refuse (ConfigError) a run whose logs, times `at_once` runs held together, would not fit."""
    per_s = size_text(logged_values(scenario) * 8.0 * LOG_COPIES / LOG_PERIOD)
    what = f"{scenario.name}: end_time={scenario.end_time:g} s ({per_s} per simulated second"
    what += f", {at_once} runs at once)" if at_once > 1 else ")"
    check_memory(run_bytes(scenario) * at_once, what, "shorten end_time")


def cost_warnings(scenario) -> list[str]:
    """Lines saying what a long run will take (memory above WARN_BYTES, wall above WARN_WALL_S)."""
    nbytes, wall = run_bytes(scenario), run_wall_s(scenario)
    if nbytes > WARN_BYTES or wall > WARN_WALL_S:
        return [
            f"quad-drake: {scenario.name} simulates {scenario.end_time:g} s: about {wall / 60:.3g} min of "
            f"wall time and {size_text(nbytes)} of memory (estimates; manual: guide, 'Running scenarios')"
        ]
    return []
