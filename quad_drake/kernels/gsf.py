"""The EKF-GSF yaw estimator of N vehicles beside their ESKFs, compiled (``estimation/gsf.py``
carries the equations and the matrix-form oracles this is tested against to 1e-12).

Each vehicle's GSF lives in one row of its book (N, :func:`book_size`): the header columns
(:data:`YAW` ... :data:`MAG_GATED`), then its bank of M models: X_j (3: v_N, v_E m/s, psi rad)
at ``HEADER + 3 j``, P_j (3 x 3 row-major) at ``HEADER + 3 M + 9 j``, w_j at ``HEADER + 12 M + j``.
Per tick, after the ESKF's prediction (:func:`tick`): the bank starts at the first fresh GPS
sample, is predicted with the IMU sample and the ESKF's roll and pitch, fuses a fresh GPS
velocity, and gives its Gaussian-sum yaw; the magnetometer's fate (fused or gated, read from the
ESKF's ``diagnostics``) says whether the yaw is aligned; the reset rule then may set the ESKF's
yaw (and its down-axis attitude covariance) to the GSF's. Each step per vehicle is a loop over
the M models' few nonzeros (rule 3 of ``kernels/__init__.py``: it runs every tick).
Pure: numba and numpy, no pydrake.
"""

import collections
import math

import numpy as np

from quad_drake.conventions import NO_SAMPLE_STAMP
from quad_drake.estimation import gsf
from quad_drake.kernels import rotations
from quad_drake.kernels.fusion import fresh
from quad_drake.kernels.jit import compiled, njit_cached

YAW, YAW_VAR, STARTED, GPS_STAMP, RESETS, ALIGNED = range(6)
MAG_BLOCKED, DISAGREE_SINCE, MAG_STAMP, MAG_GATED = range(6, 10)
"""Header columns of a vehicle's GSF book: the Gaussian-sum yaw (rad, NaN before the start) and
its variance (rad^2); 1 once the bank has started; the last GPS stamp seen (s); the resets of the
main filter's yaw so far; 1 once a magnetometer sample or a reset aligned the yaw; 1 once the
magnetometer is no longer fused (after a ``DISAGREE`` reset); since when (s, NaN: not) the yaws
disagree; the last magnetometer stamp and gated count seen in the ESKF's diagnostics."""
HEADER = 10

Model = collections.namedtuple(
    "Model",
    [
        "models", "dt", "accel_noise", "gyro_noise", "vel_var", "max_yaw_var", "yaw_disagreement",
        "disagreement_time", "max_resets", "mag_stamp_column", "mag_gated_column",
    ],
)  # fmt: skip
"""The constants of :func:`tick`: M, dt s, accel_noise m/s^2, gyro_noise rad/s, vel_var (m/s)^2
(the GPS velocity variance the bank assumes), max_yaw_var rad^2, yaw_disagreement rad,
disagreement_time s, max_resets, and the ESKF ``diagnostics`` columns of the magnetometer's last
stamp and gated count (-1: the vehicle has no magnetometer)."""

_level_delta_velocity = compiled(gsf.level_delta_velocity)
_yaw_increment = compiled(gsf.yaw_increment)
_disagreement_start = compiled(gsf.disagreement_start, wrap_to_pi=rotations.wrap_to_pi)
_reset_reason = compiled(gsf.reset_reason)
_yaw_reset_quaternion = compiled(
    gsf.yaw_reset_quaternion, quat_product=rotations.quat_product, wrap_to_pi=rotations.wrap_to_pi
)
_CLIP = gsf.INNOVATION_CLIP_NIS
_ALIGN, _DISAGREE = gsf.ALIGN, gsf.DISAGREE


def book_size(models) -> int:
    """Columns of one vehicle's GSF book with M = `models`."""
    return HEADER + 13 * models


def initial_book(models) -> np.ndarray:
    """One vehicle's GSF book before its first tick: not started, nothing seen."""
    book = np.zeros(book_size(models))
    book[YAW] = book[YAW_VAR] = book[DISAGREE_SINCE] = math.nan
    book[GPS_STAMP], book[MAG_STAMP] = NO_SAMPLE_STAMP, -1.0
    return book


