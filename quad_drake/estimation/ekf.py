"""7-state EKF of SPEC §4: x = (p_N (m), v_N (m/s), yaw (rad)), NED; roll and pitch come from
the complementary filter. Written for the physical accelerometer: a_N = R_NB f_B + g_N.

Noise matrices follow the reference: Q = diag(q_std^2) * dt_imu is applied once per predict
step, R_gps = diag(gps_std^2), R_mag = [mag_yaw_std^2]. Updates use the Joseph form and
return the normalised innovation squared (NIS); a non-finite measurement is skipped (the
state and covariance are returned unchanged and the NIS is NaN).

Tilt-aware process noise (an addition to the reference, off unless ``tilt_gyro_std`` > 0): the
EKF7 has no roll/pitch states, yet the complementary filter's roll/pitch error, a gyro random
walk that grows over the flight, rotates the specific force into a velocity error and leaks
into the integrated yaw. :class:`TiltNoise` adds that error's predicted variance, mapped
through the Jacobian of (a_N, yaw rate) with respect to (roll, pitch), to Q at every step; see
:func:`tilt_variance` and :func:`tilt_process_noise`.

Two kinds of function. The scalar formulas (:func:`attitude_trig`, :func:`yaw_free_rotation_of`,
:func:`specific_force_in_n`, :func:`state_after`, :func:`gravity_z`, :func:`mag_innovation`,
:func:`tilt_jacobian_of`, :func:`scaled_tilt_factors`) are plain float arithmetic whose own code
the running implementation, ``kernels/ekf7.py``, compiles: they exist once. The textbook matrix
forms (``predict``, ``predict_with_yaw``, ``predict_state``, ``predict_jacobian``,
``predict_covariance``, ``kalman_update``, ``gps_update``, ``mag_update``, ``tilt_process_noise``
and ``TiltNoise.process_noise``) are REFERENCE ORACLES
of the kernel's sparse covariance loops and Joseph updates, which single runs and fleets both
execute: the kernel is tested against them on seeded random inputs to 1e-12
(``tests/test_estimator_kernels.py``) and no simulation calls them (``tests/test_oracles.py``).
"""

import math
from dataclasses import dataclass

import numpy as np

from quad_drake.conventions import EKF_STATE_SIZE, GRAVITY
from quad_drake.models.rotations import wrap_to_pi

YAW_INDEX = 6


def _constant(array):
    array.flags.writeable = False
    return array


IDENTITY = _constant(np.eye(EKF_STATE_SIZE))
H_GPS = _constant(np.eye(6, EKF_STATE_SIZE))
"""GPS measurement matrix [I6 | 0]: position and velocity."""
H_MAG = _constant(np.eye(1, EKF_STATE_SIZE, YAW_INDEX))
"""Magnetometer measurement matrix [0 ... 0 1]: yaw."""


def initial_state(params) -> np.ndarray:
    """x0 (7) from Ekf7EstimatorConfig.init_state."""
    return np.array(params.init_state, dtype=float)


def initial_covariance(params) -> np.ndarray:
    """P0 = diag(init_std^2) (7x7)."""
    return np.diag(np.square(np.asarray(params.init_std, dtype=float)))


def process_noise(params) -> np.ndarray:
    """Q (7x7) per predict step = diag(q_pos_xy^2 x2, q_pos_z^2, q_vel_xy^2 x2, q_vel_z^2, q_yaw^2) dt_imu."""
    p = params
    std = [
        p.q_pos_xy_std,
        p.q_pos_xy_std,
        p.q_pos_z_std,
        p.q_vel_xy_std,
        p.q_vel_xy_std,
        p.q_vel_z_std,
        p.q_yaw_std,
    ]
    return np.diag(np.square(std)) * p.dt_imu


def gps_noise(params) -> np.ndarray:
    """R_gps (6x6) = diag(pos_xy^2 x2, pos_z^2, vel_xy^2 x2, vel_z^2), m^2 and (m/s)^2."""
    p = params
    std = [
        p.gps_pos_xy_std,
        p.gps_pos_xy_std,
        p.gps_pos_z_std,
        p.gps_vel_xy_std,
        p.gps_vel_xy_std,
        p.gps_vel_z_std,
    ]
    return np.diag(np.square(std))


def mag_noise(params) -> np.ndarray:
    """R_mag (1x1) = [mag_yaw_std^2], rad^2."""
    return np.array([[params.mag_yaw_std**2]])


