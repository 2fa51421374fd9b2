"""Pure: what each estimator's logs mean — its state vocabulary, the one place for it.

Every estimator is a sub-Diagram with the same inputs (``imu``, ``gps``, ``mag``) and the same
exported outputs:

- ``estimated_state`` (13): the estimate in the true ``state`` layout (p_N m, q_NB wxyz,
  v_N m/s, w_NB_B rad/s), what the controller flies on;
- ``covariance`` (n*n, row-major): the covariance of the estimator's error state, whose
  entries are named by ``state_names``;
- ``diagnostics`` (DIAGNOSTICS_SIZE, layout :data:`DIAGNOSTICS`): NIS of the last GPS and
  magnetometer updates and their sample stamps, and counters;

plus the logs the vocabulary lists in ``logs`` (e.g. the EKF7's ``ekf_state``). An
:class:`EstimatorVocabulary` says, for one estimator: the error-state names, their units,
which are angles (wrapped), how its error against the 13-state truth is computed (in the
covariance's coordinates, estimate minus truth), and which states enter the NEES.

Consumers (signals, consistency, plots, report, campaigns) read the vocabulary; none of
them knows an estimator's layout.
"""

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from quad_drake.estimation.eskf import attitude_errors
from quad_drake.models.error_sampling import error_truth
from quad_drake.models.rotations import euler_from_quats, wrap_angles, yaw_from_quats

DIAGNOSTICS = (
    "gps_nis",  # NIS of the last fresh GPS sample (fused or gated), NaN before the first
    "gps_stamp",  # s, its sample stamp (-1 before the first)
    "mag_nis",  # NIS of the last fresh magnetometer sample
    "mag_stamp",  # s
    "nonfinite_samples",  # count of non-finite IMU, GPS or magnetometer samples skipped
    "gps_gated",  # count of GPS samples rejected by the innovation gate
    "mag_gated",  # count of magnetometer samples rejected by the innovation gate
    "gps_resets",  # count of GPS samples a group its gate rejected was reset to (rejected too long, a regain)
    "covariance_repairs",  # count of covariance repairs (indefinite) or resets (non-finite)
    # the aiding sensors (issue 32; NaN NIS and -1 stamps without them): estimation/baro.py, mag3.py
    "baro_nis",  # NIS of the last fresh barometer height (1 dof)
    "baro_stamp",  # s
    "field_nis",  # NIS of the last fresh 3-axis magnetometer field (ESKF, 3 dof)
    "field_stamp",  # s
    "baro_gated",  # count of barometer samples rejected by the innovation gate
    "baro_resets",  # count of baro bias resets after continuous rejection
    "baro_bias",  # m, the baro bias estimate (the scalar filter beside the estimator)
    "baro_bias_std",  # m, its standard deviation
    "gps_height_restarts",  # count of GPS samples the height restarted at (gating.height_restarts)
)
"""Names of the ``diagnostics`` entries, common to every estimator."""
DIAGNOSTICS_SIZE = len(DIAGNOSTICS)
DIAG = {name: i for i, name in enumerate(DIAGNOSTICS)}
COUNTERS = (
    "nonfinite_samples",
    "gps_gated",
    "mag_gated",
    "gps_resets",
    "covariance_repairs",
    "baro_gated",
    "baro_resets",
    "gps_height_restarts",
)
NIS_DOF = {"gps": 6, "mag": 1, "baro": 1, "field": 3}
"""Degrees of freedom of each sensor's NIS (GPS p and v, magnetometer yaw or the EKF7's
tilt-compensated heading, barometer height, the ESKF's 3-axis field)."""
NIS_COLUMNS = {sensor: (DIAG[f"{sensor}_nis"], DIAG[f"{sensor}_stamp"]) for sensor in NIS_DOF}


def initial_diagnostics() -> np.ndarray:
    """One vehicle's ``diagnostics`` before its first update: no NIS (NaN), no stamps (-1),
    counters 0, no baro bias estimate (NaN)."""
    values = np.zeros(DIAGNOSTICS_SIZE)
    for nis_column, stamp_column in NIS_COLUMNS.values():
        values[nis_column], values[stamp_column] = np.nan, -1.0
    values[DIAG["baro_bias"]] = values[DIAG["baro_bias_std"]] = np.nan
    return values


