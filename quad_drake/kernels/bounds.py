"""The posterior Cramér-Rao bound of N runs at once: the array form of
:func:`quad_drake.models.accuracy_bound.posterior_crb` (leading axis N after time), so a fleet batch
summarises its runs' efficiency without a Python loop over the log samples. Pure.

The recursion is a numba-compiled loop (cached on disk) over the log samples and the runs, in
covariance form with the sparsity of the transition used block by block (see
:func:`posterior_crbs`); it agrees with the information form to rounding
(``tests/test_kernels.py``).
"""

import math

import numpy as np

from quad_drake.conventions import GRAVITY, LOG_PERIOD, ONBOARD_PERIOD
from quad_drake.kernels.jit import compiled, njit_cached
from quad_drake.kernels.rotations import rotation_into
from quad_drake.models.accuracy_bound import PCRB_PRIOR_STD, PCRB_STATES, euler_rate_entries

_euler_rate_entries = compiled(euler_rate_entries)


def posterior_crbs(
    states, gps_fresh, mag_fresh, sensors, period=LOG_PERIOD, dt_imu=ONBOARD_PERIOD
) -> dict[str, np.ndarray]:
    """{name: (n, N) variance} of :func:`~quad_drake.models.accuracy_bound.posterior_crb` for N runs.

    states: (n, N, 13) logged truth; gps_fresh, mag_fresh: (n, N) bool; sensors: the
    vehicle's SensorsConfig (the same for the N runs). The same bound propagated in
    covariance form, P = J^-1: the prediction J <- (F J^-1 F^T + Q)^-1 becomes
    P <- F P F^T + Q and the fusions J <- J + H^T R^-1 H become Kalman updates, so only the
    GPS samples need a (6 x 6) solve instead of three 9 x 9 inverses per log sample. With
    F = [[I, T I, -T^2/2 [u]x], [0, I, -T [u]x], [0, 0, I]] the product F P F^T is formed
    from 3 x 3 blocks and the skew matrix's entries, never as dense 9 x 9 products.
    The whole log fed at once to a :class:`PcrbStream`.
    """
    states = np.asarray(states, dtype=float)
    stream = PcrbStream(sensors, states.shape[1], period, dt_imu)
    parts = [stream.update(states, gps_fresh, mag_fresh), stream.finish()]
    return {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}