def attitude_trig(roll, pitch, yaw) -> tuple[float, float, float, float, float, float]:
    """(cos, sin of roll, of pitch, of yaw): the trigonometry a prediction evaluates once."""
    return math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)


def yaw_free_rotation_of(cr, sr, cp, sp, fx, fy, fz) -> tuple[float, float, float, float]:
    """(ux, uy, uz, rolled_z): u = Ry(pitch) Rx(roll) f (the yaw-free part of R_NB f) and the z
    component of Rx(roll) f, for f = (fx, fy, fz), from the cosines and sines of roll and pitch."""
    rolled_z = sr * fy + cr * fz
    return cp * fx + sp * rolled_z, cr * fy - sr * fz, -sp * fx + cp * rolled_z, rolled_z


def specific_force_in_n(trig, rotated) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """(R_NB f_B, dR_NB/dyaw f_B) as two 3-tuples, from the attitude's trig
    (:func:`attitude_trig`) and rotated = :func:`yaw_free_rotation_of` of f_B;
    R_NB = Rz(yaw) Ry(pitch) Rx(roll). The last entry of dR/dyaw f is 0 (Rz keeps z)."""
    cy, sy = trig[4], trig[5]
    ux, uy, uz = rotated[0], rotated[1], rotated[2]
    return (cy * ux - sy * uy, sy * ux + cy * uy, uz), (-sy * ux - cy * uy, cy * ux - sy * uy, 0.0)


def _rotate_specific_force(roll, pitch, yaw, f_B):
    """(R_NB f_B, dR_NB/dyaw f_B) as two 3-tuples of floats (:func:`specific_force_in_n`)."""
    trig = attitude_trig(roll, pitch, yaw)
    cr, sr, cp, sp = trig[0], trig[1], trig[2], trig[3]
    rotated = yaw_free_rotation_of(cr, sr, cp, sp, float(f_B[0]), float(f_B[1]), float(f_B[2]))
    return specific_force_in_n(trig, rotated)


def gravity_z(reference_accelerometer) -> float:
    """g_N z, m/s^2, as the EKF7 predicts with it: +GRAVITY (NED, the physical accelerometer), or
    -GRAVITY for the reference accelerometer's sign convention (``fidelity``)."""
    return -GRAVITY if reference_accelerometer else GRAVITY


def state_after(x, a_N, yaw, dt) -> tuple[float, float, float, float, float, float, float]:
    """x (7-tuple) after dt s: p += v dt, v += a_N dt (m/s^2, NED), yaw set to `yaw` (rad)."""
    px, py, pz, vx, vy, vz = x[0], x[1], x[2], x[3], x[4], x[5]
    return (
        px + vx * dt,
        py + vy * dt,
        pz + vz * dt,
        vx + a_N[0] * dt,
        vy + a_N[1] * dt,
        vz + a_N[2] * dt,
        yaw,
    )


def _fill_jacobian(G, rf_yaw, dt):
    G[0, 3] = G[1, 4] = G[2, 5] = dt
    G[3, 6] = rf_yaw[0] * dt
    G[4, 6] = rf_yaw[1] * dt
    G[5, 6] = rf_yaw[2] * dt
    return G


def predict_state(x, roll, pitch, f_B, dt) -> np.ndarray:
    """x (7) after dt s: p += v dt; v += (R(roll, pitch, x[6]) f_B + g_N) dt; yaw unchanged.

    roll, pitch: rad (complementary filter). f_B: specific force, m/s^2 (FRD). dt: s.
    """
    rf, _ = _rotate_specific_force(roll, pitch, x[YAW_INDEX], f_B)
    return _state_with_gravity(x, rf, dt)


def _state_with_gravity(x, rf, dt):
    """(7,) :func:`state_after` of x with a_N = rf + g_N (the physical accelerometer), yaw kept."""
    x = np.asarray(x, dtype=float).tolist()
    return np.array(state_after(x, (rf[0], rf[1], rf[2] + GRAVITY), x[YAW_INDEX], dt))


def predict_jacobian(x, roll, pitch, f_B, dt) -> np.ndarray:
    """G = d predict_state / dx (7x7): I7, G[0,3] = G[1,4] = G[2,5] = dt, G[3:6, 6] = R' f_B dt."""
    _, rf_yaw = _rotate_specific_force(roll, pitch, x[YAW_INDEX], f_B)
    return _fill_jacobian(np.eye(EKF_STATE_SIZE), rf_yaw, dt)


