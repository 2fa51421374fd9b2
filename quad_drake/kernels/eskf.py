"""The error-state EKF of N vehicles, compiled: what ``systems.estimators.Eskf`` runs each tick.

Nominal state, per vehicle (``estimation/eskf.py``): x = (p_N (3, m), v_N (3, m/s), q_NB (4,
wxyz), b_a (3, m/s^2, body), b_g (3, rad/s, body)), NED world N, FRD body B. Error state
dx = (dp, dv, dtheta (rad, world axes), db_a, db_g), n = 15 entries (9 without bias
estimation), truth = nominal (+) error; covariance P (n x n) of dx. With a barometer the nominal
has a 17th float, the baro bias (m), and dx a last entry, its error (n = 16 or 10;
``eskf.carries_baro_bias``): F = I and Q = walk² dt on it, injected as b_baro += db_baro.

Prediction over dt with the IMU sample (f_B m/s^2, w_B rad/s) held over the step
(``eskf.nominal_step``), R = R(q) before and R' after the step (``rotations.rotation_entries``):

    u   = R (f_B - b_a)                  specific force in N (m/s^2)
    a   = u + (0, 0, 9.81)
    p'  = p + v dt + a dt²/2,   v' = v + a dt,   q' = normalize(q (x) Exp((w_B - b_g) dt)),  b' = b
    F   = I + E,  E's blocks: dp/dv = I dt, dp/dtheta = -[u]x dt²/2, dv/dtheta = -[u]x dt,
          dp/db_a = -R dt²/2, dv/db_a = -R dt, dtheta/db_g = -R' dt
    P'  = sym(F P Fᵀ) + Q,   sym(M) = (M + Mᵀ) / 2
    Q   = [dt²/2 I; dt I] R diag(accel_var) Rᵀ [..]ᵀ on (p, v),  R diag(gyro_var) Rᵀ dt² on theta,
          bias random walks rate dt I on (b_a, b_g) (constant blocks: ``eskf.noise_buffer``)

Measurements (Joseph form on the error state, then injected: p += dp, v += dv,
q = normalize(Exp(dtheta) (x) q) (``eskf.injected_attitude``), b += db, and P <- G P Gᵀ with
G = I except its attitude block I + [dtheta]x / 2):

- magnetometer, z = yaw (rad): h(x) = atan2(R10, R00), H = (0, 0, H_theta, 0) with H_theta =
  (-R00 R20 / d, -R10 R20 / d, 1), d = R00² + R10² (``eskf.yaw_and_jacobian_of``), R = mag
  variance (rad²); b = P Hᵀ, nu = wrap(z - h), S = H b + R (``ekf.mag_innovation``), K = b / S,
  P' = P - K bᵀ - b Kᵀ + S K Kᵀ, dx = K nu;
- GPS, z = (p_N m, v_N m/s): h(x) = (p, v), H = [I6 0] or the rows of the groups the gates
  accept, R = diag(gps_pos_std², gps_vel_std²); the Joseph update of ``kernels/fusion.py``.

The scalar formulas above are the pure functions' own code compiled by numba (``eskf.py``,
``rotations.py``: they exist once); F P Fᵀ, Q, the mag posterior and G P Gᵀ are hand-unrolled
loops over the blocks' nonzeros, whose reference oracles are ``eskf.predict`` (with
``eskf.transition`` and ``eskf.process_noise``), ``eskf.mag_update``, ``eskf.inject`` and
``eskf.joseph_update`` (matrix form, tested to 1e-12 on seeded random inputs in
``tests/test_estimator_kernels.py``; no simulation calls them, ``tests/test_oracles.py``).

Shapes: x (N, 16 or 17), P (N, n, n), f_B, w_B (N, 3), imu (N, 6), estimate (N, 13). A non-finite
measurement leaves its vehicle's (x, P) unchanged and gives NaN NIS. Pure: numba and numpy, no
pydrake.
"""

import collections
import math

import numpy as np