class PcrbStream:
    """:func:`posterior_crbs` of N runs fed chunk by chunk of log samples: the covariance P is
    carried between chunks, and a sample's specific force (the central difference of the true
    velocity, ``np.gradient``'s, one-sided at the run's ends) waits for the next sample, so
    ``update`` returns the variances of the samples before the chunk's last one and
    ``finish`` those of the run's last sample. Any split gives the whole log's values."""

    def __init__(self, sensors, runs, period=LOG_PERIOD, dt_imu=ONBOARD_PERIOD):
        imu, gps, mag = sensors.imu, sensors.gps, sensors.mag
        self._use_mag = mag is not None and mag.yaw_std > 0
        self._constants = (
            np.square(imu.accel_std) * dt_imu,
            np.square(imu.gyro_std) * dt_imu,
            np.square(np.array(list(gps.pos_std) + list(gps.vel_std), dtype=float)),
            mag.yaw_std**2 if self._use_mag else 1.0,
        )
        self._period, self._runs = float(period), runs
        self._P = np.zeros((runs, 9, 9))
        self._P[:, range(9), range(9)] = np.square(np.array(PCRB_PRIOR_STD, dtype=float))
        self._held = None  # (states (1, N, 13), gps (1, N), mag (1, N)) of the last sample fed
        self._before = None  # (N, 3) true velocity of the sample before it (None: it is the first)
        self._started = False  # the first sample has been propagated

    def update(self, states, gps_fresh, mag_fresh) -> dict[str, np.ndarray]:
        """Fold samples (k, N, 13) truth, (k, N) GPS and magnetometer freshness; {name: (m, N)
        variance} of the samples now complete (the held one and all of these but the last)."""
        states = np.asarray(states, dtype=float)
        gps_fresh, mag_fresh = np.asarray(gps_fresh, dtype=bool), np.asarray(mag_fresh, dtype=bool)
        if self._held is not None:
            states = np.concatenate((self._held[0], states))
            gps_fresh = np.concatenate((self._held[1], gps_fresh))
            mag_fresh = np.concatenate((self._held[2], mag_fresh))
        if states.shape[0] == 0:
            return self._empty()
        self._held = (
            states[-1:].copy(),
            gps_fresh[-1:].copy(),
            mag_fresh[-1:].copy(),
        )  # inputs may be reused
        done = states.shape[0] - 1
        velocity = states[:, :, 7:10]
        accel = np.empty((done, self._runs, 3))
        if done:
            T = self._period
            if self._before is None:  # the run's first sample: one-sided, as np.gradient's edge
                accel[0] = (velocity[1] - velocity[0]) / T
            else:
                accel[0] = (velocity[1] - self._before) / (2.0 * T)
            accel[1:] = (velocity[2:] - velocity[: done - 1]) / (2.0 * T)
            self._before = velocity[done - 1].copy()
        return self._propagate(states[:done], accel, gps_fresh[:done], mag_fresh[:done])

    def finish(self) -> dict[str, np.ndarray]:
        """{name: (1, N) variance} of the last sample (its force one-sided, as np.gradient's edge;
        zero for a one-sample run); empty when nothing is held."""
        if self._held is None:
            return self._empty()
        states, gps_fresh, mag_fresh = self._held
        self._held = None
        velocity = states[0, :, 7:10]
        if self._before is None:
            accel = np.zeros((1, self._runs, 3))
        else:
            accel = ((velocity - self._before) / self._period)[None]
        return self._propagate(states, accel, gps_fresh, mag_fresh)

    def _empty(self):
        return {name: np.zeros((0, self._runs)) for name in (*PCRB_STATES, "Roll", "Pitch", "Yaw")}

    def _propagate(self, states, accel, gps_fresh, mag_fresh):
        if states.shape[0] == 0:
            return self._empty()
        accel_psd, gyro_psd, gps_var, yaw_var = self._constants
        variances, euler_variances = _pcrb_recursion(
            np.ascontiguousarray(states[:, :, 3:7]),
            np.ascontiguousarray(accel - np.array([0.0, 0.0, GRAVITY])),
            np.ascontiguousarray(gps_fresh, dtype=np.bool_),
            np.ascontiguousarray(mag_fresh, dtype=np.bool_)
            if self._use_mag
            else np.zeros(gps_fresh.shape, np.bool_),
            accel_psd,
            gyro_psd,
            gps_var,
            yaw_var,
            self._P,
            self._period,
            not self._started,
        )
        self._started = True
        result = {name: variances[:, :, i] for i, name in enumerate(PCRB_STATES)}
        result.update({name: euler_variances[:, :, i] for i, name in enumerate(("Roll", "Pitch", "Yaw"))})
        return result


