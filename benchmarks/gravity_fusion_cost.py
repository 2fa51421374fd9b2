"""CPU cost per 500 Hz tick of the ESKF's gravity-vector fusion (``updates.GravityUpdate.fuse``)
for n vehicles: on an aided tick (every vehicle saw a GPS sample 0.1 s ago: nothing is fused), on
an unaided one (no GPS sample ever, the force in PX4's 0.9-1.1 g band: every vehicle fused) and
on one with half the vehicles aided.

Each case calls ``fuse`` on one set of (n, ...) filter arrays (the replay's ESKF settings:
``gravity_std`` 1.0, 5 s timeout) `--number` times, `--repeats` times, and prints the best
repeat's CPU time per call (``time.process_time``: this process's user+sys, less sensitive to the
machine's other load than wall time).

    python benchmarks/gravity_fusion_cost.py [--vehicles 8] [--number 20000] [--repeats 5]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from quad_drake.conventions import GRAVITY, NO_SAMPLE_STAMP  # noqa: E402
from quad_drake.estimation import eskf  # noqa: E402
from quad_drake.kernels import eskf as eskf_kernel  # noqa: E402
from quad_drake.kernels import fusion  # noqa: E402
from quad_drake.kernels.imu_hold import HOLD_SIZE, initial_hold  # noqa: E402
from quad_drake.systems import updates  # noqa: E402

PERIOD = 0.002  # s, the estimator's tick
NOW = 20.0  # s, the time of the timed ticks


class _Clock:
    """The one thing ``GravityUpdate.fuse`` reads of its context: the time."""

    def get_time(self):
        return NOW


def _filters(n, last_gps):
    """Level filters of n vehicles whose last GPS stamps are `last_gps` (n,) s."""
    x = np.tile(eskf.initial_nominal([0.0, 0.0, -1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]), (n, 1))
    P = np.tile(np.eye(15) * 1e-3, (n, 1, 1))
    book = np.tile(fusion.initial_book(), (n, 1))
    book[:, fusion.GPS_SLOT] = last_gps
    return fusion.Filters(x, P, np.zeros((n, 1)), book, np.tile(initial_hold(), (n, 1)).reshape(n, HOLD_SIZE))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--vehicles", type=int, default=8)
    parser.add_argument("--number", type=int, default=20000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    n = args.vehicles
    update = updates.GravityUpdate(
        eskf_kernel.gravity_tick,
        eskf.gravity_variance(1.0, PERIOD),
        1.0,
        5.0,
        eskf.GRAVITY_ACCEL_BAND,
        eskf.GRAVITY_GATE,
    )
    samples = {
        "imu": np.tile([0.0, 0.0, -GRAVITY, 0.0, 0.0, 0.0], (n, 1)),
        "manoeuvre": np.tile([0.0, GRAVITY], (n, 1)),
    }
    half = np.where(np.arange(n) % 2 == 0, NOW - 0.1, NO_SAMPLE_STAMP)
    cases = {
        "aided (nothing fused)": np.full(n, NOW - 0.1),
        "unaided (all fused)": np.full(n, NO_SAMPLE_STAMP),
        "half aided": half,
    }
    clock = _Clock()
    print(f"GravityUpdate.fuse, n = {n}, best of {args.repeats} x {args.number} calls (CPU, user+sys)")
    for name, last_gps in cases.items():
        filters = _filters(n, last_gps)
        update.fuse(clock, None, filters, samples)  # compile / warm
        best = float("inf")
        for _ in range(args.repeats):
            start = time.process_time()
            for _ in range(args.number):
                update.fuse(clock, None, filters, samples)
            best = min(best, (time.process_time() - start) / args.number)
        print(f"  {name:24s} {1e6 * best:6.2f} us/tick")


if __name__ == "__main__":
    main()
