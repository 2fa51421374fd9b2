"""The barometer and 3-axis magnetometer fusion of N vehicles, compiled: what both estimators run
each tick when the vehicle carries the sensor (``systems.estimators``; one implementation for a
single run and a fleet).

The formulas are ``estimation/baro.py``'s and ``estimation/mag3.py``'s own code compiled by numba
(each module's docstring carries the equations and the design: the ESKF's baro bias as an error
state, the EKF7's as a scalar filter beside it, fed by the GPS heights; the field as a 3-dof gated,
axis-by-axis update of the ESKF's error state; the tilt-compensated heading as the EKF7's yaw
measurement):

- baro, ESKF (``baro_model(..., bias_in_state=True)``), z = h (m): h(x) = -p_z + b (b the nominal
  x[:, 16]), H = -e_2 + e_(n-1), R = height_std², NIS 1 dof; the first finite sample (the
  datum), and any after ``reset_timeout`` s of rejected samples, set b = h + p_z with the bias's
  row and column of P set to the height's (``baro.bias_state_reset``); a GPS height stamped with
  the latest baro sample feeds only the disagreement check below (the ESKF's own GPS update
  learns the bias through P);
- baro, EKF7, z = h - b_hat (m):  h(x) = -p_z,  H = -e_2,  R = height_std²,  NIS 1 dof, then
  P[2, 2] >= P_b (``baro.floored_height_variance``); the first finite sample is not fused: it sets the
  bias against the filter's height (b_meas = h + p_z, variance height_std² + P[2, 2]; fused
  against the prior, or taken as it is with ``datum_from_first_sample``, as PX4 sets its baro
  offset: ``baro.first_datum``);
  the bias: P_b += walk² (t - t_last) at each sample; at each fresh GPS height (same stamp as the
  latest baro sample) b_meas = h + z_gps, variance height_std² + gps_z_std², gated at the baro's
  gate, and not while the GPS-height check's accumulated evidence (Page's CUSUM of
  ``baro.offset_log_likelihood``, ``baro.accumulated_evidence``) says the GPS height disagrees
  persistently (``baro.gps_height_disagrees``); when it first says so the bias goes back to its
  value before the disagreeing run began; after ``reset_timeout`` s of rejected samples
  b = h + p_z, P_b = height_std² + P[2, 2] (and the evidence starts again at 0); the ESKF runs
  the same check on its bias state (b̂ = x[:, 16], innovation variance P_bb + height_std² +
  gps_z_std²) and, when it fires, withholds the GPS height but restores nothing (``baro``
  module docstring);
- field (ESKF), z = m_B - hard_iron (gauss): h(x) = R_hatᵀ m_N, H = [0 R_hatᵀ[m_N]x 0], R =
  diag(field_std²), NIS 3 dof, the gain zero outside the attitude (``attitude_only``, the default)
  and on the tilt too without ``corrects_tilt`` (PX4's on the ground: the heading alone);
- heading (EKF7), z = atan2(-l_y, l_x) + D with l = Ry(pitch) Rx(roll) (m_B - hard_iron) (rad):
  h(x) = x[6], H = e_6, R = the heading's variance from the field noise, NIS 1 dof (logged as
  the magnetometer's), then P[6, 6] >= the heading's variance from the tilt error
  (``mag3.floored_yaw_variance``).

Each ``*_rows`` kernel works IN PLACE on P (N, n, n), the diagnostics and the book, and writes
the correction dx (N, n) of the vehicles it fused (``fused`` (N,) bool): the caller adds it
(EKF7, ``kernels.ekf7.correct``) or injects it (ESKF, ``kernels.eskf.correct``). A non-finite
sample is counted and skipped. The settings a vehicle has of its own (the world field, hard iron
and declination of its magnetometer; its GPS height noise, barometer period and whether it
carries a barometer: replayed flight logs, each with its own) are per-vehicle arrays in the
models, one row per vehicle or a single row for all (:func:`per_vehicle`). Pure: numba and
numpy, no pydrake.
"""

import collections
import math

import numpy as np

