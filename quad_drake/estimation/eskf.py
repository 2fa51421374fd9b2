"""Error-state EKF (ESKF): nominal p, v, q, accelerometer and gyro biases; 15-state error covariance.

Frames and conventions: NED world N, FRD body B, q = q_NB wxyz; the accelerometer measures
the physical specific force f_B = R_NB^T (a_NB - g_N) (DESIGN §4).

Nominal state ``x`` (16 floats): p_N (m), v_N (m/s), q_NB (wxyz), b_a (m/s^2, body),
b_g (rad/s, body). Error state (truth = nominal (+) error):
``dx = (dp (3, m), dv (3, m/s), dtheta (3, rad), db_a (3), db_g (3))`` with
p = p_hat + dp, v = v_hat + dv, R_NB = Exp(dtheta) R_hat (a small rotation about the world
axes: dtheta[2] is the heading error, dtheta[0:2] the tilt), b = b_hat + db. With bias
estimation off the error state is the first 9 entries and the biases stay at their initial
values (``n = 9``); every function takes the error dimension from P.

With a barometer the filter also carries the baro bias (m: the barometer reads h = -p_z + b_baro
+ noise; ``estimation/baro.py``): its nominal at :data:`BARO_BIAS_NOMINAL` (x has 17 floats) and
its error db_baro LAST in dx (``n = 10`` or ``16``, :func:`carries_baro_bias`), a random walk of
``baro.bias_walk_std`` (Q = walk^2 dt), untouched by the transition (F = I on it) and the
attitude reset. The filter's height and the bias it corrects the barometer with are then
correlated in P, as PX4's EKF2 carries its height-sensor offsets in its state.

Prediction over one IMU period dt with the sample (f_B, w_B) held over it:
a = R_hat (f_B - b_a) + g_N;  p += v dt + a dt^2 / 2;  v += a dt;  q = q (x) Exp((w_B - b_g) dt).
Error dynamics (first order; tested against central differences of this nominal model):
F = I + [[0, I dt, -[u]x dt^2/2, -R dt^2/2, 0], [0, 0, -[u]x dt, -R dt, 0],
[0, 0, 0, 0, -R' dt], [0 ...], [0 ...]] with u = R_hat (f_B - b_a) and R' = R_hat after the
step. Process noise per step: accelerometer white noise of ``accel_std`` per sample (body)
gives Q_vv = R diag(accel_std^2) R^T dt^2 (and its dt^3/2, dt^4/4 position terms), the
gyro's gives Q_thth = R diag(gyro_std^2) R^T dt^2, bias random walks give
Q_b = bias_rw_std^2 dt I.

Measurements, fused in Joseph form with the error state, then injected
(p += dp, v += dv, q = Exp(dtheta) (x) q, b += db) and the covariance reset by
G = diag(I, I, I + [dtheta]x / 2, I, I) (first-order change of the attitude error's
reference; tested numerically):
- GPS: z = (p_N, v_N), H = [I6 0];
- magnetometer: z = yaw of R_NB, h = atan2(R10, R00), H_theta = (-R00 R20 / d, -R10 R20 / d, 1)
  with d = R00^2 + R10^2; the residual is wrapped to [-pi, pi).

Updates return the NIS nu^T S^-1 nu and leave the gating decision to the caller
(:mod:`quad_drake.estimation.gating`): a gated sample keeps the prior.

Two kinds of function. The scalar formulas (:func:`nominal_step`, :func:`quat_exp`,
:func:`quat_normalized`, :func:`injected_attitude`, :func:`yaw_and_jacobian_of`, with
``rotations.rotation_entries`` and ``ekf.mag_innovation``) are plain float arithmetic whose own
code the running implementation, ``kernels/eskf.py``, compiles: they exist once. The matrix forms
(``predict``, ``predict_nominal``, ``transition``, ``process_noise``, ``joseph_update``, ``inject``,
``gps_update``, ``mag_update``, ``gravity_update``, ``gravity_fusion_active``,
``manoeuvre_levels``) are REFERENCE ORACLES of
the kernel's sparse loops, which single runs and fleets both execute: the kernel is tested
against them on seeded random inputs to 1e-12 (``tests/test_estimator_kernels.py``) and no
simulation calls them (``tests/test_oracles.py``).
"""

import math
from dataclasses import dataclass

