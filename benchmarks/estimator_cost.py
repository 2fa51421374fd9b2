"""CPU cost of the estimators in the closed loop: EKF7 (11_gps_update) vs ESKF (11_gps_update_eskf).

Both scenarios fly the same set-up (Square.txt, noisy IMU, GPS and magnetometer, closed loop
on the estimate). Each repetition builds both diagrams, then times ``Initialize`` +
``AdvanceTo(end_time)`` of each with ``time.process_time()`` (this process's CPU time, so
other processes' load counts less than in wall time), the two back to back in alternating
order (EKF7 first in even repetitions, ESKF first in odd ones) with the same seed. The ratio
ESKF / EKF7 of each pair cancels the load both share; the script prints the median CPU s per
simulated second of each and the median (min-max) of the paired ratios. A third configuration,
11 flown on the truth with no estimator (``estimator: {kind: truth}``; IMU, GPS and
magnetometer still sampled, ``no_est``), gives the rest of the loop: ``cost - no_est`` is the
estimator's own cost.

    python benchmarks/estimator_cost.py [--repeats 7] [--end-time 10]
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from quad_drake.running import catalog  # noqa: E402
from quad_drake.running.simulation import build_diagram  # noqa: E402

CONFIGURATIONS = {
    "EKF7": ("11_gps_update", []),
    "ESKF": ("11_gps_update_eskf", []),
    "no_est": (
        "11_gps_update",
        ["vehicles.0.estimator={kind: truth}", "criteria=[]"],
    ),
}


def cpu_seconds(name, overrides, end_time, seed):
    """CPU s (process time) of Initialize + AdvanceTo(end_time) of a freshly built scenario."""
    scenario = catalog.load(name, seed, [*overrides, f"end_time={end_time}"])
    diagram, _ = build_diagram(scenario)
    simulator = Simulator(diagram)
    diagram.SetRandomContext(simulator.get_mutable_context(), RandomGenerator(scenario.seed))
    start = time.process_time()
    simulator.Initialize()
    simulator.AdvanceTo(end_time)
    return time.process_time() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--end-time", type=float, default=10.0, help="simulated s per run")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    names = list(CONFIGURATIONS)
    samples = {name: [] for name in names}
    for repeat in range(args.repeats):
        order = names if repeat % 2 == 0 else names[::-1]
        for name in order:
            scenario, overrides = CONFIGURATIONS[name]
            samples[name].append(cpu_seconds(scenario, overrides, args.end_time, args.seed) / args.end_time)
        print(
            f"repeat {repeat}: " + ", ".join(f"{n} {samples[n][-1]:.4f}" for n in names) + " CPU s per sim s",
            flush=True,
        )
    ratios = [e / k for e, k in zip(samples["ESKF"], samples["EKF7"], strict=True)]
    own = {n: [c - i for c, i in zip(samples[n], samples["no_est"], strict=True)] for n in ("EKF7", "ESKF")}
    print(f"{args.repeats} repeats of {args.end_time:g} simulated s, seed {args.seed}")
    for name in names:
        print(f"  {name:5s} median {statistics.median(samples[name]):.4f} CPU s per simulated s")
    for name, values in own.items():
        per_step = statistics.median(values) / 500.0 * 1e6
        print(
            f"  {name:5s} minus no_est: median {statistics.median(values):.4f} CPU s per simulated s "
            f"({per_step:.0f} us per 2 ms tick: IMU + estimator)"
        )
    print(
        f"  paired ratio ESKF / EKF7: median {statistics.median(ratios):.3f} "
        f"(min {min(ratios):.3f}, max {max(ratios):.3f})"
    )


if __name__ == "__main__":
    main()
