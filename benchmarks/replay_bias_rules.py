"""PX4 EKF2's bias rules on the replay's ESKF, every log at once: the table of
docs/measurements/replay.md, "The bias states against PX4's, and a logger dropout".

Each row replays the given logs (names of bundled logs, .ulg files, or folders of them) with the
ESKF's replay defaults changed as the row says, and prints roll / pitch RMS of ours - PX4's from
5 s on (mrad) with the yaw (mrad), z (m) and vz (m/s):

- A: the biases PX4's primary estimator had at the log's start (``FlightLog.estimator_imu_bias``)
  as the ESKF's ``init_accel_bias`` / ``init_gyro_bias``, our start σ;
- B: ``--set px4_start_biases=true`` (those biases and PX4's σ);
- C: PX4's bias random walk per 10 ms step as a density (``accel_bias_rw_std`` 0.0003,
  ``gyro_bias_rw_std`` 0.0001); D = B + C; E = A + C; F, G: C's gyro or accelerometer part alone;
- H: PX4's accelerometer-bias inhibition (``accel_bias_learning_tilt`` 0.2618); I = B + H;
- base: ``--set imu_gap_bridge=0`` (the last IMU sample held over a logger's dropout); J: the
  replay's defaults (the dropout bridged); K, L, M = B, D, C with the defaults.

    python benchmarks/replay_bias_rules.py real_auav_x21_attitude_flight sitl_takeoff_land_gps \\
        tests/data/flight_logs/sitl_ground_truth.ulg pub/ [--rows base A B ...]
"""

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from quad_drake.flightlogs.command import expand_logs  # noqa: E402
from quad_drake.flightlogs.reader import read_flight_log  # noqa: E402
from quad_drake.flightlogs.replay import replay_many  # noqa: E402
from quad_drake.flightlogs.settings import load_replay, resolve_log  # noqa: E402

PX4_BIAS_NOISE = {"accel_bias_rw_std": 0.0003, "gyro_bias_rw_std": 0.0001}
INHIBITION = {"accel_bias_learning_tilt": 0.2618}
NO_BRIDGE = ("imu_gap_bridge=0",)
START = ("px4_start_biases=true",)
ROWS = {  # name: (estimator fields, --set overrides, PX4's start biases as the init_* fields)
    "base": ({}, NO_BRIDGE, False),
    "A": ({}, NO_BRIDGE, True),
    "B": ({}, NO_BRIDGE + START, False),
    "C": (PX4_BIAS_NOISE, NO_BRIDGE, False),
    "D": (PX4_BIAS_NOISE, NO_BRIDGE + START, False),
    "E": (PX4_BIAS_NOISE, NO_BRIDGE, True),
    "F": ({"gyro_bias_rw_std": 0.0001}, NO_BRIDGE, False),
    "G": ({"accel_bias_rw_std": 0.0003}, NO_BRIDGE, False),
    "H": (INHIBITION, NO_BRIDGE, False),
    "I": (INHIBITION, NO_BRIDGE + START, False),
    "J": ({}, (), False),
    "K": ({}, START, False),
    "L": (PX4_BIAS_NOISE, START, False),
    "M": (PX4_BIAS_NOISE, (), False),
}


def estimator_text(fields, log, start_values) -> str:
    """The ``--estimator`` mapping of a row for `log` (a FlightLog)."""
    mapping = {"kind": "eskf", **fields}
    biases = log.estimator_imu_bias
    if start_values and biases is not None:
        mapping |= {"init_accel_bias": list(biases.accel), "init_gyro_bias": list(biases.gyro)}
    return json.dumps(mapping)


def figure(differences, state, scale):
    d = {x.state: x for x in differences}.get(state)
    return "n/a" if d is None or d.count == 0 else f"{d.rms * scale:.{1 if scale > 1 else 3}f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="+")
    parser.add_argument("--rows", nargs="+", default=list(ROWS), choices=list(ROWS))
    args = parser.parse_args()
    paths = expand_logs(args.logs)
    logs = [read_flight_log(resolve_log(p)) for p in paths]
    for row in args.rows:
        fields, overrides, start_values = ROWS[row]
        configs = [
            load_replay(p, estimator_text(fields, log, start_values), overrides)
            for p, log in zip(paths, logs, strict=True)
        ]
        print(
            f"## {row}: estimator {fields or 'defaults'}, --set {list(overrides)}, "
            f"start biases as init_*: {start_values}"
        )
        for path, result in zip(paths, replay_many(configs, logs), strict=True):
            if not hasattr(result, "attitude"):
                print(f"{Path(path).stem:32s} {result}")
                continue
            both = result.attitude + result.position
            angles = " / ".join(f"{figure(both, s, 1e3):>5s}" for s in ("Roll", "Pitch"))
            rest = "  ".join(
                f"{s.lower()} {figure(both, s, 1 if s != 'Yaw' else 1e3):>6s}"
                for s in ("Yaw", "Z", "VZ", "X")
            )
            print(f"{Path(path).stem:32s} roll / pitch {angles}  {rest}")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