import numpy as np

from quad_drake.conventions import GRAVITY, NO_SAMPLE_STAMP, PX4_UPDATE_PERIOD
from quad_drake.estimation.ekf import mag_innovation
from quad_drake.models.rotations import quat_product, rotation_entries

NOMINAL_SIZE = 16
BARO_BIAS_NOMINAL = 16
"""Index of the baro bias (m) in the nominal of a filter that carries it (x then has 17 floats)."""
P_IDX, V_IDX, Q_IDX, BA_IDX, BG_IDX = slice(0, 3), slice(3, 6), slice(6, 10), slice(10, 13), slice(13, 16)
ERROR_SIZE_WITH_BIASES, ERROR_SIZE_NAVIGATION = 15, 9
ERROR_SIZES_WITH_BARO = (ERROR_SIZE_NAVIGATION + 1, ERROR_SIZE_WITH_BIASES + 1)
"""Error sizes of a filter that carries the baro bias (its error last): 10 and 16."""


def estimates_imu_biases(n) -> bool:
    """True when an error state of size n carries the IMU biases db_a, db_g (entries 9:15)."""
    return n >= ERROR_SIZE_WITH_BIASES


def carries_baro_bias(n) -> bool:
    """True when an error state of size n carries the baro bias (its last entry, n - 1)."""
    return n == ERROR_SIZE_NAVIGATION + 1 or n == ERROR_SIZE_WITH_BIASES + 1


def navigation_size(n) -> int:
    """The size (9 or 15) of an error state of size n without its baro bias: what the
    ``covariance`` output, the vocabulary and the NEES see."""
    return n - 1 if carries_baro_bias(n) else n


def _constant(array):
    array.flags.writeable = False
    return array


def quat_exp(theta) -> tuple[float, float, float, float]:
    """Unit wxyz quaternion of the rotation vector theta (rad) as a 4-tuple."""
    tx, ty, tz = float(theta[0]), float(theta[1]), float(theta[2])
    angle = math.sqrt(tx * tx + ty * ty + tz * tz)
    if angle < 1e-12:
        return (1.0, 0.5 * tx, 0.5 * ty, 0.5 * tz)
    s = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), tx * s, ty * s, tz * s)


quat_mul = quat_product
"""Hamilton product a (x) b of two wxyz 4-sequences, as a 4-tuple (``rotations.quat_product``)."""


def quat_normalized(q) -> tuple[float, float, float, float]:
    """The wxyz 4-tuple q divided by its norm."""
    qw, qx, qy, qz = q[0], q[1], q[2], q[3]
    n = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    return qw * n, qx * n, qy * n, qz * n


def injected_attitude(q, dtheta) -> tuple[float, float, float, float]:
    """q_NB (unit wxyz 4-tuple) after the attitude error dtheta (rad, world axes): Exp(dtheta) (x) q."""
    return quat_normalized(quat_mul(quat_exp(dtheta), q))


def rotation_log(R) -> np.ndarray:
    """Rotation vector (3, rad) of a rotation matrix, |angle| < pi (the inverse of Exp)."""
    cos_angle = max(-1.0, min(1.0, 0.5 * (float(np.trace(R)) - 1.0)))
    angle = math.acos(cos_angle)
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-6:
        return 0.5 * axis
    return axis * (angle / (2.0 * math.sin(angle)))


def attitude_errors(q_hat, q_true) -> np.ndarray:
    """(n, 3) dtheta with R_hat = Exp(dtheta) R_true per row (estimate minus truth, world axes, rad).

    q_hat, q_true: (n, 4) wxyz quaternions. Vectorised: dtheta = 2 sign(w) vec(q_hat (x) q_true^*)
    mapped through the exact angle, valid for |angle| < pi.
    """
    q_hat = np.asarray(q_hat, dtype=float)
    q_true = np.asarray(q_true, dtype=float)
    aw, ax, ay, az = q_hat.T
    bw, bx, by, bz = q_true.T * np.array([[1.0], [-1.0], [-1.0], [-1.0]])
    w = aw * bw - ax * bx - ay * by - az * bz
    v = np.column_stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )
    sign = np.where(w < 0.0, -1.0, 1.0)
    w, v = w * sign, v * sign[:, None]
    norm_v = np.linalg.norm(v, axis=1)
    angle = 2.0 * np.arctan2(norm_v, w)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(norm_v > 1e-12, angle / norm_v, 2.0)
    return v * scale[:, None]