def _symmetrised(P):
    S = P + P.T
    S *= 0.5
    return S


def predict_covariance(P, G, Q) -> np.ndarray:
    """(G P G^T + (G P G^T)^T) / 2 + Q (7x7): G P G^T + Q, symmetrised (Q is diagonal)."""
    S = _symmetrised((G @ P) @ G.T)
    S += Q
    return S


def predict(x, P, roll, pitch, f_B, dt, Q, G=None) -> tuple[np.ndarray, np.ndarray]:
    """(x, P) after one IMU step: predict_state, and P <- G P G^T + Q with G = predict_jacobian.

    The rotation is evaluated once. G is an optional 7x7 work buffer from an earlier
    predict_jacobian call; its Jacobian entries are overwritten in place.
    """
    rf, rf_yaw = _rotate_specific_force(roll, pitch, x[YAW_INDEX], f_B)
    G = _fill_jacobian(np.eye(EKF_STATE_SIZE) if G is None else G, rf_yaw, dt)
    return _state_with_gravity(x, rf, dt), predict_covariance(P, G, Q)


def predict_with_yaw(
    x, P, attitude, f_B, dt, Q, G, reference_accelerometer=False
) -> tuple[list[float], np.ndarray]:
    """The EKF's 500 Hz step: (x (list of 7), P) after x[6] <- attitude yaw, then :func:`predict`.

    x: prior state (7 floats); attitude: (roll, pitch, yaw) rad from the attitude filter;
    G: a 7x7 work buffer from :func:`predict_jacobian`, its Jacobian entries overwritten.
    Scalar state arithmetic, as in :func:`predict_state`. reference_accelerometer: f_B is
    the reference's reading R_NB^T (a_NB + g_N), so a_N = R f_B - g_N (SPEC §4 PredictState).
    """
    roll, pitch, yaw = attitude
    rf, rf_yaw = _rotate_specific_force(roll, pitch, yaw, f_B)
    _fill_jacobian(G, rf_yaw, dt)
    a_N = (rf[0], rf[1], rf[2] + gravity_z(reference_accelerometer))
    return list(state_after(x, a_N, yaw, dt)), predict_covariance(P, G, Q)


def kalman_update(x, P, z, H, R, z_hat) -> tuple[np.ndarray, np.ndarray, float]:
    """(x, P, nis) after the measurement z (m) of model z_hat (m) with Jacobian H (m x 7), noise R.

    K = P H^T S^-1 with S = H P H^T + R; P <- (I - K H) P (I - K H)^T + K R K^T (Joseph form,
    symmetrised); nis = nu^T S^-1 nu with nu = z - z_hat.
    """
    nu = np.asarray(z, dtype=float) - z_hat
    PHt = P @ H.T
    S = H @ PHt + R
    solved = np.linalg.solve(S, np.column_stack((PHt.T, nu)))  # S^-1 [H P | nu]
    K = solved[:, :-1].T
    I_KH = IDENTITY - K @ H
    P_new = I_KH @ P @ I_KH.T + K @ R @ K.T
    return x + K @ nu, _symmetrised(P_new), float(nu @ solved[:, -1])


def gps_update(x, P, gps_pv, R_gps) -> tuple[np.ndarray, np.ndarray, float]:
    """Update with a GPS sample gps_pv = (p_N (m), v_N (m/s)); returns (x, P, nis).

    A non-finite sample is skipped: (x, P, nan).
    """
    z = np.asarray(gps_pv, dtype=float)
    if not np.isfinite(z).all():
        return x, P, math.nan
    return kalman_update(x, P, z, H_GPS, R_gps, x[:6])


def mag_update(x, P, yaw_meas, R_mag) -> tuple[np.ndarray, np.ndarray, float]:
    """Update with a magnetometer yaw (rad); returns (x, P, nis).

    The residual goes the short way round (the reference shifts the predicted yaw by 2 pi),
    the posterior yaw is wrapped to [-pi, pi). Same result as kalman_update with H_MAG,
    in scalar form: with h = e6^T, S = P66 + r and K = P[:, 6] / S the Joseph form is
    P - K P[6, :] - P[:, 6] K^T + S K K^T. A non-finite yaw gives (x, P, nan).
    """
    yaw_meas = float(yaw_meas)
    if not math.isfinite(yaw_meas):
        return x, P, math.nan
    p6 = P[:, YAW_INDEX]
    nu, S = mag_innovation(yaw_meas, float(x[YAW_INDEX]), float(p6[YAW_INDEX]), float(R_mag[0, 0]))
    K = p6 / S
    KhP = np.outer(K, p6)
    P_new = P - (KhP + KhP.T) + S * np.outer(K, K)
    x_new = x + K * nu
    x_new[YAW_INDEX] = wrap_to_pi(x_new[YAW_INDEX])
    return x_new, P_new, nu * nu / S


