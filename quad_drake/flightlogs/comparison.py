"""Pure: a replayed estimate judged without truth.

The flight controller's own estimate (PX4's ``vehicle_attitude`` and ``vehicle_local_position``)
is the reference: another estimator, not the truth, so a difference is the two estimators'
disagreement, bounded by both their errors. Per state: the RMS and max |difference| and the
RMS of our estimator's σ over the same samples (how large it believes its own error is).
Consistency needs no truth: the NIS of each sensor's updates, whose mean over m independent
updates lies in the χ²(dof m)/m band when the filter's innovation covariance is right, and 95 %
of single updates in the χ²(dof) 95 % band.

Our estimate is logged every LOG_PERIOD; a logged sample at t is the estimate through the IMU
samples before t, and it is interpolated linearly (angles unwrapped) to the reference's sample
times. Samples before ``compare_after`` s (the estimators' start-up from the first samples) and
reference entries PX4 marks invalid (NaN) are not compared.
"""

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from quad_drake.estimation.vocabulary import NIS_DOF
from quad_drake.judging.consistency import chi2_band, fresh_nis
from quad_drake.models.rotations import euler_from_quats, wrap_angles

ATTITUDE_STATES = ("Roll", "Pitch", "Yaw")
POSITION_STATES = ("X", "Y", "Z", "VX", "VY", "VZ")
UNITS = {"Roll": "rad", "Pitch": "rad", "Yaw": "rad", "X": "m", "Y": "m", "Z": "m"} | {
    f"V{axis}": "m/s" for axis in "XYZ"
}


@dataclass(frozen=True)
class StateDifference:
    """Our estimate minus the reference for one state over `count` compared samples."""

    state: str
    unit: str
    count: int
    rms: float
    max_abs: float
    sigma_rms: float  # RMS of our estimator's σ at those samples; NaN where it has none
    within_2sigma: float  # share of |difference| <= 2 σ (NaN without σ)
    times: np.ndarray  # (count,) s
    differences: np.ndarray  # (count,)
    reason: str = ""  # why nothing was compared (count 0): "n/a: ..."; "" when compared

    def figure(self, value, digits=4) -> str:
        """`value` (one of this difference's figures) as text: the number, or the n/a reason."""
        return self.reason if self.count == 0 else f"{value:.{digits}f}"


VALIDITY_FLAGS = {
    "X": "xy_valid",
    "Y": "xy_valid",
    "Z": "z_valid",
    "VX": "v_xy_valid",
    "VY": "v_xy_valid",
    "VZ": "v_z_valid",
}
"""The ``vehicle_local_position`` flag by which PX4 marks each state valid."""


@dataclass(frozen=True)
class NisSummary:
    """The NIS of one sensor's fresh updates: mean and its χ² band, the share in the single-update band."""

    sensor: str
    dof: int
    count: int
    mean: float
    band: tuple  # (low, high) 95 % band of the mean of `count` independent χ²(dof)
    in_band: bool  # the mean inside `band`
    single_share: float  # share of updates inside the single-update 95 % band
    times: np.ndarray  # (count,) s, the updates' stamps
    values: np.ndarray  # (count,)


def estimate_angles(estimated_state) -> np.ndarray:
    """(n, 3) roll, pitch, yaw (rad) of an ``estimated_state`` log (n, 13)."""
    roll, pitch, yaw = euler_from_quats(np.asarray(estimated_state)[:, 3:7])
    return np.column_stack([roll, pitch, yaw])


def attitude_sigmas(vocabulary, covariance, yaw) -> np.ndarray:
    """(n, 3) our σ of roll, pitch, yaw (rad) from a covariance log (n, k*k): the EKF7 has a yaw σ
    only (its roll and pitch come from the complementary filter: NaN); the ESKF's rotation error
    about N, E, D, turned into the heading frame (roll about the heading's x, pitch about its y)."""
    k = vocabulary.size
    P = np.asarray(covariance, dtype=float).reshape(-1, k, k)
    sigmas = np.full((len(P), 3), np.nan)
    names = vocabulary.state_names
    if "AttN" in names:
        n, e, d = (names.index(s) for s in ("AttN", "AttE", "AttD"))
        c, s = np.cos(yaw), np.sin(yaw)
        pnn, pee, pne = P[:, n, n], P[:, e, e], P[:, n, e]
        sigmas[:, 0] = np.sqrt(np.maximum(c * c * pnn + 2 * c * s * pne + s * s * pee, 0.0))
        sigmas[:, 1] = np.sqrt(np.maximum(s * s * pnn - 2 * c * s * pne + c * c * pee, 0.0))
        sigmas[:, 2] = np.sqrt(np.maximum(P[:, d, d], 0.0))
    elif "Yaw" in names:
        sigmas[:, 2] = np.sqrt(np.maximum(P[:, names.index("Yaw"), names.index("Yaw")], 0.0))
    return sigmas