@njit_cached
def _log_row(book, i, M, log):
    """Vehicle i's log row (``vocabulary.gsf_log_size(M)``): the Gaussian-sum yaw (rad), its std
    (rad), the resets so far and the M weights, written from its book row."""
    log[i, 0], log[i, 1], log[i, 2] = book[i, YAW], math.sqrt(book[i, YAW_VAR]), book[i, RESETS]
    w = HEADER + 12 * M
    for j in range(M):
        log[i, 3 + j] = book[i, w + j]


@njit_cached
def _log_rows(book, M, log):
    for i in range(book.shape[0]):
        _log_row(book, i, M, log)


def log_rows(book, models) -> np.ndarray:
    """The log rows (N, ``vocabulary.gsf_log_size(models)``) of GSF books (N, :func:`book_size`):
    the Gaussian-sum yaw (rad), its std (rad), the resets so far and the M weights (what
    :func:`tick` writes each tick)."""
    book = np.atleast_2d(np.asarray(book, dtype=float))
    log = np.empty((book.shape[0], 3 + models))
    _log_rows(book, models, log)
    return log


def model(params, dt, gps_vel_std, mag_columns) -> Model:
    """The :class:`Model` of GsfParams `params`, the tick dt s, the GPS velocity std (m/s) the main
    filter assumes and the magnetometer's (stamp, gated) diagnostics columns, or None without one."""
    stamp_column, gated_column = (-1, -1) if mag_columns is None else mag_columns
    return Model(
        int(params.models), float(dt), float(params.accel_noise), float(params.gyro_noise),
        max(float(gps_vel_std), float(params.vel_std_min)) ** 2, float(params.reset_max_yaw_std) ** 2,
        float(params.yaw_disagreement), float(params.disagreement_time), int(params.max_resets),
        int(stamp_column), int(gated_column),
    )  # fmt: skip


# ----- the bank ------------------------------------------------------------------------------------


@njit_cached
def _start_row(book, i, M, v_N, v_E, vel_var):
    """Vehicle i's bank started at the GPS velocity (``gsf.initial_bank``)."""
    for j in range(M):
        x, p = HEADER + 3 * j, HEADER + 3 * M + 9 * j
        book[i, x], book[i, x + 1] = v_N, v_E
        book[i, x + 2] = -math.pi + (j + 0.5) * (2.0 * math.pi / M)
        for k in range(9):
            book[i, p + k] = 0.0
        book[i, p], book[i, p + 4], book[i, p + 8] = vel_var, vel_var, (math.pi / M) ** 2
        book[i, HEADER + 12 * M + j] = 1.0 / M
    book[i, STARTED] = 1.0


@njit_cached
def _predict_row(book, i, M, roll, pitch, f_B, w_B, dt, q_vel, q_yaw):
    """Vehicle i's bank after one IMU step (``gsf.predict_bank``): P' = F P F^T + Q, F = I + E with
    E's only nonzeros E[0, 2] = -dv_E, E[1, 2] = dv_N."""
    lx, ly = _level_delta_velocity(roll, pitch, f_B, dt)
    dpsi = _yaw_increment(roll, pitch, w_B, dt)
    for j in range(M):
        x, p = HEADER + 3 * j, HEADER + 3 * M + 9 * j
        c, s = math.cos(book[i, x + 2]), math.sin(book[i, x + 2])
        dv_N, dv_E = c * lx - s * ly, s * lx + c * ly
        book[i, x] += dv_N
        book[i, x + 1] += dv_E
        book[i, x + 2] = rotations.wrap_to_pi(book[i, x + 2] + dpsi)
        a, b = -dv_E, dv_N  # F's yaw column
        p00, p01, p02 = book[i, p], book[i, p + 1], book[i, p + 2]
        p11, p12, p22 = book[i, p + 4], book[i, p + 5], book[i, p + 8]
        n00 = p00 + 2.0 * a * p02 + a * a * p22 + q_vel
        n01 = p01 + a * p12 + b * p02 + a * b * p22
        n02 = p02 + a * p22
        n11 = p11 + 2.0 * b * p12 + b * b * p22 + q_vel
        n12 = p12 + b * p22
        n22 = p22 + q_yaw
        book[i, p], book[i, p + 1], book[i, p + 2] = n00, n01, n02
        book[i, p + 3], book[i, p + 4], book[i, p + 5] = n01, n11, n12
        book[i, p + 6], book[i, p + 7], book[i, p + 8] = n02, n12, n22