def _skew(v0, v1, v2):
    return np.array([[0.0, -v2, v1], [v2, 0.0, -v0], [-v1, v0, 0.0]])


def initial_nominal(
    position, velocity, q_NB, accel_bias=(0.0, 0.0, 0.0), gyro_bias=(0.0, 0.0, 0.0)
) -> np.ndarray:
    """Nominal state (16,) from its parts (m, m/s, wxyz, m/s^2, rad/s)."""
    return np.concatenate([position, velocity, q_NB, accel_bias, gyro_bias]).astype(float)


def write_estimate(x, estimate) -> None:
    """Write the position, attitude and velocity of nominal states x (..., 16) into estimates
    (..., 13) in the true ``state`` layout (p_NB m, q_NB wxyz, v_NB m/s) IN PLACE; the body
    rate, estimate[..., 10:13], is left as it is (the prediction sets it from the IMU sample)."""
    estimate[..., 0:3] = x[..., P_IDX]
    estimate[..., 3:7] = x[..., Q_IDX]
    estimate[..., 7:10] = x[..., V_IDX]


def predict_nominal(
    x, f_B, w_B, dt
) -> tuple[list[float], np.ndarray, np.ndarray, tuple[float, float, float]]:
    """(x', R_hat, R_hat', u_N): nominal after one IMU step (a list), rotations before and after
    (3x3 arrays), and u_N = R_hat (f_B - b_a) (m/s^2, the specific force in N, a 3-tuple).

    x: nominal (16, or 17 with the baro bias, which the step keeps); f_B: specific force (m/s^2,
    FRD); w_B: gyro (rad/s); dt: s (:func:`nominal_step`).
    """
    x = list(x.tolist() if isinstance(x, np.ndarray) else x)
    x_new, r, r_next, u_N = nominal_step(tuple(x[:NOMINAL_SIZE]), f_B, w_B, dt)
    return list(x_new) + x[NOMINAL_SIZE:], np.array(r).reshape(3, 3), np.array(r_next).reshape(3, 3), u_N


def nominal_step(
    x, f_B, w_B, dt
) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...], tuple[float, float, float]]:
    """(x' (16-tuple), R_hat, R_hat' (9-tuples, row-major), u_N (3-tuple)) of
    :func:`predict_nominal`: plain float arithmetic, the code the compiled ESKF kernel runs.

    x: nominal 16-tuple of floats; f_B, w_B: 3-sequences of floats."""
    px, py, pz, vx, vy, vz, qw, qx, qy, qz, bax, bay, baz, bgx, bgy, bgz = x
    r = rotation_entries(qw, qx, qy, qz)
    fx, fy, fz = float(f_B[0]) - bax, float(f_B[1]) - bay, float(f_B[2]) - baz
    ux = r[0] * fx + r[1] * fy + r[2] * fz
    uy = r[3] * fx + r[4] * fy + r[5] * fz
    uz = r[6] * fx + r[7] * fy + r[8] * fz
    az = uz + GRAVITY
    h = 0.5 * dt * dt
    dq = quat_exp(((float(w_B[0]) - bgx) * dt, (float(w_B[1]) - bgy) * dt, (float(w_B[2]) - bgz) * dt))
    qw, qx, qy, qz = quat_normalized(quat_mul((qw, qx, qy, qz), dq))
    x_new = (
        px + vx * dt + ux * h,
        py + vy * dt + uy * h,
        pz + vz * dt + az * h,
        vx + ux * dt,
        vy + uy * dt,
        vz + az * dt,
        qw,
        qx,
        qy,
        qz,
        bax,
        bay,
        baz,
        bgx,
        bgy,
        bgz,
    )
    return x_new, r, rotation_entries(qw, qx, qy, qz), (ux, uy, uz)