def state_sigmas(vocabulary, covariance, states) -> np.ndarray:
    """(n, len(states)) our σ of each named state from a covariance log (n, k*k); NaN for a state
    the vocabulary does not name."""
    k = vocabulary.size
    P = np.asarray(covariance, dtype=float).reshape(-1, k, k)
    names = vocabulary.state_names
    sigmas = np.full((len(P), len(states)), np.nan)
    for column, state in enumerate(states):
        if state in names:
            i = names.index(state)
            sigmas[:, column] = np.sqrt(np.maximum(P[:, i, i], 0.0))
    return sigmas


def _interpolated(times, values, at, angle=False):
    """(m,) `values` (n,) at `times` (n,), linearly at the times `at` (m,); angles unwrapped first
    and wrapped after."""
    if angle:
        return wrap_angles(np.interp(at, times, np.unwrap(values)))
    return np.interp(at, times, values)


def missing_reason(state, times, ref_times, reference, compare_after) -> str:
    """Why nothing of `state` is compared ("n/a: ..."), given our log's `times` and the reference's
    `ref_times` and values `reference` (NaN: invalid); "" when something is."""
    window = (ref_times >= max(compare_after, times[0])) & (ref_times <= times[-1])
    if times[-1] < compare_after:
        return f"n/a: the log ends at {times[-1]:.1f} s, before the comparison starts ({compare_after:g} s)"
    if not window.any():
        return f"n/a: no PX4 sample between {compare_after:g} s and the log's end"
    if not np.isfinite(reference[window]).any():
        flag = VALIDITY_FLAGS.get(state)
        marked = f" ({flag} = 0)" if flag else ""
        return f"n/a: PX4 marks it invalid throughout{marked}"
    return ""


def unavailable(state, reason) -> StateDifference:
    """The StateDifference of a state not compared, for `reason` ("n/a: ...")."""
    nan, empty = math.nan, np.zeros(0)
    return StateDifference(state, UNITS[state], 0, nan, nan, nan, nan, empty, empty, reason)


def _difference(state, times, ours, sigma, ref_times, reference, compare_after, angle):
    """StateDifference of our (n,) `ours` and σ at `times` against `reference` at `ref_times`."""
    reason = missing_reason(state, times, ref_times, reference, compare_after)
    if reason:
        return unavailable(state, reason)
    keep = (ref_times >= max(compare_after, times[0])) & (ref_times <= times[-1]) & np.isfinite(reference)
    at = ref_times[keep]
    difference = _interpolated(times, ours, at, angle) - reference[keep]
    if angle:
        difference = wrap_angles(difference)
    s = np.interp(at, times, sigma) if np.isfinite(sigma).any() else np.full(len(at), np.nan)
    with np.errstate(invalid="ignore"):
        within = float(np.mean(np.abs(difference) <= 2.0 * s)) if np.isfinite(s).all() else math.nan
    return StateDifference(
        state,
        UNITS[state],
        len(at),
        float(np.sqrt(np.mean(difference**2))),
        float(np.max(np.abs(difference))),
        float(np.sqrt(np.mean(s**2))),
        within,
        at,
        difference,
    )


def compare_attitude(vocabulary, times, logs, reference, compare_after) -> list[StateDifference]:
    """[StateDifference] of roll, pitch, yaw against the reference attitude Samples (q_NB wxyz)."""
    angles = estimate_angles(logs["estimated_state"])
    sigmas = attitude_sigmas(vocabulary, logs["covariance"], angles[:, 2])
    ref = np.column_stack(euler_from_quats(reference.values))
    return [
        _difference(state, times, angles[:, i], sigmas[:, i], reference.times, ref[:, i], compare_after, True)
        for i, state in enumerate(ATTITUDE_STATES)
    ]


def compare_position(
    vocabulary, times, logs, reference, compare_after, horizontal=""
) -> list[StateDifference]:
    """[StateDifference] of x, y, z, vx, vy, vz against the reference position Samples;
    horizontal: "" to compare x and y, else why not ("n/a: ...", e.g. a log without GPS)."""
    state = np.asarray(logs["estimated_state"], dtype=float)
    ours = np.column_stack([state[:, 0:3], state[:, 7:10]])
    sigmas = state_sigmas(vocabulary, logs["covariance"], POSITION_STATES)
    return [
        unavailable(name, horizontal)
        if horizontal and name in ("X", "Y")
        else _difference(
            name,
            times,
            ours[:, i],
            sigmas[:, i],
            reference.times,
            reference.values[:, i],
            compare_after,
            False,
        )
        for i, name in enumerate(POSITION_STATES)
    ]


