"""Benchmark: is the SITL GPS's noise white? (what a white-noise tuning of the log tuner can reach)

Reads the bundled SITL log and the SITL ground-truth log (no replay) and prints, for the GPS
horizontal velocity of the bundled log after 5 s: its quantum, the share of samples unchanged
from the one before, its autocorrelation at lags 1..LAGS, and that of its first differences (a
white noise's differences have -0.5 at lag 1); and for the ground-truth log, the GPS position
and velocity error against the simulator's truth with its autocorrelation.

Usage: ``python benchmarks/sitl_gps_noise.py``
"""

import numpy as np

from quad_drake.flightlogs.reader import read_flight_log
from quad_drake.flightlogs.settings import resolve_log
from quad_drake.judging.innovations import autocorrelation

START = 5.0  # s: the replay's start-up, as the tuner judges


def main():
    log = read_flight_log(resolve_log("sitl_takeoff_land_gps"))
    keep = log.gps.times >= START
    velocity = log.gps.values[keep, 3:5]
    steps = np.diff(velocity, axis=0)
    interval = np.median(np.diff(log.gps.times))
    band = 1.96 / np.sqrt(len(velocity))
    rho = autocorrelation(velocity - velocity.mean(axis=0)).round(2)
    rho_steps = autocorrelation(steps - steps.mean(axis=0)).round(2)
    print(f"bundled SITL log: {keep.sum()} GPS samples, median interval {interval:.3f} s")
    print(f"  horizontal velocity exactly 0: {np.mean(velocity == 0, axis=0).round(3)} (x, y)")
    print(f"  unchanged from the sample before: {np.mean(steps == 0, axis=0).round(3)} (x, y)")
    print(f"  smallest nonzero step {np.min(np.abs(steps[steps != 0])):.4f} m/s")
    print(f"  step std {steps.std(axis=0).round(4)} m/s (x, y)")
    print(f"  autocorrelation lags 1-5: {rho} (band ±{band:.3f})")
    print(f"  of its first differences: {rho_steps} (white noise: -0.5 at lag 1)")

    truth_log = read_flight_log(resolve_log("tests/data/flight_logs/sitl_ground_truth.ulg"))
    gps, truth = truth_log.gps, truth_log.truth_position
    keep = (gps.times >= max(truth.times[0], START)) & (gps.times <= truth.times[-1])
    at = gps.times[keep]
    true = np.column_stack([np.interp(at, truth.times, truth.values[:, k]) for k in range(6)])
    error = gps.values[keep, :6] - true
    error = error[np.all(np.isfinite(error), axis=1)]
    band = 1.96 / np.sqrt(len(error))
    print(f"SITL ground-truth log: {len(error)} GPS samples against the simulator's truth (band ±{band:.2f})")
    for name, columns in (("position xy", [0, 1]), ("position z", [2]), ("velocity xyz", [3, 4, 5])):
        part = error[:, columns] - error[:, columns].mean(axis=0)
        std = error[:, columns].std(axis=0).round(4)
        if np.all(std > 0):
            print(f"  {name}: error std {std} m or m/s, autocorrelation {autocorrelation(part).round(2)}")
        else:
            print(f"  {name}: error std {std}: no variation (the GPS reads the truth exactly)")


if __name__ == "__main__":
    main()