from quad_drake.conventions import NO_SAMPLE_STAMP
from quad_drake.estimation import baro, eskf, gating, mag3
from quad_drake.estimation.vocabulary import DIAG
from quad_drake.kernels import rotations
from quad_drake.kernels.jit import compiled, njit_cached

_NONFINITE, _MAG_NIS, _MAG_GATED = DIAG["nonfinite_samples"], DIAG["mag_nis"], DIAG["mag_gated"]
_BARO_NIS, _BARO_GATED, _BARO_RESETS = DIAG["baro_nis"], DIAG["baro_gated"], DIAG["baro_resets"]
_BARO_BIAS, _FIELD_NIS = DIAG["baro_bias"], DIAG["field_nis"]
_BIAS, _BIAS_VAR, _LAST_HEIGHT, _LAST_STAMP = baro.BIAS, baro.BIAS_VAR, baro.LAST_HEIGHT, baro.LAST_STAMP
_REJECTED_SINCE, _GPS_STAMP, _DATUM_SET = baro.REJECTED_SINCE, baro.GPS_STAMP, baro.DATUM_SET
_EVIDENCE_HIGH, _EVIDENCE_LOW = baro.EVIDENCE_HIGH, baro.EVIDENCE_LOW
_TOLERANCE = gating.STAMP_TOLERANCE  # s, stamps are sums of periods
_BARO_NOMINAL = eskf.BARO_BIAS_NOMINAL

_joseph_scalar = compiled(baro.joseph_scalar)
_scalar_correction = compiled(baro.scalar_correction, joseph_scalar=_joseph_scalar)
_bias_state_innovation = compiled(baro.bias_state_innovation)
_bias_state_correction = compiled(baro.bias_state_correction, joseph_scalar=_joseph_scalar)
_bias_state_reset = compiled(baro.bias_state_reset)
_height_innovation = compiled(baro.height_innovation)
_floored_height_variance = compiled(baro.floored_height_variance)
_bias_predict = compiled(baro.bias_predict)
_bias_update = compiled(baro.bias_update)
_bias_from_gps = compiled(baro.bias_from_gps)
_bias_reset = compiled(baro.bias_reset)
_first_datum = compiled(baro.first_datum, bias_reset=_bias_reset, bias_update=_bias_update)
_offset_log_likelihood = compiled(baro.offset_log_likelihood)
_accumulated_evidence = compiled(baro.accumulated_evidence)
_gps_height_disagrees = compiled(baro.gps_height_disagrees)
_field_attitude_jacobian = compiled(mag3.field_attitude_jacobian, rotation_entries=rotations.rotation_entries)
_field_innovation = compiled(
    mag3.field_innovation,
    predicted_field=compiled(mag3.predicted_field, rotation_entries=rotations.rotation_entries),
    field_jacobian=compiled(mag3.field_jacobian, field_attitude_jacobian=_field_attitude_jacobian),
    inverse3=compiled(mag3.inverse3),
)
_sequential_field_update = compiled(mag3.sequential_field_update)
_heading = compiled(mag3.tilt_compensated_heading, leveled_field=compiled(mag3.leveled_field))
_heading_variances = compiled(mag3.heading_variances, heading_jacobians=compiled(mag3.heading_jacobians))
_floored_yaw_variance = compiled(mag3.floored_yaw_variance)
_wrap = rotations.wrap_to_pi


def per_vehicle(values, vectors=False) -> np.ndarray:
    """A model's per-vehicle setting as a float array: (rows,) of scalars, or (rows, k) of vectors
    (``vectors``); one row per vehicle, or one row that every vehicle takes (``_row``)."""
    return np.ascontiguousarray(np.array(values, dtype=float, ndmin=2 if vectors else 1))


@njit_cached
def _row(setting, i):
    """The row of vehicle i in a per-vehicle setting: its own, or the only one."""
    return i if setting.shape[0] > 1 else 0


