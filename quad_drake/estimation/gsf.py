"""Pure: the EKF-GSF yaw estimator, a bank of yaw hypotheses weighted as a Gaussian sum.

Yaw without a magnetometer, as PX4's ``EKFGSF_yaw`` and ArduPilot's ``EKFGSF_yaw`` estimate it
(Riseborough's Gaussian sum filter): M small EKFs (:class:`GsfParams` ``models``, PX4 uses 5)
run side by side, model j on the state X_j = (v_N, v_E m/s, psi rad) with covariance P_j (3 x 3),
started at yaws spread evenly over [-pi, pi): psi_j = -pi + (j + 1/2) 2 pi / M, P_j =
diag(r, r, (pi / M)^2) with r the GPS velocity variance, weights w_j = 1 / M. NED world, FRD body.

Prediction over dt with the IMU sample (f_B m/s^2, w_B rad/s, the main filter's gyro bias
removed) and the main filter's roll phi and pitch theta (the tilt the models share; PX4 runs a
complementary filter per model instead, which its fixed-wing turns need):

    L   = Ry(theta) Rx(phi) f_B dt                    delta velocity in the level frame (m/s)
    dv  = Rz(psi_j) L  (N, E rows)                    v_N += dv_N, v_E += dv_E
    psi_j += (sin phi w_y + cos phi w_z) / cos theta dt,  wrapped
    F   = [[1, 0, -dv_E], [0, 1, dv_N], [0, 0, 1]]   (d dv / d psi)
    P_j = F P_j F^T + diag((a dt)^2, (a dt)^2, (g dt)^2)   a = accel_noise, g = gyro_noise

Update with a GPS velocity z = (v_N, v_E) of variance r (the GPS velocity std, at least
``vel_std_min``, as PX4's 0.5 m/s floor): H = [I2 0], nu = z - H X_j, S_j = H P_j H^T + r I,
K = P_j H^T S_j^-1, X_j += K nu c, P_j = (I - K H) P_j (I - K H)^T + r K K^T, where c =
sqrt(25 / nis_j) clips an innovation beyond 5 sigma (nis_j = nu^T S_j^-1 nu > 25, PX4's
compression), c = 1 otherwise. The weights follow the Gaussian likelihood of each model's
innovation, w_j <- w_j N(nu; 0, S_j) / sum_k w_k N(nu; 0, S_k), computed in the log domain (a
sample no model explains keeps the weights as they were).

The Gaussian sum's yaw is the weighted circular mean and its variance the weighted spread:

    psi = atan2(sum w_j sin psi_j, sum w_j cos psi_j),
    var = sum w_j (P_j[2, 2] + wrap(psi_j - psi)^2).

Reset of the main filter (:func:`reset_reason`): the GSF yaw replaces the main filter's when its
variance is below ``reset_max_yaw_std``^2 and either no magnetometer sample has aligned the yaw yet
(none at take-off, or every one rejected: ``ALIGN``), or the main filter's yaw has differed from
the GSF's by more than ``yaw_disagreement`` for ``disagreement_time`` s (the magnetometer lies,
is lost and the yaw has drifted, or is rejected: ``DISAGREE``, PX4's yaw emergency, after which
the magnetometer is no longer fused), at most ``max_resets`` times a flight.

These functions are the matrix-form reference oracles of one vehicle's bank; the compiled kernel
``kernels/gsf.py`` runs the same steps on N vehicles' books and is tested against them to 1e-12
(``tests/test_gsf.py``). Pure: numpy and math, no pydrake.
"""

import math
from dataclasses import dataclass

import numpy as np

from quad_drake.config.fields import number
from quad_drake.models.rotations import quat_product, wrap_to_pi

NO_RESET, ALIGN, DISAGREE = 0, 1, 2
""":func:`reset_reason`: no reset; the first alignment (no magnetometer sample fused); the main
filter's yaw persistently away from the GSF's (the magnetometer is then no longer fused)."""

INNOVATION_CLIP_NIS = 25.0
"""An innovation beyond 5 sigma (nis > 25) is scaled back to 5 sigma (PX4's compression)."""


