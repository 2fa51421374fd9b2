"""Whose roll and pitch the accelerometer agrees with: ours or PX4's, window by window, on replayed logs.

Averaged over several seconds of flight a multirotor's specific force points away from gravity
whatever the wind and the drag (its mean acceleration over W s is Δv / W, small unless the speed
changes by metres per second), so the direction of the mean accelerometer reading, less PX4's
own accelerometer bias at the log's start (``FlightLog.estimator_imu_bias``, where logged), is a
tilt neither estimator chose. For each replay folder under OUT (``quad-drake replay ... --out
OUT``) this prints, per window of W s from COMPARE_AFTER on: that accelerometer tilt, PX4's mean
roll and pitch (``vehicle_attitude``) and ours (the replay's estimate); PX4's horizontal speed at
the window's end from its own state vector (``estimator_states`` 4:6, logged even where PX4 marks
its horizontal states invalid) and its mean collective thrust set-point
(``vehicle_thrust_setpoint``), which say whether the vehicle sped up; and the RMS of PX4's own
gravity-vector innovation (``estimator_aid_src_gravity``, PX4 v1.14 on: its tilt against the
accelerometer's direction, mrad of the unit vector) where logged. It ends with the RMS over the
windows of each estimate's mean less the accelerometer's tilt, and, over each span given
(``--spans 5:21,21:53,53:93``), ours - PX4's RMS and each tilt's mean: an estimate whose mean
tilt stands θ off the accelerometer's over T s says the vehicle's horizontal speed changed by
about g·θ·T (the acceleration that tilts the specific force by θ), printed beside the change of
PX4's own horizontal velocity over the span.

    python benchmarks/tilt_gravity_consistency.py OUT [--window 8] [--spans A:B,C:D]
"""

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
from pyulog import ULog

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from quad_drake.conventions import GRAVITY  # noqa: E402
from quad_drake.flightlogs.reader import read_flight_log  # noqa: E402
from quad_drake.flightlogs.replay import COMPARE_AFTER  # noqa: E402
from quad_drake.flightlogs.settings import load_replay, resolve_log  # noqa: E402
from quad_drake.models.rotations import euler_from_quats  # noqa: E402