@dataclass(frozen=True)
class NoiseModel:
    """What the filter assumes, prepared once from EskfEstimatorConfig (per-step arithmetic only)."""

    accel_var: np.ndarray  # (3,) (m/s^2)^2 per IMU sample, body axes
    gyro_var: np.ndarray  # (3,) (rad/s)^2 per IMU sample
    accel_bias_rate: float  # (m/s^2)^2 / s, bias random walk
    gyro_bias_rate: float  # (rad/s)^2 / s
    baro_bias_rate: float = 0.0  # m^2 / s, the baro bias's random walk (used when the filter carries it)

    @classmethod
    def from_params(cls, params) -> "NoiseModel":
        return cls(
            _constant(np.square(np.asarray(params.accel_std, dtype=float))),
            _constant(np.square(np.asarray(params.gyro_std, dtype=float))),
            float(params.accel_bias_rw_std) ** 2,
            float(params.gyro_bias_rw_std) ** 2,
            float(params.baro.bias_walk_std) ** 2,
        )


def transition_buffer(n, dt) -> np.ndarray:
    """An n x n identity with the constant dp/dv block I dt, for :func:`fill_transition`."""
    F = np.eye(n)
    F[0, 3] = F[1, 4] = F[2, 5] = dt
    return F


def fill_transition(F, R, R_next, u_N, dt) -> np.ndarray:
    """Write the attitude-dependent blocks of the error transition into F (from transition_buffer).

    R, R_next: R_hat before and after the step; u_N = R (f_B - b_a) (m/s^2). Scalar writes of
    -[u]x dt and -[u]x dt^2/2 (12 entries), numpy writes of the bias blocks when the IMU biases
    are estimated (the baro bias's row and column stay the identity's).
    """
    u0, u1, u2 = u_N
    h = 0.5 * dt * dt
    for row, scale in ((0, h), (3, dt)):  # -[u]x * scale into rows row..row+2, columns 6..8
        F[row, 7] = u2 * scale
        F[row, 8] = -u1 * scale
        F[row + 1, 6] = -u2 * scale
        F[row + 1, 8] = u0 * scale
        F[row + 2, 6] = u1 * scale
        F[row + 2, 7] = -u0 * scale
    if estimates_imu_biases(F.shape[0]):
        np.multiply(R, -h, out=F[0:3, 9:12])
        np.multiply(R, -dt, out=F[3:6, 9:12])
        np.multiply(R_next, -dt, out=F[6:9, 12:15])
    return F


def transition(R, R_next, u_N, dt, n) -> np.ndarray:
    """Error transition F (n x n, n = 9, 10, 15 or 16) of one IMU step (see the module docstring)."""
    return fill_transition(transition_buffer(n, dt), R, R_next, u_N, dt)


def noise_buffer(n, noise, dt) -> np.ndarray:
    """An n x n Q with the attitude-independent blocks filled: bias random walks (the IMU's, the
    baro's), and the gyro's when its noise is the same on every axis (then R diag R^T = var I)."""
    Q = np.zeros((n, n))
    if noise.gyro_var[0] == noise.gyro_var[1] == noise.gyro_var[2]:
        Q[6:9, 6:9] = np.eye(3) * (noise.gyro_var[0] * dt * dt)
    if estimates_imu_biases(n):
        Q[9:12, 9:12] = np.eye(3) * (noise.accel_bias_rate * dt)
        Q[12:15, 12:15] = np.eye(3) * (noise.gyro_bias_rate * dt)
    if carries_baro_bias(n):
        Q[n - 1, n - 1] = noise.baro_bias_rate * dt
    return Q


def fill_process_noise(Q, R, noise, dt) -> np.ndarray:
    """Write the attitude-dependent process-noise blocks into Q (from noise_buffer).

    Accelerometer: Q[0:6, 0:6] = G M G^T with M = R diag(accel_var) R^T and G = [dt^2/2 I; dt I];
    gyro (unless isotropic): Q[6:9, 6:9] = R diag(gyro_var) R^T dt^2.
    """
    h = 0.5 * dt * dt
    G = np.array(
        ((h, 0.0, 0.0), (0.0, h, 0.0), (0.0, 0.0, h), (dt, 0.0, 0.0), (0.0, dt, 0.0), (0.0, 0.0, dt))
    )
    GR = G @ R
    Q[0:6, 0:6] = (GR * noise.accel_var) @ GR.T
    if not noise.gyro_var[0] == noise.gyro_var[1] == noise.gyro_var[2]:
        Q[6:9, 6:9] = (R * (noise.gyro_var * (dt * dt))) @ R.T
    return Q


