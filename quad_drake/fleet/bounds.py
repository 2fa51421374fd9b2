"""The posterior Cramér-Rao bound of N runs at once: the array form of
:func:`quad_drake.accuracy_bound.posterior_crb` (leading axis N after time), so a fleet batch
summarises its runs' efficiency without a per-run loop over the log samples. Pure."""

import numpy as np

from quad_drake.accuracy_bound import PCRB_PRIOR_STD, PCRB_STATES, _rotations
from quad_drake.conventions import GRAVITY, LOG_PERIOD, ONBOARD_PERIOD


def _skews(v):
    """(N, 3, 3) skew matrices of (N, 3) vectors."""
    out = np.zeros((v.shape[0], 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def posterior_crbs(states, gps_fresh, mag_fresh, sensors, period=LOG_PERIOD, dt_imu=ONBOARD_PERIOD):
    """{name: (n, N) variance} of :func:`~quad_drake.accuracy_bound.posterior_crb` for N runs.

    states: (n, N, 13) logged truth; gps_fresh, mag_fresh: (n, N) bool; sensors: the
    vehicle's SensorsConfig (the same for the N runs). The same bound propagated in
    covariance form, P = J^-1: the prediction J <- (F J^-1 F^T + Q)^-1 becomes
    P <- F P F^T + Q and the fusions J <- J + H^T R^-1 H become Kalman updates, so only the
    GPS samples need a (6 x 6) inverse instead of three 9 x 9 inverses per log sample; it
    agrees with the information form to rounding (tests/test_fleet_kernels.py).
    """
    states = np.asarray(states, dtype=float)
    n, runs = states.shape[:2]
    imu, gps, mag = sensors.imu, sensors.gps, sensors.mag
    R_all = _rotations(states[:, :, 3:7].reshape(-1, 4)).reshape(n, runs, 3, 3)
    velocity = states[:, :, 7:10]
    accel = np.gradient(velocity, period, axis=0) if n > 1 else np.zeros((n, runs, 3))
    u_N = accel - np.array([0.0, 0.0, GRAVITY])
    accel_psd = np.square(imu.accel_std) * dt_imu
    gyro_psd = np.square(imu.gyro_std) * dt_imu
    R_gps = np.diag(np.square(list(gps.pos_std) + list(gps.vel_std)))
    P = np.broadcast_to(np.diag(np.square(PCRB_PRIOR_STD)), (runs, 9, 9)).copy()
    variances = np.zeros((n, runs, 9))
    euler_variances = np.zeros((n, runs, 3))
    T = period
    eye = np.eye(9)
    use_mag = mag is not None and mag.yaw_std > 0
    for k in range(n):
        R = R_all[k]
        Rt = R.transpose(0, 2, 1)
        if k > 0:
            A = np.zeros((runs, 9, 9))
            A[:, 0:3, 3:6] = np.eye(3)
            A[:, 3:6, 6:9] = -_skews(u_N[k])
            F = eye + A * T + (A @ A) * (0.5 * T * T)
            Ma = (R * accel_psd) @ Rt
            Q = np.zeros((runs, 9, 9))
            Q[:, 0:3, 0:3] = Ma * (T**3 / 3.0)
            Q[:, 0:3, 3:6] = Q[:, 3:6, 0:3] = Ma * (T * T / 2.0)
            Q[:, 3:6, 3:6] = Ma * T
            Q[:, 6:9, 6:9] = (R * gyro_psd) @ Rt * T
            P = F @ P @ F.transpose(0, 2, 1) + Q
        fresh = gps_fresh[k]
        if fresh.any():
            S = P[fresh, 0:6, 0:6] + R_gps
            K = P[fresh, :, 0:6] @ np.linalg.inv(S)
            P[fresh] = P[fresh] - K @ P[fresh, 0:6, :]
        fresh = mag_fresh[k] if use_mag else np.zeros(runs, dtype=bool)
        if fresh.any():
            r00, r10, r20 = R[fresh, 0, 0], R[fresh, 1, 0], R[fresh, 2, 0]
            d = r00 * r00 + r10 * r10
            h = np.zeros((int(fresh.sum()), 9))
            h[:, 6], h[:, 7], h[:, 8] = -r00 * r20 / d, -r10 * r20 / d, 1.0
            Ph = np.einsum("nij,nj->ni", P[fresh], h)
            s = np.einsum("ni,ni->n", h, Ph) + mag.yaw_std**2
            P[fresh] = P[fresh] - Ph[:, :, None] * Ph[:, None, :] / s[:, None, None]
        P = 0.5 * (P + P.transpose(0, 2, 1))
        variances[k] = np.diagonal(P, axis1=1, axis2=2)
        roll = np.arctan2(R[:, 2, 1], R[:, 2, 2])
        pitch = np.arcsin(np.clip(-R[:, 2, 0], -1.0, 1.0))
        W = _euler_rate_matrices(roll, pitch) @ Rt
        euler_variances[k] = np.einsum("nij,njk,nik->ni", W, P[:, 6:9, 6:9], W)
    result = {name: variances[:, :, i] for i, name in enumerate(PCRB_STATES)}
    result.update({name: euler_variances[:, :, i] for i, name in enumerate(("Roll", "Pitch", "Yaw"))})
    return result


def _euler_rate_matrices(roll, pitch):
    """(N, 3, 3) of ``accuracy_bound._euler_rate_matrix``."""
    sr, cr = np.sin(roll), np.cos(roll)
    cp, tp = np.cos(pitch), np.tan(pitch)
    out = np.zeros((roll.shape[0], 3, 3))
    out[:, 0, 0] = 1.0
    out[:, 0, 1], out[:, 0, 2] = sr * tp, cr * tp
    out[:, 1, 1], out[:, 1, 2] = cr, -sr
    out[:, 2, 1], out[:, 2, 2] = sr / cp, cr / cp
    return out