def completed_diagnostics(logged) -> np.ndarray:
    """A ``diagnostics`` log (m, k) as today's layout (m, DIAGNOSTICS_SIZE): a run saved by an
    earlier quad_drake has fewer columns, the entries appended to :data:`DIAGNOSTICS` since
    (``gps_height_restarts``), which that version never counted: each is given its value before
    the first update (:func:`initial_diagnostics`; a counter 0). A log of today's width is returned
    as it is."""
    logged = np.asarray(logged, dtype=float)
    width = logged.shape[-1]
    if width >= DIAGNOSTICS_SIZE:
        return logged
    missing = np.broadcast_to(initial_diagnostics()[width:], (*logged.shape[:-1], DIAGNOSTICS_SIZE - width))
    return np.concatenate([logged, missing], axis=-1)


STATE_LOG_SIZE = 13


@dataclass(frozen=True)
class EstimatorVocabulary:
    """One estimator's state vocabulary (see the module docstring)."""

    kind: str
    state_names: tuple  # error-state entries, in covariance order (``Est.E.<name>``, ``Est.S.<name>``)
    units: tuple  # unit of each entry
    angles: tuple  # True where the entry is an angle (its error is wrapped to [-pi, pi))
    nees_states: tuple  # indices of the entries the NEES is taken over
    logs: dict  # estimator-specific log name -> width, besides the three common outputs
    errors: Callable  # (logs {name: (n, w)}) -> (n, len(state_names)) estimate minus truth (also (n, N, w))
    extra_values: Callable  # (logs) -> {name: (n,)} estimated values beyond EULER_STATES (also (n, N))

    @property
    def size(self) -> int:
        return len(self.state_names)

    @property
    def nees_dof(self) -> int:
        return len(self.nees_states)

    def log_widths(self) -> dict[str, int]:
        """{log name: width} of every log this estimator exports."""
        widths = {
            "estimated_state": STATE_LOG_SIZE,
            "covariance": self.size**2,
            "diagnostics": DIAGNOSTICS_SIZE,
        }
        widths.update(self.logs)
        return widths

    def unit(self, name) -> str:
        return self.units[self.state_names.index(name)]


def ekf7_errors(logs) -> np.ndarray:
    """(n, 7) x_hat - x_true of the EKF7 (m, m/s, rad; yaw wrapped) from ``ekf_state`` and the
    truth of ``error_sampling.error_truth`` ((n, N, 7) of a fleet batch's (n, N, width) logs)."""
    state = np.asarray(error_truth(logs), dtype=float)
    errors = np.asarray(logs["ekf_state"], dtype=float).copy()
    errors[..., 0:3] -= state[..., 0:3]
    errors[..., 3:6] -= state[..., 7:10]
    errors[..., 6] = wrap_angles(errors[..., 6] - yaw_from_quats(state[..., 3:7]))
    return errors


def eskf_errors(logs) -> np.ndarray:
    """(n, 9 or 15) estimate minus truth of the ESKF's error state ((n, N, 9 or 15) of a batch).

    Against the truth of ``error_sampling.error_truth`` (:func:`nominal_errors` of the nominal the
    logs hold: p, v, q_NB from ``estimated_state``, the biases from ``imu_bias``), the biases only
    when the covariance has 15 states.
    """
    estimate = np.asarray(logs["estimated_state"], dtype=float)
    n = 15 if np.shape(logs["covariance"])[-1] == 15 * 15 else 9
    bias = np.asarray(logs["imu_bias"], dtype=float) if n == 15 else np.zeros(estimate.shape[:-1] + (6,))
    nominal = np.concatenate([estimate[..., 0:3], estimate[..., 7:10], estimate[..., 3:7], bias], axis=-1)
    return nominal_errors(nominal, error_truth(logs), n)


def nominal_errors(nominal, truth, n) -> np.ndarray:
    """(..., n) an ESKF nominal (..., 16: p_N m, v_N m/s, q_NB wxyz, b_a m/s², b_g rad/s) minus the
    true state (..., 13), in the ESKF's error state: dp (m), dv (m/s), the attitude error dtheta
    with R_hat = Exp(dtheta) R_true (rad, world axes) and, when n = 15, the biases against a true
    bias of zero (the simulated IMU has none)."""
    nominal, truth = np.asarray(nominal, dtype=float), np.asarray(truth, dtype=float)
    parts = [nominal[..., 0:3] - truth[..., 0:3], nominal[..., 3:6] - truth[..., 7:10]]
    dtheta = attitude_errors(nominal[..., 6:10].reshape(-1, 4), truth[..., 3:7].reshape(-1, 4))
    parts.append(dtheta.reshape(truth.shape[:-1] + (3,)))
    if n == 15:
        parts.append(nominal[..., 10:16])
    return np.concatenate(parts, axis=-1)


