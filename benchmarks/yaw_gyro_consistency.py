"""Whose yaw the gyro agrees with: ours or PX4's, window by window, on replayed logs.

Over a few seconds a MEMS gyro's integral is good to a few mrad (PX4's own gyro bias estimate is
about 1 mrad/s on the logs of docs/measurements/replay.md), far better than a magnetometer in a
flying vehicle. For each replay folder under OUT (``quad-drake replay ... --out OUT``) this cuts
the log into windows of W s and prints, per window, the yaw change the gyro integrates (the Euler
yaw rate (q sin(roll) + r cos(roll)) / cos(pitch) of the body rates, with PX4's roll and pitch),
PX4's (``vehicle_attitude``) and ours (the replay's estimate), and the RMS over the windows of
each estimate's change less the gyro's. An estimator whose yaw leaves the gyro's by far more
than its bias allows is pulled by something else (its magnetometer, or its field and bias model).
It then prints the mean and standard deviation of ours - PX4's from 5 s on (the replay compares
from then): a constant offset, or a drift, or steps.

    python benchmarks/yaw_gyro_consistency.py OUT [--window 4] [--each]
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from quad_drake.flightlogs.reader import read_flight_log  # noqa: E402
from quad_drake.flightlogs.replay import COMPARE_AFTER  # noqa: E402
from quad_drake.flightlogs.settings import load_replay, resolve_log  # noqa: E402
from quad_drake.models.rotations import euler_from_quats, wrap_angles  # noqa: E402


def yaw_changes(folder, window) -> tuple[np.ndarray, np.ndarray, str]:
    """((k,) window starts s, (k, 3) yaw changes rad of the gyro, PX4's, ours, summary line)."""
    log = read_flight_log(resolve_log(load_replay(folder / "config.yaml").log))
    saved = np.load(folder / "logs.npz")
    times = saved["times"]
    ours = np.unwrap(euler_from_quats(saved["replay/estimated_state"][:, 3:7])[2])
    ref = log.reference_attitude
    roll, pitch, px4 = euler_from_quats(ref.values)
    px4 = np.unwrap(px4)
    imu_t, rates = log.imu.times, log.imu.values[:, 3:6]
    r, p = np.interp(imu_t, ref.times, roll), np.interp(imu_t, ref.times, pitch)
    yaw_rate = (rates[:, 1] * np.sin(r) + rates[:, 2] * np.cos(r)) / np.cos(p)
    gyro = np.concatenate([[0.0], np.cumsum(0.5 * (yaw_rate[1:] + yaw_rate[:-1]) * np.diff(imu_t))])
    end = min(times[-1], ref.times[-1], imu_t[-1])
    starts = np.arange(0.0, end - window + 1e-9, window)
    stops = starts + window
    series = ((imu_t, gyro), (ref.times, px4), (times, ours))
    changes = np.column_stack([np.interp(stops, t, y) - np.interp(starts, t, y) for t, y in series])
    compared = (ref.times >= COMPARE_AFTER) & (ref.times <= times[-1])
    difference = wrap_angles(np.interp(ref.times[compared], times, ours) - px4[compared])
    off = 1e3 * (changes[:, 1:] - changes[:, :1])
    worst = np.argmax(np.abs(off), axis=0)
    summary = (
        f"{folder.name}: yaw change less the gyro's over {len(starts)} windows of {window:g} s, RMS "
        f"PX4 {np.sqrt(np.mean(off[:, 0] ** 2)):.0f} mrad (worst {off[worst[0], 0]:+.0f} at "
        f"{starts[worst[0]]:g} s), ours {np.sqrt(np.mean(off[:, 1] ** 2)):.0f} mrad (worst "
        f"{off[worst[1], 1]:+.0f} at {starts[worst[1]]:g} s); ours - PX4's from {COMPARE_AFTER:g} s: "
        f"mean {1e3 * difference.mean():+.0f}, std {1e3 * difference.std():.0f} mrad"
    )
    return starts, changes, summary


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="a replay's --out folder")
    parser.add_argument("--window", type=float, default=4.0, help="s per window (default 4)")
    parser.add_argument("--each", action="store_true", help="also print every window")
    args = parser.parse_args()
    folders = sorted(p.parent for p in args.out.glob("*/logs.npz"))
    if not folders or not args.window > 0:
        print(f"yaw_gyro_consistency: no replay folders under {args.out}, or a window <= 0", file=sys.stderr)
        return 2
    for folder in folders:
        try:
            starts, changes, summary = yaw_changes(folder, args.window)
        except (AttributeError, TypeError):  # no PX4 attitude in the log
            print(f"{folder.name}: no PX4 attitude to compare")
            continue
        print(summary)
        if args.each:
            for start, (gyro, px4, ours) in zip(starts, 1e3 * changes, strict=True):
                print(f"  {start:6.1f} s  gyro {gyro:+6.0f}  PX4 {px4:+6.0f}  ours {ours:+6.0f} mrad")
    return 0


if __name__ == "__main__":
    sys.exit(main())