@njit_cached
def _bias_of(x, P, book, i, in_state):
    """(bias m, its variance m^2) of vehicle i: the filter's state (nominal x[i, 16], P's last
    entry) when it carries the bias, else its baro book's scalar filter."""
    if in_state:
        last = P.shape[1] - 1
        return x[i, _BARO_NOMINAL], P[i, last, last]
    return book[i, _BIAS], book[i, _BIAS_VAR]


@njit_cached
def _gps_height_check(book, i, in_state, innovation, innovation_var, offset, threshold):
    """One GPS height through vehicle i's GPS-height check (``baro`` module docstring): both sides'
    evidence accumulated. The EKF7's scalar filter (not `in_state`) books its bias when a side
    starts a run and, on the sample that first passes `threshold`, goes back to the booked value
    of the side that passed it; the ESKF's bias state is not restored (``baro`` module
    docstring). True while the GPS height agrees with the barometer."""
    was_disagreeing = _gps_height_disagrees(book[i, _EVIDENCE_HIGH], book[i, _EVIDENCE_LOW], threshold)
    cap = 2.0 * threshold
    for side in range(2):
        sign = 1.0 if side == 0 else -1.0
        column = _EVIDENCE_HIGH + side
        if not in_state and book[i, column] == 0.0:  # a new run may start here: the bias before it
            book[i, baro.RUN_BIAS_HIGH + side] = book[i, _BIAS]
            book[i, baro.RUN_BIAS_VAR_HIGH + side] = book[i, _BIAS_VAR]
        log_likelihood = _offset_log_likelihood(sign * innovation, innovation_var, offset)
        book[i, column] = _accumulated_evidence(book[i, column], log_likelihood, cap)
        if not in_state and not was_disagreeing and book[i, column] > threshold:
            book[i, _BIAS] = book[i, baro.RUN_BIAS_HIGH + side]
            book[i, _BIAS_VAR] = book[i, baro.RUN_BIAS_VAR_HIGH + side]
    return not _gps_height_disagrees(book[i, _EVIDENCE_HIGH], book[i, _EVIDENCE_LOW], threshold)