@njit_cached
def _fuse_row(book, i, M, v_N, v_E, r, log_likelihood):
    """Vehicle i's bank after a GPS velocity (``gsf.fuse_velocity_bank``): the Joseph update of
    each model (2 x 2 S inverted in closed form), then the weights' Bayes update."""
    for j in range(M):
        x, p = HEADER + 3 * j, HEADER + 3 * M + 9 * j
        P = book[i, p : p + 9]
        nu0, nu1 = v_N - book[i, x], v_E - book[i, x + 1]
        s00, s01, s11 = P[0] + r, P[1], P[4] + r
        det = s00 * s11 - s01 * s01
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det
        nis = nu0 * (i00 * nu0 + i01 * nu1) + nu1 * (i01 * nu0 + i11 * nu1)
        clip = math.sqrt(_CLIP / nis) if nis > _CLIP else 1.0
        # K = P H^T S^-1 (3 x 2): rows k of P's first two columns times S^-1
        k = np.empty((3, 2))
        for row in range(3):
            pa, pb = P[3 * row], P[3 * row + 1]
            k[row, 0], k[row, 1] = pa * i00 + pb * i01, pa * i01 + pb * i11
        for row in range(3):
            book[i, x + row] += (k[row, 0] * nu0 + k[row, 1] * nu1) * clip
        book[i, x + 2] = rotations.wrap_to_pi(book[i, x + 2])
        # Joseph: A = I - K H (A[:, 0:2] = I[:, 0:2] - K, A[:, 2] = e_2), P' = A P A^T + r K K^T
        A = np.eye(3)
        for row in range(3):
            A[row, 0] -= k[row, 0]
            A[row, 1] -= k[row, 1]
        AP = np.zeros((3, 3))
        for a in range(3):
            for b in range(3):
                for c in range(3):
                    AP[a, b] += A[a, c] * P[3 * c + b]
        new = np.empty(9)
        for a in range(3):
            for b in range(3):
                value = r * (k[a, 0] * k[b, 0] + k[a, 1] * k[b, 1])
                for c in range(3):
                    value += AP[a, c] * A[b, c]
                new[3 * a + b] = value
        for a in range(3):
            for b in range(3):
                book[i, p + 3 * a + b] = 0.5 * (new[3 * a + b] + new[3 * b + a])
        log_likelihood[j] = -0.5 * nis - 0.5 * math.log(det) - math.log(2.0 * math.pi)
    w = HEADER + 12 * M
    top = -math.inf
    for j in range(M):
        log_likelihood[j] += math.log(book[i, w + j])
        top = max(top, log_likelihood[j])
    if math.isfinite(top):
        total = 0.0
        for j in range(M):
            log_likelihood[j] = math.exp(log_likelihood[j] - top)
            total += log_likelihood[j]
        for j in range(M):
            book[i, w + j] = log_likelihood[j] / total


@njit_cached
def _gaussian_sum_row(book, i, M):
    """Vehicle i's Gaussian-sum yaw and variance into its header (``gsf.gaussian_sum_yaw``)."""
    w = HEADER + 12 * M
    sin_sum = cos_sum = 0.0
    for j in range(M):
        psi = book[i, HEADER + 3 * j + 2]
        sin_sum += book[i, w + j] * math.sin(psi)
        cos_sum += book[i, w + j] * math.cos(psi)
    yaw = math.atan2(sin_sum, cos_sum)
    var = 0.0
    for j in range(M):
        delta = rotations.wrap_to_pi(book[i, HEADER + 3 * j + 2] - yaw)
        var += book[i, w + j] * (book[i, HEADER + 3 * M + 9 * j + 8] + delta * delta)
    book[i, YAW], book[i, YAW_VAR] = yaw, var


