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

Estimator signals come from the logs every estimator exports (``estimated_state``,
``covariance``, ``diagnostics``), read through its :class:`EstimatorVocabulary`
(``quad_drake.estimation.vocabulary``):

- ``Est.X, Est.Y, Est.Z, Est.VX, Est.VY, Est.VZ, Est.Roll, Est.Pitch, Est.Yaw``: the
  estimate (m, m/s, rad), and ``Est.E.Roll, Est.E.Pitch, Est.E.Yaw`` its Euler-angle errors
  (wrapped), ``Est.E.MaxEuler`` the largest of them, ``Est.E.Pos``, ``Est.E.Vel`` the norms
  of the position and velocity errors, for every estimator;
- ``Est.E.<name>`` (estimate minus truth) and ``Est.S.<name>`` (sqrt of the covariance
  diagonal) for every error-state entry the vocabulary names (EKF7: X Y Z VX VY VZ Yaw;
  ESKF: X Y Z VX VY VZ AttN AttE AttD [BAX BAY BAZ BGX BGY BGZ]); ``Est.<name>`` for its
  extra values (ESKF: the bias estimates BAX ... BGZ);
- ``Est.GpsNIS`` (fresh on each GPS sample) and ``Est.MagNIS``, and the counters
  ``Est.NonFinite``, ``Est.GpsGated``, ``Est.MagGated``, ``Est.GpsResets``,
  ``Est.CovRepairs`` (cumulative counts).
"""

from dataclasses import dataclass

import numpy as np

from .conventions import P_SLICE, Q_SLICE, REF_P_SLICE, REF_YAW_INDEX, V_SLICE, W_SLICE
from .estimation.vocabulary import DIAG, NIS_COLUMNS
from .rotations import euler_from_quats, wrap_angles  # noqa: F401 (re-exported for the analyzers)


@dataclass(frozen=True)
class Signal:
    values: np.ndarray  # (n,) one value per logged sample
    fresh: np.ndarray  # (n,) bool: sample carries a new measurement


AXES = ("X", "Y", "Z")
LOG_WIDTHS = {"state": 13, "reference": 10, "motor_forces": 4, "contacts": 3, "imu": 6, "gps": 7, "mag": 2}
"""Widths of the logs every vehicle may have; an estimator's come from its vocabulary."""
COUNTER_SIGNALS = {
    "nonfinite_samples": "NonFinite",
    "gps_gated": "GpsGated",
    "mag_gated": "MagGated",
    "gps_resets": "GpsResets",
    "covariance_repairs": "CovRepairs",
}


def stamp_fresh(stamps):
    """True where a stamp differs from the previous sample's and a sample exists (stamp >= 0).

    stamps: (n,) or (n, N) (N runs of a fleet batch), samples along the first axis.
    """
    previous = np.concatenate((np.full((1,) + stamps.shape[1:], -1.0), stamps[:-1]))
    return (stamps != previous) & (stamps >= 0)