def process_noise(R, noise, dt, n) -> np.ndarray:
    """Q (n x n) of one IMU step at attitude R (see the module docstring); noise: NoiseModel."""
    return fill_process_noise(noise_buffer(n, noise, dt), R, noise, dt)


def predict(x, P, f_B, w_B, dt, noise, F=None, Q=None) -> tuple[list[float], np.ndarray]:
    """(x', P') after one IMU step: nominal propagation and P' = F P F^T + Q (symmetrised).

    noise: NoiseModel. F, Q: optional work buffers from transition_buffer / noise_buffer
    (same n and dt), overwritten in place.
    """
    n = P.shape[0]
    x_new, R, R_next, u_N = predict_nominal(x, f_B, w_B, dt)
    F = fill_transition(transition_buffer(n, dt) if F is None else F, R, R_next, u_N, dt)
    Q = fill_process_noise(noise_buffer(n, noise, dt) if Q is None else Q, R, noise, dt)
    P_new = (F @ P) @ F.T
    P_new += P_new.T
    P_new *= 0.5
    P_new += Q
    return x_new, P_new


def joseph_update(P, H, R_meas, nu) -> tuple[np.ndarray, np.ndarray, float]:
    """(dx, P', nis): the error-state correction of innovation nu (m) with Jacobian H (m x n).

    S = H P H^T + R; K = P H^T S^-1; P' = (I - K H) P (I - K H)^T + K R K^T (symmetrised);
    nis = nu^T S^-1 nu. Returns NaN nis (and dx = 0, P unchanged) when S is singular.
    """
    PHt = P @ H.T
    S = H @ PHt + R_meas
    try:
        solved = np.linalg.solve(S, np.column_stack((PHt.T, nu)))
    except np.linalg.LinAlgError:
        return np.zeros(P.shape[0]), P, math.nan
    K = solved[:, :-1].T
    I_KH = np.eye(P.shape[0]) - K @ H
    P_new = I_KH @ P @ I_KH.T + K @ R_meas @ K.T
    return K @ nu, 0.5 * (P_new + P_new.T), float(nu @ solved[:, -1])


def inject(x, P, dx) -> tuple[np.ndarray, np.ndarray]:
    """(x', P'): the error dx (n) injected into the nominal x (16, or 17 with the baro bias) and P
    reset by G (module docstring).

    G differs from I only in its attitude block A = I + [dtheta]x / 2, so G P G^T is formed as
    rows 6:9 <- A P[6:9, :], then columns 6:9 <- P[:, 6:9] A^T.
    """
    x = np.array(x, dtype=float)
    x[0:6] += dx[0:6]
    t0, t1, t2 = (0.5 * float(c) for c in dx[6:9])
    x[Q_IDX] = injected_attitude(tuple(x[Q_IDX].tolist()), dx[6:9])
    if estimates_imu_biases(dx.shape[0]):
        x[10:16] += dx[9:15]
    if carries_baro_bias(dx.shape[0]):
        x[BARO_BIAS_NOMINAL] += dx[-1]
    A = np.array(((1.0, -t2, t1), (t2, 1.0, -t0), (-t1, t0, 1.0)))
    P = np.array(P, dtype=float)
    P[6:9, :] = A @ P[6:9, :]
    P[:, 6:9] = P[:, 6:9] @ A.T
    return x, P


def reset_jacobian(dtheta, n) -> np.ndarray:
    """G (n x n): identity with the attitude block I + [dtheta]x / 2."""
    G = np.eye(n)
    G[6:9, 6:9] += 0.5 * _skew(dtheta[0], dtheta[1], dtheta[2])
    return G


def gps_update(x, P, gps_pv, R_gps) -> tuple[np.ndarray, np.ndarray, float]:
    """(x', P', nis) after fusing a GPS sample (p_N m, v_N m/s); R_gps (6x6).

    A non-finite sample gives (x, P, nan). The caller decides the gate on nis (a gated
    sample must keep (x, P)).
    """
    z = np.asarray(gps_pv, dtype=float)
    if not np.isfinite(z).all():
        return x, P, math.nan
    x = np.asarray(x, dtype=float)
    H = np.eye(6, P.shape[0])
    dx, P_new, nis = joseph_update(P, H, R_gps, z - x[0:6])
    if math.isnan(nis):
        return x, P, nis
    x_new, P_new = inject(x, P_new, dx)
    return x_new, P_new, nis