# ----- the tick ------------------------------------------------------------------------------------


@njit_cached
def _magnetometer_row(diagnostics, book, i, stamp_column, gated_column):
    """Book vehicle i's last magnetometer sample (read from the ESKF's diagnostics): a new stamp
    whose gated count did not grow was fused, which aligns the yaw."""
    if stamp_column < 0:
        return
    stamp, gated = diagnostics[i, stamp_column], diagnostics[i, gated_column]
    if stamp != book[i, MAG_STAMP]:
        if gated == book[i, MAG_GATED]:
            book[i, ALIGNED] = 1.0
        book[i, MAG_STAMP] = stamp
    book[i, MAG_GATED] = gated


@njit_cached
def _reset_row(x, P, book, i):
    """Vehicle i's ESKF yaw set to its GSF yaw (``gsf.eskf_yaw_reset``)."""
    q = _yaw_reset_quaternion(x[i, 6], x[i, 7], x[i, 8], x[i, 9], book[i, YAW])
    for k in range(4):
        x[i, 6 + k] = q[k]
    for k in range(P.shape[1]):
        P[i, 8, k] = 0.0
        P[i, k, 8] = 0.0
    P[i, 8, 8] = book[i, YAW_VAR]


@njit_cached
def _tick(
    x, P, diagnostics, book, log, imu, gps, t, blocked, M, dt, accel_noise, gyro_noise, vel_var,
    max_yaw_var, yaw_disagreement, disagreement_time, max_resets, stamp_column, gated_column,
):  # fmt: skip
    log_likelihood = np.empty(M)
    q_vel, q_yaw = (accel_noise * dt) ** 2, (gyro_noise * dt) ** 2
    for i in range(x.shape[0]):
        _magnetometer_row(diagnostics, book, i, stamp_column, gated_column)
        stamp = gps[i, 6]
        gps_fresh = fresh(stamp, book[i, GPS_STAMP]) and math.isfinite(stamp)
        if gps_fresh:
            book[i, GPS_STAMP] = stamp
            gps_fresh = math.isfinite(gps[i, 3]) and math.isfinite(gps[i, 4])
        if book[i, STARTED] == 0.0:
            if gps_fresh:
                _start_row(book, i, M, gps[i, 3], gps[i, 4], vel_var)
                _gaussian_sum_row(book, i, M)
            blocked[i] = book[i, MAG_BLOCKED] != 0.0
            _log_row(book, i, M, log)
            continue
        imu_finite = True
        for k in range(6):
            imu_finite = imu_finite and math.isfinite(imu[i, k])
        if imu_finite:
            roll, pitch, _ = rotations.euler_from_quat((x[i, 6], x[i, 7], x[i, 8], x[i, 9]))
            f_B = (imu[i, 0], imu[i, 1], imu[i, 2])
            w_B = (imu[i, 3] - x[i, 13], imu[i, 4] - x[i, 14], imu[i, 5] - x[i, 15])
            _predict_row(book, i, M, roll, pitch, f_B, w_B, dt, q_vel, q_yaw)
        if gps_fresh:
            _fuse_row(book, i, M, gps[i, 3], gps[i, 4], vel_var, log_likelihood)
        _gaussian_sum_row(book, i, M)
        main_yaw = rotations.euler_from_quat((x[i, 6], x[i, 7], x[i, 8], x[i, 9]))[2]
        yaw, var = book[i, YAW], book[i, YAW_VAR]
        previous = book[i, DISAGREE_SINCE]
        since = _disagreement_start(previous, t, yaw, var, main_yaw, max_yaw_var, yaw_disagreement)
        book[i, DISAGREE_SINCE] = since
        reason = _reset_reason(
            t, since, book[i, YAW_VAR], book[i, ALIGNED] != 0.0, book[i, RESETS], max_yaw_var,
            disagreement_time, max_resets,
        )  # fmt: skip
        if reason != 0:
            _reset_row(x, P, book, i)
            book[i, RESETS] += 1.0
            book[i, ALIGNED] = 1.0
            book[i, DISAGREE_SINCE] = math.nan
            if reason == _DISAGREE and stamp_column >= 0:
                book[i, MAG_BLOCKED] = 1.0
        blocked[i] = book[i, MAG_BLOCKED] != 0.0
        _log_row(book, i, M, log)