@dataclass
class GsfParams:
    """The EKF-GSF yaw estimator beside an estimator (``estimator: {kind: eskf, gsf: {enabled:
    true}}``): its bank and when its yaw resets the main filter's (module docstring). Off by
    default. Defaults are PX4's (``EKFGSF_yaw.h``, ``EKF2_GSF_TAS``-era parameters)."""

    enabled: bool = False
    models: int = number(5, minimum=2, maximum=32)  # yaw hypotheses in the bank
    accel_noise: float = number(2.0, positive=True)  # m/s^2, horizontal delta-velocity noise (PX4: 2)
    gyro_noise: float = number(0.1, positive=True)  # rad/s, yaw-rate noise (PX4: 0.1)
    vel_std_min: float = number(0.5, positive=True)  # m/s, floor of the GPS velocity std (PX4: 0.5)
    reset_max_yaw_std: float = number(0.262, positive=True, maximum=math.pi)  # rad, 15 deg (PX4)
    yaw_disagreement: float = number(0.436, positive=True, maximum=math.pi)  # rad, 25 deg (PX4)
    disagreement_time: float = number(1.0, nonnegative=True)  # s of disagreement before a reset
    max_resets: int = number(3, minimum=1)  # resets a flight at most (PX4: 3)


# ----- the bank of one vehicle (matrix-form reference oracles) -------------------------------------


def initial_bank(models, v_NE, vel_var) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X (M, 3), P (M, 3, 3), w (M,)): the bank started at the GPS velocity v_NE (2, m/s) of
    variance vel_var ((m/s)^2), yaws evenly spread over [-pi, pi) (module docstring)."""
    X = np.zeros((models, 3))
    X[:, 0], X[:, 1] = v_NE[0], v_NE[1]
    X[:, 2] = -math.pi + (np.arange(models) + 0.5) * (2.0 * math.pi / models)
    P = np.zeros((models, 3, 3))
    P[:, 0, 0] = P[:, 1, 1] = vel_var
    P[:, 2, 2] = (math.pi / models) ** 2
    return X, P, np.full(models, 1.0 / models)


def level_delta_velocity(roll, pitch, f_B, dt) -> tuple[float, float]:
    """(L_x, L_y) m/s: the horizontal components of Ry(pitch) Rx(roll) f_B dt (FRD, rad, m/s^2, s)."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    fx, fy, fz = f_B[0] * dt, f_B[1] * dt, f_B[2] * dt
    return cp * fx + sp * (sr * fy + cr * fz), cr * fy - sr * fz


def yaw_increment(roll, pitch, w_B, dt) -> float:
    """The ZYX yaw change (rad) of the body rate w_B (rad/s, FRD) over dt s at roll, pitch (rad)."""
    return (math.sin(roll) * w_B[1] + math.cos(roll) * w_B[2]) / math.cos(pitch) * dt


def predict_bank(X, P, roll, pitch, f_B, w_B, dt, params) -> tuple[np.ndarray, np.ndarray]:
    """(X', P') of every model after one IMU step (module docstring); params: GsfParams."""
    lx, ly = level_delta_velocity(roll, pitch, f_B, dt)
    dpsi = yaw_increment(roll, pitch, w_B, dt)
    Q = np.diag([(params.accel_noise * dt) ** 2] * 2 + [(params.gyro_noise * dt) ** 2])
    X_new, P_new = np.array(X, dtype=float), np.empty_like(P)
    for j in range(X.shape[0]):
        c, s = math.cos(X[j, 2]), math.sin(X[j, 2])
        dv_N, dv_E = c * lx - s * ly, s * lx + c * ly
        X_new[j] = (X[j, 0] + dv_N, X[j, 1] + dv_E, wrap_to_pi(X[j, 2] + dpsi))
        F = np.array([[1.0, 0.0, -dv_E], [0.0, 1.0, dv_N], [0.0, 0.0, 1.0]])
        P_new[j] = F @ P[j] @ F.T + Q
    return X_new, 0.5 * (P_new + np.swapaxes(P_new, 1, 2))


