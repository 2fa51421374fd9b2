"""Pure: the reference simulator's named signals (``Quad.Pos.X``, ``Quad.Est.E.Yaw`` …)
derived from one vehicle's logged arrays.

Besides the reference's names, the aiding sensors' samples (issue 32): ``Baro.Height`` (m, up,
fresh on each barometer sample) and, for a 3-axis magnetometer in place of ``MagYaw``,
``Mag.X``, ``Mag.Y``, ``Mag.Z`` (gauss, body FRD); and the truth of the flight (safety
criteria, ``quad_drake.judging.safety``):
``StateFinite`` (1 while all 13 state entries are finite), ``Tilt`` (rad, the body z axis from the
vertical), ``FloorContact`` (1 while on the
floor), ``FloorTouchdowns`` (touchdowns so far, after take-off), ``TouchdownSpeed`` (each touchdown's
descent speed, m/s, at the sample that counts it: a landing or a crash) and ``WallContactSteps``
(1 ms steps so far stopped at a wall or the ceiling). With wind, ``Wind.X/Y/Z`` (m/s, NED); with a
range-limited IMU, ``IMU.AccelSaturated`` and ``IMU.GyroSaturated`` (saturated samples so far);
with a no-aiding failsafe, ``Failsafe.PositionValid``, ``Failsafe.NoAidTime`` (s) and
``Failsafe.Phase`` (:data:`FAILSAFE_SIGNALS`).

Logs are sampled every LOG_PERIOD at t = 0.005 k (k >= 1), each value as it was
just before the systems' updates at t. Sensor signals carry a ``fresh`` mask:
true on samples where a new measurement arrived since the previous sample
(SPEC §0.2), judged by a changed stamp, never by comparing float times.

The errors (``Est.E.*``, ``PosFollowErr``) and ``Ref.*`` follow one of two definitions
(``quad_drake.models.error_sampling``): at the sample (the physical default), or, when the logs carry
``tick_state`` and ``tick_reference`` (``fidelity: reference``), the binary's: at the last
onboard tick, against that tick's truth and reference.

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
- ``Est.GpsNIS`` (fresh on each GPS sample), ``Est.MagNIS`` (the yaw, or the EKF7's
  tilt-compensated heading), ``Est.BaroNIS`` and ``Est.FieldNIS`` (the ESKF's 3-axis field), and
  the counters ``Est.NonFinite``, ``Est.GpsGated``, ``Est.MagGated``, ``Est.GpsResets``,
  ``Est.CovRepairs``, ``Est.BaroGated``, ``Est.BaroResets``, ``Est.GpsHeightRestarts``
  (cumulative counts); ``Est.BaroBias``
  and ``Est.BaroBiasStd`` (m, the baro bias estimate and its standard deviation, NaN without a
  barometer).
"""

import functools
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..conventions import MAG_FIELD_SIZE, P_SLICE, Q_SLICE, REF_P_SLICE, REF_YAW_INDEX, V_SLICE, W_SLICE
from ..estimation.registry import vehicle_vocabulary
from ..estimation.vocabulary import DIAG, NIS_COLUMNS, STATE_UNITS
from ..models.error_sampling import TICK_LOG_WIDTHS, error_reference, error_truth
from ..models.faults import SENSORS
from ..models.fidelity import PHYSICAL
from ..models.rotations import euler_from_quats, wrap_angles  # noqa: F401 (re-exported for the analyzers)


def signal_unit(name) -> str:
    """Unit of a named signal (``Quad.Est.E.VX`` -> ``m/s``); "" when unknown."""
    return key_unit(name.split(".", 1)[-1])


def key_unit(key) -> str:
    """Unit of a signal named without its vehicle (``Est.E.VX`` -> ``m/s``, as a campaign pools
    its metrics over vehicles); "" when unknown."""
    last = key.rsplit(".", 1)[-1]
    if key.startswith("Wind.") or key == "TouchdownSpeed":
        return "m/s"
    if key.startswith(("Omega.", "IMU.GX", "IMU.GY", "IMU.GZ")):
        return "rad/s"
    if key.startswith(("IMU.AX", "IMU.AY", "IMU.AZ")):
        return "m/s^2"
    if key.startswith("Thrust."):
        return "N"
    if key.startswith("Mag."):
        return "gauss"
    if key.startswith("Est.") and last in STATE_UNITS:
        return STATE_UNITS[last]
    if key == "Failsafe.NoAidTime":
        return "s"
    if last in ("Roll", "Pitch", "Yaw", "MagYaw", "MaxEuler", "Tilt"):
        return "rad"
    if key.startswith("Vel.") or last in ("VX", "VY", "VZ", "Vel"):
        return "m/s"
    if last in ("X", "Y", "Z", "Pos", "PosFollowErr", "Height", "BaroBias", "BaroBiasStd"):
        return "m"
    return ""