def smoothed_errors(logs) -> np.ndarray:
    """(m, n) the RTS smoother's ``smoothed_state`` (an ESKF nominal, ``flightlogs.smoothing``)
    minus the truth of ``error_sampling.error_truth``, in the error state its ``smoothed_sigma``
    (m, n) names (:func:`nominal_errors`)."""
    return nominal_errors(logs["smoothed_state"], error_truth(logs), np.shape(logs["smoothed_sigma"])[-1])


def _no_extra_values(logs):
    return {}


def _bias_values(logs):
    bias = np.asarray(logs["imu_bias"], dtype=float)
    return {name: bias[..., i] for i, name in enumerate(("BAX", "BAY", "BAZ", "BGX", "BGY", "BGZ"))}


EKF7 = EstimatorVocabulary(
    kind="ekf7",
    state_names=("X", "Y", "Z", "VX", "VY", "VZ", "Yaw"),
    units=("m", "m", "m", "m/s", "m/s", "m/s", "rad"),
    angles=(False,) * 6 + (True,),
    nees_states=tuple(range(7)),
    logs={"attitude": 3, "ekf_state": 7},
    errors=ekf7_errors,
    extra_values=_no_extra_values,
)
"""Complementary filter + 7-state EKF: x = (p_N, v_N, yaw); roll/pitch (no covariance) from the filter."""

_ESKF_NAV = ("X", "Y", "Z", "VX", "VY", "VZ", "AttN", "AttE", "AttD")
_ESKF_NAV_UNITS = ("m", "m", "m", "m/s", "m/s", "m/s", "rad", "rad", "rad")
ESKF9 = EstimatorVocabulary(
    kind="eskf",
    state_names=_ESKF_NAV,
    units=_ESKF_NAV_UNITS,
    angles=(False,) * 6 + (True,) * 3,
    nees_states=tuple(range(9)),
    logs={"imu_bias": 6},
    errors=eskf_errors,
    extra_values=_bias_values,
)
"""Error-state EKF without bias estimation: dp, dv, dtheta (rotation about N, E, D)."""
ESKF15 = EstimatorVocabulary(
    kind="eskf",
    state_names=_ESKF_NAV + ("BAX", "BAY", "BAZ", "BGX", "BGY", "BGZ"),
    units=_ESKF_NAV_UNITS + ("m/s^2",) * 3 + ("rad/s",) * 3,
    angles=(False,) * 6 + (True,) * 3 + (False,) * 6,
    nees_states=tuple(range(9)),  # navigation states: the simulated IMU has no bias to compare with
    logs={"imu_bias": 6},
    errors=eskf_errors,
    extra_values=_bias_values,
)
"""Error-state EKF with accelerometer and gyro bias states (15); NEES over the 9 navigation states."""


def gsf_log_size(models) -> int:
    """Width of the ``gsf`` log of an EKF-GSF yaw estimator of M = `models` hypotheses: the
    Gaussian-sum yaw (rad, NaN before its first GPS sample), its std (rad), the resets of the main
    filter's yaw so far, the M weights (``estimation/gsf.py``)."""
    return 3 + models


def with_gsf(vocabulary, models) -> EstimatorVocabulary:
    """`vocabulary` with the ``gsf`` log of an EKF-GSF of M = `models` hypotheses beside it, read as
    the values ``Est.GsfYaw`` (rad), ``Est.GsfYawStd`` (rad), ``Est.GsfYawErr`` (rad, GSF yaw minus
    the true yaw, wrapped), ``Est.GsfResets`` and ``Est.GsfWeight<j>``."""
    base_values = vocabulary.extra_values

    def extra_values(logs):
        values = dict(base_values(logs))
        log = np.asarray(logs["gsf"], dtype=float)
        values.update({"GsfYaw": log[..., 0], "GsfYawStd": log[..., 1], "GsfResets": log[..., 2]})
        true_yaw = yaw_from_quats(np.asarray(error_truth(logs), dtype=float)[..., 3:7])
        values["GsfYawErr"] = wrap_angles(log[..., 0] - true_yaw)
        values.update({f"GsfWeight{j}": log[..., 3 + j] for j in range(models)})
        return values

    logs = dict(vocabulary.logs, gsf=gsf_log_size(models))
    return dataclasses.replace(vocabulary, logs=logs, extra_values=extra_values)


