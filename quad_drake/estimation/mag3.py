"""Pure: 3-axis magnetometer fusion: the field vector for the ESKF, the tilt-compensated heading
for the EKF7.

Frames: NED world N, FRD body B; R_NB = Rz(yaw) Ry(pitch) Rx(roll). The sensor
(``sensor_models.magnetometer_field``) reads m_B = R_NB^T m_N + hard_iron + noise (gauss), with
m_N the world field (``sensor_models.world_field``: strength, declination D, inclination I).
The filter subtracts its own hard-iron calibration first (``MagFieldFusionParams.hard_iron``).

**ESKF, the vector** (PX4 EKF2's 3-axis fusion, ``EKF2_MAG_TYPE``; without estimating the field
or the hard iron): with R_NB = Exp(dtheta) R_hat (eskf.py: dtheta about the world axes),

    h(x) = R_hat^T m_N,  R^T m_N = R_hat^T Exp(-dtheta) m_N ~ R_hat^T (m_N - dtheta x m_N)
                                 = h(x) + R_hat^T [m_N]x dtheta,
    so H = [0_3x6, R_hat^T [m_N]x, 0_3x(n-9)] (3 x n), R = diag(field_std^2) (gauss^2).

The heading error dtheta_D and the tilt both enter (a field with inclination I constrains the
tilt too; the yaw is seen through the horizontal component, strength cos I). The 3-dof NIS
nu^T S^-1 nu gates the whole sample (S = H P H^T + R, 3 x 3, inverted in closed form); an
accepted sample is fused one axis at a time (:func:`sequential_field_update`, PX4 fuses the axes
one by one too), which with the diagonal R and H taken at the prior equals the batch update.
By default (``attitude_only``) the gain is zero outside the attitude, as PX4 fuses the
magnetometer into the attitude and field states only: the field measures the attitude, and a
disturbed sample that passes the gate while the attitude variance is large (a GPS outage, when
the position and the tilt are strongly correlated) must not move the position; the Joseph form
keeps P the covariance of that sub-optimal update.

**EKF7, the heading**: the EKF7 has no roll/pitch states; it levels the field with the attitude
filter's roll and pitch, l = Ry(pitch) Rx(roll) m_B = Rz(yaw)^T m_N, whose horizontal part is
cos I |m| (cos(yaw - D), -sin(yaw - D)), so

    yaw = atan2(-l_y, l_x) + D    (:func:`tilt_compensated_heading`)

is fused as the EKF7's yaw measurement with R the variance of the field noise carried through
the heading's Jacobian (:func:`heading_jacobians`, :func:`heading_variances`); the share of the
roll/pitch error (``Ekf7EstimatorConfig`` tilt noise, ``tilt_std``), slowly varying and common to many
samples, floors the posterior yaw variance instead (:func:`floored_yaw_variance`). The EKF7's
tilt comes from the complementary filter (0.07 rad RMS on 11) and the heading's sensitivity to it
is about tan(inclination) = 2 at I = 1.1 rad: the tilt-compensated heading is a poor yaw sensor
for the EKF7 (README "Sensors"), the reason the ESKF fuses the vector.

Scalar float arithmetic and small arrays only: ``kernels/`` compile these functions' own code.
"""

import math
from dataclasses import dataclass
from typing import List

import numpy as np

from quad_drake.config.fields import noise_stds, number, vector
from quad_drake.models.rotations import rotation_entries
from quad_drake.models.sensor_models import world_field

ATTITUDE_START = 6
"""The first of the ESKF error-state entries the field depends on (dtheta, 6..8, rad, world axes)."""


@dataclass
class MagFieldFusionParams:
    """What an estimator assumes of a 3-axis magnetometer (fused only when the vehicle's
    magnetometer is ``three_axis``): the world field, the hard-iron calibration and the noise."""

    field_strength: float = number(0.5, positive=True)  # gauss, |m_N|
    declination: float = number(0.0, minimum=-math.pi, maximum=math.pi)  # rad, east of true north
    inclination: float = number(1.1, minimum=-math.pi / 2, maximum=math.pi / 2)  # rad, below horizontal
    hard_iron: List[float] = vector(0.0, 0.0, 0.0)  # gauss, the calibrated body FRD offset, subtracted
    field_std: List[float] = noise_stds(0.005, 0.005, 0.005)  # gauss per sample, body x y z
    gate_sigma: float = number(5.0, nonnegative=True)  # sigma; the 3-dof field (ESKF) / heading (EKF7) gate
    # ESKF: true, the field corrects only the attitude (PX4 fuses the magnetometer into attitude and
    # field states only), so a disturbed sample the gate lets through cannot move position or
    # velocity; false: every state correlated with the attitude (the full Kalman gain)
    attitude_only: bool = True
    # ESKF: false, the field corrects the heading alone (its gain on the tilt errors about N and E
    # zeroed), as PX4 fuses it on the ground (``fuseMag(..., update_tilt=false)`` unless in 3-D
    # mode in flight, where its own field states absorb a field it does not know)
    corrects_tilt: bool = True
    tilt_std: float = number(0.0, nonnegative=True)  # rad, EKF7: the roll/pitch error the heading carries