@dataclass(frozen=True)
class Signal:
    """One logged signal: its value at each log sample and whether that sample is fresh."""

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
    "baro": 2,
    "wind": 3,
    "imu_saturation": 2,
    "failsafe": 3,
}
"""Widths of the logs every vehicle may have; an estimator's come from its vocabulary."""
COUNTER_SIGNALS = {
    "nonfinite_samples": "NonFinite",
    "gps_gated": "GpsGated",
    "mag_gated": "MagGated",
    "gps_resets": "GpsResets",
    "covariance_repairs": "CovRepairs",
    "baro_gated": "BaroGated",
    "baro_resets": "BaroResets",
    "gps_height_restarts": "GpsHeightRestarts",
}

FAILSAFE_SIGNALS = ("PositionValid", "NoAidTime", "Phase")
"""``V.Failsafe.<name>`` of the no-aiding failsafe's status (``control.failsafe.STATUS``): 1 while
the horizontal position is valid, s without position aiding, the phase (0 nominal, 1 descending,
2 landed)."""


def stamp_fresh(stamps) -> np.ndarray:
    """True where a stamp differs from the previous sample's and a sample exists (stamp >= 0).

    stamps: (n,) or (n, N) (N runs of a fleet batch), samples along the first axis.
    """
    previous = np.concatenate((np.full((1,) + stamps.shape[1:], -1.0), stamps[:-1]))
    return (stamps != previous) & (stamps >= 0)


class Signals(Mapping):
    """{signal name: :class:`Signal`} whose arrays are derived on first access and kept.

    The names (and their order) are known at once; a caller that reads a few signals of a
    log, as a campaign's summaries do, derives only those (and what they share, e.g. the
    true Euler angles). makers: {name: a function of no argument returning its Signal}.
    """

    def __init__(self, makers=(), values=()):
        self._makers = dict(makers)
        self._values = dict(values)

    def __getitem__(self, name):
        value = self._values.get(name)
        if value is None:
            value = self._values[name] = self._makers[name]()
        return value

    def __contains__(self, name):
        return name in self._makers

    def __iter__(self):
        return iter(self._makers)

    def __len__(self):
        return len(self._makers)

    def __repr__(self):
        return f"Signals({list(self._makers)})"

    def merged(self, *others) -> "Signals":
        """These signals and the `others`' (Signals), a later one taking a name they share."""
        makers, values = dict(self._makers), dict(self._values)
        for other in others:
            makers.update(other._makers)
            values.update(other._values)
        return Signals(makers, values)

    def from_sample(self, start) -> "Signals":
        """The same signals from sample `start` on (values and fresh masks sliced on access)."""

        def sliced(name):
            signal = self[name]
            return Signal(signal.values[start:], signal.fresh[start:])

        return Signals({name: functools.partial(sliced, name) for name in self._makers})