def nis_summary(diagnostics, sensor, compare_after=0.0, probability=0.95) -> NisSummary | None:
    """NisSummary of the fresh `sensor` ("gps" or "mag") updates in a diagnostics log from
    compare_after s on; None when there are none."""
    stamps, values = fresh_nis(diagnostics, sensor)
    keep = (stamps >= compare_after) & np.isfinite(values)
    stamps, values = stamps[keep], values[keep]
    if not len(values):
        return None
    dof = NIS_DOF[sensor]
    band = chi2_band(dof, len(values), probability)
    tail = (1.0 - probability) / 2.0
    low, high = chi2.ppf([tail, 1.0 - tail], dof)
    mean = float(np.mean(values))
    single = float(np.mean((values >= low) & (values <= high)))
    return NisSummary(
        sensor, dof, len(values), mean, band, band[0] <= mean <= band[1], single, stamps, values
    )


INNOVATION_NAMES = {"gps": POSITION_STATES, "mag": ("Yaw",)}
"""The components of each sensor's innovation: GPS p_N (m), v_N (m/s); magnetometer yaw (rad)."""


def fresh_rows(samples, compare_after=0.0) -> np.ndarray:
    """Indices of the log rows of a stamped sensor log (n, k+1: values, stamp) where a fresh,
    finite sample stamped at or after compare_after s first shows (never row 0: the row before
    it holds the estimate the sample is compared with)."""
    stamps = samples[:, -1]
    fresh = np.flatnonzero((np.diff(stamps, prepend=-math.inf) > 0) & (stamps >= max(compare_after, 0.0)))
    return fresh[(fresh > 0) & np.isfinite(samples[fresh, :-1]).all(axis=1)]


def innovations(logs, sensor, compare_after=0.0) -> tuple[np.ndarray, np.ndarray]:
    """(stamps (m,) s, innovations (m, k)) of each fresh `sensor` sample ("gps" or "mag") in the
    replay's logs from compare_after s on: the sample minus our estimate logged before it arrived
    (the prior to within one LOG_PERIOD, 5 ms; the yaw difference wrapped), in the order of
    :data:`INNOVATION_NAMES`. Empty when the log has no such samples."""
    samples, estimate = logs[sensor], logs["estimated_state"]
    fresh = fresh_rows(samples, compare_after)
    before = fresh - 1  # the row logged before the sample arrived
    if sensor == "gps":
        predicted = np.column_stack([estimate[before, 0:3], estimate[before, 7:10]])
        values = samples[fresh, 0:6] - predicted
    else:
        yaw = euler_from_quats(estimate[before, 3:7])[2]
        values = wrap_angles(samples[fresh, 0] - yaw)[:, None]
    return samples[fresh, -1], values


TRUTH_STATES = ATTITUDE_STATES + POSITION_STATES
"""The states judged against a simulator's ground truth."""
NEES_BLOCKS = {"position": ("X", "Y", "Z"), "velocity": ("VX", "VY", "VZ")}
"""Our covariance blocks whose NEES against the ground truth is judged (m, m/s)."""


@dataclass(frozen=True)
class TruthError:
    """Ours and PX4's estimate minus the simulator's ground truth for one state, at our logged
    times from compare_after s on: RMS of each (NaN where one is not available), count of samples."""

    state: str
    unit: str
    count: int
    ours_rms: float
    px4_rms: float
    reason: str = ""  # "n/a: ..." when nothing was judged

    def figure(self, value, digits=4) -> str:
        """`value` as text: the number, or the n/a reason (PX4's: "n/a" where PX4 marks it invalid)."""
        if self.count == 0:
            return self.reason
        return f"{value:.{digits}f}" if math.isfinite(value) else "n/a"


@dataclass(frozen=True)
class NeesSummary:
    """Our NEES of one covariance block against the ground truth: mean over `count` logged samples
    and the χ²(dof) band of a mean of that many independent samples (the samples are correlated
    over time, so the band is a guide, not a test)."""

    block: str
    dof: int
    count: int
    mean: float
    band: tuple
    in_band: bool


