"""A fleet batch's summaries: CPU ms per run of its records, apart from the flight.

Usage: python benchmarks/bench_fleet_summaries.py [--scenario 11_gps_update] [--runs 200]

In CPU time of this process (``time.process_time``), after a 2-run warm-up that loads numba's
cached kernels: the flight with full logs (``campaigns.fleet.diagram.run_fleet``), the same batch
flown and summarised while it flies (``campaigns.fleet.runner.simulate_batch``), and the summaries
alone (``fleet.summaries.summarize_logs``: a BatchSummary fed the full logs chunk by chunk), with the peak
resident memory of the process.
"""

import argparse
import resource
import time

from quad_drake.campaigns.fleet.diagram import run_fleet
from quad_drake.campaigns.fleet.runner import BatchTask, simulate_batch
from quad_drake.campaigns.fleet.summaries import summarize_logs
from quad_drake.running import catalog


def _cpu(function, *args):
    start = time.process_time()
    result = function(*args)
    return time.process_time() - start, result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="11_gps_update")
    parser.add_argument("--runs", type=int, default=200)
    args = parser.parse_args()
    scenario = catalog.load(args.scenario)
    seeds = tuple(range(args.runs))
    simulate_batch(BatchTask(catalog.load(args.scenario, None, ["end_time=0.5"]), 0, (0, 1)))  # warm-up
    streamed, _ = _cpu(simulate_batch, BatchTask(scenario, 0, seeds))
    streamed_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    flight, (times, logs, _) = _cpu(run_fleet, scenario, seeds)
    summaries, _ = _cpu(lambda: summarize_logs(scenario, seeds, logs).records(0, 0.0))
    per_run = 1e3 / args.runs
    print(f"{args.scenario}, {args.runs} runs of {scenario.end_time:g} s (CPU ms per run):")
    print(f"  streamed batch (flight + summaries) {streamed * per_run:.1f}, peak RSS {streamed_rss:.0f} MiB")
    print(
        f"  flight with full logs {flight * per_run:.1f}; summaries of those logs {summaries * per_run:.1f}"
    )


if __name__ == "__main__":
    main()