def vehicle_signals(name, logs, vocabulary=None):
    """{signal name: Signal} for vehicle `name` from its logs {log name: (n, width) array}.

    The logs may also be a fleet batch's (n, N, width) arrays: then every Signal's values and
    fresh mask are (n, N), run j's its column j.

    Only the logs present produce signals (no IMU log, no ``Name.IMU.*``); estimator
    signals need the vehicle's EstimatorVocabulary. Works for n = 0, which gives the names
    a scenario can refer to before it is run.
    """
    signals = {}
    state = logs["state"]
    always = np.ones(state.shape[:-1], dtype=bool)

    def put(key, values, fresh=always):
        signals[f"{name}.{key}"] = Signal(values, fresh)

    p, v, w = state[..., P_SLICE], state[..., V_SLICE], state[..., W_SLICE]
    roll, pitch, yaw = euler_from_quats(state[..., Q_SLICE])
    for i, axis in enumerate(AXES):
        put(f"Pos.{axis}", p[..., i])
        put(f"Vel.{axis}", v[..., i])
        put(f"Omega.{axis}", w[..., i])
    put("Roll", roll)
    put("Pitch", pitch)
    put("Yaw", yaw)
    put("StateFinite", np.isfinite(state).all(axis=-1).astype(float))
    if "contacts" in logs:
        contacts = logs["contacts"]
        put("FloorContact", contacts[..., 0])
        put("FloorTouchdowns", contacts[..., 1])
        put("WallContactSteps", contacts[..., 2])
    if "reference" in logs:
        ref = logs["reference"]
        for i, axis in enumerate(AXES):
            put(f"Ref.{axis}", ref[..., REF_P_SLICE][..., i])
        put("Ref.Yaw", ref[..., REF_YAW_INDEX])
        put("PosFollowErr", np.linalg.norm(ref[..., REF_P_SLICE] - p, axis=-1))
    if "motor_forces" in logs:
        for i, motor in enumerate("ABCD"):
            put(f"Thrust.{motor}", logs["motor_forces"][..., i])
    if "imu" in logs:
        for i, key in enumerate(("AX", "AY", "AZ", "GX", "GY", "GZ")):
            put(f"IMU.{key}", logs["imu"][..., i])
    if "gps" in logs:
        gps = logs["gps"]
        fresh = stamp_fresh(gps[..., 6])
        for i, key in enumerate(("X", "Y", "Z", "VX", "VY", "VZ")):
            put(f"GPS.{key}", gps[..., i], fresh)
    if "mag" in logs:
        put("MagYaw", logs["mag"][..., 0], stamp_fresh(logs["mag"][..., 1]))
    if vocabulary is not None and "estimated_state" in logs:
        _estimator_signals(put, logs, vocabulary, p, v, (roll, pitch, yaw))
    return signals


def _estimator_signals(put, logs, vocabulary, p, v, euler):
    estimate = logs["estimated_state"]
    p_hat, v_hat = estimate[..., P_SLICE], estimate[..., V_SLICE]
    euler_hat = euler_from_quats(estimate[..., Q_SLICE])
    for i, axis in enumerate(AXES):
        put(f"Est.{axis}", p_hat[..., i])
        put(f"Est.V{axis}", v_hat[..., i])
    euler_errors = []
    for key, value, truth in zip(("Roll", "Pitch", "Yaw"), euler_hat, euler, strict=True):
        put(f"Est.{key}", value)
        euler_errors.append(wrap_angles(value - truth))
        put(f"Est.E.{key}", euler_errors[-1])
    put("Est.E.MaxEuler", np.max(np.abs(euler_errors), axis=0))
    put("Est.E.Pos", np.linalg.norm(p_hat - p, axis=-1))
    put("Est.E.Vel", np.linalg.norm(v_hat - v, axis=-1))
    errors = vocabulary.errors(logs)
    k = vocabulary.size
    sigma = np.sqrt(np.maximum(logs["covariance"][..., :: k + 1], 0.0))  # diagonal of the row-major P
    for i, key in enumerate(vocabulary.state_names):
        put(f"Est.E.{key}", errors[..., i])
        put(f"Est.S.{key}", sigma[..., i])
    for key, values in vocabulary.extra_values(logs).items():
        put(f"Est.{key}", values)
    diagnostics = logs["diagnostics"]
    for sensor, (nis_column, stamp_column) in NIS_COLUMNS.items():
        put(
            f"Est.{sensor.capitalize()}NIS",
            diagnostics[..., nis_column],
            stamp_fresh(diagnostics[..., stamp_column]),
        )
    for counter, key in COUNTER_SIGNALS.items():
        put(f"Est.{key}", diagnostics[..., DIAG[counter]])


def empty_logs(log_widths):
    """Zero-sample logs of the given {name: width}: ``vehicle_signals`` on them lists the signal names."""
    return {log: np.zeros((0, width)) for log, width in log_widths.items()}