def yaw_and_jacobian(q) -> tuple[float, np.ndarray]:
    """(yaw (rad), dyaw/dtheta (3,)) of the nominal attitude q (wxyz), for R = Exp(dtheta) R_hat."""
    yaw, h_theta = yaw_and_jacobian_of(float(q[0]), float(q[1]), float(q[2]), float(q[3]))
    return yaw, np.array(h_theta)


def yaw_and_jacobian_of(qw, qx, qy, qz) -> tuple[float, tuple[float, float, float]]:
    """:func:`yaw_and_jacobian` of the floats (qw, qx, qy, qz), the Jacobian as a 3-tuple: h =
    atan2(R10, R00), H_theta = (-R00 R20 / d, -R10 R20 / d, 1) with d = R00^2 + R10^2."""
    r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
    r10 = 2.0 * (qx * qy + qw * qz)
    r20 = 2.0 * (qx * qz - qw * qy)
    d = r00 * r00 + r10 * r10
    return math.atan2(r10, r00), (-r00 * r20 / d, -r10 * r20 / d, 1.0)


def mag_update(x, P, yaw_meas, R_mag) -> tuple[np.ndarray, np.ndarray, float]:
    """(x', P', nis) after fusing a magnetometer yaw (rad) with variance R_mag (1x1); NaN sample skipped.

    Scalar Joseph form: with b = P H^T, S = H b + r and K = b / S,
    P' = P - K b^T - b K^T + S K K^T (the same as (I - KH) P (I - KH)^T + K r K^T).
    """
    yaw_meas = float(yaw_meas)
    if not math.isfinite(yaw_meas):
        return x, P, math.nan
    x = np.asarray(x, dtype=float)
    yaw, h_theta = yaw_and_jacobian(x[Q_IDX])
    b = P[:, 6:9] @ h_theta
    nu, S = mag_innovation(yaw_meas, yaw, float(b[6:9] @ h_theta), float(R_mag[0, 0]))
    K = b / S
    Kb = np.outer(K, b)
    P_new = P - Kb
    P_new -= Kb.T
    P_new += S * np.outer(K, K)
    x_new, P_new = inject(x, P_new, K * nu)
    return x_new, P_new, nu * nu / S


ACCEL_BIAS_LEARNING_TAU = 0.5
"""s: the decay of the peak-held manoeuvre levels (PX4 EKF2's ``EKF2_ABL_TAU``)."""
ACCEL_BIAS_LEARNING_GYRO_LIMIT = 3.0
"""rad/s: above this peak-held rate no accelerometer bias is learned (PX4's ``EKF2_ABL_GYRLIM``)."""
ACCEL_BIAS_LEARNING_ACCEL_LIMIT = 25.0
"""m/s^2: the same of the specific force's magnitude (PX4's ``EKF2_ABL_ACCLIM``)."""


MANOEUVRE_SIZE = 9
"""Floats per vehicle of :func:`manoeuvre_levels`' state: the levels (|w_B| rad/s, |f_B| m/s^2),
then the sums over the current update period of w_B dt (3), f_B dt (3) and dt (1)."""


def manoeuvre_levels(state, imu, dt) -> None:
    """PX4 EKF2's manoeuvre levels IN PLACE on state (N, :data:`MANOEUVRE_SIZE`); imu (N, 6: f_B,
    w_B) this tick's samples, dt s. PX4 computes them on its delayed IMU, the samples summed over
    its update period (:data:`PX4_UPDATE_PERIOD`, 10 ms): each vehicle's finite samples are summed
    tick by tick (a non-finite one is left out), and once a period is summed the magnitudes of the
    mean rate and specific force over it update the levels (state[:, 0:2], the peak-held |w_B| and
    |f_B|): each max(the mean's, the level decayed by 1 - period / ACCEL_BIAS_LEARNING_TAU), as
    ``Ekf::updateIMUBiasInhibit``. A vehicle's levels hold between its updates."""
    finite = np.isfinite(imu).all(axis=1)
    state[finite, 2:5] += imu[finite, 3:6] * dt
    state[finite, 5:8] += imu[finite, 0:3] * dt
    state[finite, 8] += dt
    due = np.flatnonzero(state[:, 8] >= PX4_UPDATE_PERIOD - 1e-9)
    if len(due) == 0:
        return
    span = state[due, 8]
    mean_rate = np.linalg.norm(state[due, 2:5], axis=1) / span
    mean_force = np.linalg.norm(state[due, 5:8], axis=1) / span
    decay = 1.0 - np.minimum(span / ACCEL_BIAS_LEARNING_TAU, 1.0)
    state[due, 0:2] = np.fmax(np.column_stack((mean_rate, mean_force)), decay[:, None] * state[due, 0:2])
    state[due, 2:] = 0.0


