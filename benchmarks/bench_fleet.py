"""Fleet vs process pool: runs per minute of one scenario's campaign, both from this one run.

Usage: python benchmarks/bench_fleet.py [--scenario 11_gps_update] [--fleet-runs 1000]
       [--batch B] [--pool-runs 20] [--jobs 2] [--rounds 3] [--no-jit]

Both campaigns run on `jobs` worker processes (spawned: their Drake import and, for the
fleet, numba's cache load are inside the wall time), seeds from the scenario's. The fleet's
batch defaults to fleet-runs / jobs. Printed: wall time, runs per minute and CPU seconds per
run of each (CPU time of the workers, from os.times, is the figure that does not depend on
what else the machine runs) and their ratio, per round: `rounds` rounds run the two campaigns in
turn, in alternating order, and the median of the rounds' ratios is printed (the machine is
shared: its speed drifts by 10-20 % between minutes, so one round's ratio moves as much); then
the numba JIT cost of a fleet on a cold cache against a warm one (a 1-vehicle, 0.01 s fleet in
a fresh interpreter; --no-jit skips it).
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

from quad_drake.campaigns import InProcessRunner, ProcessPoolRunner, run_campaign
from quad_drake.running import catalog

TINY_FLEET = (
    "import time; t = time.perf_counter(); from quad_drake.running import catalog; "
    "from quad_drake.campaigns.fleet.diagram import run_fleet; "
    "run_fleet(catalog.load({name!r}, None, ['end_time=0.01']), [0]); print(time.perf_counter() - t)"
)


def timed_campaign(scenario, runs, jobs, fleet_batch=None):
    """(campaign, wall s, CPU s of this process and its finished children)."""
    runner = InProcessRunner() if jobs == 1 else ProcessPoolRunner(jobs)
    before, start = os.times(), time.perf_counter()
    campaign = run_campaign(scenario, runs, runner=runner, progress=False, fleet_batch=fleet_batch)
    wall, after = time.perf_counter() - start, os.times()
    cpu = sum(after[i] - before[i] for i in range(4))
    return campaign, wall, cpu


def jit_seconds(name, cache_dir=None):
    """Wall s of a tiny fleet of `name` in a fresh interpreter (NUMBA_CACHE_DIR = cache_dir)."""
    env = dict(os.environ, **({"NUMBA_CACHE_DIR": cache_dir} if cache_dir else {}))
    out = subprocess.run(
        [sys.executable, "-c", TINY_FLEET.format(name=name)],
        env=env,
        check=True,
        capture_output=True,
        text=True,
    )
    return float(out.stdout.split()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="11_gps_update")
    parser.add_argument("--fleet-runs", type=int, default=1000)
    parser.add_argument("--batch", type=int)
    parser.add_argument("--pool-runs", type=int, default=20)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--no-jit", action="store_true")
    args = parser.parse_args()
    scenario = catalog.load(args.scenario)
    batch = args.batch or -(-args.fleet_runs // args.jobs)
    cpus = os.cpu_count()
    print(f"{args.scenario}: runs of {scenario.end_time:g} s, {args.jobs} worker processes, {cpus} CPUs")
    ratios = []
    for round_index in range(args.rounds):
        campaigns = [
            (f"fleet (batch {batch})", args.fleet_runs, batch),
            ("process pool", args.pool_runs, None),
        ]
        if round_index % 2:  # alternate the order: a drift of the machine's speed favours neither
            campaigns.reverse()
        rates = {}  # is_pool -> (runs/min wall, runs/min on the busy cores)
        for label, runs, fleet_batch in campaigns:
            campaign, wall, cpu = timed_campaign(scenario, runs, args.jobs, fleet_batch)
            per_wall, per_cpu = 60.0 * runs / wall, 60.0 * runs / cpu * args.jobs
            rates[fleet_batch is None] = (per_wall, per_cpu)
            print(
                f"{label:20s} {runs:6d} runs  wall {wall:8.1f} s  {per_wall:9.1f} runs/min  "
                f"CPU {cpu / runs:7.3f} s/run  ({per_cpu:9.1f} runs/min on {args.jobs} busy cores)"
            )
        (fleet_wall, fleet_cpu), (pool_wall, pool_cpu) = rates[False], rates[True]
        ratios.append((fleet_wall / pool_wall, fleet_cpu / pool_cpu))
        wall_ratio, cpu_ratio = ratios[-1]
        print(f"round {round_index + 1}: ratio fleet / pool {wall_ratio:.1f}x wall, {cpu_ratio:.1f}x CPU")
    if args.rounds > 1:
        wall_ratios, cpu_ratios = zip(*ratios, strict=True)
        print(
            f"ratio fleet / pool, median of {args.rounds} rounds (min-max): "
            f"{statistics.median(wall_ratios):.1f}x wall ({min(wall_ratios):.1f}-{max(wall_ratios):.1f}), "
            f"{statistics.median(cpu_ratios):.1f}x CPU ({min(cpu_ratios):.1f}-{max(cpu_ratios):.1f})"
        )
    if not args.no_jit:
        with tempfile.TemporaryDirectory() as empty:
            cold = jit_seconds(args.scenario, empty)
        warm = jit_seconds(args.scenario)
        print(f"numba: a tiny fleet in a fresh interpreter: {cold:.1f} s on a cold cache, {warm:.1f} s warm")


if __name__ == "__main__":
    main()
