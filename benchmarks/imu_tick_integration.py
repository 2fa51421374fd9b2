"""How far a held IMU sample's integration drifts from the log's own, per log.

The replay's estimators predict on the 2 ms onboard tick. Until 2026-12-07 the playback held each
logged IMU sample from the first tick at or after its time to the next sample's, so a 200 Hz
IMU's samples were integrated over 4 and 6 ms in turn; now each tick carries the mean of the
log's IMU signal over its own interval (``schedule.imu_tick_means``), whose integral is the
samples' own. For each log this integrates both over the replayed stretch and prints, per axis
group, the difference held - exact accumulated over each 1 s window: its mean (a drift rate, as a
gyro or accelerometer bias would give) and its RMS, beside the IMU's rate, its tick durations as
held and its sample-to-sample spread (the vibration that the alternation integrates).

    python benchmarks/imu_tick_integration.py real_auav_x21_attitude_flight pub/x500v2_v6xrt.ulg ...
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from quad_drake.conventions import ONBOARD_PERIOD  # noqa: E402
from quad_drake.flightlogs.reader import read_flight_log  # noqa: E402
from quad_drake.flightlogs.schedule import IMU_BRIDGE_WINDOW, bridged_imu, first_ticks, imu_tick_means  # noqa: E402
from quad_drake.flightlogs.settings import resolve_log  # noqa: E402

WINDOW = 1.0  # s


def held_rows(times, values, ticks):
    """The rows of the playback before 2026-12-07: at each tick the latest sample first due by it."""
    due = np.searchsorted(first_ticks(times), ticks, side="right") - 1
    return values[np.maximum(due, 0)]


def drift(times, values):
    """(mean, RMS) over 1 s windows of held - exact integral, (6,) each: rad/s-integrals for the gyro
    (rad), m/s for the accelerometer, per window."""
    ticks, exact = imu_tick_means(times, values)
    held = held_rows(times, values, ticks)
    difference = np.cumsum((held - exact) * ONBOARD_PERIOD, axis=0)
    edges = np.searchsorted(ticks * ONBOARD_PERIOD, np.arange(0.0, ticks[-1] * ONBOARD_PERIOD, WINDOW))
    steps = np.diff(difference[edges], axis=0)
    return steps.mean(axis=0), np.sqrt(np.mean(steps**2, axis=0))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="+", help="flight logs (a bundled log's name or a path)")
    args = parser.parse_args(argv)
    print(
        "log | IMU Hz | tick durations held (ms) | spread gyro rad/s, accel m/s^2 | gyro drift per s: "
        "mean, RMS (mrad) | accel drift per s: mean, RMS (m/s)"
    )
    for name in args.logs:
        log = read_flight_log(resolve_log(name))
        imu, _ = bridged_imu(log.imu, IMU_BRIDGE_WINDOW)  # as the replay plays it
        times, values = imu.times, imu.values
        ticks = first_ticks(times)
        durations = np.unique(np.diff(ticks)) * ONBOARD_PERIOD * 1e3
        spread = np.std(np.diff(values, axis=0), axis=0)
        mean, rms = drift(times, values)
        rate = (len(times) - 1) / (times[-1] - times[0])
        shown = ", ".join(f"{d:.0f}" for d in durations[:4]) + (" ..." if len(durations) > 4 else "")
        print(
            f"{Path(name).stem} | {rate:.0f} | {shown} | {np.linalg.norm(spread[3:]):.3f}, "
            f"{np.linalg.norm(spread[:3]):.2f} | {1e3 * np.linalg.norm(mean[3:]):.2f}, "
            f"{1e3 * np.linalg.norm(rms[3:]):.2f} | {np.linalg.norm(mean[:3]):.4f}, "
            f"{np.linalg.norm(rms[:3]):.4f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