from quad_drake.conventions import NO_SAMPLE_STAMP
from quad_drake.estimation import eskf
from quad_drake.estimation.vocabulary import DIAG
from quad_drake.kernels import fusion, rotations
from quad_drake.kernels.fusion import fresh_mag, looks_healthy, mag_gate, mag_innovation
from quad_drake.kernels.imu_hold import IMU_FINITE, IMU_MISSING, bridge_imu_row, hold_weight
from quad_drake.kernels.jit import compiled, njit_cached

Model = collections.namedtuple("Model", ["dt", "accel_var", "gyro_var", "isotropic_gyro", "Q_constant"])
"""The filter's constants: dt s, accel_var and gyro_var (3,) per IMU sample (``eskf.NoiseModel``),
isotropic_gyro (the gyro's Q block is then constant), Q_constant (n, n): ``eskf.noise_buffer``."""

_NONFINITE = DIAG["nonfinite_samples"]
_WITH_BIASES = eskf.ERROR_SIZE_WITH_BIASES
_BARO_SIZES = eskf.ERROR_SIZES_WITH_BARO
_BARO_NOMINAL = eskf.BARO_BIAS_NOMINAL
_quat_exp = compiled(eskf.quat_exp)
_quat_normalized = compiled(eskf.quat_normalized)
_nominal_step = compiled(
    eskf.nominal_step,
    rotation_entries=rotations.rotation_entries,
    quat_exp=_quat_exp,
    quat_mul=rotations.quat_product,
    quat_normalized=_quat_normalized,
)
_injected_attitude = compiled(
    eskf.injected_attitude,
    quat_exp=_quat_exp,
    quat_mul=rotations.quat_product,
    quat_normalized=_quat_normalized,
)
_yaw_and_jacobian = compiled(eskf.yaw_and_jacobian_of)


def model(noise, Q_constant, dt) -> Model:
    """The :class:`Model` of an ``eskf.NoiseModel`` `noise`, its Q_constant (``eskf.noise_buffer(n,
    noise, dt)``) and the predict step dt s."""
    gyro = noise.gyro_var
    isotropic = bool(gyro[0] == gyro[1] == gyro[2])
    return Model(float(dt), noise.accel_var, gyro, isotropic, np.asarray(Q_constant, dtype=float))


# ----- prediction ----------------------------------------------------------------------------------


@njit_cached
def _matrix_into(entries, R):
    """Write 9 row-major entries into R (3, 3)."""
    for a in range(3):
        for b in range(3):
            R[a, b] = entries[3 * a + b]