def uncorrelate_unobservable_accel_bias(x, P, tilt, levels=None) -> None:
    """PX4 EKF2's accelerometer-bias inhibition (``Ekf::updateIMUBiasInhibit``), IN PLACE on P
    (N, n, n) of filters carrying the biases (n >= 15; x (N, 16+) their nominal states, q_NB at
    6..9): the bias of a body axis whose angle to the vertical exceeds `tilt` (rad; |R_NB[2, axis]|
    <= cos tilt), and every axis's while the vehicle manoeuvres hard (levels (N, 2) of
    :func:`manoeuvre_levels` above ACCEL_BIAS_LEARNING_GYRO_LIMIT or
    ACCEL_BIAS_LEARNING_ACCEL_LIMIT; None: not checked), is not learned: its row and column of P
    are zeroed but for its variance, so no update moves it (K's row is P's row times H^T S^-1) and
    it takes no part in the next prediction's correlations. A level axis's bias and the tilt about
    the other horizontal axis move the accelerometer alike: on a still vehicle the split between
    them is the priors', which PX4 leaves to the tilt."""
    w, qx, qy, qz = x[:, 6], x[:, 7], x[:, 8], x[:, 9]
    down_z = w * w - qx * qx - qy * qy + qz * qz
    down = np.column_stack((2.0 * (qx * qz - w * qy), 2.0 * (qy * qz + w * qx), down_z))  # R_NB[2, :]
    inhibited = np.abs(down) <= math.cos(tilt)
    if levels is not None:
        high = (levels[:, 0] > ACCEL_BIAS_LEARNING_GYRO_LIMIT) | (
            levels[:, 1] > ACCEL_BIAS_LEARNING_ACCEL_LIMIT
        )
        inhibited |= high[:, None]
    for axis in range(3):
        rows = np.flatnonzero(inhibited[:, axis])
        if len(rows):
            k = 9 + axis
            variance = P[rows, k, k]
            P[rows, k, :] = 0.0
            P[rows, :, k] = 0.0
            P[rows, k, k] = variance


def gps_noise(params) -> np.ndarray:
    """R_gps (6x6) = diag(gps_pos_std^2, gps_vel_std^2), m^2 and (m/s)^2."""
    return np.diag(np.square(list(params.gps_pos_std) + list(params.gps_vel_std)))


def mag_noise(params) -> np.ndarray:
    """R_mag (1x1) = [mag_yaw_std^2], rad^2."""
    return np.array([[params.mag_yaw_std**2]])


def initial_covariance(params, baro=False) -> np.ndarray:
    """P0 (9, 10, 15 or 16 square) = diag(init_std^2) of (p, v, theta[, b_a, b_g][, b_baro]);
    baro: True for a filter that carries the baro bias (``params.baro.bias_init_std``)."""
    std = list(params.init_pos_std) + list(params.init_vel_std) + list(params.init_att_std)
    if params.estimate_biases:
        std += list(params.init_accel_bias_std) + list(params.init_gyro_bias_std)
    if baro:
        std.append(params.baro.bias_init_std)
    return np.diag(np.square(std))


GRAVITY_GATE = 0.25
"""sigma: PX4 EKF2's innovation gate of the gravity vector (``Ekf::controlGravityFusion``)."""
GRAVITY_ACCEL_BAND = (0.9 * GRAVITY, 1.1 * GRAVITY)
"""m/s^2: the peak-held |f_B| (:func:`manoeuvre_levels`) within which the accelerometer is taken
as gravity (PX4's 0.9 g to 1.1 g)."""