def tick(filters, book, log, imu, gps, t, model, blocked) -> None:
    """One tick of the N vehicles' GSFs IN PLACE on their ESKF ``fusion.Filters`` `filters` (x (N,
    16), P (N, k, k), diagnostics) and GSF `book` (N, :func:`book_size`) (module docstring); each
    vehicle's log row written into `log` (N, ``vocabulary.gsf_log_size``, :func:`log_rows`).

    imu (N, 6): f_B m/s^2, w_B rad/s (a non-finite sample is not predicted on); gps (N, 7): p,
    v_N m/s, stamp s; t: s, the tick time; model: :class:`Model`; blocked (N,) bool, written: the
    vehicles whose magnetometer is no longer fused."""
    m = model
    _tick(
        filters.x, filters.P, filters.diagnostics, book, log, imu, gps, float(t), blocked, m.models, m.dt,
        m.accel_noise, m.gyro_noise, m.vel_var, m.max_yaw_var, m.yaw_disagreement, m.disagreement_time,
        m.max_resets, m.mag_stamp_column, m.mag_gated_column,
    )  # fmt: skip


@njit_cached
def _predict_rows(book, M, roll, pitch, f_B, w_B, dt, q_vel, q_yaw):
    for i in range(book.shape[0]):
        force, rate = (f_B[i, 0], f_B[i, 1], f_B[i, 2]), (w_B[i, 0], w_B[i, 1], w_B[i, 2])
        _predict_row(book, i, M, roll[i], pitch[i], force, rate, dt, q_vel, q_yaw)
        _gaussian_sum_row(book, i, M)


@njit_cached
def _fuse_rows(book, M, v_NE, vel_var):
    log_likelihood = np.empty(M)
    for i in range(book.shape[0]):
        _fuse_row(book, i, M, v_NE[i, 0], v_NE[i, 1], vel_var, log_likelihood)
        _gaussian_sum_row(book, i, M)


def predict(book, models, roll, pitch, f_B, w_B, dt, params) -> np.ndarray:
    """The books (N, :func:`book_size`) after one IMU step of every bank, their Gaussian-sum yaw
    updated (``gsf.predict_bank``, ``gsf.gaussian_sum_yaw`` per row); roll, pitch (N,) rad; f_B
    (N, 3) m/s^2; w_B (N, 3) rad/s; params: GsfParams. The form the oracles are tested against."""
    book = np.array(book, dtype=float)
    q_vel, q_yaw = (params.accel_noise * dt) ** 2, (params.gyro_noise * dt) ** 2
    _predict_rows(book, models, np.asarray(roll, float), np.asarray(pitch, float), f_B, w_B, dt, q_vel, q_yaw)
    return book


def fuse_velocity(book, models, v_NE, vel_var) -> np.ndarray:
    """The books after a GPS velocity v_NE (N, 2) m/s of variance vel_var (``gsf.fuse_velocity_bank``
    per row), their Gaussian-sum yaw updated."""
    book = np.array(book, dtype=float)
    _fuse_rows(book, models, np.asarray(v_NE, dtype=float), float(vel_var))
    return book


def bank_of(book_row, models) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X (M, 3), P (M, 3, 3), w (M,)) copies of one vehicle's bank in its book row."""
    M, start = models, HEADER
    X = book_row[start : start + 3 * M].reshape(M, 3).copy()
    P = book_row[start + 3 * M : start + 12 * M].reshape(M, 3, 3).copy()
    return X, P, book_row[start + 12 * M : start + 13 * M].copy()