def mag_innovation(yaw_meas, yaw, yaw_variance, r) -> tuple[float, float]:
    """(nu rad, S rad^2) of a magnetometer yaw yaw_meas against the predicted yaw (rad) of
    variance H P H^T = yaw_variance, noise r: nu = wrap(yaw_meas - yaw), the short way round,
    S = yaw_variance + r. Shared by both estimators' mag updates and their compiled kernels."""
    return wrap_to_pi(yaw_meas - yaw), yaw_variance + r


def tilt_variance(t, gyro_std, tau, dt) -> float:
    """Per-axis variance (rad^2) of the complementary filter's roll/pitch error from gyro noise, t s in.

    The filter (``complementary.complementary_update``) integrates the gyro (noise gyro_std
    rad/s per sample, step dt s) and keeps a = tau / (tau + dt) of the result each step, so
    the error follows e_(k+1) = a (e_k + n_k dt) and its variance V_(k+1) = a^2 (V_k + (gyro_std
    dt)^2) from V_0 = 0 (the filter starts at the truth): V = s (1 - a^(2k)) / (1 - a^2) with
    s = (a gyro_std dt)^2 and k = t / dt steps. The accelerometer's share (weight 1 - a) is
    not noise on a drag-free multirotor (its specific force carries no tilt, so it pulls the
    estimate towards level: a trajectory-dependent bias) and is left out.
    """
    a = tau / (tau + dt)
    step = (a * gyro_std * dt) ** 2
    return step * (1.0 - a ** (2.0 * max(t, 0.0) / dt)) / (1.0 - a * a)


def tilt_jacobian(roll, pitch, yaw, fx, fy, fz, wy, wz) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Sensitivity of the prediction to roll and pitch errors: two 4-tuples (d/droll, d/dpitch) of
    (a_N x, y, z in m/s^2 per rad, yaw rate in rad/s per rad).

    a_N = R_NB f_B with R_NB = Rz(yaw) Ry(pitch) Rx(roll) (as :func:`predict_state`; gravity
    does not depend on the angles) and the ZYX yaw rate (wy sin(roll) + wz cos(roll)) / cos(pitch)
    of the body rate w_NB_B (rad/s). Angles in rad, f_B in m/s^2 (FRD). Plain float
    arithmetic (the fleet compiles it).
    """
    trig = attitude_trig(roll, pitch, yaw)
    cr, sr, cp, sp = trig[0], trig[1], trig[2], trig[3]
    return tilt_jacobian_of(trig, yaw_free_rotation_of(cr, sr, cp, sp, fx, fy, fz), wy, wz)


def tilt_jacobian_of(trig, rotated, wy, wz) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """:func:`tilt_jacobian` from the attitude's trig = (cos, sin of roll, of pitch, of yaw) and
    rotated = (ux, uy, uz, rolled_z) of :func:`yaw_free_rotation_of` (a prediction has both already)."""
    cr, sr, cp, sp, cy, sy = trig
    ux, uy, uz, rolled_z = rotated
    # d u / d roll = (sp uy, -rolled_z, cp uy); d u / d pitch = (uz, 0, -ux); a_N = Rz(yaw) u
    dux_r, duy_r, duz_r = sp * uy, -rolled_z, cp * uy
    yaw_rate_numerator = wy * sr + wz * cr
    d_roll = (
        cy * dux_r - sy * duy_r,
        sy * dux_r + cy * duy_r,
        duz_r,
        (wy * cr - wz * sr) / cp,
    )
    d_pitch = (cy * uz, sy * uz, -ux, yaw_rate_numerator * sp / (cp * cp))
    return d_roll, d_pitch


def tilt_gains(variance, velocity_time, yaw_time, dt) -> tuple[float, float]:
    """(velocity_gain, yaw_gain) = sqrt(variance dt velocity_time), sqrt(variance dt yaw_time).

    variance: roll/pitch error variance, rad^2 (:func:`tilt_variance`); dt: the predict step,
    s. The tilt error changes slowly, so it enters Q as white noise held for an effective time
    (s) on the velocity and on the yaw: these gains scale the Jacobian's rows
    (:func:`tilt_noise_factors`).
    """
    return math.sqrt(variance * dt * velocity_time), math.sqrt(variance * dt * yaw_time)


def tilt_noise_factors(
    roll, pitch, yaw, fx, fy, fz, wy, wz, velocity_gain, yaw_gain
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(a, b), two 4-tuples with Q_tilt = a a^T + b b^T on (v_N, yaw): the columns d/droll and
    d/dpitch of :func:`tilt_jacobian`, velocity rows times velocity_gain and the yaw row times
    yaw_gain (:func:`tilt_gains`). Plain float arithmetic (the fleet compiles it)."""
    return scaled_tilt_factors(tilt_jacobian(roll, pitch, yaw, fx, fy, fz, wy, wz), velocity_gain, yaw_gain)