@njit_cached
def _apply_transition(S, D, A, dt, biases):
    """D = F S, column by column, for an (n, n) S (a transposed view too) and the error transition
    F = I + E of the blocks A (see _predict_row): only E's nonzero blocks are multiplied."""
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
def _predict_row(x, P, i, f_B, w_B, dt, accel_var, gyro_var, isotropic_gyro, Q_constant, work):
    """Vehicle i's prediction IN PLACE on x, P (the :class:`Model`'s fields as arguments); work:
    (R, R', A, FP, M) buffers, 3x3, 3x3, 5x3x3 (E's blocks) and two n x n."""
    R, R_next, A, FP, M = work
    n = P.shape[1]
    h = 0.5 * dt * dt
    prior = (
        x[i, 0], x[i, 1], x[i, 2], x[i, 3], x[i, 4], x[i, 5], x[i, 6], x[i, 7],
        x[i, 8], x[i, 9], x[i, 10], x[i, 11], x[i, 12], x[i, 13], x[i, 14], x[i, 15],
    )  # fmt: skip
    posterior, r, r_next, u_N = _nominal_step(prior, f_B, w_B, dt)
    for k in range(16):
        x[i, k] = posterior[k]
    _matrix_into(r, R)
    _matrix_into(r_next, R_next)
    ux, uy, uz = u_N
    # E's blocks: A[0] = -[u]x h, A[1] = -[u]x dt, A[2] = -R h, A[3] = -R dt, A[4] = -R' dt
    for k, scale in enumerate((h, dt)):
        A[k, 0, 0], A[k, 0, 1], A[k, 0, 2] = 0.0, uz * scale, -uy * scale
        A[k, 1, 0], A[k, 1, 1], A[k, 1, 2] = -uz * scale, 0.0, ux * scale
        A[k, 2, 0], A[k, 2, 1], A[k, 2, 2] = uy * scale, -ux * scale, 0.0
    for a in range(3):
        for b in range(3):
            A[2, a, b] = R[a, b] * -h
            A[3, a, b] = R[a, b] * -dt
            A[4, a, b] = R_next[a, b] * -dt
    biases = n >= _WITH_BIASES
    _apply_transition(P[i], FP, A, dt, biases)  # F P
    _apply_transition(FP.T, M, A, dt, biases)  # F (F P)^T = (F P F^T)^T: symmetrised below
    for r in range(n):  # P' = sym(F P F^T) + Q, Q's constant blocks
        for c in range(n):
            P[i, r, c] = (M[r, c] + M[c, r]) * 0.5 + Q_constant[r, c]
    for a in range(6):  # Q's accelerometer block G R diag(accel_var) R^T G^T, G = [h I; dt I]
        ga = h if a < 3 else dt
        for b in range(6):
            gb = h if b < 3 else dt
            q = 0.0
            for k in range(3):
                q += (ga * R[a % 3, k]) * accel_var[k] * (gb * R[b % 3, k])
            P[i, a, b] = (M[a, b] + M[b, a]) * 0.5 + q
    if not isotropic_gyro:  # Q's gyro block R diag(gyro_var) R^T dt^2
        for a in range(3):
            for b in range(3):
                q = 0.0
                for k in range(3):
                    q += R[a, k] * (gyro_var[k] * (dt * dt)) * R[b, k]
                P[i, 6 + a, 6 + b] = (M[6 + a, 6 + b] + M[6 + b, 6 + a]) * 0.5 + q


@njit_cached
def _work(n):
    return np.empty((3, 3)), np.empty((3, 3)), np.empty((5, 3, 3)), np.empty((n, n)), np.empty((n, n))


@njit_cached
def _predict_rows(x, P, f_B, w_B, dt, accel_var, gyro_var, isotropic_gyro, Q_constant):
    work = _work(P.shape[1])
    for i in range(x.shape[0]):
        force, rate = (f_B[i, 0], f_B[i, 1], f_B[i, 2]), (w_B[i, 0], w_B[i, 1], w_B[i, 2])
        _predict_row(x, P, i, force, rate, dt, accel_var, gyro_var, isotropic_gyro, Q_constant, work)


def predict(x, P, f_B, w_B, model) -> tuple[np.ndarray, np.ndarray]:
    """(x', P') after one IMU step (``eskf.predict`` per row): nominal step, P' = F P F^T symmetrised + Q.

    x (N, 16 or 17); P (N, n, n), n = 9, 10, 15 or 16; f_B, w_B (N, 3); model: the :class:`Model`
    (:func:`model`).
    """
    x, P = np.array(x, dtype=float), np.array(P, dtype=float)
    m = model
    _predict_rows(x, P, f_B, w_B, m.dt, m.accel_var, m.gyro_var, m.isotropic_gyro, m.Q_constant)
    return x, P


@njit_cached
def _predict_tick(
    x, P, diagnostics, book, hold, imu, estimate, dt, accel_var, gyro_var, isotropic_gyro, Q_constant
):
    """:func:`predict_tick` on the fields of its groups (numba runs a loop over flat arguments
    faster than over the fields of a namedtuple); the book is not used."""
    work = _work(P.shape[1])
    healthy = np.empty(x.shape[0], dtype=np.bool_)
    weight = hold_weight(dt)
    for i in range(x.shape[0]):
        status = bridge_imu_row(imu, hold, i, weight)
        if status != IMU_FINITE:
            diagnostics[i, _NONFINITE] += 1.0
        if status != IMU_MISSING:
            s = imu if status == IMU_FINITE else hold  # the sample, or the running mean
            f_B, w_B = (s[i, 0], s[i, 1], s[i, 2]), (s[i, 3], s[i, 4], s[i, 5])
            _predict_row(x, P, i, f_B, w_B, dt, accel_var, gyro_var, isotropic_gyro, Q_constant, work)
        for k in range(3):
            estimate[i, 10 + k] = imu[i, 3 + k] - x[i, 13 + k] if status == IMU_FINITE else math.nan
        healthy[i] = looks_healthy(P[i])
    return healthy


