"""Fleet flight speed: CPU seconds per run of a scenario's fleet Diagram (``campaigns.fleet.diagram``).

Flies the scenario (default ``11_gps_update``, shortened to ``--seconds`` of simulated time) as
fleets of each ``--sizes`` N, ``--repeats`` times each (the best kept), and prints the CPU time
(``time.process_time``, the figure that depends least on the machine's other load) of the flight
(``campaigns.fleet.diagram.fly``) per run of the full scenario length and per vehicle per 2 ms onboard
tick, then the fit of CPU per tick = fixed + N x per-vehicle over the sizes (least squares).
The Diagram's sink reads every exported signal at the 5 ms log samples, as a campaign's does, and
keeps nothing: the figure is the flight, not the logs or their summaries (``campaigns.fleet.streaming``).
``--floor`` adds, per size, the same flight with every handler of the fleet systems emptied (no
maths, no noise drawn): the layout's floor, Drake's steps and state copies, the port plumbing and
the sink's reads. ``--profile N`` prints the cProfile top entries of one flight of N vehicles
instead.

    python benchmarks/bench_fleet_flight.py [--scenario 11_gps_update] [--seconds 5] [--sizes 500 1000]
                                            [--repeats 3] [--floor] [--profile N]
"""

import argparse
import cProfile
import dataclasses
import pstats
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pydrake.systems.framework import LeafSystem  # noqa: E402

from benchmarks.handlers import empty, replaced_handlers  # noqa: E402
from quad_drake.campaigns.fleet.diagram import build_fleet_diagram, fly, release_memory  # noqa: E402
from quad_drake.conventions import LOG_PERIOD, ONBOARD_PERIOD  # noqa: E402
from quad_drake.running import catalog  # noqa: E402
from quad_drake.systems import controller, faults, noise, plant, sensors, trajectory  # noqa: E402
from quad_drake.systems import estimators as estimator_systems  # noqa: E402


class ReadingSink(LeafSystem):
    """Evaluates every input (N x width each) at t = k LOG_PERIOD and keeps nothing."""

    def __init__(self, signals, n):
        super().__init__()
        self._evaluate = [self.DeclareVectorInputPort(f"{v}.{s}", n * w).Eval for (v, s), w in signals]
        self.DeclarePeriodicPublishEvent(LOG_PERIOD, 0.0, self._read)

    def _read(self, context):
        for evaluate in self._evaluate:
            evaluate(context)


def flight_cpu(scenario, n):
    """CPU s of flying `scenario` with N = n runs (seeds 0..n-1), the Diagram's build excluded."""
    diagram, _ = build_fleet_diagram(scenario, list(range(n)), lambda signals, _: ReadingSink(signals, n))
    start = time.process_time()
    fly(diagram, scenario.end_time)
    cpu = time.process_time() - start
    release_memory(diagram)
    return cpu


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="11_gps_update")
    parser.add_argument("--seconds", type=float, default=5.0, help="simulated seconds per flight")
    parser.add_argument("--sizes", type=int, nargs="+", default=[500, 1000])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--floor", action="store_true", help="also fly each size with empty handlers")
    parser.add_argument("--profile", type=int, default=None, metavar="N")
    args = parser.parse_args()
    full = catalog.load(args.scenario)
    scenario = dataclasses.replace(full, end_time=args.seconds)
    flight_cpu(scenario, 2)  # numba cache load, imports
    if args.profile is not None:
        profiler = cProfile.Profile()
        profiler.enable()
        flight_cpu(scenario, args.profile)
        profiler.disable()
        pstats.Stats(profiler).sort_stats("tottime").print_stats(25)
        return
    ticks = args.seconds / ONBOARD_PERIOD
    per_tick = {}
    for n in args.sizes:
        cpu = min(flight_cpu(scenario, n) for _ in range(args.repeats))
        per_tick[n] = cpu / ticks
        per_run = cpu / n * full.end_time / args.seconds
        print(
            f"N={n:5d}: {cpu:.2f} s CPU for {args.seconds:g} s (best of {args.repeats}); "
            f"{per_run * 1e3:.1f} ms per {full.end_time:g} s run; "
            f"{cpu / ticks / n * 1e6:.2f} us per vehicle-tick"
        )
        if args.floor:
            systems = (plant, sensors, faults, controller, trajectory, noise, estimator_systems)
            with replaced_handlers(systems, empty):
                floor = min(flight_cpu(scenario, n) for _ in range(args.repeats))
            print(
                f"         layout floor (empty handlers): {floor:.2f} s CPU; "
                f"{floor / n * full.end_time / args.seconds * 1e3:.1f} ms per run; "
                f"{floor / ticks / n * 1e6:.2f} us per vehicle-tick ({100 * floor / cpu:.0f} % of the flight)"
            )
    if len(per_tick) > 1:
        sizes = np.array(list(per_tick), dtype=float)
        slope, fixed = np.polyfit(sizes, np.array(list(per_tick.values())), 1)
        print(f"fit: {fixed * 1e3:.3f} ms fixed per tick + {slope * 1e6:.2f} us per vehicle-tick")


if __name__ == "__main__":
    main()