def predicted_gravity(x, n) -> tuple[np.ndarray, np.ndarray]:
    """(h (M, 3), H (M, 3, n)): the direction of -g in the body frame through the estimates x
    (M, 16+), h = R_hat^T (0, 0, -1) (unit, FRD), and its Jacobian against the error state of
    size n, H = R_hat^T [(0, 0, -1)]x on the attitude error (row i: -R[1, i], R[0, i], 0; the
    tilt only), zero elsewhere."""
    r = rotation_entries(x[:, 6], x[:, 7], x[:, 8], x[:, 9])  # R_NB row-major, each (M,)
    H = np.zeros((x.shape[0], 3, n))
    H[:, :, 6] = -np.column_stack(r[3:6])
    H[:, :, 7] = np.column_stack(r[0:3])
    return -np.column_stack(r[6:9]), H


def gravity_update(x, P, f_B, var, gate_var) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PX4 EKF2's gravity-vector fusion (``Ekf::controlGravityFusion``, its ``EKF2_IMU_CTRL`` bit
    2) of M filters: (dx (M, n), P' (M, n, n), fused (M,) bool), the errors to inject
    (``kernels.eskf.correct``) and the covariance after the update; x (M, 16+), P (M, n, n).

    The measurement is the unit vector of the accelerometer's reading less its bias, f_B (M, 3)
    m/s^2 body FRD, read as the direction of -g (:func:`predicted_gravity`), each axis fused in
    turn with the variance `var` (unit vector^2, per update) as PX4 fuses its three in turn,
    linearised once (Joseph form). The sample is rejected whole (fused False, dx 0, P unchanged)
    when an axis's innovation exceeds :data:`GRAVITY_GATE` sigma of its innovation variance
    with `gate_var` (PX4's per-update variance: the gate stays PX4's where `var` is rescaled to
    another update rate, :func:`gravity_variance`)."""
    x, P, f_B = np.asarray(x, dtype=float), np.asarray(P, dtype=float), np.asarray(f_B, dtype=float)
    n = P.shape[1]
    if n >= ERROR_SIZE_WITH_BIASES:
        f_B = f_B - x[:, BA_IDX]
    h, H = predicted_gravity(x, n)
    nu = f_B / np.linalg.norm(f_B, axis=1)[:, None] - h
    S0 = np.einsum("mij,mjk,mik->mi", H, P, H)
    fused = np.all(nu * nu <= GRAVITY_GATE**2 * (S0 + gate_var), axis=1) & np.isfinite(nu).all(axis=1)
    dx, P_new = np.zeros((x.shape[0], n)), P.copy()
    eye = np.eye(n)
    for axis in range(3):
        h_axis, Pm = H[fused, axis], P_new[fused]
        Ph = np.einsum("mij,mj->mi", Pm, h_axis)
        K = Ph / (np.einsum("mi,mi->m", h_axis, Ph) + var)[:, None]
        dx[fused] += K * (nu[fused, axis] - np.einsum("mi,mi->m", h_axis, dx[fused]))[:, None]
        A = eye - np.einsum("mi,mj->mij", K, h_axis)
        P_new[fused] = A @ Pm @ np.transpose(A, (0, 2, 1)) + var * np.einsum("mi,mj->mij", K, K)
    return dx, P_new, fused


def gravity_fusion_active(last_gps, now, timeout, levels, band, f_B) -> np.ndarray:
    """(M,) bool: the filters the gravity fusion (:func:`gravity_update`) applies to this tick,
    PX4's conditions: not aided horizontally (last_gps (M,), the last GPS stamp seen, s, is
    ``NO_SAMPLE_STAMP`` or more than `timeout` s before `now` s), the peak-held |f_B| `levels`
    (M,) m/s^2 (:func:`manoeuvre_levels`) strictly within `band` (low, high) m/s^2
    (:data:`GRAVITY_ACCEL_BAND`) and the accelerometer sample f_B (M, 3) finite."""
    last_gps, levels, f_B = np.asarray(last_gps), np.asarray(levels), np.asarray(f_B)
    unaided = (last_gps == NO_SAMPLE_STAMP) | (now - last_gps > timeout)
    return unaided & (levels > band[0]) & (levels < band[1]) & np.isfinite(f_B).all(axis=1)


def gravity_variance(gravity_std, dt) -> float:
    """(unit vector)^2: the variance of one gravity update every dt s for PX4's std per its
    10 ms update (:data:`PX4_UPDATE_PERIOD`)."""
    return gravity_std**2 * PX4_UPDATE_PERIOD / dt
