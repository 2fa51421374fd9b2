"""Many logs at once: CPU seconds per log of k copies of a bundled flight log replayed one by one
(a Diagram each) and in one Diagram (``replay.replay_many``: a LogPlayback of k flights and an
estimator of k vehicles).

Copy i is replayed with its own magnetic declination (``mag_declination`` = the log's + i 1e-6 rad),
so the k vehicles differ in a per-vehicle setting and the one Diagram runs the per-vehicle models
(``registry.EstimatorKind.per_vehicle``), not the fleet's one model for n identical vehicles. Each
figure is user + sys CPU (``time.process_time``, this process: the replay is single-threaded) over
the replays of that row divided by k, after one warm-up replay (numba's compiled kernels loaded):
the replay and its judging, the log read once beforehand (``read``: what reading the ULog costs
per log on top, in either path, as ``quad-drake replay`` reads each); ``ratio`` is one by one over
one Diagram, measured in the same run (a ratio that survives machine load). Every copy's estimate
is checked equal between the two.

    python benchmarks/bench_replay_many.py [--log sitl_takeoff_land_gps] [--copies 1 8 32] [--kinds eskf ekf7]
"""

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from quad_drake.flightlogs import earth_field  # noqa: E402
from quad_drake.flightlogs.reader import read_flight_log  # noqa: E402
from quad_drake.flightlogs.replay import replay, replay_many  # noqa: E402
from quad_drake.flightlogs.settings import default_replay, resolve_log  # noqa: E402

DECLINATION_STEP = 1e-6
"""rad between the copies' declinations: tiny, so every copy replays the same flight, yet each
vehicle has a setting of its own."""


def copies(kind, log, flight, k) -> list:
    """k ReplayConfigs of the bundled `log` (its FlightLog `flight`) under `kind`'s defaults, each
    its own declination."""
    declination = earth_field.magnetometer_model(flight).declination if flight.mag_field is not None else 0.0
    base = dataclasses.replace(default_replay(kind), log=log)
    return [
        dataclasses.replace(base, name=f"{log}_{i}", mag_declination=declination + i * DECLINATION_STEP)
        for i in range(k)
    ]


def cpu_per_log(run, k) -> tuple[float, list]:
    """(CPU s per log, results) of run() replaying k logs."""
    start = time.process_time()
    results = run()
    return (time.process_time() - start) / k, results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", default="sitl_takeoff_land_gps", help="a bundled log's name")
    parser.add_argument("--copies", type=int, nargs="+", default=[1, 8, 32])
    parser.add_argument("--kinds", nargs="+", default=["eskf", "ekf7"])
    args = parser.parse_args()
    read, flights = cpu_per_log(lambda: [read_flight_log(resolve_log(args.log)) for _ in range(3)], 3)
    flight = flights[0]
    print(f"log {args.log} ({flight.duration:.1f} s, read {read:.3f} s); CPU s per log (user + sys)")
    print(f"{'kind':5s} {'k':>4s} {'one by one':>11s} {'one Diagram':>12s} {'ratio':>6s}")
    for kind in args.kinds:
        replay(copies(kind, args.log, flight, 1)[0], flight)  # warm-up: numba's kernels compiled or loaded
        for k in args.copies:
            configs = copies(kind, args.log, flight, k)
            alone, separate = cpu_per_log(lambda c=configs: [replay(config, flight) for config in c], k)
            shared, together = cpu_per_log(lambda c=configs: replay_many(c, [flight] * len(c)), k)
            assert all(r.logs_in_diagram == k for r in together)
            for a, b in zip(separate, together, strict=True):
                np.testing.assert_array_equal(a.logs["estimated_state"], b.logs["estimated_state"])
            ratio = alone / shared if shared > 0 else math.nan
            print(f"{kind:5s} {k:4d} {alone:11.3f} {shared:12.3f} {ratio:6.2f}", flush=True)


if __name__ == "__main__":
    main()