def vehicle_signals(name, logs, vocabulary=None) -> Signals:
    """{signal name: Signal} (a :class:`Signals`) for vehicle `name` from its logs {log name:
    (n, width) array}, each derived when first read.

    The logs may also be a fleet batch's (n, N, width) arrays: then every Signal's values and
    fresh mask are (n, N), run j's its column j.

    Only the logs present produce signals (no IMU log, no ``Name.IMU.*``); estimator
    signals need the vehicle's EstimatorVocabulary. Works for n = 0, which gives the names
    a scenario can refer to before it is run.
    """
    makers = {}
    state = logs["state"]
    always = np.ones(state.shape[:-1], dtype=bool)

    def put(key, values, fresh=lambda: always):
        """Signal `key` of the functions (no argument) giving its values and fresh mask."""
        makers[f"{name}.{key}"] = lambda: Signal(values(), fresh())

    p, v, w = state[..., P_SLICE], state[..., V_SLICE], state[..., W_SLICE]
    euler = functools.cache(lambda: euler_from_quats(state[..., Q_SLICE]))
    for i, axis in enumerate(AXES):
        put(f"Pos.{axis}", lambda i=i: p[..., i])
        put(f"Vel.{axis}", lambda i=i: v[..., i])
        put(f"Omega.{axis}", lambda i=i: w[..., i])
    for i, key in enumerate(("Roll", "Pitch", "Yaw")):
        put(key, lambda i=i: euler()[i])
    put("Tilt", lambda: tilt_angles(state[..., Q_SLICE]))
    put("StateFinite", lambda: np.isfinite(state).all(axis=-1).astype(float))
    if "contacts" in logs:
        contacts = logs["contacts"]
        for i, key in enumerate(("FloorContact", "FloorTouchdowns", "WallContactSteps")):
            put(key, lambda i=i: contacts[..., i])
        put("TouchdownSpeed", lambda: touchdown_speeds(contacts[..., 1], v[..., 2]))
    if "wind" in logs:
        for i, axis in enumerate(AXES):
            put(f"Wind.{axis}", lambda i=i: logs["wind"][..., i])
    if "imu_saturation" in logs:
        put("IMU.AccelSaturated", lambda: logs["imu_saturation"][..., 0])
        put("IMU.GyroSaturated", lambda: logs["imu_saturation"][..., 1])
    truth = error_truth(logs)  # the sample's state, or the last onboard tick's (error_sampling)
    if truth is not state:
        euler_truth = functools.cache(lambda: euler_from_quats(truth[..., Q_SLICE]))
    else:
        euler_truth = euler
    if "reference" in logs:
        ref = error_reference(logs)
        for i, axis in enumerate(AXES):
            put(f"Ref.{axis}", lambda i=i: ref[..., REF_P_SLICE][..., i])
        put("Ref.Yaw", lambda: ref[..., REF_YAW_INDEX])
        put("PosFollowErr", lambda: np.linalg.norm(ref[..., REF_P_SLICE] - truth[..., P_SLICE], axis=-1))
    if "motor_forces" in logs:
        for i, motor in enumerate("ABCD"):
            put(f"Thrust.{motor}", lambda i=i: logs["motor_forces"][..., i])
    if "imu" in logs:
        for i, key in enumerate(("AX", "AY", "AZ", "GX", "GY", "GZ")):
            put(f"IMU.{key}", lambda i=i: logs["imu"][..., i])
    if "gps" in logs:
        gps = logs["gps"]
        gps_fresh = functools.cache(lambda: stamp_fresh(gps[..., 6]))
        for i, key in enumerate(("X", "Y", "Z", "VX", "VY", "VZ")):
            put(f"GPS.{key}", lambda i=i: gps[..., i], gps_fresh)
    if "mag" in logs:
        mag = logs["mag"]
        mag_fresh = functools.cache(lambda: stamp_fresh(mag[..., -1]))
        if mag.shape[-1] == 2:  # the yaw magnetometer
            put("MagYaw", lambda: mag[..., 0], mag_fresh)
        else:  # 3-axis: the body-frame field, gauss
            for i, axis in enumerate(AXES):
                put(f"Mag.{axis}", lambda i=i: mag[..., i], mag_fresh)
    if "failsafe" in logs:
        for i, key in enumerate(FAILSAFE_SIGNALS):
            put(f"Failsafe.{key}", lambda i=i: logs["failsafe"][..., i])
    if "baro" in logs:
        baro = logs["baro"]
        put("Baro.Height", lambda: baro[..., 0], functools.cache(lambda: stamp_fresh(baro[..., 1])))
    if vocabulary is not None and "estimated_state" in logs:
        _estimator_signals(put, logs, vocabulary, truth[..., P_SLICE], truth[..., V_SLICE], euler_truth)
    return Signals(makers)


def _estimator_signals(put, logs, vocabulary, p, v, euler):
    """Put the estimator's signals (module docstring); p, v, euler: the truth the errors are taken
    against (:func:`~quad_drake.models.error_sampling.error_truth`), euler the (roll, pitch, yaw) on call."""
    estimate = logs["estimated_state"]
    p_hat, v_hat = estimate[..., P_SLICE], estimate[..., V_SLICE]
    euler_hat = functools.cache(lambda: euler_from_quats(estimate[..., Q_SLICE]))
    for i, axis in enumerate(AXES):
        put(f"Est.{axis}", lambda i=i: p_hat[..., i])
        put(f"Est.V{axis}", lambda i=i: v_hat[..., i])
    euler_errors = [functools.cache(lambda i=i: wrap_angles(euler_hat()[i] - euler()[i])) for i in range(3)]
    for i, key in enumerate(("Roll", "Pitch", "Yaw")):
        put(f"Est.{key}", lambda i=i: euler_hat()[i])
        put(f"Est.E.{key}", euler_errors[i])
    put("Est.E.MaxEuler", lambda: np.max(np.abs([e() for e in euler_errors]), axis=0))
    put("Est.E.Pos", lambda: np.linalg.norm(p_hat - p, axis=-1))
    put("Est.E.Vel", lambda: np.linalg.norm(v_hat - v, axis=-1))
    errors = functools.cache(lambda: vocabulary.errors(logs))
    k = vocabulary.size
    sigma = functools.cache(
        lambda: np.sqrt(np.maximum(logs["covariance"][..., :: k + 1], 0.0))
    )  # diagonal of P
    for i, key in enumerate(vocabulary.state_names):
        put(f"Est.E.{key}", lambda i=i: errors()[..., i])
        put(f"Est.S.{key}", lambda i=i: sigma()[..., i])
    for key, values in vocabulary.extra_values(logs).items():
        put(f"Est.{key}", lambda values=values: values)
    diagnostics = logs["diagnostics"]
    for sensor, (nis_column, stamp_column) in NIS_COLUMNS.items():
        put(
            f"Est.{sensor.capitalize()}NIS",
            lambda nis_column=nis_column: diagnostics[..., nis_column],
            lambda stamp_column=stamp_column: stamp_fresh(diagnostics[..., stamp_column]),
        )
    for counter, key in COUNTER_SIGNALS.items():
        put(f"Est.{key}", lambda counter=counter: diagnostics[..., DIAG[counter]])
    put("Est.BaroBias", lambda: diagnostics[..., DIAG["baro_bias"]])  # m; NaN without a barometer
    put("Est.BaroBiasStd", lambda: diagnostics[..., DIAG["baro_bias_std"]])


