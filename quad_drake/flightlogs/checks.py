"""Pure: whether a FlightLog can be replayed, and what weakens its replay.

:func:`log_warnings` raises FlightLogError (one line, exit 2) where a replay cannot mean anything
and returns one line per weakness where it still can:

- an IMU slower than MIN_IMU_RATE: the estimators integrate each sample over the time to the next
  one, and at that rate a multirotor's attitude changes between samples by more than any figure
  the replay reports (a 9 Hz ``sensor_combined`` is a logger's subsample, not the IMU): exit 2;
- an IMU slower than PX4_IMU_RATE (EKF2's own prediction rate) or with gaps longer than IMU_GAP:
  a warning with the rate or the gaps;
- a file that ends mid-message (``FlightLog.truncated``): a warning with how much was replayed;
- a log that leaves less than SHORT_COMPARISON s to compare: a warning;
- PX4 positions far from the GPS (``FlightLog.gps_mismatches``: an edited origin or a corrupted
  sample): a warning that they are not compared;
- IMU samples the log flags as clipped (``FlightLog.imu_clipping``): a warning with how many and
  the first, since the replay fuses them as logged;
- PX4 switching the IMU that ``sensor_combined`` carries, or its primary EKF2 instance, within
  the replayed stretch (``FlightLog.imu_switches``, ``estimator_switches``: a failover): a
  warning that the figures after the first switch compare estimates on different sensors;
- a vehicle that is not a multirotor by its ``MAV_TYPE`` parameter (a fixed wing, a VTOL, any
  other): a warning that PX4's estimator fuses what the replay does not in forward flight, and
  that the replay's at-rest test is a multirotor's.
"""

import numpy as np

from quad_drake.flightlogs.reader import GPS_MISMATCH, FlightLogError

MIN_IMU_RATE = 50.0
"""Hz: below it a replay cannot follow a multirotor's attitude (exit 2)."""
PX4_IMU_RATE = 100.0
"""Hz: PX4 EKF2's prediction rate; an IMU below it is replayed with a warning."""
SHORT_COMPARISON = 10.0
"""s: a comparison over less than this is too short to judge an estimator by (a warning)."""
IMU_GAP = 0.1
"""s: an interval between IMU samples longer than this is a gap (a dropout in the log)."""
ROTARY_WING_TYPES = frozenset((2, 3, 4, 13, 14, 15, 29))
"""MAVLink MAV_TYPE of a vehicle the replay's rules fit (they are a multirotor's): quadrotor,
coaxial, helicopter, hexa-, octo-, tri- and dodecarotor."""
VTOL_TYPES = frozenset(range(19, 26))
"""MAVLink MAV_TYPE of a VTOL (tailsitters, tiltrotor, fixed-rotor, tiltwing, reserved)."""


def imu_rate(log) -> float:
    """Hz: the log's median IMU rate (the inverse of the median interval)."""
    intervals = np.diff(log.imu.times)
    return 1.0 / float(np.median(intervals)) if len(intervals) else 0.0


def log_warnings(log, compare_after=0.0) -> list[str]:
    """[one-line warning] of a FlightLog that can be replayed; FlightLogError if it cannot.
    compare_after: s from the start before the replay compares anything (a log that leaves less
    than SHORT_COMPARISON s after it is said to be short)."""
    rate = imu_rate(log)
    if rate < MIN_IMU_RATE:
        raise FlightLogError(
            f"{log.source}: the IMU is logged at {rate:.3g} Hz, below the {MIN_IMU_RATE:g} Hz a replay "
            "needs (a logger's subsample of sensor_combined?); cannot replay"
        )
    warnings = []
    if rate < PX4_IMU_RATE:
        warnings.append(
            f"The IMU is logged at {rate:.0f} Hz, below PX4 EKF2's {PX4_IMU_RATE:g} Hz: each sample "
            "is held over its whole interval."
        )
    gaps = np.diff(log.imu.times)
    gaps = gaps[gaps > IMU_GAP]
    if gaps.size:
        warnings.append(
            f"The IMU has {gaps.size} gaps longer than {IMU_GAP:g} s (longest {gaps.max():.2f} s): "
            "each is filled from the mean of the samples before it to the mean of those after it "
            "(--set imu_gap_bridge)."
        )
    if log.duration - compare_after < SHORT_COMPARISON:
        warnings.append(
            f"The IMU covers {log.duration:.1f} s: {max(log.duration - compare_after, 0.0):.1f} s are "
            f"compared (from {compare_after:g} s on); too short a stretch to judge an estimator by."
        )
    if log.truncated:
        warnings.append(f"The file ends mid-message (cut short): replayed its first {log.duration:.1f} s.")
    if log.gps_mismatches:
        warnings.append(
            f"warning: {log.gps_mismatches} of PX4's {len(log.reference_position)} positions lie more than "
            f"{GPS_MISMATCH:g} m from the GPS through PX4's own origin (ref_lat, ref_lon): an origin edited "
            "in the file (a scrubbed location?) or corrupted samples; their x, y and z are not compared."
        )
    return warnings + _clipping_warning(log) + _switches_warning(log) + _vehicle_warning(log)