EULER_STATES = ("X", "Y", "Z", "VX", "VY", "VZ", "Roll", "Pitch", "Yaw")
"""Entries a state can have that ``estimated_state`` alone gives: p_N (m), v_N (m/s), ZYX Euler
angles of the body FRD frame (rad)."""


def euler_errors(names) -> Callable[[dict], np.ndarray]:
    """The errors function ((n, len(names)) estimate minus truth, Euler angles wrapped) of a state
    whose entries `names` are from :data:`EULER_STATES`, read from ``estimated_state``."""
    columns = [EULER_STATES.index(name) for name in names]

    def errors(logs):
        state = np.asarray(error_truth(logs), dtype=float)
        estimate = np.asarray(logs["estimated_state"], dtype=float)
        true_euler = np.stack(euler_from_quats(state[..., 3:7]), axis=-1)
        est_euler = np.stack(euler_from_quats(estimate[..., 3:7]), axis=-1)
        all_errors = np.concatenate(
            [
                estimate[..., 0:3] - state[..., 0:3],
                estimate[..., 7:10] - state[..., 7:10],
                wrap_angles(est_euler - true_euler),
            ],
            axis=-1,
        )
        return all_errors[..., columns]

    return errors


def euler_vocabulary(kind, names) -> EstimatorVocabulary:
    """The EstimatorVocabulary of an estimator whose state entries `names` (from
    :data:`EULER_STATES`) are all read from ``estimated_state`` (a custom estimator's); NEES over
    every entry."""
    names = tuple(names)
    return EstimatorVocabulary(
        kind=kind,
        state_names=names,
        units=tuple(
            "rad" if name in ("Roll", "Pitch", "Yaw") else ("m/s" if name[0] == "V" else "m")
            for name in names
        ),
        angles=tuple(name in ("Roll", "Pitch", "Yaw") for name in names),
        nees_states=tuple(range(len(names))),
        logs={},
        errors=euler_errors(names),
        extra_values=_no_extra_values,
    )


STATE_UNITS = {
    name: unit
    for v in (EKF7, ESKF15, euler_vocabulary("euler", EULER_STATES))
    for name, unit in zip(v.state_names, v.units, strict=True)
}
"""Unit of every error-state name any estimator uses (the names mean the same in each)."""


def health_counts(diagnostics) -> dict[str, int]:
    """{counter: final count} of a ``diagnostics`` log (n, DIAGNOSTICS_SIZE); zeros when empty."""
    diagnostics = np.asarray(diagnostics, dtype=float)
    last = diagnostics[-1] if diagnostics.shape[0] else np.zeros(DIAGNOSTICS_SIZE)
    return {name: int(last[DIAG[name]]) for name in COUNTERS}


def health_line(vehicle, kind, counts) -> str:
    """One console/report line of an estimator's counters; starts with WARNING when the covariance
    was repaired or reset, or the filter reset itself to the GPS."""
    text = (
        f"{vehicle} estimator {kind}: {counts['gps_gated']} GPS and {counts['mag_gated']} mag samples "
        f"gated, {counts['gps_resets']} GPS resets, {counts['covariance_repairs']} covariance repairs, "
        f"{counts['nonfinite_samples']} non-finite samples skipped"
    )
    if counts.get("baro_gated", 0) or counts.get("baro_resets", 0):
        text += f", {counts['baro_gated']} baro samples gated, {counts['baro_resets']} baro bias resets"
    if counts.get("gps_height_restarts", 0):
        restarts = counts["gps_height_restarts"]
        text += f", {restarts} GPS height restarts (the GPS the height reference, after a gap in its samples)"
    alarm = counts["covariance_repairs"] > 0 or counts["gps_resets"] > 0
    return ("WARNING: " if alarm else "") + text
