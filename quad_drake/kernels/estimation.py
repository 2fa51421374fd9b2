"""Pure: the estimators' scalar functions in batched array form, for fleets of N vehicles.

Every function here is the array form of one scalar function (named in its docstring) with a
leading vehicle axis, tested against the scalar function row by row on seeded random inputs to
1e-12 (``tests/test_fleet_estimators.py``). The scalar functions (``estimation/complementary.py``,
``ekf.py``, ``eskf.py``, ``gating.py``, ``delay_compensation.py``) stay the reference
implementation; their docstrings give the units, frames and conventions, which are the same here.

Two ways of batching, chosen by measurement (``benchmarks/bench_fleet_estimators.py``): the
per-tick steps (attitude filter, predictions, the cheap covariance check, magnetometer updates,
error injection, estimate assembly) are numba-compiled loops over the vehicles that repeat the
scalar arithmetic, operation for operation, with the sparsity of the transition matrices used
as the scalar code uses it; the 10 Hz GPS updates (a 6x6 solve each), the PSD check and the
gating book-keeping are numpy over the whole batch. numba compiles on first use and caches the
machine code on disk (``jit.njit_cached``).

Shapes: a state x is (N, n), a covariance P (N, n, n), a specific force f_B or gyro sample w_B
(N, 3) (m/s^2, rad/s, FRD), an angle, stamp or NIS (N,), a per-vehicle flag (N,) bool. Inputs
are not modified unless a docstring says so. A non-finite measurement leaves its vehicle's
(x, P) unchanged and gives NaN NIS, as the scalar updates do.
"""

import math

import numpy as np

from quad_drake.conventions import GRAVITY, NO_SAMPLE_STAMP
from quad_drake.delay_compensation import TIME_TOLERANCE
from quad_drake.estimation import ekf, eskf, gating
from quad_drake.estimation.complementary import VARIANTS
from quad_drake.estimation.vocabulary import DIAG
from quad_drake.jit import njit_cached
from quad_drake.kernels.flight import compiled

GPS_SLOT, MAG_SLOT = 0, 1
GPS_POLICY = slice(2, 2 + gating.GPS_BOOK_SIZE)
BOOK_SIZE = 2 + gating.GPS_BOOK_SIZE
"""Columns of an estimator's book (N, BOOK_SIZE): the last GPS and mag stamps seen (s;
freshness), then the GPS policy's book (``gating.gps_gate_decisions``)."""


def initial_book():
    """One vehicle's book before its first tick: no sample seen, the GPS policy's initial book."""
    return np.concatenate(([NO_SAMPLE_STAMP, NO_SAMPLE_STAMP], gating.initial_gps_book()))


_TWO_PI = 2.0 * math.pi
_NONFINITE, _MAG_NIS, _MAG_GATED = DIAG["nonfinite_samples"], DIAG["mag_nis"], DIAG["mag_gated"]
_ESKF_BIASES = eskf.ERROR_SIZE_WITH_BIASES


# ----- scalar helpers of the compiled loops (the scalar modules' own formulas) ---------------------


@njit_cached
def _wrap(angle):
    """rotations.wrap_to_pi."""
    return (angle + math.pi) % _TWO_PI - math.pi


@njit_cached
def _quat_from_euler(roll, pitch, yaw):
    """rotations.quat_from_euler_tuple."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


@njit_cached
def _euler_from_quat(w, x, y, z):
    """rotations.euler_from_quat."""
    n2 = w * w + x * x + y * y + z * z
    roll = math.atan2(2.0 * (y * z + w * x), w * w - x * x - y * y + z * z)
    pitch = math.asin(max(-1.0, min(1.0, -2.0 * (x * z - w * y) / n2)))
    yaw = math.atan2(2.0 * (x * y + w * z), w * w + x * x - y * y - z * z)
    return roll, pitch, yaw


@njit_cached
def _quat_exp(tx, ty, tz):
    """eskf.quat_exp."""
    angle = math.sqrt(tx * tx + ty * ty + tz * tz)
    if angle < 1e-12:
        return (1.0, 0.5 * tx, 0.5 * ty, 0.5 * tz)
    s = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), tx * s, ty * s, tz * s)


@njit_cached
def _quat_mul(aw, ax, ay, az, bw, bx, by, bz):
    """eskf.quat_mul."""
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit_cached
def rotation_into(qw, qx, qy, qz, R):
    """Writes R_NB of a unit wxyz quaternion into R (3, 3) (eskf._rotation_entries)."""
    R[0, 0] = 1 - 2 * (qy * qy + qz * qz)
    R[0, 1] = 2 * (qx * qy - qw * qz)
    R[0, 2] = 2 * (qx * qz + qw * qy)
    R[1, 0] = 2 * (qx * qy + qw * qz)
    R[1, 1] = 1 - 2 * (qx * qx + qz * qz)
    R[1, 2] = 2 * (qy * qz - qw * qx)
    R[2, 0] = 2 * (qx * qz - qw * qy)
    R[2, 1] = 2 * (qy * qz + qw * qx)
    R[2, 2] = 1 - 2 * (qx * qx + qy * qy)


# ----- complementary filter ------------------------------------------------------------------------


@njit_cached
def _row_sum(values, i):
    """The sum of row i of a 2-D array, from 0.0 in column order (Python's ``sum``)."""
    total = 0.0
    for k in range(values.shape[1]):
        total += values[i, k]
    return total


@njit_cached
def _row_finite(values, i, total=0.0):
    """True if the sum of `total` and row i is finite (one NaN or inf makes the sum NaN or inf)."""
    for k in range(values.shape[1]):
        total += values[i, k]
    return math.isfinite(total)


IMU_HOLD_TIME = 0.02
"""s: time constant of an estimator's running mean of its finite IMU samples (a 20 ms mean of
10 samples at 500 Hz: 1/sqrt(10) of one sample's noise, and the lag of a manoeuvre's rate change
is under one tick's worth). Over an IMU dropout the estimators dead-reckon with this mean, so
their attitude, velocity and position keep moving as the vehicle did before the gap."""
HOLD_SIZE = 7
"""Columns of a hold (N, HOLD_SIZE): the running mean of f_B (m/s^2) and w_B (rad/s), then 1.0
once a finite sample has started it (0.0 before)."""
IMU_FINITE, IMU_HELD, IMU_MISSING = 0, 1, 2
"""What :func:`_bridge_imu_row` found: a finite sample (the mean takes it), a non-finite one with
a mean to dead-reckon on, a non-finite one before any finite sample."""


def initial_hold():
    """One vehicle's hold before its first IMU sample (not started)."""
    return np.zeros(HOLD_SIZE)


@njit_cached
def _bridge_imu_row(imu, hold, i, weight):
    """IMU_FINITE, IMU_HELD or IMU_MISSING for vehicle i's sample imu (N, 6); a finite sample moves
    the running mean hold (N, HOLD_SIZE) by weight (the first one starts it)."""
    if _row_finite(imu, i):
        started = hold[i, 6] > 0.0
        for k in range(6):
            hold[i, k] = hold[i, k] + weight * (imu[i, k] - hold[i, k]) if started else imu[i, k]
        hold[i, 6] = 1.0
        return IMU_FINITE
    return IMU_HELD if hold[i, 6] > 0.0 else IMU_MISSING


@njit_cached
def _complementary_row(roll, pitch, yaw, fx, fy, fz, wx, wy, wz, dt, tau, nonlinear, reference_accelerometer):
    """complementary.complementary_update of one vehicle, (roll, pitch, yaw)."""
    if nonlinear:
        qw, qx, qy, qz = _quat_from_euler(roll, pitch, yaw)
        rate = math.sqrt(wx * wx + wy * wy + wz * wz)
        s = math.sin(0.5 * rate * dt) / rate if rate > 1e-12 else 0.5 * dt
        c = math.cos(0.5 * rate * dt)
        dx, dy, dz = wx * s, wy * s, wz * s
        roll_pred, pitch_pred, yaw_pred = _euler_from_quat(
            qw * c - qx * dx - qy * dy - qz * dz,
            qw * dx + qx * c + qy * dz - qz * dy,
            qw * dy - qx * dz + qy * c + qz * dx,
            qw * dz + qx * dy - qy * dx + qz * c,
        )
    else:
        roll_pred, pitch_pred, yaw_pred = roll + dt * wx, pitch + dt * wy, yaw + dt * wz
    if reference_accelerometer:
        roll_acc, pitch_acc = math.atan2(fy, fz), math.atan2(-fx, GRAVITY)
    else:
        roll_acc, pitch_acc = math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))
    gyro_weight = tau / (tau + dt)
    accel_weight = dt / (tau + dt)
    return (
        gyro_weight * roll_pred + accel_weight * roll_acc,
        gyro_weight * pitch_pred + accel_weight * pitch_acc,
        _wrap(yaw_pred),
    )