@njit_cached
def _baro_rows(x, P, baro_samples, gps, book, diagnostics, model, dx, fused):
    height_var, gps_z_vars, walk_std, threshold, reset_timeout, stamp_matches = model[:6]
    check_offset, check_threshold, carried, state, datum_from_first_sample = model[6:]
    in_state, from_first_sample = state > 0.0, datum_from_first_sample > 0.0
    for i in range(x.shape[0]):
        fused[i] = False
        if not carried[_row(carried, i)]:  # a vehicle without a barometer: as if it had no update
            continue
        gps_z_var, stamp_match = gps_z_vars[_row(gps_z_vars, i)], stamp_matches[_row(stamp_matches, i)]
        stamp = baro_samples[i, 1]
        if stamp != NO_SAMPLE_STAMP and stamp != book[i, _LAST_STAMP]:
            previous = book[i, _LAST_STAMP]
            if not in_state and previous != NO_SAMPLE_STAMP and math.isfinite(stamp):
                book[i, _BIAS_VAR] = _bias_predict(book[i, _BIAS_VAR], stamp - previous, walk_std)
            book[i, _LAST_STAMP] = stamp
            height = baro_samples[i, 0]
            book[i, _LAST_HEIGHT] = height
            if not (math.isfinite(height) and math.isfinite(stamp)):
                diagnostics[i, _NONFINITE] += 1.0
            elif book[i, _DATUM_SET] == 0.0:  # the first finite sample sets the datum (module docstring)
                if in_state:  # b = h + p_z, correlated with the height (the filter's height kept)
                    x[i, _BARO_NOMINAL] = _bias_reset(height, x[i, 2], height_var, P[i, 2, 2])[0]
                    P[i] = _bias_state_reset(P[i], height_var)
                else:
                    book[i, _BIAS], book[i, _BIAS_VAR] = _first_datum(
                        book[i, _BIAS],
                        book[i, _BIAS_VAR],
                        height,
                        x[i, 2],
                        height_var,
                        P[i, 2, 2],
                        from_first_sample,
                    )
                book[i, _DATUM_SET] = 1.0
            else:
                if in_state:
                    nu, S = _bias_state_innovation(x[i, 2], x[i, _BARO_NOMINAL], P[i], height, height_var)
                else:
                    nu, S = _height_innovation(x[i, 2], P[i], height, book[i, _BIAS], height_var)
                nis = nu * nu / S
                diagnostics[i, _BARO_NIS], diagnostics[i, _BARO_NIS + 1] = nis, stamp
                if nis <= threshold:
                    if in_state:
                        dx[i], P[i], _ = _bias_state_correction(P[i], nu, S)
                    else:
                        correction, P_new, _ = _scalar_correction(P[i], baro.HEIGHT_INDEX, -1.0, nu, S)
                        P_new[2, 2] = _floored_height_variance(P_new[2, 2], book[i, _BIAS_VAR])
                        P[i] = P_new
                        dx[i] = correction
                    fused[i] = True
                    book[i, _REJECTED_SINCE] = math.nan
                else:
                    diagnostics[i, _BARO_GATED] += 1.0
                    since = book[i, _REJECTED_SINCE]
                    if math.isnan(since):
                        book[i, _REJECTED_SINCE] = stamp
                    elif reset_timeout > 0.0 and stamp - since >= reset_timeout - _TOLERANCE:
                        bias, bias_var = _bias_reset(height, x[i, 2], height_var, P[i, 2, 2])
                        if in_state:
                            x[i, _BARO_NOMINAL] = bias
                            P[i] = _bias_state_reset(P[i], height_var)
                        else:
                            book[i, _BIAS], book[i, _BIAS_VAR] = bias, bias_var
                        book[i, _REJECTED_SINCE] = math.nan
                        book[i, _EVIDENCE_HIGH] = book[i, _EVIDENCE_LOW] = 0.0
                        diagnostics[i, _BARO_RESETS] += 1.0
        gps_stamp = gps[i, 6]
        if gps_stamp != NO_SAMPLE_STAMP and gps_stamp != book[i, _GPS_STAMP]:
            book[i, _GPS_STAMP] = gps_stamp
            matched = abs(gps_stamp - book[i, _LAST_STAMP]) <= stamp_match
            if matched and math.isfinite(gps[i, 2]) and math.isfinite(book[i, _LAST_HEIGHT]):
                bias, bias_var = _bias_of(x, P, book, i, in_state)
                measured = _bias_from_gps(book[i, _LAST_HEIGHT], gps[i, 2])
                variance = height_var + gps_z_var
                innovation = measured - bias
                agrees = True
                if check_offset > 0.0:
                    agrees = _gps_height_check(
                        book, i, in_state, innovation, bias_var + variance, check_offset, check_threshold
                    )
                if not in_state and agrees and innovation * innovation <= threshold * (bias_var + variance):
                    book[i, _BIAS], book[i, _BIAS_VAR] = _bias_update(
                        book[i, _BIAS], book[i, _BIAS_VAR], measured, variance
                    )
        bias, bias_var = _bias_of(x, P, book, i, in_state)
        diagnostics[i, _BARO_BIAS] = bias
        diagnostics[i, _BARO_BIAS + 1] = math.sqrt(bias_var)


def baro_rows(x, P, baro_samples, gps, book, diagnostics, model, dx, fused) -> None:
    """One tick of the barometer fusion of N filters (module docstring) IN PLACE on P (N, n, n),
    book (N, ``baro.BARO_BOOK_SIZE``) and diagnostics (and x's baro bias at a bias reset, when the
    filter carries it); the corrections of the fused vehicles into dx (N, n) and fused (N,).
    x (N, width): p_z is x[:, 2] in both estimators, the ESKF's baro bias x[:, 16]; baro_samples
    (N, 2: height m, stamp s); gps (N, 7: p m, v m/s, stamp s); model: :func:`baro_model`."""
    _baro_rows(x, P, baro_samples, gps, book, diagnostics, model, dx, fused)


