"""Pure: the estimators' scalar functions in batched array form, for fleets of N vehicles.

Every function here is the array form of one scalar function (named in its docstring) with a
leading vehicle axis: the same arithmetic, vectorised with numpy, and tested against the scalar
function on seeded random inputs to 1e-12 (``tests/test_fleet_estimators.py``). The scalar
functions (``estimation/complementary.py``, ``ekf.py``, ``eskf.py``, ``gating.py`` and
``delay_compensation.py``) stay the reference implementation; their docstrings give the
units, frames and conventions, which are the same here.

Shapes: a state x is (N, n), a covariance P (N, n, n), a specific force f_B or gyro sample w_B
(N, 3) (m/s^2, rad/s, FRD), an angle, stamp or NIS (N,), a per-vehicle flag (N,) bool. Inputs
are not modified unless a docstring says so. A non-finite measurement leaves its vehicle's
(x, P) unchanged and gives NaN NIS, as the scalar updates do; the arithmetic never touches it.
"""

import math

import numpy as np

from quad_drake.conventions import GRAVITY, NO_SAMPLE_STAMP
from quad_drake.delay_compensation import TIME_TOLERANCE
from quad_drake.estimation import eskf, gating
from quad_drake.estimation.complementary import VARIANTS
from quad_drake.estimation.vocabulary import DIAG
from quad_drake.rotations import wrap_angles

GPS_SLOT, MAG_SLOT, GPS_REJECTION_START = 0, 1, 2
"""Columns of an estimator's book (N, 3): last GPS stamp seen, last mag stamp seen, start of the
GPS rejection run (as ``systems/estimators.py``)."""
_NIS_COLUMN = {GPS_SLOT: DIAG["gps_nis"], MAG_SLOT: DIAG["mag_nis"]}
_GATED_COLUMN = {GPS_SLOT: DIAG["gps_gated"], MAG_SLOT: DIAG["mag_gated"]}


# ----- rotations -----------------------------------------------------------------------------------


def quat_from_euler(roll, pitch, yaw):
    """(w, x, y, z) arrays of R = Rz(yaw) Ry(pitch) Rx(roll) (``rotations.quat_from_euler_tuple``)."""
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quat(w, x, y, z):
    """(roll, pitch, yaw) arrays, rad, of wxyz quaternions, any norm (``rotations.euler_from_quat``)."""
    n2 = w * w + x * x + y * y + z * z
    roll = np.arctan2(2.0 * (y * z + w * x), w * w - x * x - y * y + z * z)
    pitch = np.arcsin(np.minimum(np.maximum(-2.0 * (x * z - w * y) / n2, -1.0), 1.0))
    yaw = np.arctan2(2.0 * (x * y + w * z), w * w + x * x - y * y - z * z)
    return roll, pitch, yaw


def quat_exp(tx, ty, tz):
    """(w, x, y, z) arrays of unit quaternions of rotation vectors (tx, ty, tz) rad (``eskf.quat_exp``)."""
    angle = np.sqrt(tx * tx + ty * ty + tz * tz)
    small = angle < 1e-12
    safe = np.where(small, 1.0, angle)
    s = np.sin(0.5 * safe) / safe
    return (
        np.where(small, 1.0, np.cos(0.5 * safe)),
        np.where(small, 0.5 * tx, tx * s),
        np.where(small, 0.5 * ty, ty * s),
        np.where(small, 0.5 * tz, tz * s),
    )