@njit_cached
def _complementary_rows(attitude, f_B, w_B, dt, tau, nonlinear, reference_accelerometer):
    out = np.empty((attitude.shape[0], 3))
    for i in range(attitude.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = _complementary_row(
            attitude[i, 0], attitude[i, 1], attitude[i, 2], f_B[i, 0], f_B[i, 1], f_B[i, 2],
            w_B[i, 0], w_B[i, 1], w_B[i, 2], dt, tau, nonlinear, reference_accelerometer,
        )  # fmt: skip
    return out


@njit_cached
def _complementary_tick(attitude, rate, hold, imu, ekf_state, dt, tau, nonlinear, reference_accelerometer):
    weight = dt / (IMU_HOLD_TIME + dt)
    for i in range(attitude.shape[0]):
        yaw = ekf_state[i, 6]
        status = _bridge_imu_row(imu, hold, i, weight)
        source = imu if status == IMU_FINITE else hold[:, 0:6]
        for k in range(3):
            rate[i, k] = imu[i, 3 + k] if status == IMU_FINITE else math.nan
        if status == IMU_MISSING:
            attitude[i, 2] = yaw
            continue
        attitude[i, 0], attitude[i, 1], attitude[i, 2] = _complementary_row(
            attitude[i, 0], attitude[i, 1], yaw, source[i, 0], source[i, 1], source[i, 2],
            source[i, 3], source[i, 4], source[i, 5], dt, tau, nonlinear, reference_accelerometer,
        )  # fmt: skip


def _check_variant(variant):
    if variant not in VARIANTS:
        raise ValueError(f"unknown attitude filter variant {variant!r}; expected one of {VARIANTS}")
    return variant == "nonlinear"


def complementary_update(attitude, f_B, w_B, dt, tau, variant, reference_accelerometer=False):
    """(N, 3) roll, pitch, yaw after one filter step from the prior ``attitude`` (N, 3), rad.

    ``complementary.complementary_update`` per row; f_B, w_B (N, 3); dt, tau s; variant
    ``"nonlinear"`` or ``"small_angle"``.
    """
    nonlinear = _check_variant(variant)
    return _complementary_rows(
        attitude, f_B, w_B, float(dt), float(tau), nonlinear, bool(reference_accelerometer)
    )


def complementary_tick(attitude, rate, hold, imu, ekf_state, dt, tau, variant, reference_accelerometer=False):
    """One tick of N attitude filters IN PLACE (``systems.estimators.ComplementaryFilter`` per vehicle).

    attitude (N, 3) rad, rate (N, 3) rad/s and hold (N, HOLD_SIZE): the filters' state, updated;
    imu (N, 6); ekf_state (N, 7), whose yaw is the prior yaw. A vehicle takes
    :func:`complementary_update` and its gyro sample as rate; over a non-finite IMU sample it takes
    the update with its running mean of the IMU (:data:`IMU_HOLD_TIME`) and a NaN rate (no rate
    measured: the controller then commands no body moment); before its first finite sample it
    keeps its roll and pitch and takes the prior yaw.
    """
    nonlinear = _check_variant(variant)
    _complementary_tick(
        attitude, rate, hold, imu, ekf_state, float(dt), float(tau), nonlinear, bool(reference_accelerometer)
    )


def round_to_float32(*arrays):
    """Round every entry of each float64 array IN PLACE to the nearest float32 (kept float64).

    ``Fidelity.float32_estimator``: the reference stores its attitude filter's angles
    (``rollEst``, ``pitchEst``), its last gyro sample and its EKF's state and covariance
    (``VectorXf``, ``MatrixXf``) in float, so after each 500 Hz tick they take the nearest
    float32 (SPEC §4). Any shapes: (N, 3) attitudes, (N, 7) states, (N, 7, 7) covariances.
    """
    for values in arrays:
        np.copyto(values, values.astype(np.float32))


@njit_cached
def _assembled_rows(attitude, ekf_state, body_rate, out):
    for i in range(attitude.shape[0]):
        q = _quat_from_euler(attitude[i, 0], attitude[i, 1], ekf_state[i, 6])
        for k in range(3):  # entry by entry: a slice is a new array view per vehicle in numba
            out[i, k] = ekf_state[i, k]
            out[i, 7 + k] = ekf_state[i, 3 + k]
            out[i, 10 + k] = body_rate[i, k]
        for k in range(4):
            out[i, 3 + k] = q[k]


def ekf7_estimated_state(attitude, ekf_state, body_rate, out=None):
    """(N, 13) EKF7 estimates in the ``state`` layout (``systems.estimators.EstimatedStateAssembler``),
    written into `out` (an (N, 13) float array, e.g. a view of an output port) when given.

    p = x[0:3], q_NB = quat(roll, pitch, x[6]) wxyz, v = x[3:6], w = body rate; attitude (N, 3),
    ekf_state (N, 7), body_rate (N, 3).
    """
    if out is None:
        out = np.empty((attitude.shape[0], 13))
    _assembled_rows(attitude, ekf_state, body_rate, out)
    return out


# ----- 7-state EKF ---------------------------------------------------------------------------------


_yaw_free_rotation_of = compiled(ekf.yaw_free_rotation_of)
_tilt_jacobian_of = compiled(ekf.tilt_jacobian_of)
_scaled_tilt_factors = compiled(ekf.scaled_tilt_factors)
NO_TILT = (0.0, 0.0)
"""Tilt gains (velocity, yaw) that switch the tilt-aware Q off."""


@njit_cached
def _add_tilt_noise(P_out, i, trig, rotated, wy, wz, gains):
    """P_out[i, 3:7, 3:7] += a a^T + b b^T of ekf.tilt_noise_factors (gains = ekf.tilt_gains), from
    the prediction's trig and rotated specific force (ekf.tilt_jacobian_of)."""
    a, b = _scaled_tilt_factors(_tilt_jacobian_of(trig, rotated, wy, wz), gains[0], gains[1])
    for r in range(4):
        for c in range(4):
            P_out[i, 3 + r, 3 + c] += a[r] * a[c] + b[r] * b[c]


@njit_cached
def _ekf7_predict_row(x, P, x_out, P_out, i, attitude, f_B, dt, Q, gravity_z, GP, M):
    """ekf.predict_with_yaw of vehicle i from (x, P) into (x_out, P_out) (may be the same arrays).
    Returns the attitude's trig (cos, sin of roll, pitch, yaw) and (ux, uy, uz, rolled_z) of
    ekf.yaw_free_rotation_of, which the tilt-aware Q reuses."""
    roll, pitch, yaw = attitude[i, 0], attitude[i, 1], attitude[i, 2]
    fx, fy, fz = f_B[i, 0], f_B[i, 1], f_B[i, 2]
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    ux, uy, uz, rolled_z = _yaw_free_rotation_of(cr, sr, cp, sp, fx, fy, fz)
    g3 = (-sy * ux - cy * uy) * dt
    g4 = (cy * ux - sy * uy) * dt
    for k in range(3):
        x_out[i, k] = x[i, k] + x[i, 3 + k] * dt
    x_out[i, 3] = x[i, 3] + (cy * ux - sy * uy) * dt
    x_out[i, 4] = x[i, 4] + (sy * ux + cy * uy) * dt
    x_out[i, 5] = x[i, 5] + (uz + gravity_z) * dt
    x_out[i, 6] = yaw
    # G = I7 + dt at (0..2, 3..5) + (g3, g4) at (3, 6), (4, 6): G P, then (G P) G^T
    for c in range(7):
        for r in range(3):
            GP[r, c] = P[i, r, c] + dt * P[i, r + 3, c]
        GP[3, c] = P[i, 3, c] + g3 * P[i, 6, c]
        GP[4, c] = P[i, 4, c] + g4 * P[i, 6, c]
        GP[5, c] = P[i, 5, c]
        GP[6, c] = P[i, 6, c]
    for r in range(7):
        for c in range(3):
            M[r, c] = GP[r, c] + GP[r, c + 3] * dt
        M[r, 3] = GP[r, 3] + GP[r, 6] * g3
        M[r, 4] = GP[r, 4] + GP[r, 6] * g4
        M[r, 5] = GP[r, 5]
        M[r, 6] = GP[r, 6]
    for r in range(7):
        for c in range(7):
            P_out[i, r, c] = (M[r, c] + M[c, r]) * 0.5 + Q[r, c]
    return (cr, sr, cp, sp, cy, sy), (ux, uy, uz, rolled_z)


@njit_cached
def _ekf7_predict_rows(x, P, attitude, f_B, dt, Q, gravity_z):
    x_new, P_new = np.empty_like(x), np.empty_like(P)
    GP, M = np.empty((7, 7)), np.empty((7, 7))
    for i in range(x.shape[0]):
        _ekf7_predict_row(x, P, x_new, P_new, i, attitude, f_B, dt, Q, gravity_z, GP, M)
    return x_new, P_new


@njit_cached
def ekf7_tick(
    x,
    P,
    hold,
    attitude,
    imu,
    gps,
    mag,
    diagnostics,
    book,
    dt,
    Q,
    tilt_gains,
    gravity_z,
    r_mag,
    threshold,
    healthy,
):
    """The prediction and, on a quiet tick, the magnetometer step of one EKF7 tick IN PLACE
    (``systems.estimators.Ekf``), compiled as one call; True when the tick was quiet.

    Prediction: a vehicle takes :func:`ekf7_predict_with_yaw` with f_B = imu[:, 0:3], Q (7, 7)
    and, with tilt_gains = ``ekf.TiltNoise.gains`` (velocity, yaw) of this tick ((0.0, 0.0): off),
    the tilt-aware block of its attitude and IMU sample (``ekf.TiltNoise.process_noise``);
    gravity_z = :func:`gravity_z`. A non-finite IMU sample counts in diagnostics (N,
    DIAGNOSTICS_SIZE) and the vehicle dead-reckons on its running mean hold (N, HOLD_SIZE,
    updated by the finite ones); a vehicle with no mean yet, or a non-finite attitude (N, 3) rad
    (also counted), is not predicted. healthy (N,) bool: written with
    :func:`covariance_looks_healthy` of the new P. A quiet tick is one where every P looks
    healthy and no vehicle has a fresh GPS sample (gps (N, 7), stamp against book[:, GPS_SLOT],
    :func:`fresh`): then nothing is repaired or fused from the GPS, and the tick ends here with
    :func:`ekf7_mag_tick` (mag (N, 2), r_mag = R_mag[0, 0] rad^2, threshold its gate).
    Otherwise the caller runs the repair, the mag step and the GPS fusion
    (``systems.estimators.GatedFusion._fuse_fresh``).
    """
    GP, M = np.empty((7, 7)), np.empty((7, 7))
    weight = dt / (IMU_HOLD_TIME + dt)
    quiet = True
    for i in range(x.shape[0]):
        status = _bridge_imu_row(imu, hold, i, weight)
        attitude_finite = _row_finite(attitude, i)
        if status != IMU_FINITE or not attitude_finite:
            diagnostics[i, _NONFINITE] += 1.0
        source = imu if status == IMU_FINITE else hold[:, 0:6]
        if status != IMU_MISSING and attitude_finite:
            trig, rotated = _ekf7_predict_row(x, P, x, P, i, attitude, source, dt, Q, gravity_z, GP, M)
            if tilt_gains[0] > 0.0 or tilt_gains[1] > 0.0:
                _add_tilt_noise(P, i, trig, rotated, source[i, 4], source[i, 5], tilt_gains)
        healthy[i] = _row_healthy(P, i)
        if not healthy[i] or fresh(gps[i, 6], book[i, GPS_SLOT]):
            quiet = False
    if quiet:
        _ekf7_mag_tick(x, P, mag, diagnostics, book, r_mag, threshold)
    return quiet


def ekf7_predict_with_yaw(x, P, attitude, f_B, dt, Q, reference_accelerometer=False):
    """(x', P') of the EKF7's 500 Hz step (``ekf.predict_with_yaw`` per row): yaw <- attitude yaw, predict.

    x (N, 7); P (N, 7, 7); attitude (N, 3) roll, pitch, yaw rad; f_B (N, 3); Q (7, 7).
    """
    return _ekf7_predict_rows(x, P, attitude, f_B, float(dt), Q, gravity_z(reference_accelerometer))


def gravity_z(reference_accelerometer):
    """g_N z, m/s^2, as the EKF7 predicts with it: +GRAVITY (NED, the physical accelerometer), or
    -GRAVITY for the reference accelerometer's sign convention (``fidelity``)."""
    return -GRAVITY if reference_accelerometer else GRAVITY


@njit_cached
def _gps_joseph_row(x, P, z, R, i, comps, m, x_out, P_out, inject, work):
    """The update of vehicle i with the m GPS components comps[:m] (indices into (p, v); H = rows
    comps of [I6 0], ``ekf.kalman_update`` / ``eskf.joseph_update``) into (x_out, P_out), which hold
    the prior; returns (nis, singular). A singular S leaves them as they are.

    [K^T | S^-1 nu] = S^-1 [H P | nu] by Gaussian elimination with partial pivoting (LAPACK's
    gesv, singular on an exactly zero pivot); P' = (I - K H) P (I - K H)^T + K R K^T symmetrised;
    then x' = x + K nu (EKF7) or the injection of K nu (ESKF, ``inject``).
    """
    S, X, nu, K, T, KR, dx = work
    n = P.shape[1]
    for a in range(m):
        ca = comps[a]
        nu[a] = z[i, ca] - x[i, ca]
        for b in range(m):
            S[a, b] = P[i, ca, comps[b]] + R[ca, comps[b]]
        for c in range(n):
            X[a, c] = P[i, ca, c]
        X[a, n] = nu[a]
    for k in range(m):
        pivot, best = k, abs(S[k, k])
        for r in range(k + 1, m):
            if abs(S[r, k]) > best:
                pivot, best = r, abs(S[r, k])
        if best == 0.0:
            return math.nan, True
        if pivot != k:
            for c in range(m):
                S[k, c], S[pivot, c] = S[pivot, c], S[k, c]
            for c in range(n + 1):
                X[k, c], X[pivot, c] = X[pivot, c], X[k, c]
        for r in range(k + 1, m):
            f = S[r, k] / S[k, k]
            for c in range(k, m):
                S[r, c] -= f * S[k, c]
            for c in range(n + 1):
                X[r, c] -= f * X[k, c]
    for k in range(m - 1, -1, -1):
        for c in range(n + 1):
            value = X[k, c]
            for j in range(k + 1, m):
                value -= S[k, j] * X[j, c]
            X[k, c] = value / S[k, k]
    nis = 0.0
    for a in range(m):
        nis += nu[a] * X[a, n]
    for r in range(n):
        dx[r] = 0.0
        for k in range(m):
            K[r, k] = X[k, r]
            dx[r] += K[r, k] * nu[k]
    for r in range(n):
        for c in range(n):
            value = P[i, r, c]
            for k in range(m):
                value -= K[r, k] * P[i, comps[k], c]
            T[r, c] = value
        for j in range(m):
            value = 0.0
            for k in range(m):
                value += K[r, k] * R[comps[k], comps[j]]
            KR[r, j] = value
    for r in range(n):
        for c in range(n):
            value = T[r, c]
            for k in range(m):
                value += KR[r, k] * K[c, k] - T[r, comps[k]] * K[c, k]
            P_out[i, r, c] = value
    for r in range(n):
        for c in range(r):
            value = (P_out[i, r, c] + P_out[i, c, r]) * 0.5
            P_out[i, r, c] = P_out[i, c, r] = value
    if inject:
        _inject_row(x_out, P_out, i, dx)
    else:
        for r in range(n):
            x_out[i, r] += dx[r]
    return nis, False


@njit_cached
def _gps_rows(x, P, z, R, inject, mask):
    n = P.shape[1]
    x_new, P_new = x.copy(), P.copy()
    nis = np.full(x.shape[0], np.nan)
    work = (
        np.empty((6, 6)), np.empty((6, n + 1)), np.empty(6), np.empty((n, 6)),
        np.empty((n, n)), np.empty((n, 6)), np.empty(n),
    )  # fmt: skip
    comps = np.empty(6, dtype=np.int64)
    singular = False
    for i in range(x.shape[0]):
        m = 0
        finite = True
        for a in range(6):
            if mask[i, a]:
                comps[m] = a
                m += 1
                finite = finite and math.isfinite(z[i, a])
        if m > 0 and finite:
            nis[i], skipped = _gps_joseph_row(x, P, z, R, i, comps, m, x_new, P_new, inject, work)
            singular = singular or skipped
    return x_new, P_new, nis, singular


def _component_mask(mask, count):
    """(N, 6) bool of the GPS components each vehicle fuses: all of them when mask is None."""
    if mask is None:
        return np.ones((count, 6), dtype=bool)
    return np.ascontiguousarray(mask, dtype=bool)


def ekf7_gps_update(x, P, gps_pv, R_gps, mask=None):
    """(x', P', nis) after GPS samples gps_pv (N, 6: p m, v m/s) with R_gps (6, 6) (``ekf.gps_update``).

    mask (N, 6) bool, optional: the components each vehicle fuses (H = those rows of [I6 0]; a
    vehicle with none keeps (x, P) with NaN NIS); default all six. A singular innovation
    covariance raises LinAlgError, as the scalar update does.
    """
    z = np.asarray(gps_pv, dtype=float)
    x_new, P_new, nis, singular = _gps_rows(x, P, z, R_gps, False, _component_mask(mask, len(z)))
    if singular:
        raise np.linalg.LinAlgError("Singular matrix")
    return x_new, P_new, nis


@njit_cached
def _ekf7_mag_innovation(x, P, i, yaw_meas, r):
    """(nu rad, S rad^2) of vehicle i's magnetometer yaw (ekf.mag_update)."""
    return _wrap(yaw_meas - x[i, 6]), P[i, 6, 6] + r


@njit_cached
def _ekf7_mag_apply(x, P, x_out, P_out, i, nu, S, p6):
    """ekf.mag_update's posterior of vehicle i into (x_out, P_out) (may alias); p6: a 7-buffer."""
    for a in range(7):
        p6[a] = P[i, a, 6]
    for a in range(7):
        Ka = p6[a] / S
        for b in range(7):
            Kb = p6[b] / S
            P_out[i, a, b] = P[i, a, b] - (Ka * p6[b] + Kb * p6[a]) + S * (Ka * Kb)
        x_out[i, a] = x[i, a] + Ka * nu
    x_out[i, 6] = _wrap(x_out[i, 6])


@njit_cached
def _ekf7_mag_rows(x, P, yaw_meas, r):
    x_new, P_new = x.copy(), P.copy()
    nis = np.full(x.shape[0], np.nan)
    p6 = np.empty(7)
    for i in range(x.shape[0]):
        if math.isfinite(yaw_meas[i]):
            nu, S = _ekf7_mag_innovation(x, P, i, yaw_meas[i], r)
            _ekf7_mag_apply(x, P, x_new, P_new, i, nu, S, p6)
            nis[i] = nu * nu / S
    return x_new, P_new, nis


def ekf7_mag_update(x, P, yaw_meas, R_mag):
    """(x', P', nis) after magnetometer yaws (N,) rad with R_mag (1, 1) (``ekf.mag_update`` per row)."""
    return _ekf7_mag_rows(x, P, np.asarray(yaw_meas, dtype=float), float(R_mag[0, 0]))


@njit_cached
def fresh(stamps, seen):
    """True where a stamp (s) differs from the last one seen and is a sample (not NO_SAMPLE_STAMP;
    ``systems.estimators._fresh``): (N,) bool of stamps and seen (N,), or one bool of two floats
    (as the compiled kernels call it)."""
    return (stamps != seen) & (stamps != NO_SAMPLE_STAMP)


@njit_cached
def _fresh_mag(mag, book, diagnostics, i):
    """True when vehicle i has a fresh finite mag sample to fuse; books its stamp, counts a non-finite one."""
    stamp = mag[i, 1]
    if not fresh(stamp, book[i, MAG_SLOT]):
        return False
    book[i, MAG_SLOT] = stamp
    if not (math.isfinite(stamp) and math.isfinite(mag[i, 0])):
        diagnostics[i, _NONFINITE] += 1.0
        return False
    return True


@njit_cached
def _mag_gate(diagnostics, i, nis, stamp, threshold):
    """True when the gate accepts vehicle i's mag NIS; logs it and counts the gated and NaN ones."""
    if math.isnan(nis):
        diagnostics[i, _NONFINITE] += 1.0
        return False
    diagnostics[i, _MAG_NIS] = nis
    diagnostics[i, _MAG_NIS + 1] = stamp
    if nis <= threshold:
        return True
    diagnostics[i, _MAG_GATED] += 1.0
    return False


@njit_cached
def _ekf7_mag_tick(x, P, mag, diagnostics, book, r, threshold):
    p6 = np.empty(7)
    for i in range(x.shape[0]):
        if _fresh_mag(mag, book, diagnostics, i):
            nu, S = _ekf7_mag_innovation(x, P, i, mag[i, 0], r)
            if _mag_gate(diagnostics, i, nu * nu / S, mag[i, 1], threshold):
                _ekf7_mag_apply(x, P, x, P, i, nu, S, p6)


def ekf7_mag_tick(x, P, mag, diagnostics, book, R_mag, threshold):
    """The magnetometer step of one EKF7 tick IN PLACE (``_GatedFusion._fuse`` for the mag slot).

    mag (N, 2: yaw rad, stamp s); x, P, diagnostics, book as in :func:`fuse_gps`. Fresh (changed stamp)
    samples are booked; non-finite ones counted; the others fused when the gate (NIS threshold)
    accepts them, else counted as gated.
    """
    _ekf7_mag_tick(x, P, mag, diagnostics, book, float(R_mag[0, 0]), float(threshold))


# ----- gating and covariance health ----------------------------------------------------------------


@njit_cached
def _row_healthy(P, i):
    """gating.covariance_looks_healthy of P[i]."""
    total = 0.0
    variances_ok = True
    for a in range(P.shape[1]):
        variances_ok = variances_ok and P[i, a, a] >= 0.0
        for b in range(P.shape[2]):
            total += P[i, a, b]
    return math.isfinite(total) and variances_ok


@njit_cached
def _looks_healthy_rows(P):
    healthy = np.empty(P.shape[0], dtype=np.bool_)
    for i in range(P.shape[0]):
        healthy[i] = _row_healthy(P, i)
    return healthy


def covariance_looks_healthy(P):
    """(N,) cheap per-tick check: all entries finite, variances >= 0 (``gating.covariance_looks_healthy``)."""
    return _looks_healthy_rows(P)


@njit_cached
def _symmetrise_checked(P, check):
    """For each checked vehicle with a finite P[i]: P[i] <- (P[i] + P[i]^T) / 2 IN PLACE. Returns (N,)
    True where the full check stays undecided: a non-finite P[i] (left as it is), or a symmetrised
    one without a Cholesky factor in floating point (a pivot <= 0).

    A successful factorisation bounds the smallest eigenvalue below by about -n^2 eps max(diag S),
    far inside ``gating.repaired_covariance``'s -1e-12 |largest| tolerance, so those matrices are
    COVARIANCE_OK without an eigendecomposition.
    """
    count, n = P.shape[0], P.shape[1]
    undecided = np.zeros(count, dtype=np.bool_)
    L = np.empty((n, n))
    for i in range(count):
        if not check[i]:
            continue
        finite = True
        for a in range(n):
            for b in range(n):
                finite = finite and math.isfinite(P[i, a, b])
        if not finite:
            undecided[i] = True
            continue
        for a in range(n):
            for b in range(a + 1):
                value = 0.5 * (P[i, a, b] + P[i, b, a])
                P[i, a, b] = P[i, b, a] = L[a, b] = value
        for k in range(n):
            pivot = L[k, k]
            for j in range(k):
                pivot -= L[k, j] * L[k, j]
            if not pivot > 0.0:
                undecided[i] = True
                break
            root = math.sqrt(pivot)
            L[k, k] = root
            for r in range(k + 1, n):
                value = L[r, k]
                for j in range(k):
                    value -= L[r, j] * L[k, j]
                L[r, k] = value / root
    return undecided


def repair_covariances(P, check, fallback):
    """``gating.repaired_covariance`` IN PLACE on the vehicles flagged in check (N,); returns (N,) outcomes.

    P (N, n, n); fallback (n, n). The positive-definite ones (most) are only symmetrised (a
    compiled Cholesky test decides them); the others go through the scalar function itself
    (eigendecomposition), one by one. Unchecked vehicles: COVARIANCE_OK, P untouched.
    """
    outcomes = np.full(P.shape[0], gating.COVARIANCE_OK)
    for i in np.flatnonzero(_symmetrise_checked(P, np.asarray(check, dtype=bool))):
        P[i], outcomes[i] = gating.repaired_covariance(P[i], fallback)
    return outcomes


def repaired_covariance(P, fallback):
    """(P', outcomes (M,)) of ``gating.repaired_covariance`` per row: symmetrised, clipped or reset."""
    P = np.array(P, dtype=float)
    return P, repair_covariances(P, np.ones(P.shape[0], dtype=bool), fallback)


def fuse_gps(rows, stamps, z, x, P, diagnostics, book, update, R, gates):
    """Fuse the fresh GPS samples of the vehicles ``rows`` through the gates (``gating``'s GPS policy).

    rows: int indices (or a full slice) of the vehicles whose sample is fresh; stamps (N,) s; z
    (N, 6) the samples (p m, v m/s); x (N, n), P (N, n, n), diagnostics (N, DIAGNOSTICS_SIZE),
    book (N, BOOK_SIZE): updated IN PLACE for those rows; update(x, P, z, R, mask) -> (x', P',
    nis) a batched update of the components in mask (N, 6) (:func:`ekf7_gps_update`,
    :func:`eskf_gps_update`); R (6, 6); gates a ``gating.GpsGates``. The GPS states are the
    first six of x (p, v) in both estimators.

    Per vehicle: the stamp is booked; a non-finite stamp or sample counts a non-finite sample and
    keeps (x, P); otherwise the joint 6-dof NIS of the prior and the stamp are logged, the groups
    the gates accept are fused in one update, and the groups ``gating.gps_gate_decisions`` resets
    are set to the sample; ``gps_gated`` counts the samples with a rejected group, ``gps_resets``
    those with a reset.
    """
    s = stamps[rows]
    book[rows, GPS_SLOT] = s
    index = np.arange(x.shape[0])[rows]
    z_rows = z[rows]
    valid = np.isfinite(s) & np.isfinite(z_rows).all(axis=1)
    diagnostics[index[~valid], DIAG["nonfinite_samples"]] += 1.0
    if not valid.any():
        return
    index, s, z_rows = index[valid], s[valid], z_rows[valid]
    x_prior, P_prior = x[index], P[index]
    nu = z_rows - x_prior[:, 0:6]
    S = P_prior[:, 0:6, 0:6] + R
    diagnostics[index, DIAG["gps_nis"]] = gating.innovation_nis(nu, S)
    diagnostics[index, DIAG["gps_stamp"]] = s
    policy_book = book[index, GPS_POLICY]
    accepted, reset = gating.gps_gate_decisions(gating.gps_group_nis(nu, S), s, policy_book, gates)
    book[index, GPS_POLICY] = policy_book
    diagnostics[index[~accepted.all(axis=1)], DIAG["gps_gated"]] += 1.0
    diagnostics[index[reset.any(axis=1)], DIAG["gps_resets"]] += 1.0
    x_new, P_new, _ = update(x_prior, P_prior, z_rows, R, gating.component_mask(accepted))
    for g, components in enumerate(gating.GPS_GROUP_COMPONENTS):
        due = reset[:, g]
        if due.any():
            idx = list(components)
            x_new[due], P_new[due] = gating.reset_states(
                x_new[due], P_new[due], idx, z_rows[due][:, idx], R[np.ix_(idx, idx)]
            )
    x[index] = x_new
    P[index] = P_new


# ----- error-state EKF -----------------------------------------------------------------------------


@njit_cached
def _eskf_predict_row(
    x, P, x_out, P_out, i, f_B, w_B, dt, accel_var, gyro_var, isotropic_gyro, Q_constant, work
):
    """eskf.predict of vehicle i from (x, P) into (x_out, P_out) (may be the same arrays).

    work: (R, R_next, A, FP, M) buffers, 3x3, 3x3, 5x3x3 (the transition's blocks) and two n x n.
    """
    R, R_next, A, FP, M = work
    n = P.shape[1]
    h = 0.5 * dt * dt
    # nominal step (eskf.predict_nominal)
    qw, qx, qy, qz = x[i, 6], x[i, 7], x[i, 8], x[i, 9]
    rotation_into(qw, qx, qy, qz, R)
    fx, fy, fz = f_B[i, 0] - x[i, 10], f_B[i, 1] - x[i, 11], f_B[i, 2] - x[i, 12]
    ux = R[0, 0] * fx + R[0, 1] * fy + R[0, 2] * fz
    uy = R[1, 0] * fx + R[1, 1] * fy + R[1, 2] * fz
    uz = R[2, 0] * fx + R[2, 1] * fy + R[2, 2] * fz
    az = uz + GRAVITY
    dq = _quat_exp((w_B[i, 0] - x[i, 13]) * dt, (w_B[i, 1] - x[i, 14]) * dt, (w_B[i, 2] - x[i, 15]) * dt)
    qw, qx, qy, qz = _quat_mul(qw, qx, qy, qz, dq[0], dq[1], dq[2], dq[3])
    norm = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    qw, qx, qy, qz = qw * norm, qx * norm, qy * norm, qz * norm
    x_out[i, 0] = x[i, 0] + x[i, 3] * dt + ux * h
    x_out[i, 1] = x[i, 1] + x[i, 4] * dt + uy * h
    x_out[i, 2] = x[i, 2] + x[i, 5] * dt + az * h
    x_out[i, 3] = x[i, 3] + ux * dt
    x_out[i, 4] = x[i, 4] + uy * dt
    x_out[i, 5] = x[i, 5] + az * dt
    x_out[i, 6], x_out[i, 7], x_out[i, 8], x_out[i, 9] = qw, qx, qy, qz
    for k in range(10, 16):
        x_out[i, k] = x[i, k]
    rotation_into(qw, qx, qy, qz, R_next)
    # error transition F = I + E (eskf.fill_transition): E's blocks, A[0] = -[u]x h, A[1] = -[u]x dt,
    # A[2] = -R h, A[3] = -R dt, A[4] = -R' dt (3x3 each); F P F^T = (F (F P)^T)^T from them
    for k, scale in enumerate((h, dt)):
        A[k, 0, 0], A[k, 0, 1], A[k, 0, 2] = 0.0, uz * scale, -uy * scale
        A[k, 1, 0], A[k, 1, 1], A[k, 1, 2] = -uz * scale, 0.0, ux * scale
        A[k, 2, 0], A[k, 2, 1], A[k, 2, 2] = uy * scale, -ux * scale, 0.0
    for a in range(3):
        for b in range(3):
            A[2, a, b] = R[a, b] * -h
            A[3, a, b] = R[a, b] * -dt
            A[4, a, b] = R_next[a, b] * -dt
    biases = n == _ESKF_BIASES
    _apply_transition(P[i], FP, A, dt, biases)  # F P
    _apply_transition(FP.T, M, A, dt, biases)  # F (F P)^T = (F P F^T)^T: symmetrised below
    for r in range(n):
        for c in range(n):
            P_out[i, r, c] = (M[r, c] + M[c, r]) * 0.5 + Q_constant[r, c]
    # attitude-dependent process noise (eskf.fill_process_noise)
    for a in range(6):
        ga = h if a < 3 else dt
        for b in range(6):
            gb = h if b < 3 else dt
            q = 0.0
            for k in range(3):
                q += (ga * R[a % 3, k]) * accel_var[k] * (gb * R[b % 3, k])
            P_out[i, a, b] = (M[a, b] + M[b, a]) * 0.5 + q
    if not isotropic_gyro:
        for a in range(3):
            for b in range(3):
                q = 0.0
                for k in range(3):
                    q += R[a, k] * (gyro_var[k] * (dt * dt)) * R[b, k]
                P_out[i, 6 + a, 6 + b] = (M[6 + a, 6 + b] + M[6 + b, 6 + a]) * 0.5 + q


@njit_cached
def _apply_transition(S, D, A, dt, biases):
    """D = F S, column by column, for an (n, n) S (a transposed view too) and the error transition
    F = I + E of the blocks A (see _eskf_predict_row): only E's nonzero blocks are multiplied."""
    for c in range(S.shape[1]):
        for r in range(3):
            p = S[r, c] + dt * S[3 + r, c]
            w = S[3 + r, c]
            t = S[6 + r, c]
            for k in range(3):
                p += A[0, r, k] * S[6 + k, c]
                w += A[1, r, k] * S[6 + k, c]
            if biases:
                for k in range(3):
                    p += A[2, r, k] * S[9 + k, c]
                    w += A[3, r, k] * S[9 + k, c]
                    t += A[4, r, k] * S[12 + k, c]
            D[r, c], D[3 + r, c], D[6 + r, c] = p, w, t
        for r in range(9, S.shape[0]):
            D[r, c] = S[r, c]


@njit_cached
def _eskf_work(n):
    return np.empty((3, 3)), np.empty((3, 3)), np.empty((5, 3, 3)), np.empty((n, n)), np.empty((n, n))


@njit_cached
def _eskf_predict_rows(x, P, f_B, w_B, dt, accel_var, gyro_var, isotropic_gyro, Q_constant):
    x_new, P_new = np.empty_like(x), np.empty_like(P)
    work = _eskf_work(P.shape[1])
    for i in range(x.shape[0]):
        _eskf_predict_row(
            x, P, x_new, P_new, i, f_B, w_B, dt, accel_var, gyro_var, isotropic_gyro, Q_constant, work
        )
    return x_new, P_new


@njit_cached
def _eskf_tick(x, P, hold, imu, estimate, diagnostics, dt, accel_var, gyro_var, isotropic_gyro, Q_constant):
    work = _eskf_work(P.shape[1])
    healthy = np.empty(x.shape[0], dtype=np.bool_)
    weight = dt / (IMU_HOLD_TIME + dt)
    for i in range(x.shape[0]):
        status = _bridge_imu_row(imu, hold, i, weight)
        if status != IMU_FINITE:
            diagnostics[i, _NONFINITE] += 1.0
        source = imu if status == IMU_FINITE else hold[:, 0:6]
        if status != IMU_MISSING:
            _eskf_predict_row(
                x, P, x, P, i, source[:, 0:3], source[:, 3:6], dt, accel_var, gyro_var, isotropic_gyro,
                Q_constant, work,
            )  # fmt: skip
        for k in range(3):
            estimate[i, 10 + k] = imu[i, 3 + k] - x[i, 13 + k] if status == IMU_FINITE else math.nan
        healthy[i] = _row_healthy(P, i)
    return healthy


def _noise_arguments(noise, Q_constant):
    gyro = noise.gyro_var
    return noise.accel_var, gyro, bool(gyro[0] == gyro[1] == gyro[2]), np.asarray(Q_constant, dtype=float)


def eskf_predict(x, P, f_B, w_B, dt, noise, Q_constant):
    """(x', P') after one IMU step (``eskf.predict`` per row): nominal step, P' = F P F^T symmetrised + Q.

    x (N, 16); P (N, n, n), n = 15 or 9; noise: eskf.NoiseModel; Q_constant: ``eskf.noise_buffer(n,
    noise, dt)`` (the attitude-independent blocks).
    """
    return _eskf_predict_rows(x, P, f_B, w_B, float(dt), *_noise_arguments(noise, Q_constant))


def eskf_predict_tick(x, P, hold, imu, estimate, diagnostics, dt, noise, Q_constant):
    """The prediction of one ESKF tick IN PLACE on x (N, 16), P (N, n, n) (``systems.estimators.Eskf``).

    A vehicle takes :func:`eskf_predict` with its IMU sample (N, 6) and its body rate estimate[:,
    10:13] (N, 13) becomes gyro - gyro bias. Over a non-finite sample (counted in diagnostics) it
    dead-reckons on its running mean hold (N, HOLD_SIZE; :data:`IMU_HOLD_TIME`) and its body rate
    is NaN (not measured: the controller then commands no body moment); before its first finite
    sample it is not predicted. Returns :func:`covariance_looks_healthy` of the new P.
    """
    return _eskf_tick(x, P, hold, imu, estimate, diagnostics, float(dt), *_noise_arguments(noise, Q_constant))


@njit_cached
def _inject_row(x, P, i, dx):
    """eskf.inject of the error dx (n,) into vehicle i, IN PLACE on x and P."""
    n = P.shape[1]
    for k in range(6):
        x[i, k] += dx[k]
    t0, t1, t2 = 0.5 * dx[6], 0.5 * dx[7], 0.5 * dx[8]
    e = _quat_exp(dx[6], dx[7], dx[8])
    q = _quat_mul(e[0], e[1], e[2], e[3], x[i, 6], x[i, 7], x[i, 8], x[i, 9])
    norm = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    for k in range(4):
        x[i, 6 + k] = q[k] * norm
    if n == _ESKF_BIASES:
        for k in range(6):
            x[i, 10 + k] += dx[9 + k]
    # rows 6:9 <- A P[6:9, :], then columns 6:9 <- P[:, 6:9] A^T, A = I + [dtheta]x / 2
    for c in range(n):
        r6, r7, r8 = P[i, 6, c], P[i, 7, c], P[i, 8, c]
        P[i, 6, c] = r6 - t2 * r7 + t1 * r8
        P[i, 7, c] = t2 * r6 + r7 - t0 * r8
        P[i, 8, c] = -t1 * r6 + t0 * r7 + r8
    for r in range(n):
        c6, c7, c8 = P[i, r, 6], P[i, r, 7], P[i, r, 8]
        P[i, r, 6] = c6 - c7 * t2 + c8 * t1
        P[i, r, 7] = c6 * t2 + c7 - c8 * t0
        P[i, r, 8] = -c6 * t1 + c7 * t0 + c8


@njit_cached
def _inject_rows(x, P, dx):
    x, P = x.copy(), P.copy()
    for i in range(x.shape[0]):
        _inject_row(x, P, i, dx[i])
    return x, P


def eskf_inject(x, P, dx):
    """(x', P'): errors dx (N, n) injected into the nominal x (N, 16), P reset by G (``eskf.inject``)."""
    return _inject_rows(x, P, dx)


def eskf_gps_update(x, P, gps_pv, R_gps, mask=None):
    """(x', P', nis) after GPS samples gps_pv (N, 6) with R_gps (6, 6) (``eskf.gps_update`` per row).

    mask: the components each vehicle fuses, as :func:`ekf7_gps_update`. A vehicle whose
    innovation covariance is singular keeps (x, P) with NaN NIS, as the scalar one.
    """
    z = np.asarray(gps_pv, dtype=float)
    x_new, P_new, nis, _ = _gps_rows(x, P, z, R_gps, True, _component_mask(mask, len(z)))
    return x_new, P_new, nis


@njit_cached
def _eskf_mag_innovation(x, P, i, yaw_meas, r, b):
    """(nu rad, S rad^2) of vehicle i's magnetometer yaw, b = P H^T into the n-buffer b (eskf.mag_update)."""
    qw, qx, qy, qz = x[i, 6], x[i, 7], x[i, 8], x[i, 9]
    r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
    r10 = 2.0 * (qx * qy + qw * qz)
    r20 = 2.0 * (qx * qz - qw * qy)
    d = r00 * r00 + r10 * r10
    h0, h1 = -r00 * r20 / d, -r10 * r20 / d
    for a in range(P.shape[1]):
        b[a] = P[i, a, 6] * h0 + P[i, a, 7] * h1 + P[i, a, 8]
    return _wrap(yaw_meas - math.atan2(r10, r00)), b[6] * h0 + b[7] * h1 + b[8] + r


@njit_cached
def _eskf_mag_apply(x_out, P_out, i, nu, S, b, K):
    """eskf.mag_update's posterior of vehicle i IN PLACE on (x_out, P_out), which hold the prior."""
    n = P_out.shape[1]
    for a in range(n):
        K[a] = b[a] / S
    for a in range(n):
        for c in range(n):
            P_out[i, a, c] = P_out[i, a, c] - K[a] * b[c] - K[c] * b[a] + S * (K[a] * K[c])
    for a in range(n):
        K[a] *= nu
    _inject_row(x_out, P_out, i, K)


@njit_cached
def _eskf_mag_rows(x, P, yaw_meas, r):
    x_new, P_new = x.copy(), P.copy()
    nis = np.full(x.shape[0], np.nan)
    b, K = np.empty(P.shape[1]), np.empty(P.shape[1])
    for i in range(x.shape[0]):
        if math.isfinite(yaw_meas[i]):
            nu, S = _eskf_mag_innovation(x, P, i, yaw_meas[i], r, b)
            _eskf_mag_apply(x_new, P_new, i, nu, S, b, K)
            nis[i] = nu * nu / S
    return x_new, P_new, nis


def eskf_mag_update(x, P, yaw_meas, R_mag):
    """(x', P', nis) after magnetometer yaws (N,) rad with R_mag (1, 1) (``eskf.mag_update`` per row)."""
    return _eskf_mag_rows(x, P, np.asarray(yaw_meas, dtype=float), float(R_mag[0, 0]))


@njit_cached
def _eskf_mag_tick(x, P, mag, diagnostics, book, r, threshold):
    b, K = np.empty(P.shape[1]), np.empty(P.shape[1])
    for i in range(x.shape[0]):
        if _fresh_mag(mag, book, diagnostics, i):
            nu, S = _eskf_mag_innovation(x, P, i, mag[i, 0], r, b)
            if _mag_gate(diagnostics, i, nu * nu / S, mag[i, 1], threshold):
                _eskf_mag_apply(x, P, i, nu, S, b, K)


def eskf_mag_tick(x, P, mag, diagnostics, book, R_mag, threshold):
    """The magnetometer step of one ESKF tick IN PLACE: :func:`ekf7_mag_tick` with :func:`eskf_mag_update`."""
    _eskf_mag_tick(x, P, mag, diagnostics, book, float(R_mag[0, 0]), float(threshold))


# ----- GPS delay compensation ----------------------------------------------------------------------


def odometry_step(odometry, estimate, previous, previous_velocity_step, fused, period):
    """(odometry (N, 6), velocity step (N, 3)) after one tick (``delay_compensation.odometry_step`` per row).

    odometry, estimate, previous (N, 6: p m, v m/s); previous_velocity_step (N, 3); fused (N,) bool.
    """
    fused = fused[:, None]
    dp = np.where(fused, previous[:, 3:6] * period, estimate[:, 0:3] - previous[:, 0:3])
    dv = np.where(fused, previous_velocity_step, estimate[:, 3:6] - previous[:, 3:6])
    return np.concatenate((odometry[:, 0:3] + dp, odometry[:, 3:6] + dv), axis=1), dv


def predicted_odometry(odometry, velocity, velocity_step, period):
    """(N, 6) odometry one tick ahead (``delay_compensation.predicted_odometry`` per row)."""
    return np.concatenate((odometry[:, 0:3] + velocity * period, odometry[:, 3:6] + velocity_step), axis=1)


def compensated_gps(sample, row_then, odometry_now):
    """(N, 7) GPS samples shifted by the predicted motion since their stamps (``compensated_gps`` per row).

    sample (N, 7); row_then (N, 7) the history rows at the stamps (a NaN time: no row);
    odometry_now (N, 6). Rows whose history time does not match the stamp pass unchanged.
    """
    out = np.array(sample, dtype=float)
    match = np.abs(row_then[:, 0] - sample[:, 6]) <= TIME_TOLERANCE
    out[match, 0:6] = sample[match, 0:6] + odometry_now[match] - row_then[match, 1:7]
    return out
