"""Pure: the reference simulator's named signals (``Quad.Pos.X``, ``Quad.Est.E.Yaw`` …)
derived from one vehicle's logged arrays.

Besides the reference's names, the truth of the flight (safety criteria, ``quad_drake.safety``):
``StateFinite`` (1 while all 13 state entries are finite), ``FloorContact`` (1 while on the
floor), ``FloorTouchdowns`` (touchdowns so far, after take-off) and ``WallContactSteps``
(1 ms steps so far stopped at a wall or the ceiling).

Logs are sampled every LOG_PERIOD at t = 0.005 k (k >= 1), each value as it was
just before the systems' updates at t. Sensor signals carry a ``fresh`` mask:
true on samples where a new measurement arrived since the previous sample
(SPEC §0.2), judged by a changed stamp, never by comparing float times.
"""

import math
from dataclasses import dataclass

import numpy as np

from .conventions import P_SLICE, Q_SLICE, REF_P_SLICE, REF_YAW_INDEX, V_SLICE, W_SLICE


@dataclass(frozen=True)
class Signal:
    values: np.ndarray  # (n,) one value per logged sample
    fresh: np.ndarray  # (n,) bool: sample carries a new measurement


AXES = ("X", "Y", "Z")
LOG_WIDTHS = {
    "state": 13,
    "reference": 10,
    "motor_forces": 4,
    "contacts": 3,
    "imu": 6,
    "gps": 7,
    "mag": 2,
    "attitude": 3,
    "ekf_state": 7,
    "covariance": 49,
    "diagnostics": 5,
}


def euler_from_quats(q):
    """(roll, pitch, yaw) arrays of an (n, 4) array of wxyz quaternions (SPEC §0.1)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    roll = np.arctan2(2 * (y * z + w * x), w * w - x * x - y * y + z * z)
    pitch = np.arcsin(np.clip(-2 * (x * z - w * y), -1.0, 1.0))
    yaw = np.arctan2(2 * (x * y + w * z), w * w + x * x - y * y - z * z)
    return roll, pitch, yaw


def wrap_angles(a):
    """Array version of rotations.wrap_to_pi: into [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def stamp_fresh(stamps):
    """True where a stamp differs from the previous sample's and a sample exists (stamp >= 0)."""
    previous = np.concatenate(([-1.0], stamps[:-1]))
    return (stamps != previous) & (stamps >= 0)


def vehicle_signals(name, logs):
    """{signal name: Signal} for vehicle `name` from its logs {log name: (n, width) array}.

    Only the logs present produce signals (no IMU log, no ``Name.IMU.*``). Works for
    n = 0, which gives the names a scenario can refer to before it is run.
    """
    signals = {}
    state = logs["state"]
    always = np.ones(state.shape[0], dtype=bool)

    def put(key, values, fresh=always):
        signals[f"{name}.{key}"] = Signal(values, fresh)

    p, v, w = state[:, P_SLICE], state[:, V_SLICE], state[:, W_SLICE]
    roll, pitch, yaw = euler_from_quats(state[:, Q_SLICE])
    for i, axis in enumerate(AXES):
        put(f"Pos.{axis}", p[:, i])
        put(f"Vel.{axis}", v[:, i])
        put(f"Omega.{axis}", w[:, i])
    put("Roll", roll)
    put("Pitch", pitch)
    put("Yaw", yaw)
    put("StateFinite", np.isfinite(state).all(axis=1).astype(float))
    if "contacts" in logs:
        contacts = logs["contacts"]
        put("FloorContact", contacts[:, 0])
        put("FloorTouchdowns", contacts[:, 1])
        put("WallContactSteps", contacts[:, 2])
    if "reference" in logs:
        ref = logs["reference"]
        for i, axis in enumerate(AXES):
            put(f"Ref.{axis}", ref[:, REF_P_SLICE][:, i])
        put("Ref.Yaw", ref[:, REF_YAW_INDEX])
        put("PosFollowErr", np.linalg.norm(ref[:, REF_P_SLICE] - p, axis=1))
    if "motor_forces" in logs:
        for i, motor in enumerate("ABCD"):
            put(f"Thrust.{motor}", logs["motor_forces"][:, i])
    if "imu" in logs:
        for i, key in enumerate(("AX", "AY", "AZ", "GX", "GY", "GZ")):
            put(f"IMU.{key}", logs["imu"][:, i])
    if "gps" in logs:
        gps = logs["gps"]
        fresh = stamp_fresh(gps[:, 6])
        for i, key in enumerate(("X", "Y", "Z", "VX", "VY", "VZ")):
            put(f"GPS.{key}", gps[:, i], fresh)
    if "mag" in logs:
        put("MagYaw", logs["mag"][:, 0], stamp_fresh(logs["mag"][:, 1]))
    if "ekf_state" in logs:
        _estimator_signals(put, logs, p, v, roll, pitch, yaw)
    return signals


def _estimator_signals(put, logs, p, v, roll, pitch, yaw):
    x_hat = logs["ekf_state"]
    attitude = logs["attitude"]
    sigma = np.sqrt(np.maximum(logs["covariance"][:, ::8], 0.0))  # diagonal of the row-major 7x7
    names = ("X", "Y", "Z", "VX", "VY", "VZ", "Yaw")
    truth = np.column_stack([p, v, yaw])
    for i, key in enumerate(names):
        put(f"Est.{key}", x_hat[:, i])
        put(f"Est.S.{key}", sigma[:, i])
        error = x_hat[:, i] - truth[:, i]
        put(f"Est.E.{key}", wrap_angles(error) if key == "Yaw" else error)
    put("Est.Roll", attitude[:, 0])
    put("Est.Pitch", attitude[:, 1])
    roll_error = attitude[:, 0] - roll
    pitch_error = attitude[:, 1] - pitch
    yaw_error = wrap_angles(x_hat[:, 6] - yaw)
    put("Est.E.Roll", roll_error)
    put("Est.E.Pitch", pitch_error)
    put("Est.E.MaxEuler", np.max(np.abs([roll_error, pitch_error, yaw_error]), axis=0))
    put("Est.E.Pos", np.linalg.norm(x_hat[:, 0:3] - p, axis=1))
    put("Est.E.Vel", np.linalg.norm(x_hat[:, 3:6] - v, axis=1))


def empty_logs(log_names):
    """Zero-sample logs of the given names: ``vehicle_signals`` on them lists the signal names."""
    return {log: np.zeros((0, LOG_WIDTHS[log])) for log in log_names}