def predict_tick(filters, imu, estimate, model) -> np.ndarray:
    """The prediction of one ESKF tick IN PLACE on the ``fusion.Filters`` `filters` (x (N, 16 or 17), P
    (N, n, n), diagnostics, book, hold) (``systems.estimators.Eskf``).

    A vehicle takes :func:`predict` with its IMU sample imu (N, 6) and :class:`Model` `model`, and
    its body rate estimate[:, 10:13] (N, 13) becomes gyro - gyro bias. Over a non-finite sample
    (counted in diagnostics) it dead-reckons on its running mean of the IMU (``imu_hold``) and
    its body rate is NaN (not measured: the controller then commands no body moment); before its
    first finite sample it is not predicted. Returns ``fusion.covariance_looks_healthy`` of the new P.
    """
    f, m = filters, model
    return _predict_tick(
        f.x, f.P, f.diagnostics, f.book, f.hold, imu, estimate,
        m.dt, m.accel_var, m.gyro_var, m.isotropic_gyro, m.Q_constant,
    )  # fmt: skip


# ----- injection -----------------------------------------------------------------------------------


@njit_cached
def _inject_row(x, P, i, dx):
    """The error dx (n,) injected into vehicle i IN PLACE on x and P (``eskf.inject``)."""
    n = P.shape[1]
    for k in range(6):
        x[i, k] += dx[k]
    q = _injected_attitude((x[i, 6], x[i, 7], x[i, 8], x[i, 9]), (dx[6], dx[7], dx[8]))
    for k in range(4):
        x[i, 6 + k] = q[k]
    if n >= _WITH_BIASES:
        for k in range(6):
            x[i, 10 + k] += dx[9 + k]
    if n == _BARO_SIZES[0] or n == _BARO_SIZES[1]:
        x[i, _BARO_NOMINAL] += dx[n - 1]
    # P <- G P G^T: rows 6:9 <- A P[6:9, :], then columns 6:9 <- P[:, 6:9] A^T, A = I + [dtheta]x / 2
    t0, t1, t2 = 0.5 * dx[6], 0.5 * dx[7], 0.5 * dx[8]
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
def correct(x, P, dx, fused) -> None:
    """How the ESKF applies a correction: the errors dx[i] (n,) injected IN PLACE into the fused
    vehicles' (fused (N,) bool) nominal x[i] and P[i] (``eskf.inject``)."""
    for i in range(x.shape[0]):
        if fused[i]:
            _inject_row(x, P, i, dx[i])


def inject(x, P, dx) -> tuple[np.ndarray, np.ndarray]:
    """(x', P'): errors dx (N, n) injected into the nominal x (N, 16 or 17), P reset by G
    (``eskf.inject``)."""
    x, P = np.array(x, dtype=float), np.array(P, dtype=float)
    correct(x, P, dx, np.ones(x.shape[0], dtype=np.bool_))
    return x, P


# ----- GPS -----------------------------------------------------------------------------------------