def _truth_columns(log, times):
    """(n, 9) the ground truth's roll, pitch, yaw, p_N, v_N at our logged `times` (NaN outside its
    span or where it has none)."""
    columns = np.full((len(times), len(TRUTH_STATES)), np.nan)
    if log.truth_attitude is not None:
        angles = np.column_stack(euler_from_quats(log.truth_attitude.values))
        span = (times >= log.truth_attitude.times[0]) & (times <= log.truth_attitude.times[-1])
        for i in range(3):
            columns[span, i] = _interpolated(log.truth_attitude.times, angles[:, i], times[span], True)
    if log.truth_position is not None:
        truth = log.truth_position
        span = (times >= truth.times[0]) & (times <= truth.times[-1])
        for i in range(6):
            finite = np.isfinite(truth.values[:, i])
            if finite.any():
                columns[span, 3 + i] = np.interp(times[span], truth.times[finite], truth.values[finite, i])
    return columns


def _reference_columns(log, times):
    """(n, 9) PX4's roll, pitch, yaw, p_N, v_N at our logged `times` (NaN where invalid or absent)."""
    columns = np.full((len(times), len(TRUTH_STATES)), np.nan)
    if log.reference_attitude is not None:
        ref = log.reference_attitude
        angles = np.column_stack(euler_from_quats(ref.values))
        span = (times >= ref.times[0]) & (times <= ref.times[-1])
        for i in range(3):
            columns[span, i] = _interpolated(ref.times, angles[:, i], times[span], True)
    if log.reference_position is not None:
        ref = log.reference_position
        for i in range(6):
            finite = np.isfinite(ref.values[:, i])
            if finite.any():
                span = (times >= ref.times[finite][0]) & (times <= ref.times[finite][-1])
                columns[span, 3 + i] = np.interp(times[span], ref.times[finite], ref.values[finite, i])
    return columns


def _our_columns(logs):
    """(n, 9) our roll, pitch, yaw, p_N, v_N of a replay's logs."""
    state = np.asarray(logs["estimated_state"], dtype=float)
    return np.column_stack([estimate_angles(state), state[:, 0:3], state[:, 7:10]])


def truth_errors(times, logs, log, compare_after) -> list[TruthError]:
    """[TruthError] of ours and PX4's estimates against a FlightLog's ground truth (module
    docstring), at our logged `times` from compare_after s on; [] without a ground truth."""
    if log.truth_attitude is None and log.truth_position is None:
        return []
    truth, ours, px4 = _truth_columns(log, times), _our_columns(logs), _reference_columns(log, times)
    late = times >= compare_after
    errors = []
    for i, state in enumerate(TRUTH_STATES):
        keep = late & np.isfinite(truth[:, i])
        if not keep.any():
            reason = "n/a: the ground truth has no " + ("position without a fix" if i in (3, 4, 5) else state)
            errors.append(TruthError(state, UNITS[state], 0, math.nan, math.nan, reason))
            continue
        angle = i < 3
        ours_error = ours[keep, i] - truth[keep, i]
        px4_error = px4[keep, i] - truth[keep, i]
        if angle:
            ours_error, px4_error = wrap_angles(ours_error), wrap_angles(px4_error)
        finite = np.isfinite(px4_error)
        px4_rms = float(np.sqrt(np.mean(px4_error[finite] ** 2))) if finite.any() else math.nan
        errors.append(
            TruthError(state, UNITS[state], int(keep.sum()), float(np.sqrt(np.mean(ours_error**2))), px4_rms)
        )
    return errors


def truth_nees(vocabulary, times, logs, log, compare_after, probability=0.95) -> list[NeesSummary]:
    """[NeesSummary] of our position and velocity blocks (those the vocabulary names) against the
    ground truth from compare_after s on; [] without a ground truth position."""
    if log.truth_position is None:
        return []
    truth, ours = _truth_columns(log, times), _our_columns(logs)
    k = vocabulary.size
    P = np.asarray(logs["covariance"], dtype=float).reshape(-1, k, k)
    summaries = []
    for block, states in NEES_BLOCKS.items():
        if not all(s in vocabulary.state_names for s in states):
            continue
        index = [vocabulary.state_names.index(s) for s in states]
        columns = [TRUTH_STATES.index(s) for s in states]
        error = ours[:, columns] - truth[:, columns]
        keep = (times >= compare_after) & np.isfinite(error).all(axis=1)
        if not keep.any():
            continue
        block_P = P[keep][:, index][:, :, index]
        nees = np.einsum("ni,ni->n", error[keep], np.linalg.solve(block_P, error[keep][:, :, None])[:, :, 0])
        band = chi2_band(len(states), int(keep.sum()), probability)
        mean = float(np.mean(nees))
        summaries.append(
            NeesSummary(block, len(states), int(keep.sum()), mean, band, band[0] <= mean <= band[1])
        )
    return summaries