@njit_cached
def _pcrb_recursion(
    quaternions, u_N, gps_fresh, mag_fresh, accel_psd, gyro_psd, gps_var, yaw_var, P, T, first
):
    """((n, N, 9) variances, (n, N, 3) Euler-angle variances) of the covariance-form PCRB.

    quaternions: (n, N, 4) q_NB wxyz; u_N: (n, N, 3) specific force in N; gps_fresh, mag_fresh:
    (n, N) bool (mag all false when it is not fused); accel_psd, gyro_psd: (3,) std^2 * dt_imu;
    gps_var: (6,) GPS p, v variances; yaw_var: magnetometer yaw variance; P: (N, 9, 9) the
    covariance before these samples, updated in place; T: the log period, s; first: the first
    sample is the run's (no prediction before it: P holds the prior).
    """
    n, runs = u_N.shape[0], u_N.shape[1]
    variances = np.zeros((n, runs, 9))
    euler_variances = np.zeros((n, runs, 3))
    a, b = T, 0.5 * T * T
    q_pp, q_pv, q_vv = T**3 / 3.0, T * T / 2.0, T
    M = np.empty((9, 9))
    SX = np.empty((3, 9))
    XS = np.empty((9, 3))
    Ma = np.empty((3, 3))
    Mg = np.empty((3, 3))
    S6 = np.empty((6, 6))
    G = np.empty((6, 9))
    ph = np.empty(9)
    W = np.empty((3, 3))
    R = np.empty((3, 3))
    for k in range(n):
        for j in range(runs):
            Pj = P[j]
            rotation_into(
                quaternions[k, j, 0], quaternions[k, j, 1], quaternions[k, j, 2], quaternions[k, j, 3], R
            )
            if k > 0 or not first:
                u0, u1, u2 = u_N[k, j, 0], u_N[k, j, 1], u_N[k, j, 2]
                # M = F P: rows of the attitude block times S = [u]x
                for c in range(9):
                    x0, x1, x2 = Pj[6, c], Pj[7, c], Pj[8, c]
                    SX[0, c] = -u2 * x1 + u1 * x2
                    SX[1, c] = u2 * x0 - u0 * x2
                    SX[2, c] = -u1 * x0 + u0 * x1
                for r in range(3):
                    for c in range(9):
                        M[r, c] = Pj[r, c] + a * Pj[r + 3, c] - b * SX[r, c]
                        M[r + 3, c] = Pj[r + 3, c] - a * SX[r, c]
                        M[r + 6, c] = Pj[r + 6, c]
                # F P F^T = M F^T: columns of the attitude block times S^T = -S
                for r in range(9):
                    x0, x1, x2 = M[r, 6], M[r, 7], M[r, 8]
                    XS[r, 0] = x1 * u2 - x2 * u1
                    XS[r, 1] = -x0 * u2 + x2 * u0
                    XS[r, 2] = x0 * u1 - x1 * u0
                for r in range(9):
                    for c in range(3):
                        Pj[r, c] = M[r, c] + a * M[r, c + 3] + b * XS[r, c]
                        Pj[r, c + 3] = M[r, c + 3] + a * XS[r, c]
                        Pj[r, c + 6] = M[r, c + 6]
                # + Q: R diag(psd) R^T integrated over T
                for r in range(3):
                    for c in range(3):
                        sa, sg = 0.0, 0.0
                        for m in range(3):
                            sa += R[r, m] * accel_psd[m] * R[c, m]
                            sg += R[r, m] * gyro_psd[m] * R[c, m]
                        Ma[r, c], Mg[r, c] = sa, sg
                for r in range(3):
                    for c in range(3):
                        Pj[r, c] += Ma[r, c] * q_pp
                        Pj[r, c + 3] += Ma[r, c] * q_pv
                        Pj[r + 3, c] += Ma[r, c] * q_pv
                        Pj[r + 3, c + 3] += Ma[r, c] * q_vv
                        Pj[r + 6, c + 6] += Mg[r, c] * q_vv
            if gps_fresh[k, j]:
                # P <- P - P[:, :6] S^-1 P[:6, :], S = P[:6, :6] + R_gps, by Cholesky S = L L^T
                for r in range(6):
                    for c in range(6):
                        S6[r, c] = Pj[r, c]
                    S6[r, r] += gps_var[r]
                for c in range(6):
                    s = S6[c, c]
                    for m in range(c):
                        s -= S6[c, m] * S6[c, m]
                    S6[c, c] = math.sqrt(s)
                    for r in range(c + 1, 6):
                        s = S6[r, c]
                        for m in range(c):
                            s -= S6[r, m] * S6[c, m]
                        S6[r, c] = s / S6[c, c]
                for c in range(9):  # G = L^-1 P[:6, :]
                    for r in range(6):
                        s = Pj[r, c]
                        for m in range(r):
                            s -= S6[r, m] * G[m, c]
                        G[r, c] = s / S6[r, r]
                for r in range(9):  # P -= G^T G
                    for c in range(9):
                        s = 0.0
                        for m in range(6):
                            s += G[m, r] * G[m, c]
                        M[r, c] = Pj[r, c] - s
                for r in range(9):
                    for c in range(9):
                        Pj[r, c] = M[r, c]
            if mag_fresh[k, j]:
                r00, r10, r20 = R[0, 0], R[1, 0], R[2, 0]
                d = r00 * r00 + r10 * r10
                h6, h7 = -r00 * r20 / d, -r10 * r20 / d
                for r in range(9):
                    ph[r] = Pj[r, 6] * h6 + Pj[r, 7] * h7 + Pj[r, 8]
                inverse = 1.0 / (ph[6] * h6 + ph[7] * h7 + ph[8] + yaw_var)
                for r in range(9):
                    for c in range(9):
                        Pj[r, c] -= ph[r] * ph[c] * inverse
            for r in range(9):
                for c in range(r + 1, 9):
                    mean = 0.5 * (Pj[r, c] + Pj[c, r])
                    Pj[r, c] = mean
                    Pj[c, r] = mean
                variances[k, j, r] = Pj[r, r]
            # Euler-angle variances: W = E(roll, pitch) R^T, diag(W P_att W^T)
            e1, e2, e4, e5, e7, e8 = _euler_rate_entries(R[2, 0], R[2, 1], R[2, 2])
            for c in range(3):
                W[0, c] = R[c, 0] + e1 * R[c, 1] + e2 * R[c, 2]
                W[1, c] = e4 * R[c, 1] + e5 * R[c, 2]
                W[2, c] = e7 * R[c, 1] + e8 * R[c, 2]
            for r in range(3):
                s = 0.0
                for c in range(3):
                    for m in range(3):
                        s += W[r, c] * Pj[6 + c, 6 + m] * W[r, m]
                euler_variances[k, j, r] = s
    return variances, euler_variances