def gps_update(x, P, gps_pv, R_gps, mask=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x', P', nis) after GPS samples gps_pv (N, 6) with R_gps (6, 6) (``eskf.gps_update`` per row).

    mask: the components each vehicle fuses, as ``ekf7.gps_update``. A vehicle whose innovation
    covariance is singular keeps (x, P) with NaN NIS, as the scalar one.
    """
    x_new, P_new, nis, _ = fusion.gps_update(x, P, gps_pv, R_gps, correct, mask)
    return x_new, P_new, nis


# ----- magnetometer --------------------------------------------------------------------------------


@njit_cached
def _mag_innovation_row(x, P, i, yaw_meas, r, b):
    """(nu rad, S rad^2) of vehicle i's magnetometer yaw; b = P H^T into the n-buffer b."""
    yaw, h = _yaw_and_jacobian(x[i, 6], x[i, 7], x[i, 8], x[i, 9])
    for a in range(P.shape[1]):
        b[a] = P[i, a, 6] * h[0] + P[i, a, 7] * h[1] + P[i, a, 8] * h[2]
    return mag_innovation(yaw_meas, yaw, b[6] * h[0] + b[7] * h[1] + b[8] * h[2], r)


@njit_cached
def _mag_update_row(x, P, i, nu, S, b, K):
    """Vehicle i's magnetometer posterior IN PLACE: K = b / S, P' = P - K b^T - b K^T + S K K^T,
    then dx = K nu injected; K: an n-buffer."""
    n = P.shape[1]
    for a in range(n):
        K[a] = b[a] / S
    for a in range(n):
        for c in range(n):
            P[i, a, c] = P[i, a, c] - K[a] * b[c] - K[c] * b[a] + S * (K[a] * K[c])
    for a in range(n):
        K[a] *= nu
    _inject_row(x, P, i, K)


@njit_cached
def _mag_tick(x, P, mag, diagnostics, book, r, threshold):
    b, K = np.empty(P.shape[1]), np.empty(P.shape[1])
    for i in range(x.shape[0]):
        if fresh_mag(mag, book, diagnostics, i):
            nu, S = _mag_innovation_row(x, P, i, mag[i, 0], r, b)
            if mag_gate(diagnostics, i, nu * nu / S, mag[i, 1], threshold):
                _mag_update_row(x, P, i, nu, S, b, K)


def mag_tick(filters, mag, R_mag, threshold) -> None:
    """The magnetometer step of one ESKF tick IN PLACE on the ``fusion.Filters`` `filters`: fresh
    samples booked, non-finite ones counted, the others fused where the gate accepts them (as
    ``ekf7.mag_tick``)."""
    f = filters
    _mag_tick(f.x, f.P, mag, f.diagnostics, f.book, float(R_mag[0, 0]), float(threshold))