def baro_model(params, gps_z_std, gate_threshold, baro_period, carried=True, bias_in_state=False) -> tuple:
    """The baro kernel's constants from BaroFusionParams: (height_var m², gps_z_var m² per vehicle,
    walk_std m/sqrt(s), the gate's NIS threshold, reset_timeout s, stamp_match s per vehicle: half
    the baro period, the largest stamp difference of a baro sample and a GPS sample taken as
    simultaneous, the GPS-height check's gps_check_offset m (0 = off) and gps_check_threshold,
    carried per vehicle: 0 for a vehicle without a barometer, whose row the kernel leaves as it is,
    and 1.0 when the filter carries the bias in its state (`bias_in_state`: the ESKF,
    ``eskf.carries_baro_bias``), 0.0 when the scalar filter in the book estimates it (the EKF7)),
    and 1.0 when the EKF7's first sample sets its datum as it is (``datum_from_first_sample``).
    gps_z_std (m), baro_period (s) and carried: one value for every vehicle or one per vehicle
    (:func:`per_vehicle`)."""
    return (
        float(params.height_std) ** 2,
        per_vehicle(gps_z_std) ** 2,
        float(params.bias_walk_std),
        float(gate_threshold),
        float(params.reset_timeout),
        0.5 * per_vehicle(baro_period),
        float(params.gps_check_offset),
        float(params.gps_check_threshold),
        np.array(carried, dtype=np.bool_, ndmin=1),
        1.0 if bias_in_state else 0.0,
        1.0 if params.datum_from_first_sample else 0.0,
    )


@njit_cached
def _fresh_field(mag, book, slot, diagnostics, i):
    """True when vehicle i has a fresh finite 3-axis sample (N, 4: m_B gauss, stamp s); books its
    stamp in book[i, slot] and counts a non-finite one."""
    stamp = mag[i, 3]
    if stamp == NO_SAMPLE_STAMP or stamp == book[i, slot]:
        return False
    book[i, slot] = stamp
    if not (math.isfinite(stamp) and math.isfinite(mag[i, 0] + mag[i, 1] + mag[i, 2])):
        diagnostics[i, _NONFINITE] += 1.0
        return False
    return True


@njit_cached
def _field_rows(x, P, mag, book, slot, diagnostics, model, dx, fused):
    world_fields, hard_irons, field_var, threshold, attitude_only, corrects_tilt = model
    for i in range(x.shape[0]):
        fused[i] = False
        if not _fresh_field(mag, book, slot, diagnostics, i):
            continue
        q = (x[i, 6], x[i, 7], x[i, 8], x[i, 9])
        m_B = (mag[i, 0], mag[i, 1], mag[i, 2])
        w, h = _row(world_fields, i), _row(hard_irons, i)
        m_N = (world_fields[w, 0], world_fields[w, 1], world_fields[w, 2])
        hard_iron = (hard_irons[h, 0], hard_irons[h, 1], hard_irons[h, 2])
        nu, H, _, nis = _field_innovation(q, P[i], m_B, m_N, hard_iron, field_var)
        if math.isnan(nis):
            diagnostics[i, _NONFINITE] += 1.0
            continue
        diagnostics[i, _FIELD_NIS], diagnostics[i, _FIELD_NIS + 1] = nis, mag[i, 3]
        if nis <= threshold:
            correction, P_new = _sequential_field_update(P[i], nu, H, field_var, attitude_only, corrects_tilt)
            P[i] = P_new
            dx[i] = correction
            fused[i] = True
        else:
            diagnostics[i, _MAG_GATED] += 1.0


def field_rows(x, P, mag, book, slot, diagnostics, model, dx, fused) -> None:
    """One tick of the ESKF's 3-axis field fusion of N filters IN PLACE (module docstring): x (N,
    16) nominal states (q_NB at 6..9), P (N, n, n), mag (N, 4: m_B gauss, stamp s), book[:, slot]
    the last field stamp seen; the corrections into dx (N, n), fused (N,). model:
    :func:`field_model`."""
    _field_rows(x, P, mag, book, slot, diagnostics, model, dx, fused)


