"""A fleet batch's post-processing: CPU ms per run of its records, apart from the flight.

Usage: python benchmarks/bench_fleet_summaries.py [--scenario 11_gps_update] [--runs 200]

Flies one batch of `runs` runs (``fleet.simulation.run_fleet``), then times, in CPU time of
this process (``time.process_time``), the batch's PCRB (``fleet.runner.batch_bounds``) and its
whole post-processing (``fleet.runner.summarize_batch``: signals, NEES, PCRB, criteria and
records of the N runs), after a 2-run warm-up that loads numba's cached kernels.
"""

import argparse
import time

from quad_drake import catalog
from quad_drake.fleet.runner import FleetBatch, batch_bounds, summarize_batch
from quad_drake.fleet.simulation import run_fleet


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="11_gps_update")
    parser.add_argument("--runs", type=int, default=200)
    args = parser.parse_args()
    scenario = catalog.load(args.scenario)
    seeds = tuple(range(args.runs))
    start = time.process_time()
    times, logs, wall = run_fleet(scenario, seeds)
    flight = time.process_time() - start
    summarize_batch(FleetBatch(scenario, 0, (0, 1)), times, logs, wall)  # warm-up: numba's cache
    start = time.process_time()
    batch_bounds(scenario, logs)
    bounds = time.process_time() - start
    start = time.process_time()
    summarize_batch(FleetBatch(scenario, 0, seeds), times, logs, wall)
    post = time.process_time() - start
    per_run = 1e3 / args.runs
    print(f"{args.scenario}, {args.runs} runs of {scenario.end_time:g} s (CPU ms per run):")
    print(f"  flight {flight * per_run:.1f}, post-processing {post * per_run:.1f}", end="")
    print(f" (of which PCRB {bounds * per_run:.1f})")


if __name__ == "__main__":
    main()