def quat_mul(a, b):
    """Hamilton products a (x) b of two (w, x, y, z) tuples of arrays (``eskf.quat_mul``)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


# ----- complementary filter ------------------------------------------------------------------------


def accel_roll_pitch(f_B, reference_accelerometer=False):
    """(roll, pitch) arrays, rad, of gravity alone in f_B (N, 3) (``complementary.accel_roll_pitch``)."""
    fx, fy, fz = f_B[:, 0], f_B[:, 1], f_B[:, 2]
    if reference_accelerometer:
        return np.arctan2(fy, fz), np.arctan2(-fx, GRAVITY)
    return np.arctan2(-fy, -fz), np.arctan2(fx, np.hypot(fy, fz))


def integrate_euler_exact(roll, pitch, yaw, w_B, dt):
    """ZYX angles after dt s at constant body rates w_B (N, 3) (``complementary.integrate_euler_exact``)."""
    wx, wy, wz = w_B[:, 0], w_B[:, 1], w_B[:, 2]
    qw, qx, qy, qz = quat_from_euler(roll, pitch, yaw)
    rate = np.sqrt(wx * wx + wy * wy + wz * wz)
    turning = rate > 1e-12
    safe = np.where(turning, rate, 1.0)
    s = np.where(turning, np.sin(0.5 * safe * dt) / safe, 0.5 * dt)
    c = np.cos(0.5 * rate * dt)
    dx, dy, dz = wx * s, wy * s, wz * s
    return euler_from_quat(
        qw * c - qx * dx - qy * dy - qz * dz,
        qw * dx + qx * c + qy * dz - qz * dy,
        qw * dy - qx * dz + qy * c + qz * dx,
        qw * dz + qx * dy - qy * dx + qz * c,
    )


def complementary_update(attitude, f_B, w_B, dt, tau, variant, reference_accelerometer=False):
    """(N, 3) roll, pitch, yaw after one filter step from the prior ``attitude`` (N, 3), rad.

    ``complementary.complementary_update`` per row; f_B, w_B (N, 3); dt, tau s; variant
    ``"nonlinear"`` or ``"small_angle"``.
    """
    roll, pitch, yaw = attitude[:, 0], attitude[:, 1], attitude[:, 2]
    if variant == "nonlinear":
        roll_pred, pitch_pred, yaw_pred = integrate_euler_exact(roll, pitch, yaw, w_B, dt)
    elif variant == "small_angle":
        roll_pred = roll + dt * w_B[:, 0]
        pitch_pred = pitch + dt * w_B[:, 1]
        yaw_pred = yaw + dt * w_B[:, 2]
    else:
        raise ValueError(f"unknown attitude filter variant {variant!r}; expected one of {VARIANTS}")
    roll_acc, pitch_acc = accel_roll_pitch(f_B, reference_accelerometer)
    gyro_weight = tau / (tau + dt)
    accel_weight = dt / (tau + dt)
    out = np.empty_like(attitude)
    out[:, 0] = gyro_weight * roll_pred + accel_weight * roll_acc
    out[:, 1] = gyro_weight * pitch_pred + accel_weight * pitch_acc
    out[:, 2] = wrap_angles(yaw_pred)
    return out


# ----- 7-state EKF ---------------------------------------------------------------------------------


def _rotate_specific_force(roll, pitch, yaw, f_B):
    """(R_NB f_B, dR_NB/dyaw f_B) as tuples of 3 and 2 arrays (the derivative's z entry is 0)."""
    fx, fy, fz = f_B[:, 0], f_B[:, 1], f_B[:, 2]
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    rolled_z = sr * fy + cr * fz
    ux = cp * fx + sp * rolled_z
    uy = cr * fy - sr * fz
    uz = -sp * fx + cp * rolled_z
    return (cy * ux - sy * uy, sy * ux + cy * uy, uz), (-sy * ux - cy * uy, cy * ux - sy * uy)


def ekf7_predict_with_yaw(x, P, attitude, f_B, dt, Q, reference_accelerometer=False):
    """(x', P') of the EKF7's 500 Hz step (``ekf.predict_with_yaw``): yaw <- attitude yaw, then predict.

    x (N, 7); P (N, 7, 7); attitude (N, 3) roll, pitch, yaw rad; f_B (N, 3); Q (7, 7). P' = G P G^T
    symmetrised + Q, formed from G's sparsity (I7 plus dt at (0..2, 3..5) and R' f dt at (3..5, 6)).
    """
    gravity_z = -GRAVITY if reference_accelerometer else GRAVITY
    rf, rf_yaw = _rotate_specific_force(attitude[:, 0], attitude[:, 1], attitude[:, 2], f_B)
    x_new = np.empty_like(x)
    x_new[:, 0:3] = x[:, 0:3] + x[:, 3:6] * dt
    x_new[:, 3] = x[:, 3] + rf[0] * dt
    x_new[:, 4] = x[:, 4] + rf[1] * dt
    x_new[:, 5] = x[:, 5] + (rf[2] + gravity_z) * dt
    x_new[:, 6] = attitude[:, 2]
    g3, g4 = (rf_yaw[0] * dt)[:, None], (rf_yaw[1] * dt)[:, None]
    GP = P.copy()
    GP[:, 0:3, :] += P[:, 3:6, :] * dt
    GP[:, 3, :] += g3 * P[:, 6, :]
    GP[:, 4, :] += g4 * P[:, 6, :]
    S = GP.copy()
    S[:, :, 0:3] += GP[:, :, 3:6] * dt
    S[:, :, 3] += g3 * GP[:, :, 6]
    S[:, :, 4] += g4 * GP[:, :, 6]
    P_new = S + S.transpose(0, 2, 1)
    P_new *= 0.5
    P_new += Q
    return x_new, P_new


def _finite_rows(z):
    """(finite (M,), z with non-finite rows zeroed): the rows an update may use."""
    finite = np.isfinite(z).all(axis=1) if z.ndim == 2 else np.isfinite(z)
    if finite.all():
        return finite, z
    safe = np.where(finite[:, None] if z.ndim == 2 else finite, z, 0.0)
    return finite, safe


def _skip_nonfinite(finite, x, P, x_new, P_new, nis):
    """x_new, P_new, nis with the rows of non-finite samples back to (x, P, NaN)."""
    if finite.all():
        return x_new, P_new, nis
    keep = ~finite
    x_new[keep] = x[keep]
    P_new[keep] = P[keep]
    nis[keep] = math.nan
    return x_new, P_new, nis


def _position_velocity_update(P, R, nu):
    """(K (M, n, 6), P' (M, n, n), nis) of a Joseph update with H = [I6 0] (``ekf.kalman_update``).

    S = P[:6, :6] + R; [K^T | S^-1 nu] = S^-1 [H P | nu]; P' = (I - K H) P (I - K H)^T + K R K^T,
    symmetrised. Raises LinAlgError when an S is singular.
    """
    n = P.shape[1]
    S = P[:, 0:6, 0:6] + R
    rhs = np.concatenate((P[:, 0:6, :], nu[:, :, None]), axis=2)
    solved = np.linalg.solve(S, rhs)
    K = solved[:, :, :n].transpose(0, 2, 1)
    I_KH = np.broadcast_to(np.eye(n), P.shape).copy()
    I_KH[:, :, 0:6] -= K
    P_new = np.matmul(np.matmul(I_KH, P), I_KH.transpose(0, 2, 1))
    P_new += np.matmul(np.matmul(K, R), K.transpose(0, 2, 1))
    P_new += P_new.transpose(0, 2, 1).copy()
    P_new *= 0.5
    return K, P_new, np.einsum("ij,ij->i", nu, solved[:, :, n])


def ekf7_gps_update(x, P, gps_pv, R_gps):
    """(x', P', nis) after GPS samples gps_pv (N, 6: p m, v m/s) with R_gps (6, 6) (``ekf.gps_update``)."""
    finite, z = _finite_rows(gps_pv)
    nu = z - x[:, 0:6]
    K, P_new, nis = _position_velocity_update(P, R_gps, nu)
    x_new = x + np.einsum("nij,nj->ni", K, nu)
    return _skip_nonfinite(finite, x, P, x_new, P_new, nis)


def ekf7_mag_update(x, P, yaw_meas, R_mag):
    """(x', P', nis) after magnetometer yaws (N,) rad with R_mag (1, 1) (``ekf.mag_update``)."""
    finite, yaw_meas = _finite_rows(yaw_meas)
    nu = wrap_angles(yaw_meas - x[:, 6])
    p6 = P[:, :, 6]
    S = p6[:, 6] + R_mag[0, 0]
    K = p6 / S[:, None]
    KhP = K[:, :, None] * p6[:, None, :]
    P_new = P - (KhP + KhP.transpose(0, 2, 1)) + S[:, None, None] * (K[:, :, None] * K[:, None, :])
    x_new = x + K * nu[:, None]
    x_new[:, 6] = wrap_angles(x_new[:, 6])
    return _skip_nonfinite(finite, x, P, x_new, P_new, nu * nu / S)


# ----- gating and covariance health ----------------------------------------------------------------


def rejection_start(previous_start, accepted, stamp):
    """(M,) start of each rejection run, s: NaN where accepted (``gating.rejection_start``)."""
    return np.where(accepted, math.nan, np.where(np.isnan(previous_start), stamp, previous_start))


def reset_due(start, stamp, timeout):
    """(M,) True where rejected continuously for >= timeout s (> 0) (``gating.reset_due``)."""
    if not timeout > 0.0:
        return np.zeros(np.shape(start), dtype=bool)
    return ~np.isnan(start) & (stamp - start >= timeout)


def reset_states(x, P, indices, values, covariance):
    """(x', P') with x[:, indices] = values (M, m), that block of P = covariance (m, m), no cross terms.

    ``gating.reset_states`` per row; returns new arrays.
    """
    x = np.array(x, dtype=float)
    P = np.array(P, dtype=float)
    idx = np.asarray(indices)
    x[:, idx] = values
    P[:, idx, :] = 0.0
    P[:, :, idx] = 0.0
    P[:, idx[:, None], idx[None, :]] = covariance
    return x, P


def covariance_looks_healthy(P):
    """(N,) cheap per-tick check: all entries finite, variances >= 0 (``gating.covariance_looks_healthy``)."""
    return np.isfinite(P.sum(axis=(1, 2))) & (np.diagonal(P, axis1=1, axis2=2).min(axis=1) >= 0.0)


def _positive_definite(S):
    """(M,) True where the symmetric S (M, n, n) has a Cholesky factor in floating point (all pivots > 0).

    A successful factorisation bounds the smallest eigenvalue below by about -n^2 eps max(diag S),
    far inside ``gating.repaired_covariance``'s -1e-12 |largest| tolerance, so those matrices need
    no eigendecomposition: they are COVARIANCE_OK.
    """
    A = S.copy()
    ok = np.ones(S.shape[0], dtype=bool)
    n = S.shape[1]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for k in range(n):
            pivot = A[:, k, k]
            ok &= pivot > 0.0
            if k + 1 < n:
                column = A[:, k + 1 :, k] / np.sqrt(np.where(ok, pivot, 1.0))[:, None]
                A[:, k + 1 :, k + 1 :] -= column[:, :, None] * column[:, None, :]
    return ok


def repaired_covariance(P, fallback):
    """(P', outcomes (M,)) of ``gating.repaired_covariance`` per row: symmetrised, clipped or reset.

    The positive-definite rows (most) are decided by a batched Cholesky test; the others go
    through the scalar function itself (eigendecomposition), one by one.
    """
    P = np.asarray(P, dtype=float)
    P_new = P + P.transpose(0, 2, 1)
    P_new *= 0.5
    outcomes = np.full(P.shape[0], gating.COVARIANCE_OK)
    finite = np.isfinite(P).all(axis=(1, 2))
    unclear = np.flatnonzero(finite)[~_positive_definite(P_new[finite])]
    for i in np.concatenate((np.flatnonzero(~finite), unclear)):
        P_new[i], outcomes[i] = gating.repaired_covariance(P[i], fallback)
    return P_new, outcomes


def fuse(slot, rows, stamps, z, x, P, diagnostics, book, update, R, threshold, reset_timeout=0.0, reset=()):
    """Fuse the fresh samples of the vehicles ``rows`` (the fleet form of ``_GatedFusion._fuse``).

    slot: GPS_SLOT or MAG_SLOT; rows: int indices (or a full slice) of the vehicles whose sample
    is fresh; stamps (N,) s; z (N, m) or (N,) the samples; x (N, n), P (N, n, n), diagnostics
    (N, DIAGNOSTICS_SIZE), book (N, 3): updated IN PLACE for those rows; update(x, P, z, R) ->
    (x', P', nis) a batched update; threshold: the gate's NIS threshold; reset_timeout (s) and
    reset (the state indices the GPS measures): the reset to the GPS after continuous rejection.

    Per vehicle, as the scalar path: the stamp is booked; a non-finite stamp or sample counts a
    non-finite sample and keeps (x, P); otherwise the NIS and stamp are logged and the gate
    accepts the update, or keeps the prior and counts it gated, and after ``reset_timeout`` s
    of GPS rejection resets the GPS states to the sample (counted).
    """
    s = stamps[rows]
    book[rows, slot] = s
    x_prior, P_prior, z_rows = x[rows], P[rows], z[rows]
    finite_stamp = np.isfinite(s)
    if not finite_stamp.all():
        z_rows = np.where(finite_stamp[:, None] if z_rows.ndim == 2 else finite_stamp, z_rows, math.nan)
    x_new, P_new, nis = update(x_prior, P_prior, z_rows, R)
    index = np.arange(x.shape[0])[rows]
    valid = ~np.isnan(nis)
    diagnostics[index[~valid], DIAG["nonfinite_samples"]] += 1.0
    diagnostics[index[valid], _NIS_COLUMN[slot]] = nis[valid]
    diagnostics[index[valid], _NIS_COLUMN[slot] + 1] = s[valid]
    accepted = valid & (nis <= threshold)
    rejected = valid & ~accepted
    if slot == GPS_SLOT:
        start = book[index, GPS_REJECTION_START]
        start[valid] = rejection_start(start[valid], accepted[valid], s[valid])
        book[index, GPS_REJECTION_START] = start
    diagnostics[index[rejected], _GATED_COLUMN[slot]] += 1.0
    keep = ~accepted
    x_new[keep] = x_prior[keep]
    P_new[keep] = P_prior[keep]
    if slot == GPS_SLOT:
        due = rejected & reset_due(book[index, GPS_REJECTION_START], s, reset_timeout)
        if due.any():
            diagnostics[index[due], DIAG["gps_resets"]] += 1.0
            book[index[due], GPS_REJECTION_START] = math.nan
            x_new[due], P_new[due] = reset_states(x_prior[due], P_prior[due], reset, z_rows[due], R)
    x[rows] = x_new
    P[rows] = P_new


def fresh(stamps, seen):
    """(N,) True where a stamp differs from the last one seen and is a sample (``_fresh`` per vehicle)."""
    return (stamps != seen) & (stamps != NO_SAMPLE_STAMP)


# ----- error-state EKF -----------------------------------------------------------------------------


def _rotation_entries(qw, qx, qy, qz):
    """(N, 3, 3) R_NB of unit wxyz quaternion arrays (``eskf._rotation_entries``)."""
    R = np.empty((qw.shape[0], 3, 3))
    R[:, 0, 0] = 1 - 2 * (qy * qy + qz * qz)
    R[:, 0, 1] = 2 * (qx * qy - qw * qz)
    R[:, 0, 2] = 2 * (qx * qz + qw * qy)
    R[:, 1, 0] = 2 * (qx * qy + qw * qz)
    R[:, 1, 1] = 1 - 2 * (qx * qx + qz * qz)
    R[:, 1, 2] = 2 * (qy * qz - qw * qx)
    R[:, 2, 0] = 2 * (qx * qz - qw * qy)
    R[:, 2, 1] = 2 * (qy * qz + qw * qx)
    R[:, 2, 2] = 1 - 2 * (qx * qx + qy * qy)
    return R


def eskf_predict_nominal(x, f_B, w_B, dt):
    """(x', R_hat, R_hat', u_N) of one IMU step (``eskf.predict_nominal`` per row).

    x (N, 16) nominal; f_B, w_B (N, 3); returns x' (N, 16), R and R' (N, 3, 3), u_N (N, 3).
    """
    qw, qx, qy, qz = x[:, 6], x[:, 7], x[:, 8], x[:, 9]
    R = _rotation_entries(qw, qx, qy, qz)
    f = f_B - x[:, 10:13]
    u = np.empty_like(f)
    for i in range(3):
        u[:, i] = R[:, i, 0] * f[:, 0] + R[:, i, 1] * f[:, 1] + R[:, i, 2] * f[:, 2]
    a = u.copy()
    a[:, 2] += GRAVITY
    h = 0.5 * dt * dt
    w = (w_B - x[:, 13:16]) * dt
    q = quat_mul((qw, qx, qy, qz), quat_exp(w[:, 0], w[:, 1], w[:, 2]))
    n = 1.0 / np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    x_new = np.empty_like(x)
    x_new[:, 0:3] = x[:, 0:3] + x[:, 3:6] * dt + a * h
    x_new[:, 3:6] = x[:, 3:6] + a * dt
    for i in range(4):
        x_new[:, 6 + i] = q[i] * n
    x_new[:, 10:16] = x[:, 10:16]
    return x_new, R, _rotation_entries(x_new[:, 6], x_new[:, 7], x_new[:, 8], x_new[:, 9]), u


def _add_product(Y, rows, A, X, cols):
    """Y[:, rows:rows+3] += A @ X[:, cols:cols+3] for A (N, 3, 3), X (N, n, m), written out."""
    X0, X1, X2 = X[:, cols], X[:, cols + 1], X[:, cols + 2]
    for i in range(3):
        Y[:, rows + i] += A[:, i, 0, None] * X0 + A[:, i, 1, None] * X1 + A[:, i, 2, None] * X2


def _apply_transition(X, minus_skew_u, R, R_next, dt):
    """F X for the error transition F (``eskf.fill_transition``) and X (N, n, m), from F's blocks.

    minus_skew_u: -[u_N]x (N, 3, 3); R, R_next: R_hat before and after the step.
    """
    n = X.shape[1]
    h = 0.5 * dt * dt
    W = np.zeros((X.shape[0], 3, X.shape[2]))
    _add_product(W, 0, minus_skew_u, X, 6)
    if n == eskf.ERROR_SIZE_WITH_BIASES:
        _add_product(W, 0, -R, X, 9)
    Y = X.copy()
    Y[:, 0:3] += X[:, 3:6] * dt + W * h
    Y[:, 3:6] += W * dt
    if n == eskf.ERROR_SIZE_WITH_BIASES:
        _add_product(Y, 6, R_next * -dt, X, 12)
    return Y


def _minus_skew(u):
    """(N, 3, 3) -[u]x of u (N, 3)."""
    S = np.zeros((u.shape[0], 3, 3))
    S[:, 0, 1], S[:, 0, 2] = u[:, 2], -u[:, 1]
    S[:, 1, 0], S[:, 1, 2] = -u[:, 2], u[:, 0]
    S[:, 2, 0], S[:, 2, 1] = u[:, 1], -u[:, 0]
    return S


def _rotated_diagonal(R, variances):
    """(N, 3, 3) R diag(variances) R^T."""
    Rv = R * variances
    return (
        Rv[:, :, 0, None] * R[:, None, :, 0]
        + Rv[:, :, 1, None] * R[:, None, :, 1]
        + Rv[:, :, 2, None] * R[:, None, :, 2]
    )


def eskf_predict(x, P, f_B, w_B, dt, noise, Q_constant):
    """(x', P') after one IMU step (``eskf.predict`` per row): nominal step, P' = F P F^T symmetrised + Q.

    x (N, 16); P (N, n, n), n = 15 or 9; noise: eskf.NoiseModel; Q_constant: ``eskf.noise_buffer(n,
    noise, dt)`` (the attitude-independent blocks). F P F^T is formed from F's blocks.
    """
    x_new, R, R_next, u = eskf_predict_nominal(x, f_B, w_B, dt)
    minus_skew_u = _minus_skew(u)
    FP = _apply_transition(P, minus_skew_u, R, R_next, dt)
    FPF = _apply_transition(np.ascontiguousarray(FP.transpose(0, 2, 1)), minus_skew_u, R, R_next, dt)
    P_new = FPF + FPF.transpose(0, 2, 1)
    P_new *= 0.5
    P_new += Q_constant
    M = _rotated_diagonal(R, noise.accel_var)
    h = 0.5 * dt * dt
    P_new[:, 0:3, 0:3] += M * (h * h)
    P_new[:, 0:3, 3:6] += M * (h * dt)
    P_new[:, 3:6, 0:3] += M * (dt * h)
    P_new[:, 3:6, 3:6] += M * (dt * dt)
    if not noise.gyro_var[0] == noise.gyro_var[1] == noise.gyro_var[2]:
        P_new[:, 6:9, 6:9] += _rotated_diagonal(R, noise.gyro_var * (dt * dt))
    return x_new, P_new


def eskf_inject(x, P, dx):
    """(x', P'): errors dx (N, n) injected into the nominal x (N, 16), P reset by G (``eskf.inject``)."""
    x = np.array(x, dtype=float)
    x[:, 0:6] += dx[:, 0:6]
    t0, t1, t2 = 0.5 * dx[:, 6, None], 0.5 * dx[:, 7, None], 0.5 * dx[:, 8, None]
    q = quat_mul(quat_exp(dx[:, 6], dx[:, 7], dx[:, 8]), (x[:, 6], x[:, 7], x[:, 8], x[:, 9]))
    norm = 1.0 / np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    for i in range(4):
        x[:, 6 + i] = q[i] * norm
    if dx.shape[1] == eskf.ERROR_SIZE_WITH_BIASES:
        x[:, 10:16] += dx[:, 9:15]
    P = np.array(P, dtype=float)
    r6, r7, r8 = P[:, 6].copy(), P[:, 7].copy(), P[:, 8].copy()
    P[:, 6] = r6 - t2 * r7 + t1 * r8
    P[:, 7] = t2 * r6 + r7 - t0 * r8
    P[:, 8] = -t1 * r6 + t0 * r7 + r8
    c6, c7, c8 = P[:, :, 6].copy(), P[:, :, 7].copy(), P[:, :, 8].copy()
    P[:, :, 6] = c6 - c7 * t2 + c8 * t1
    P[:, :, 7] = c6 * t2 + c7 - c8 * t0
    P[:, :, 8] = -c6 * t1 + c7 * t0 + c8
    return x, P


def eskf_gps_update(x, P, gps_pv, R_gps):
    """(x', P', nis) after GPS samples gps_pv (N, 6) with R_gps (6, 6) (``eskf.gps_update`` per row).

    A singular innovation covariance (never seen in practice) sends the batch through the
    scalar function row by row, which returns NaN NIS for that row.
    """
    finite, z = _finite_rows(gps_pv)
    nu = z - x[:, 0:6]
    try:
        K, P_new, nis = _position_velocity_update(P, R_gps, nu)
    except np.linalg.LinAlgError:
        rows = [eskf.gps_update(x[i], P[i], gps_pv[i], R_gps) for i in range(x.shape[0])]
        return tuple(np.array([row[k] for row in rows]) for k in range(3))
    x_new, P_new = eskf_inject(x, P_new, np.einsum("nij,nj->ni", K, nu))
    return _skip_nonfinite(finite, x, P, x_new, P_new, nis)


def eskf_yaw_and_jacobian(q):
    """(yaw (N,), dyaw/dtheta (N, 3)) of nominal attitudes q (N, 4) wxyz (``eskf.yaw_and_jacobian``)."""
    qw, qx, qy, qz = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
    r10 = 2.0 * (qx * qy + qw * qz)
    r20 = 2.0 * (qx * qz - qw * qy)
    d = r00 * r00 + r10 * r10
    h = np.empty((q.shape[0], 3))
    h[:, 0] = -r00 * r20 / d
    h[:, 1] = -r10 * r20 / d
    h[:, 2] = 1.0
    return np.arctan2(r10, r00), h


def eskf_mag_update(x, P, yaw_meas, R_mag):
    """(x', P', nis) after magnetometer yaws (N,) rad with R_mag (1, 1) (``eskf.mag_update`` per row)."""
    finite, yaw_meas = _finite_rows(yaw_meas)
    yaw, h = eskf_yaw_and_jacobian(x[:, 6:10])
    b = P[:, :, 6] * h[:, 0, None] + P[:, :, 7] * h[:, 1, None] + P[:, :, 8] * h[:, 2, None]
    S = b[:, 6] * h[:, 0] + b[:, 7] * h[:, 1] + b[:, 8] * h[:, 2] + R_mag[0, 0]
    nu = wrap_angles(yaw_meas - yaw)
    K = b / S[:, None]
    Kb = K[:, :, None] * b[:, None, :]
    P_new = P - Kb
    P_new -= Kb.transpose(0, 2, 1)
    P_new += S[:, None, None] * (K[:, :, None] * K[:, None, :])
    x_new, P_new = eskf_inject(x, P_new, K * nu[:, None])
    return _skip_nonfinite(finite, x, P, x_new, P_new, nu * nu / S)


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
