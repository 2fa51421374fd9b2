"""Benchmark: is the SITL GPS's noise white? (what a white-noise tuning of the log tuner can reach)

Reads the bundled SITL log and the SITL ground-truth log (no replay) and prints, for the GPS
horizontal velocity of the bundled log after 5 s: its quantum, the share of samples unchanged
from the one before, its autocorrelation at lags 1..LAGS, and that of its first differences (a
white noise's differences have -0.5 at lag 1); for its take-off and touchdown (where the GPS
vertical speed crosses CONTACT_SPEED within CONTACT_HEIGHT of the ground), the vertical
velocity change the IMU integrates (the specific force rotated by PX4's attitude, plus gravity,
less its mean at rest before the take-off) beside the GPS's and PX4's over CONTACT_WINDOW s
around each: a simulator whose IMU leaves out
the ground's contact force shows none of the GPS's stop; and for the ground-truth log, the GPS
position and velocity error against the simulator's truth with its autocorrelation.

Usage: ``python benchmarks/sitl_gps_noise.py``
"""

import numpy as np

from quad_drake.conventions import GRAVITY
from quad_drake.flightlogs.reader import read_flight_log
from quad_drake.flightlogs.settings import resolve_log
from quad_drake.judging.innovations import autocorrelation
from quad_drake.models.rotations import rotation_from_quat

START = 5.0  # s: the replay's start-up, as the tuner judges
CONTACT_SPEED = 0.1  # m/s: the GPS vertical speed above which the vehicle has left the ground
CONTACT_HEIGHT = 0.3  # m: how near its height at rest the GPS must be for a crossing to be a contact
CONTACT_WINDOW = (-0.3, 0.5)  # s around a contact over which the velocity changes are compared


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

    ground_contacts(log)

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


def ground_contacts(log):
    """Print, for each take-off and touchdown of `log` (a FlightLog with GPS, an IMU and PX4's
    estimate), the vertical velocity change (m/s, down) the IMU integrates, the GPS's and PX4's."""
    imu, gps, reference = log.imu, log.gps, log.reference_position
    attitude = log.reference_attitude
    quats = np.column_stack([np.interp(imu.times, attitude.times, q) for q in attitude.values.T])
    forces = imu.values[:, 0:3]
    down = np.array([(rotation_from_quat(q) @ f)[2] for q, f in zip(quats, forces, strict=True)]) + GRAVITY
    moving = np.abs(gps.values[:, 5]) > CONTACT_SPEED
    changes = np.flatnonzero(np.diff(moving.astype(int)))
    if not len(changes):
        return
    ground = np.median(gps.values[: changes[0] + 1, 2])
    changes = [i for i in changes if abs(gps.values[i, 2] - ground) < CONTACT_HEIGHT]
    rest = (imu.times >= START) & (imu.times < gps.times[changes[0]] + CONTACT_WINDOW[0])
    offset = down[rest].mean()
    print(f"  ground contacts (GPS vertical speed crossing {CONTACT_SPEED} m/s near the ground; the IMU")
    print(f"  less its offset at rest, {offset:+.3f} m/s^2):")
    for i in changes:
        what = "take-off" if moving[i + 1] else "touchdown"
        a, b = gps.times[i] + CONTACT_WINDOW[0], gps.times[i] + CONTACT_WINDOW[1]
        inside = (imu.times >= a) & (imu.times < b)
        integrated = np.sum((down[inside] - offset) * np.gradient(imu.times[inside]))
        gps_change = np.interp(b, gps.times, gps.values[:, 5]) - np.interp(a, gps.times, gps.values[:, 5])
        px4 = np.interp(b, reference.times, reference.values[:, 5]) - np.interp(
            a, reference.times, reference.values[:, 5]
        )
        print(
            f"    {what} at {gps.times[i]:.2f} s, over {a:.2f}-{b:.2f} s: the IMU integrates "
            f"{integrated:+.3f}, the GPS {gps_change:+.3f}, PX4's estimate {px4:+.3f} m/s"
        )


if __name__ == "__main__":
    main()