def fuse_velocity_bank(X, P, w, v_NE, vel_var) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X', P', w') after the GPS velocity v_NE (2, m/s) of variance vel_var (module docstring)."""
    H = np.eye(2, 3)
    R = vel_var * np.eye(2)
    X_new, P_new = np.array(X, dtype=float), np.empty_like(P)
    log_likelihood = np.empty(X.shape[0])
    for j in range(X.shape[0]):
        nu = np.asarray(v_NE, dtype=float) - X[j, 0:2]
        S = H @ P[j] @ H.T + R
        S_inv = np.linalg.inv(S)
        nis = float(nu @ S_inv @ nu)
        K = P[j] @ H.T @ S_inv
        clip = math.sqrt(INNOVATION_CLIP_NIS / nis) if nis > INNOVATION_CLIP_NIS else 1.0
        X_new[j] = X[j] + K @ nu * clip
        X_new[j, 2] = wrap_to_pi(X_new[j, 2])
        I_KH = np.eye(3) - K @ H
        P_j = I_KH @ P[j] @ I_KH.T + K @ R @ K.T
        P_new[j] = 0.5 * (P_j + P_j.T)
        log_likelihood[j] = -0.5 * nis - 0.5 * math.log(np.linalg.det(S)) - math.log(2.0 * math.pi)
    return X_new, P_new, normalized_weights(w, log_likelihood)


def normalized_weights(w, log_likelihood) -> np.ndarray:
    """w_j L_j / sum_k w_k L_k of the weights w (M,) and log-likelihoods (M,); w unchanged when no
    model has a finite positive product."""
    log_w = np.log(np.asarray(w, dtype=float)) + log_likelihood
    top = np.max(log_w)
    if not math.isfinite(top):
        return np.array(w, dtype=float)
    new = np.exp(log_w - top)
    return new / new.sum()


def gaussian_sum_yaw(X, P, w) -> tuple[float, float]:
    """(yaw rad, variance rad^2) of the bank: the weighted circular mean and spread."""
    yaw = math.atan2(float(w @ np.sin(X[:, 2])), float(w @ np.cos(X[:, 2])))
    spread = np.array([wrap_to_pi(psi - yaw) for psi in X[:, 2]])
    return yaw, float(w @ (P[:, 2, 2] + spread**2))


# ----- resets of the main filter -------------------------------------------------------------------


def disagreement_start(since, t, gsf_yaw, gsf_var, main_yaw, max_yaw_var, yaw_disagreement) -> float:
    """The time (s) since which a confident GSF (gsf_var <= max_yaw_var) has disagreed with the
    main filter's yaw by more than yaw_disagreement (rad), `since` (NaN: not disagreeing) carried
    on at time t; NaN when they agree (or the GSF is not confident)."""
    disagree = gsf_var <= max_yaw_var and abs(wrap_to_pi(main_yaw - gsf_yaw)) > yaw_disagreement
    if not disagree:
        return math.nan
    return t if math.isnan(since) else since


def reset_reason(t, since, gsf_var, aligned, resets, max_yaw_var, disagreement_time, max_resets) -> int:
    """Why the GSF yaw resets the main filter's now (:data:`ALIGN`, :data:`DISAGREE`), or
    :data:`NO_RESET` (module docstring). since: :func:`disagreement_start` (s or NaN); aligned:
    a magnetometer sample or a reset has aligned the yaw; resets: the resets so far."""
    if resets >= max_resets or not gsf_var <= max_yaw_var:
        return NO_RESET
    if not aligned:
        return ALIGN
    if not math.isnan(since) and t - since >= disagreement_time:
        return DISAGREE
    return NO_RESET


def yaw_reset_quaternion(qw, qx, qy, qz, yaw) -> tuple[float, float, float, float]:
    """q_NB (wxyz) with its ZYX yaw set to `yaw` (rad), roll and pitch kept: Rz(yaw - yaw(q)) (x) q,
    a rotation about the world down axis."""
    current = math.atan2(2.0 * (qx * qy + qw * qz), qw * qw + qx * qx - qy * qy - qz * qz)
    half = 0.5 * wrap_to_pi(yaw - current)
    return quat_product((math.cos(half), 0.0, 0.0, math.sin(half)), (qw, qx, qy, qz))


def eskf_yaw_reset(x, P, yaw, yaw_var) -> tuple[np.ndarray, np.ndarray]:
    """(x', P') of an ESKF (nominal x (16), error covariance P (k, k), dtheta in world axes at
    6:9) with its yaw reset to `yaw` (rad): the quaternion rotated about down
    (:func:`yaw_reset_quaternion`), the down-axis attitude error decorrelated from every other
    state with variance yaw_var (rad^2), as PX4's ``resetQuatStateYaw``."""
    x, P = np.array(x, dtype=float), np.array(P, dtype=float)
    x[6:10] = yaw_reset_quaternion(*x[6:10], yaw)
    P[8, :] = P[:, 8] = 0.0
    P[8, 8] = yaw_var
    return x, P