def field_model(params, gate_threshold) -> tuple:
    """(m_N (rows, 3) gauss NED, hard_iron (rows, 3) gauss FRD, field_var (3-tuple, gauss²),
    threshold, attitude_only, corrects_tilt) of MagFieldFusionParams: one, or a sequence of
    one per vehicle that differ only in their world field and hard iron (:func:`per_vehicle`;
    the others' figures are the first's)."""
    each = _each(params)
    first = each[0]
    return (
        per_vehicle([mag3.assumed_world_field(p) for p in each], vectors=True),
        per_vehicle([p.hard_iron for p in each], vectors=True),
        tuple(float(s) ** 2 for s in first.field_std),
        float(gate_threshold),
        bool(first.attitude_only),
        bool(first.corrects_tilt),
    )


def _each(params) -> tuple:
    """A model's MagFieldFusionParams as a tuple: one per vehicle, or the one of all."""
    return tuple(params) if isinstance(params, (list, tuple)) else (params,)


@njit_cached
def _heading_rows(x, P, mag, attitude, book, slot, diagnostics, model, dx, fused):
    hard_irons, field_var, declinations, tilt_var, threshold = model
    for i in range(x.shape[0]):
        fused[i] = False
        if not _fresh_field(mag, book, slot, diagnostics, i):
            continue
        h = _row(hard_irons, i)
        hard_iron = (hard_irons[h, 0], hard_irons[h, 1], hard_irons[h, 2])
        declination = declinations[_row(declinations, i)]
        mx, my, mz = mag[i, 0] - hard_iron[0], mag[i, 1] - hard_iron[1], mag[i, 2] - hard_iron[2]
        roll, pitch = attitude[i, 0], attitude[i, 1]
        heading = _heading(roll, pitch, mx, my, mz, declination)
        r, tilt_part = _heading_variances(roll, pitch, mx, my, mz, field_var, tilt_var)
        nu = _wrap(heading - x[i, 6])
        S = P[i, 6, 6] + r
        nis = nu * nu / S
        if not math.isfinite(nis):
            diagnostics[i, _NONFINITE] += 1.0
            continue
        diagnostics[i, _MAG_NIS], diagnostics[i, _MAG_NIS + 1] = nis, mag[i, 3]
        if nis <= threshold:
            correction, P_new, _ = _scalar_correction(P[i], 6, 1.0, nu, S)
            P_new[6, 6] = _floored_yaw_variance(P_new[6, 6], tilt_part)
            P[i] = P_new
            dx[i] = correction
            fused[i] = True
        else:
            diagnostics[i, _MAG_GATED] += 1.0


def heading_rows(x, P, mag, attitude, book, slot, diagnostics, model, dx, fused) -> None:
    """One tick of the EKF7's tilt-compensated heading fusion of N filters IN PLACE (module
    docstring): x (N, 7), P (N, 7, 7), mag (N, 4: m_B gauss, stamp s), attitude (N, 3: roll,
    pitch, yaw rad, the attitude filter's), book[:, slot] the last field stamp seen; the
    corrections into dx (N, 7), fused (N,). model: a :class:`HeadingModel`."""
    _heading_rows(x, P, mag, attitude, book, slot, diagnostics, tuple(model), dx, fused)


HeadingModel = collections.namedtuple(
    "HeadingModel", ["hard_iron", "field_var", "declination", "tilt_var", "threshold"]
)
"""The heading kernel's constants: hard_iron (rows, 3) gauss, field_var (3, gauss²), declination
(rows,) rad, tilt_var rad² (the attitude's roll/pitch error variance), threshold (the gate's NIS
threshold); rows: one per vehicle or one for all (:func:`per_vehicle`)."""


def heading_model(params, gate_threshold) -> HeadingModel:
    """The :class:`HeadingModel` of MagFieldFusionParams (one, or one per vehicle that differ only in
    their hard iron and declination, as :func:`field_model`'s) and a gate's NIS threshold."""
    each = _each(params)
    return HeadingModel(
        per_vehicle([p.hard_iron for p in each], vectors=True),
        tuple(float(s) ** 2 for s in each[0].field_std),
        per_vehicle([p.declination for p in each]),
        float(each[0].tilt_std) ** 2,
        float(gate_threshold),
    )
