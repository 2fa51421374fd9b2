"""Monte Carlo throughput: runs per minute of a scenario with 1, 2, ... worker processes.

Usage: python benchmarks/bench_montecarlo.py [--scenario 11_gps_update] [--runs 8] [--jobs 1 2]

Wall time covers the whole campaign, worker start-up (a spawned process imports Drake)
included; the speed-up of J jobs is bounded by the number of physical cores.
"""

import argparse
import os

from quad_drake.campaigns import InProcessRunner, ProcessPoolRunner, run_campaign, table
from quad_drake.running import catalog


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="11_gps_update")
    parser.add_argument("--runs", type=int, default=8)
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    scenario = catalog.load(args.scenario)
    print(f"{args.scenario}: {args.runs} runs of {scenario.end_time:g} s, {os.cpu_count()} CPUs")
    print(f"{'jobs':>4s} {'wall [s]':>9s} {'runs/min':>9s} {'sim s/run':>10s} {'x real (all runs)':>18s}")
    reference = None
    for jobs in args.jobs:
        runner = InProcessRunner() if jobs == 1 else ProcessPoolRunner(jobs)
        campaign = run_campaign(scenario, args.runs, runner=runner, progress=False)
        t = campaign.timing()
        reference = reference or table(campaign)
        assert table(campaign) == reference, "the table must not depend on the runner"
        print(
            f"{jobs:4d} {t['wall_time_s']:9.1f} {t['runs_per_minute']:9.1f} {t['simulation_s_mean']:10.2f} "
            f"{args.runs * scenario.end_time / t['wall_time_s']:18.1f}"
        )


if __name__ == "__main__":
    main()