def assumed_world_field(params) -> tuple[float, float, float]:
    """m_N (3-tuple, gauss, NED) of MagFieldFusionParams."""
    return world_field(params.field_strength, params.declination, params.inclination)


def predicted_field(qw, qx, qy, qz, mx, my, mz) -> tuple[float, float, float]:
    """h(x) = R_NB^T m_N (3-tuple, gauss, body FRD) of the unit quaternion q_NB (wxyz) and the
    world field m_N = (mx, my, mz) (gauss, NED)."""
    r = rotation_entries(qw, qx, qy, qz)
    return (
        r[0] * mx + r[3] * my + r[6] * mz,
        r[1] * mx + r[4] * my + r[7] * mz,
        r[2] * mx + r[5] * my + r[8] * mz,
    )


def field_attitude_jacobian(qw, qx, qy, qz, mx, my, mz) -> np.ndarray:
    """d h / d dtheta = R_hat^T [m_N]x (3 x 3 array, gauss/rad) for R_NB = Exp(dtheta) R_hat
    (module docstring)."""
    r = rotation_entries(qw, qx, qy, qz)
    # [m]x = [[0, -mz, my], [mz, 0, -mx], [-my, mx, 0]]; R^T row i is column i of R: (r[i], r[3+i], r[6+i])
    J = np.empty((3, 3))
    for i in range(3):
        a, b, c = r[i], r[3 + i], r[6 + i]
        J[i, 0] = b * mz - c * my
        J[i, 1] = -a * mz + c * mx
        J[i, 2] = a * my - b * mx
    return J


def field_jacobian(q, m_N, n) -> np.ndarray:
    """H (3 x n) of the field against the ESKF's error state of size n (9 or 15): the attitude
    block (columns 6..8, dtheta) of :func:`field_attitude_jacobian`, zero elsewhere."""
    H = np.zeros((3, n))
    J = field_attitude_jacobian(q[0], q[1], q[2], q[3], m_N[0], m_N[1], m_N[2])
    for i in range(3):
        for j in range(3):
            H[i, ATTITUDE_START + j] = J[i, j]
    return H


def inverse3(S) -> tuple[np.ndarray, float]:
    """(S^-1 (3 x 3), det) of a 3 x 3 matrix in closed form (cofactors); det <= 0 for a
    covariance that is not positive definite (then the inverse is not to be used)."""
    a, b, c = S[0, 0], S[0, 1], S[0, 2]
    d, e, f = S[1, 0], S[1, 1], S[1, 2]
    g, h, k = S[2, 0], S[2, 1], S[2, 2]
    co00, co01, co02 = e * k - f * h, f * g - d * k, d * h - e * g
    det = a * co00 + b * co01 + c * co02
    inv = np.empty((3, 3))
    if det == 0.0:
        inv[:] = math.nan
        return inv, det
    s = 1.0 / det
    inv[0, 0], inv[0, 1], inv[0, 2] = co00 * s, (c * h - b * k) * s, (b * f - c * e) * s
    inv[1, 0], inv[1, 1], inv[1, 2] = co01 * s, (a * k - c * g) * s, (c * d - a * f) * s
    inv[2, 0], inv[2, 1], inv[2, 2] = co02 * s, (b * g - a * h) * s, (a * e - b * d) * s
    return inv, det