def tilt_angles(quaternions) -> np.ndarray:
    """rad in [0, pi]: the angle of the body z axis from the world's (down), acos R_NB[2, 2], of
    quaternions (..., 4) wxyz (normalised here)."""
    w, x, y, z = np.moveaxis(quaternions, -1, 0)
    r22 = 1.0 - 2.0 * (x * x + y * y) / (w * w + x * x + y * y + z * z)
    return np.arccos(np.clip(r22, -1.0, 1.0))


def touchdown_speeds(touchdowns, vz) -> np.ndarray:
    """The descent speed (m/s, down) of each touchdown at the sample that counts it, 0 elsewhere:
    ``vz`` at the sample before (the last one in the air, at most 5 ms before the contact; the
    floor zeroes vz). touchdowns: the cumulative count (``FloorTouchdowns``); both (n,) or (n, N)."""
    new = np.zeros(touchdowns.shape, dtype=bool)
    new[1:] = touchdowns[1:] > touchdowns[:-1]
    before = np.concatenate((np.zeros((1,) + vz.shape[1:]), vz[:-1]))
    return np.where(new, np.maximum(before, 0.0), 0.0)


def empty_logs(log_widths) -> dict[str, np.ndarray]:
    """Zero-sample logs of the given {name: width}: ``vehicle_signals`` on them lists the signal names."""
    return {log: np.zeros((0, width)) for log, width in log_widths.items()}


def vehicle_log_widths(vehicle, fidelity=PHYSICAL) -> dict[str, int]:
    """{name: width} of the signals a vehicle exports (and the top level logs) under the
    :class:`~quad_drake.models.fidelity.Fidelity` `fidelity` (``errors_at_onboard_tick`` adds
    ``error_sampling.TICK_LOG_WIDTHS``)."""
    widths = {name: LOG_WIDTHS[name] for name in ("state", "reference", "motor_forces", "contacts")}
    if fidelity.errors_at_onboard_tick:
        widths.update(TICK_LOG_WIDTHS)
    sensors = vehicle.sensors
    widths.update({s: sensor_width(sensors, s) for s in SENSORS if getattr(sensors, s) is not None})
    if vehicle.wind is not None:
        widths["wind"] = LOG_WIDTHS["wind"]
    if sensors.imu is not None and (sensors.imu.delta_velocity or sensors.imu.gyro_limit > 0):
        widths["imu_saturation"] = LOG_WIDTHS["imu_saturation"]
    vocabulary = vehicle_vocabulary(vehicle)
    if vocabulary is not None:
        widths.update(vocabulary.log_widths())
    if vehicle.failsafe is not None:
        widths["failsafe"] = LOG_WIDTHS["failsafe"]
    return widths


def sensor_width(sensors, sensor) -> int:
    """Width of one sample of `sensor` ("imu", "gps", "mag", "baro") of a SensorsConfig: its log's
    and its port's (a 3-axis magnetometer's is MAG_FIELD_SIZE)."""
    if sensor == "mag" and sensors.mag is not None and sensors.mag.three_axis:
        return MAG_FIELD_SIZE
    return LOG_WIDTHS[sensor]


def vehicle_log_names(vehicle, fidelity=PHYSICAL) -> list[str]:
    """Names of the signals a vehicle exports (and the top level logs) under `fidelity`."""
    return list(vehicle_log_widths(vehicle, fidelity))