def mag_update(x, P, yaw_meas, R_mag) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x', P', nis) after magnetometer yaws (N,) rad with R_mag (1, 1) (``eskf.mag_update`` per row):
    :func:`mag_tick` with every sample fresh and no gate (``fusion.mag_update``)."""
    return fusion.mag_update(mag_tick, x, P, yaw_meas, R_mag)


# ----- gravity vector ------------------------------------------------------------------------------


@njit_cached
def _gravity_row(x, P, i, f_B, var, gate_var, gate, dx, Ph, K, Ah):
    """PX4's gravity fusion of vehicle i IN PLACE (``eskf.gravity_update``, its sparse form: H has
    two non-zero columns per axis, 6 and 7, -R[1, axis] and R[0, axis]); dx, Ph, K, Ah (n,)
    scratch. Returns whether the sample was fused (within the gate on every axis)."""
    n = P.shape[1]
    f0, f1, f2 = f_B[0], f_B[1], f_B[2]
    if n >= _WITH_BIASES:
        f0, f1, f2 = f0 - x[i, 10], f1 - x[i, 11], f2 - x[i, 12]
    norm = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    r = rotations.rotation_entries(x[i, 6], x[i, 7], x[i, 8], x[i, 9])
    nu = (f0 / norm + r[6], f1 / norm + r[7], f2 / norm + r[8])  # z - h, h = -R[2, :]
    for axis in range(3):
        a, b = -r[3 + axis], r[axis]
        s0 = a * a * P[i, 6, 6] + 2.0 * a * b * P[i, 6, 7] + b * b * P[i, 7, 7]
        if not nu[axis] * nu[axis] <= gate * gate * (s0 + gate_var):
            return False
    for k in range(n):
        dx[k] = 0.0
    for axis in range(3):
        a, b = -r[3 + axis], r[axis]
        for k in range(n):
            Ph[k] = a * P[i, k, 6] + b * P[i, k, 7]
        s = a * Ph[6] + b * Ph[7] + var
        residual = nu[axis] - (a * dx[6] + b * dx[7])
        for k in range(n):
            K[k] = Ph[k] / s
            dx[k] += K[k] * residual
        # Joseph: A = P - K Ph^T (P symmetric: h P = Ph^T), then A - (A h^T) K^T + var K K^T
        for r_ in range(n):
            for c in range(n):
                P[i, r_, c] -= K[r_] * Ph[c]
        for r_ in range(n):
            Ah[r_] = a * P[i, r_, 6] + b * P[i, r_, 7]
        for r_ in range(n):
            for c in range(n):
                P[i, r_, c] += -Ah[r_] * K[c] + var * K[r_] * K[c]
    _inject_row(x, P, i, dx)
    return True


@njit_cached
def gravity_tick(
    x, P, imu, levels, book, now, timeout, band_low, band_high, var, gate_var, gate
) -> np.ndarray:
    """PX4's gravity-vector fusion IN PLACE on the vehicles of x (N, 16+), P (N, n, n) that it
    applies to this tick (``eskf.gravity_fusion_active``): not aided horizontally (the last GPS
    stamp of their book (N, ``fusion.BOOK_SIZE``) is ``NO_SAMPLE_STAMP`` or more than `timeout` s
    before `now` s), their peak-held |f_B| (levels (N, 2): |w_B| rad/s, |f_B| m/s^2; column 1)
    strictly within (band_low, band_high) m/s^2 and their accelerometer sample (imu (N, 6+):
    f_B m/s^2 first) finite. Each such row: ``eskf.gravity_update`` with var, gate_var, gate, the
    errors injected (``eskf.inject``). An aided tick allocates and computes nothing but the test.
    Returns fused (N,) bool."""
    N = x.shape[0]
    fused = np.zeros(N, dtype=np.bool_)
    scratch = np.empty((0, 0))
    for i in range(N):
        last_gps = book[i, fusion.GPS_SLOT]
        if last_gps != NO_SAMPLE_STAMP and not now - last_gps > timeout:
            continue
        if not (band_low < levels[i, 1] < band_high):
            continue
        if not (math.isfinite(imu[i, 0]) and math.isfinite(imu[i, 1]) and math.isfinite(imu[i, 2])):
            continue
        if scratch.shape[0] == 0:
            scratch = np.empty((4, P.shape[1]))  # dx, Ph, K, Ah
        fused[i] = _gravity_row(
            x, P, i, imu[i, 0:3], var, gate_var, gate, scratch[0], scratch[1], scratch[2], scratch[3]
        )
    return fused


@njit_cached
def manoeuvre_tick(state, imu, dt, period, tau) -> None:
    """``eskf.manoeuvre_levels`` compiled, IN PLACE on state (N, ``eskf.MANOEUVRE_SIZE``) with
    this tick's imu (N, 6) over dt s; period: PX4's update (s), tau: the levels' decay time (s)."""
    for i in range(state.shape[0]):
        finite = True
        for k in range(6):
            if not math.isfinite(imu[i, k]):
                finite = False
        if finite:
            for k in range(3):
                state[i, 2 + k] += imu[i, 3 + k] * dt
                state[i, 5 + k] += imu[i, k] * dt
            state[i, 8] += dt
        span = state[i, 8]
        if span >= period - 1e-9:
            rate = math.sqrt(state[i, 2] ** 2 + state[i, 3] ** 2 + state[i, 4] ** 2) / span
            force = math.sqrt(state[i, 5] ** 2 + state[i, 6] ** 2 + state[i, 7] ** 2) / span
            decay = 1.0 - min(span / tau, 1.0)
            state[i, 0] = max(rate, decay * state[i, 0])
            state[i, 1] = max(force, decay * state[i, 1])
            for k in range(2, 9):
                state[i, k] = 0.0