def field_innovation(
    q, P, m_B, m_N, hard_iron, field_var
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(nu (3,), H (3 x n), S (3 x 3), nis) of a 3-axis sample m_B (gauss, FRD) against the ESKF
    at its nominal attitude q (wxyz) and covariance P (n x n): nu = (m_B - hard_iron) - R_hat^T m_N,
    H from :func:`field_jacobian`, S = H P H^T + diag(field_var), nis = nu^T S^-1 nu (NaN when S is
    not positive definite). field_var: (3,) gauss^2. Loops over the entries (numba compiles it)."""
    n = P.shape[0]
    h = predicted_field(q[0], q[1], q[2], q[3], m_N[0], m_N[1], m_N[2])
    nu = np.empty(3)
    for i in range(3):
        nu[i] = m_B[i] - hard_iron[i] - h[i]
    H = field_jacobian(q, m_N, n)
    S = np.empty((3, 3))
    for i in range(3):  # S = J P_theta J^T + R, J = H's attitude block
        for j in range(3):
            value = 0.0
            for a in range(3):
                for c in range(3):
                    value += (
                        H[i, ATTITUDE_START + a]
                        * P[ATTITUDE_START + a, ATTITUDE_START + c]
                        * H[j, ATTITUDE_START + c]
                    )
            S[i, j] = value
        S[i, i] += field_var[i]
    inv, det = inverse3(S)
    nis = math.nan
    if det > 0.0:
        nis = 0.0
        for i in range(3):
            for j in range(3):
                nis += nu[i] * inv[i, j] * nu[j]
    return nu, H, S, nis


def sequential_field_update(
    P, nu, H, field_var, attitude_only, corrects_tilt=True
) -> tuple[np.ndarray, np.ndarray]:
    """(dx (n,), P' (n x n)): the field innovation nu (3,) fused one axis at a time with the rows
    of H (3 x n, taken at the prior) and the diagonal noise field_var (3,): for each axis i the
    scalar Joseph update b = P h_i^T, S_i = h_i b + r_i, K = b / S_i, dx += K (nu_i - h_i dx),
    P <- P - K b^T - b K^T + S_i K K^T. Equal to the batch update with R = diag(field_var).

    attitude_only: K's entries outside the attitude (error states 6..8) are set to 0 before they
    are used, so the field corrects the attitude alone and position, velocity and biases keep
    their values. The update above is the Joseph form, valid for any gain: P stays the covariance
    of the (now sub-optimal) estimate, and the non-attitude rows keep their variances while their
    cross-covariance with the attitude shrinks as (I - K H). Equal to the batch update with the
    rows of K = P H^T S^-1 outside the attitude zeroed (:func:`eskf_field_update`). Not
    corrects_tilt: K's entries of the tilt errors (about N and E, states 6 and 7) set to 0 too,
    so the field corrects the heading alone (PX4's ``update_tilt`` false).
    Loops over the entries (numba compiles it)."""
    n = P.shape[0]
    P = P.copy()
    dx = np.zeros(n)
    b = np.empty(n)
    k = np.empty(n)
    for axis in range(3):
        s = field_var[axis]
        residual = nu[axis]
        for r in range(n):
            value = 0.0
            for c in range(n):
                value += P[r, c] * H[axis, c]
            b[r] = value
        for r in range(n):
            s += H[axis, r] * b[r]
            residual -= H[axis, r] * dx[r]
        for r in range(n):
            k[r] = b[r] / s
            if attitude_only and (r < ATTITUDE_START or r >= ATTITUDE_START + 3):
                k[r] = 0.0
            if not corrects_tilt and (r == ATTITUDE_START or r == ATTITUDE_START + 1):
                k[r] = 0.0
            dx[r] += k[r] * residual
        for r in range(n):
            for c in range(n):
                P[r, c] = P[r, c] - k[r] * b[c] - b[r] * k[c] + s * k[r] * k[c]
    return dx, P


def eskf_field_update(
    x, P, m_B, m_N, hard_iron, field_var, attitude_only, corrects_tilt=True
) -> tuple[np.ndarray, np.ndarray, float]:
    """Oracle: (x', P', nis) of the ESKF (nominal x (16,), P (9 or 15 square)) fusing a 3-axis
    sample m_B (gauss) with the dense batch update: K = P H^T S^-1 with H of :func:`field_jacobian`,
    S = H P H^T + diag(field_var), K's rows outside the attitude zeroed when attitude_only, the
    Joseph form P' = (I - K H) P (I - K H)^T + K R K^T, then ``eskf.inject``. A non-finite sample
    gives (x, P, nan)."""
    from quad_drake.estimation import eskf

    m_B = np.asarray(m_B, dtype=float)
    if not np.isfinite(m_B).all():
        return x, P, math.nan
    x = np.asarray(x, dtype=float)
    q = x[6:10]
    h = np.array(predicted_field(q[0], q[1], q[2], q[3], m_N[0], m_N[1], m_N[2]))
    nu = m_B - np.asarray(hard_iron, dtype=float) - h
    H = field_jacobian(q, m_N, P.shape[0])
    R = np.diag(np.asarray(field_var, dtype=float))
    S = H @ P @ H.T + R
    keep = np.ones(P.shape[0], dtype=bool)
    if attitude_only:
        keep[:] = False
        keep[ATTITUDE_START : ATTITUDE_START + 3] = True
    if not corrects_tilt:  # the tilt is observed: axis by axis (PX4's order) differs from the batch
        keep[ATTITUDE_START : ATTITUDE_START + 2] = False
        P_new, dx = P.copy(), np.zeros(P.shape[0])
        for axis in range(3):
            h = H[axis]
            K = np.where(keep, P_new @ h / (h @ P_new @ h + R[axis, axis]), 0.0)
            dx += K * (nu[axis] - h @ dx)
            I_KH = np.eye(P.shape[0]) - np.outer(K, h)
            P_new = I_KH @ P_new @ I_KH.T + R[axis, axis] * np.outer(K, K)
    else:
        K = np.where(keep[:, None], P @ H.T @ np.linalg.inv(S), 0.0)
        I_KH = np.eye(P.shape[0]) - K @ H
        P_new = I_KH @ P @ I_KH.T + K @ R @ K.T
        dx = K @ nu
    x_new, P_new = eskf.inject(x, 0.5 * (P_new + P_new.T), dx)
    return x_new, P_new, float(nu @ np.linalg.solve(S, nu))


def leveled_field(roll, pitch, mx, my, mz) -> tuple[float, float, float]:
    """l = Ry(pitch) Rx(roll) m_B (3-tuple, gauss): the body field with the tilt taken out,
    = Rz(yaw)^T m_N (roll, pitch in rad; m_B gauss, FRD)."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    rolled_z = sr * my + cr * mz
    return cp * mx + sp * rolled_z, cr * my - sr * mz, -sp * mx + cp * rolled_z


def tilt_compensated_heading(roll, pitch, mx, my, mz, declination) -> float:
    """Yaw (rad, wrapped to [-pi, pi)) of a body field m_B (gauss, FRD, hard iron removed) at
    roll and pitch (rad): atan2(-l_y, l_x) + declination with l = :func:`leveled_field`."""
    lx, ly, _ = leveled_field(roll, pitch, mx, my, mz)
    yaw = math.atan2(-ly, lx) + declination
    return (yaw + math.pi) % (2.0 * math.pi) - math.pi


def heading_jacobians(roll, pitch, mx, my, mz) -> tuple[tuple[float, float, float], tuple[float, float]]:
    """(d yaw / d m_B (3-tuple, rad/gauss), d yaw / d (roll, pitch) (2-tuple, rad/rad)) of
    :func:`tilt_compensated_heading`.

    With l = Ry Rx m_B and rho^2 = l_x^2 + l_y^2: d yaw = (l_y dl_x - l_x dl_y) / rho^2;
    dl/dm_B = Ry Rx; dl_x/droll = sin(pitch) l_y, dl_y/droll = -(sin(roll) m_y + cos(roll) m_z),
    dl_x/dpitch = l_z, dl_y/dpitch = 0."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    rolled_z = sr * my + cr * mz
    lx, ly, lz = cp * mx + sp * rolled_z, cr * my - sr * mz, -sp * mx + cp * rolled_z
    rho2 = lx * lx + ly * ly
    gx, gy = ly / rho2, -lx / rho2  # d yaw / d l_x, d l_y
    # rows of Ry Rx: l_x = cp mx + sp sr my + sp cr mz; l_y = cr my - sr mz
    d_field = (gx * cp, gx * sp * sr + gy * cr, gx * sp * cr - gy * sr)
    d_tilt = (gx * sp * ly - gy * rolled_z, gx * lz)
    return d_field, d_tilt


def heading_variances(roll, pitch, mx, my, mz, field_var, tilt_var) -> tuple[float, float]:
    """(field part, tilt part) of :func:`heading_variance` (rad^2): J_m diag(field_var) J_m^T, white
    from sample to sample, and tilt_var |J_tilt|^2, the share of the attitude filter's roll/pitch
    error, which changes slowly (a bias common to many samples)."""
    d_field, d_tilt = heading_jacobians(roll, pitch, mx, my, mz)
    field_part = d_field[0] ** 2 * field_var[0] + d_field[1] ** 2 * field_var[1]
    field_part += d_field[2] ** 2 * field_var[2]
    return field_part, tilt_var * (d_tilt[0] ** 2 + d_tilt[1] ** 2)


def floored_yaw_variance(p_yaw, tilt_part) -> float:
    """The EKF7's yaw variance (rad^2) after a heading fusion: at least the heading's tilt part.

    The tilt error that levels the field is common to many samples (the attitude filter's roll and
    pitch drift slowly), so fused one by one as independent they would make the yaw far better
    known than that error allows; as ``baro.floored_height_variance`` for the baro bias."""
    return tilt_part if p_yaw < tilt_part else p_yaw


def heading_variance(roll, pitch, mx, my, mz, field_var, tilt_var) -> float:
    """Variance (rad^2) of :func:`tilt_compensated_heading` from the field noise field_var (3,
    gauss^2, body axes) and the roll/pitch error variance tilt_var (rad^2 each, independent):
    J_m diag(field_var) J_m^T + tilt_var |J_tilt|^2 (:func:`heading_jacobians`)."""
    d_field, d_tilt = heading_jacobians(roll, pitch, mx, my, mz)
    field_part = d_field[0] ** 2 * field_var[0] + d_field[1] ** 2 * field_var[1]
    field_part += d_field[2] ** 2 * field_var[2]
    return field_part + tilt_var * (d_tilt[0] ** 2 + d_tilt[1] ** 2)