def scaled_tilt_factors(jacobian, velocity_gain, yaw_gain) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """:func:`tilt_noise_factors` of a :func:`tilt_jacobian` (d_roll, d_pitch)."""
    d_roll, d_pitch = jacobian
    a = (
        velocity_gain * d_roll[0],
        velocity_gain * d_roll[1],
        velocity_gain * d_roll[2],
        yaw_gain * d_roll[3],
    )
    b = (
        velocity_gain * d_pitch[0],
        velocity_gain * d_pitch[1],
        velocity_gain * d_pitch[2],
        yaw_gain * d_pitch[3],
    )
    return a, b


def tilt_process_noise(attitude, f_B, w_B, variance, velocity_time, yaw_time, dt) -> np.ndarray:
    """Q_tilt (4x4) for (v_N, yaw) of one predict step: variance * dt * S (J_r J_r^T + J_p J_p^T) S.

    J_r, J_p: :func:`tilt_jacobian` at attitude (roll, pitch, yaw rad), f_B (m/s^2) and w_B
    (rad/s); variance: roll/pitch error variance, rad^2 (:func:`tilt_variance`), the two
    axes independent; S = diag(sqrt(velocity_time) x3, sqrt(yaw_time)), times in s
    (:func:`tilt_gains`).
    """
    a, b = tilt_noise_factors(
        attitude[0], attitude[1], attitude[2], f_B[0], f_B[1], f_B[2], w_B[1], w_B[2],
        *tilt_gains(variance, velocity_time, yaw_time, dt),
    )  # fmt: skip
    factors = np.array((a, b))
    return factors.T @ factors  # a a^T + b b^T: one small matmul, ~1/3 the cost of two np.outer


@dataclass(frozen=True)
class TiltNoise:
    """The EKF7's tilt-aware process noise: ``Ekf7EstimatorConfig`` ``tilt_gyro_std`` (rad/s per IMU sample,
    the gyro noise the attitude filter integrates), ``tilt_velocity_time`` and ``tilt_yaw_time``
    (s), the attitude filter's ``tau`` (s) and the filter step dt (s)."""

    gyro_std: float
    tau: float
    velocity_time: float
    yaw_time: float
    dt: float

    @classmethod
    def from_params(cls, params, attitude_filter, dt) -> "TiltNoise | None":
        """The TiltNoise of Ekf7EstimatorConfig `params` and AttitudeFilterParams `attitude_filter`, or None
        when ``tilt_gyro_std`` is 0 (constant Q, as the reference)."""
        if params.tilt_gyro_std == 0.0:
            return None
        return cls(
            float(params.tilt_gyro_std),
            float(attitude_filter.tau),
            float(params.tilt_velocity_time),
            float(params.tilt_yaw_time),
            float(dt),
        )

    def variance(self, t) -> float:
        """Roll/pitch error variance (rad^2) t s into the flight (:func:`tilt_variance`)."""
        return tilt_variance(t, self.gyro_std, self.tau, self.dt)

    def gains(self, t) -> tuple[float, float]:
        """(velocity_gain, yaw_gain) t s into the flight (:func:`tilt_gains`)."""
        return tilt_gains(self.variance(t), self.velocity_time, self.yaw_time, self.dt)

    def process_noise(self, t, Q, attitude, f_B, w_B) -> np.ndarray:
        """Q (7x7) plus :func:`tilt_process_noise` on the (v_N, yaw) block, t s into the flight."""
        total = Q.copy()
        total[3:7, 3:7] += tilt_process_noise(
            attitude, f_B, w_B, self.variance(t), self.velocity_time, self.yaw_time, self.dt
        )
        return total