def px4_topics(path, start_us) -> dict:
    """{name: (times s from the log's first IMU sample, data)} of the extra PX4 topics read here."""
    wanted = ["estimator_states", "vehicle_thrust_setpoint", "estimator_aid_src_gravity"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pyulog's notes on unregistered message ids
        ulog = ULog(str(path), wanted)
    found = {}
    for dataset in ulog.data_list:
        if dataset.multi_id == 0:
            found[dataset.name] = ((dataset.data["timestamp"] - start_us) / 1e6, dataset.data)
    return found


def window_mean(times, values, start, stop) -> float:
    """Mean of `values` over the samples in [start, stop), NaN where none."""
    inside = (times >= start) & (times < stop)
    return float(np.mean(values[inside])) if inside.any() else float("nan")


def accelerometer_tilt(force) -> tuple[float, float]:
    """(roll, pitch) rad of a mean FRD specific force (m/s^2) that points away from gravity."""
    fx, fy, fz = force
    return float(np.arctan2(-fy, -fz)), float(np.arctan2(fx, np.hypot(fy, fz)))


def consistency(folder, window, spans) -> None:
    """Print the window table and the summaries of one replay folder."""
    path = resolve_log(load_replay(folder / "config.yaml").log)
    log = read_flight_log(path)
    saved = np.load(folder / "logs.npz")
    times = saved["times"]
    ours = np.column_stack(euler_from_quats(saved["replay/estimated_state"][:, 3:7])[:2])
    ref = log.reference_attitude
    px4 = np.column_stack(euler_from_quats(ref.values)[:2])
    bias = np.zeros(3) if log.estimator_imu_bias is None else np.asarray(log.estimator_imu_bias.accel)
    extra = px4_topics(path, log.start_time * 1e6) if str(path).endswith(".ulg") else {}
    imu_t, force = log.imu.times, log.imu.values[:, 0:3] - bias
    end = min(times[-1], ref.times[-1], imu_t[-1])
    starts = np.arange(COMPARE_AFTER, end - window + 1e-9, window)
    print(f"{folder.name}: windows of {window:g} s; accelerometer less PX4's bias {np.round(bias, 3)}")
    print(
        "   t s | accel roll pitch |   PX4 roll pitch |  ours roll pitch (mrad) | PX4 speed m/s | thrust "
        "| PX4 gravity innov mrad"
    )
    rows = []
    for a in starts:
        b = a + window
        tilt = accelerometer_tilt([window_mean(imu_t, force[:, k], a, b) for k in range(3)])
        p = [window_mean(ref.times, px4[:, k], a, b) for k in range(2)]
        o = [window_mean(times, ours[:, k], a, b) for k in range(2)]
        speed = thrust = innovation = float("nan")
        if "estimator_states" in extra:
            t, d = extra["estimator_states"]
            speed = float(np.hypot(np.interp(b, t, d["states[4]"]), np.interp(b, t, d["states[5]"])))
        if "vehicle_thrust_setpoint" in extra:
            t, d = extra["vehicle_thrust_setpoint"]
            thrust = -window_mean(t, d["xyz[2]"], a, b)
        if "estimator_aid_src_gravity" in extra:
            t, d = extra["estimator_aid_src_gravity"]
            inside = (t >= a) & (t < b)
            if inside.any():
                horizontal = np.stack([d["innovation[0]"][inside], d["innovation[1]"][inside]])
                innovation = 1e3 * float(np.sqrt(np.mean(horizontal**2)))
        rows.append((*tilt, *p, *o))
        print(
            f"{a:6.0f} | {1e3 * tilt[0]:7.1f} {1e3 * tilt[1]:7.1f} | {1e3 * p[0]:7.1f} {1e3 * p[1]:7.1f} | "
            f"{1e3 * o[0]:7.1f} {1e3 * o[1]:7.1f} | {speed:13.1f} | {thrust:6.3f} | {innovation:6.1f}"
        )
    if not rows:
        print(f"  shorter than one window after {COMPARE_AFTER:g} s")
        return
    rows = 1e3 * np.array(rows)
    for name, columns in (("PX4", slice(2, 4)), ("ours", slice(4, 6))):
        off = rows[:, columns] - rows[:, 0:2]
        rms = np.sqrt(np.nanmean(off**2, axis=0))
        print(f"  {name} less the accelerometer's tilt, RMS: roll {rms[0]:.1f}, pitch {rms[1]:.1f}")
    for a, b in spans:
        if a >= end:
            continue
        inside = (ref.times >= a) & (ref.times < b) & (ref.times <= times[-1])
        difference = np.column_stack([np.interp(ref.times[inside], times, ours[:, k]) for k in range(2)])
        difference -= px4[inside]
        rms = 1e3 * np.sqrt(np.mean(difference**2, axis=0))
        b = min(b, end)
        tilt = np.array(accelerometer_tilt([window_mean(imu_t, force[:, k], a, b) for k in range(3)]))
        means = {
            "PX4": np.array([window_mean(ref.times, px4[:, k], a, b) for k in range(2)]),
            "ours": np.array([window_mean(times, ours[:, k], a, b) for k in range(2)]),
        }
        implied = {name: GRAVITY * np.linalg.norm(m - tilt) * (b - a) for name, m in means.items()}
        logged = "n/a"
        if "estimator_states" in extra:
            t, d = extra["estimator_states"]
            change = [np.interp(b, t, d[f"states[{k}]"]) - np.interp(a, t, d[f"states[{k}]"]) for k in (4, 5)]
            logged = f"{np.hypot(*change):.1f}"
        print(
            f"  {a:g}-{b:g} s: ours - PX4's RMS roll {rms[0]:.1f}, pitch {rms[1]:.1f} mrad; mean tilt "
            f"(roll, pitch mrad) accelerometer {np.round(1e3 * tilt, 1)}, "
            f"PX4 {np.round(1e3 * means['PX4'], 1)}, ours {np.round(1e3 * means['ours'], 1)}; the speed "
            f"change each implies: PX4's {implied['PX4']:.1f}, ours {implied['ours']:.1f} m/s (PX4's own "
            f"velocity changed by {logged} m/s)"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="a quad-drake replay --out folder")
    parser.add_argument("--window", type=float, default=8.0, help="s per window (default 8)")
    parser.add_argument("--spans", default="", help="spans A:B,C:D (s) for ours - PX4's RMS")
    args = parser.parse_args()
    try:
        spans = [tuple(float(v) for v in span.split(":", 1)) for span in args.spans.split(",") if span]
    except ValueError:
        spans = [()]
    folders = sorted(p.parent for p in args.out.glob("*/logs.npz"))
    if not folders or not args.window > 0 or any(len(span) != 2 for span in spans):
        print(
            f"tilt_gravity_consistency: no replay folders under {args.out}, a window <= 0 or a span "
            f"not A:B (--spans {args.spans!r})",
            file=sys.stderr,
        )
        return 2
    for folder in folders:
        consistency(folder, args.window, spans)
    return 0


if __name__ == "__main__":
    sys.exit(main())