def _vehicle_warning(log) -> list[str]:
    """[one line] on a vehicle that is not rotary-wing by the log's MAV_TYPE, or [] for a
    rotary-wing one (ROTARY_WING_TYPES) or a log that does not say (a CSV)."""
    mav_type = log.parameters.get("MAV_TYPE")
    if mav_type is None or int(mav_type) in ROTARY_WING_TYPES:
        return []
    mav_type = int(mav_type)
    if mav_type == 1:
        vehicle, flight = "a fixed wing", "in flight"
    elif mav_type in VTOL_TYPES:
        vehicle, flight = "a VTOL", "in its fixed-wing flight"
    else:
        vehicle, flight = "not said to be a multirotor", "in forward flight"
    return [
        f"warning: the log's vehicle is {vehicle} (MAV_TYPE {mav_type}): {flight} PX4's estimator "
        "can fuse its airspeed and a synthetic sideslip, which the replay does not, and the replay's "
        "at-rest test (the IMU's vibration) is a multirotor's; the estimates can part there."
    ]


def _clipping_warning(log) -> list[str]:
    """[one line] on the IMU samples the log flags as clipped, or [] where none is."""
    if log.imu_clipping is None:
        return []
    flags = log.imu_clipping.values.astype(int)
    parts = []
    for column, sensor in enumerate(("accelerometer", "gyro")):
        rows = np.flatnonzero(flags[:, column])
        if rows.size:
            axes = np.bitwise_or.reduce(flags[rows, column])
            names = ", ".join(axis for bit, axis in enumerate("xyz") if axes & (1 << bit))
            first = log.imu_clipping.times[rows[0]]
            parts.append(f"the {sensor} on {rows.size} sample(s) (first at {first:.2f} s; axes {names})")
    return [
        f"The log flags the IMU as clipped: {' and '.join(parts)}. The replay fuses those samples as "
        "logged (PX4 raises a clipped accelerometer axis's noise and learns no bias on it): the "
        "estimates can part there."
    ]


def _switches_warning(log) -> list[str]:
    """[one line] on PX4's changes of IMU and of primary estimator within the log (a failover), or
    [] where there are none."""
    parts, consequences = [], []
    if log.imu_switches:
        time, before, after = log.imu_switches[0]
        sensor, axis = ("accelerometer", 0) if before[0] != after[0] else ("gyro", 1)
        parts.append(
            f"the IMU sensor_combined carries {len(log.imu_switches)} time(s) (first at {time:.2f} s: "
            f"{sensor} {before[axis]} -> {after[axis]})"
        )
        consequences.append("the replay fuses another IMU with the biases it learned on the first")
    if log.estimator_switches:
        time, before, after = log.estimator_switches[0]
        parts.append(
            f"its primary EKF2 instance {len(log.estimator_switches)} time(s) (first at {time:.2f} s: "
            f"{before} -> {after})"
        )
        consequences.append("PX4's estimate is another instance's, built on its own sensors from the start")
    if not parts:
        return []
    first = min(switches[0][0] for switches in (log.imu_switches, log.estimator_switches) if switches)
    return [
        f"PX4 switched {' and '.join(parts)}: from {first:.2f} s on {' and '.join(consequences)}; "
        "the figures after it do not compare like with like."
    ]
