"""Pure: accuracy bounds of a vehicle's sensors — the hover Riccati bound and the posterior CRB.

**Hover (steady-state Riccati) bound.** The best accuracy any estimator could reach with the
scenario's TRUE sensor noise (``sensors`` config, not the filter's assumed Q and R), from a
linear time-invariant model at hover:

- horizontal position/velocity/tilt, per axis N (tilt = pitch) and E (tilt = roll): the
  state [p, v, theta] with v' = g theta + accelerometer noise and theta a random walk of
  the gyro noise: x_{k+1} = F x_k + G n_k, F = [[1, dt, g dt^2/2], [0, 1, g dt], [0, 0, 1]],
  G = [[dt^2/2, 0], [dt, 0], [0, dt]], n = (``accel_std[i]``, gyro std of the tilt axis) per
  IMU sample held over the IMU period dt; the GPS measures p and v every GPS period with
  ``pos_std[i]`` and ``vel_std[i]``. With 11's sensors this gives sigma_v = 0.062 m/s and
  sigma_theta = 0.0166 rad (time-averaged): the tilt a noisy gyro leaves is what limits the
  horizontal velocity, not the accelerometer;
- vertical: a double integrator [p, v] driven by ``accel_std[2]`` (tilt enters only at
  second order);
- yaw: a random walk driven by the gyro noise (``gyro_std[2] * dt`` per IMU sample),
  measured directly by the magnetometer every mag period with ``yaw_std``.

The IMU-driven covariance is propagated over one measurement period (M = period / dt
IMU steps, rounded) and the discrete algebraic Riccati equation of that period is
solved with ``scipy.linalg.solve_discrete_are``. Reported per state: the steady-state
posterior sigma (just after an update), the prior sigma (just before the next one) and
the time-averaged sigma sqrt(mean_j P_j) over the M IMU steps of a period, which is the
one to compare with an RMS error sampled uniformly in time.

Assumptions (all make the bound optimistic, i.e. a lower bound on the RMS error):
body axes aligned with NED (level flight; x and y are exact for any yaw when
accel_std x = y and the gyro's x = y); yaw rate = body z rate; the GPS position random walk
(``pos_random_walk_std``) and accelerometer saturation are ignored; the trajectory's own
accelerations are ignored (at hover only gravity couples tilt into velocity).

**Posterior Cramér–Rao bound (PCRB)** along a run's logged TRUE trajectory
(:func:`posterior_crb`): the information-filter recursion (Tichavský et al., 1998) of the
navigation error model of ``estimation/eskf.py`` (error state dp, dv, dtheta, 9 states; the
simulated IMU has no bias, so the bias states of the 15-state model carry no information
and are left out) linearised about the truth, with the true sensor noise:

    J_{k+1} = (F_k J_k^-1 F_k^T + Q_k)^-1 + H^T R^-1 H  (H, R of the sensors fused at k+1),

F_k = I + A_k T + A_k^2 T^2 / 2 with A = [[0, I, 0], [0, 0, -[u]x], [0, 0, 0]], u = the true
specific force in N (a_N - g_N, from the logged true velocity), T = the log period (5 ms);
Q_k = the accelerometer and gyro white noise (``std^2 * dt_imu`` per second, rotated to N)
integrated over T. GPS (p, v) is fused at each fresh GPS stamp, the magnetometer yaw
(Jacobian at the true attitude) at each fresh magnetometer stamp seen in the log.
J_0 = P_0^-1 with PCRB_PRIOR_STD (the estimators' default initial sigmas). The bound's
Euler-angle variances come from the dtheta block through d(roll, pitch, yaw)/dtheta =
W(roll, pitch) R^T. Over-optimistic where the log misses magnetometer samples (the log
sees each 10 ms sample, the 5 ms log period is finer).
"""

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_discrete_are

from ..conventions import GRAVITY, LOG_PERIOD, ONBOARD_PERIOD

AXES = ("X", "Y", "Z")


@dataclass(frozen=True)
class StateBound:
    """Steady-state standard deviations of one estimated state (m, m/s or rad)."""

    posterior_std: float  # just after a measurement update
    prior_std: float  # just before the next update
    mean_std: float  # sqrt of the variance averaged over the update period


def _steps(period, dt):
    steps = int(round(period / dt))
    if steps < 1:
        raise ValueError(f"measurement period {period} s is shorter than the IMU period {dt} s")
    return steps


def _propagation(F, Q, steps):
    """(F^steps, noise covariance accumulated over `steps` steps, [(F^j, Q_j) for j < steps])."""
    n = F.shape[0]
    transition, accumulated = np.eye(n), np.zeros((n, n))
    history = []
    for _ in range(steps):
        history.append((transition.copy(), accumulated.copy()))
        transition = F @ transition
        accumulated = F @ accumulated @ F.T + Q
    return transition, accumulated, history


def steady_state_kalman(F, Q, H, R, steps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(posterior, prior, time-averaged) steady-state covariances of a Kalman filter.

    The state x_{k+1} = F x_k + w_k, cov(w) = Q per step, is measured z = H x + v,
    cov(v) = R, every `steps` steps. Time average over the `steps` steps that start at
    an update (the posterior counts once, the prior is the next period's start).
    Raises ValueError unless R is positive definite.
    """
    F, Q, H, R = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (F, Q, H, R))
    if not np.all(np.linalg.eigvalsh(R) > 0.0):
        raise ValueError(
            "steady_state_kalman: measurement noise R must be positive definite "
            "(a sensor std of 0 makes the bound trivially 0)"
        )
    transition, accumulated, history = _propagation(F, Q, steps)
    n = F.shape[0]
    if not accumulated.any():  # noiseless: perfect in steady state
        zero = np.zeros((n, n))
        return zero, zero, zero
    prior = solve_discrete_are(transition.T, H.T, accumulated, R)
    gain = prior @ H.T @ np.linalg.inv(H @ prior @ H.T + R)
    posterior = (np.eye(n) - gain @ H) @ prior
    posterior = 0.5 * (posterior + posterior.T)
    mean = sum(phi @ posterior @ phi.T + q for phi, q in history) / steps
    return posterior, prior, mean


def _bounds(posterior, prior, mean):
    return [
        StateBound(*(math.sqrt(max(float(m[i, i]), 0.0)) for m in (posterior, prior, mean)))
        for i in range(posterior.shape[0])
    ]


def position_velocity_tilt_bound(
    accel_std, gyro_std, pos_std, vel_std, gps_period, dt=ONBOARD_PERIOD
) -> tuple[StateBound, StateBound, StateBound]:
    """(position, velocity, tilt) StateBound of one horizontal axis: [p, v, theta], v' = g theta.

    gyro_std: rad/s per IMU sample of the tilt axis (pitch for N, roll for E).
    """
    F = np.array([[1.0, dt, 0.5 * GRAVITY * dt * dt], [0.0, 1.0, GRAVITY * dt], [0.0, 0.0, 1.0]])
    G = np.array([[0.5 * dt * dt, 0.0], [dt, 0.0], [0.0, dt]])
    Q = G @ np.diag([accel_std**2, gyro_std**2]) @ G.T
    R = np.diag([pos_std**2, vel_std**2])
    position, velocity, tilt = _bounds(*steady_state_kalman(F, Q, np.eye(2, 3), R, _steps(gps_period, dt)))
    return position, velocity, tilt


def position_velocity_bound(
    accel_std, pos_std, vel_std, gps_period, dt=ONBOARD_PERIOD
) -> tuple[StateBound, StateBound]:
    """(position, velocity) StateBound of one axis: double integrator, GPS p and v (vertical axis)."""
    F = np.array([[1.0, dt], [0.0, 1.0]])
    G = np.array([[0.5 * dt * dt], [dt]])
    Q = G @ G.T * accel_std**2
    R = np.diag([pos_std**2, vel_std**2])
    position, velocity = _bounds(*steady_state_kalman(F, Q, np.eye(2), R, _steps(gps_period, dt)))
    return position, velocity


def yaw_bound(gyro_std, yaw_std, mag_period, dt=ONBOARD_PERIOD) -> StateBound:
    """StateBound of yaw: gyro random walk, direct magnetometer measurement."""
    (bound,) = _bounds(
        *steady_state_kalman(
            [[1.0]], [[(gyro_std * dt) ** 2]], [[1.0]], [[yaw_std**2]], _steps(mag_period, dt)
        )
    )
    return bound


def accuracy_bound(vehicle) -> dict[str, StateBound]:
    """{state name: StateBound} for the states a VehicleConfig's sensors make observable.

    Names as the ``Est.E.*`` signals: X, Y, Z, VX, VY, VZ, Pitch (the N axis's tilt), Roll
    (the E axis's) (need imu and gps) and Yaw (needs imu and mag). Empty without an IMU.
    """
    sensors = vehicle.sensors
    bounds = {}
    if sensors.imu is None:
        return bounds
    if sensors.gps is not None:
        gps, imu = sensors.gps, sensors.imu
        tilt_gyro = (imu.gyro_std[1], imu.gyro_std[0])  # N axis: pitch (body y), E axis: roll (body x)
        triples = [
            position_velocity_tilt_bound(
                imu.accel_std[i], tilt_gyro[i], gps.pos_std[i], gps.vel_std[i], gps.period
            )
            for i in range(2)
        ]
        triples.append(
            position_velocity_bound(imu.accel_std[2], gps.pos_std[2], gps.vel_std[2], gps.period) + (None,)
        )
        bounds.update({axis: t[0] for axis, t in zip(AXES, triples, strict=True)})
        bounds.update({"V" + axis: t[1] for axis, t in zip(AXES, triples, strict=True)})
        bounds.update({"Pitch": triples[0][2], "Roll": triples[1][2]})
    if sensors.mag is not None:
        bounds["Yaw"] = yaw_bound(sensors.imu.gyro_std[2], sensors.mag.yaw_std, sensors.mag.period)
    return bounds


# ----- posterior Cramér-Rao bound along a logged true trajectory ---------------------------

PCRB_STATES = ("X", "Y", "Z", "VX", "VY", "VZ", "AttN", "AttE", "AttD")
"""Error-state entries of the PCRB (the ESKF's navigation states); plus Roll, Pitch, Yaw derived."""
PCRB_PRIOR_STD = (0.1, 0.1, 0.3, 0.1, 0.1, 0.3, 0.05, 0.05, 0.05)
"""sigma of J_0^-1 (m, m/s, rad): the estimators' default initial uncertainty."""


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _rotations(q):
    """(n, 3, 3) R_NB of (n, 4) wxyz quaternions."""
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=1,
    )


def posterior_crb(
    state, gps_fresh, mag_fresh, sensors, period=LOG_PERIOD, dt_imu=ONBOARD_PERIOD
) -> dict[str, np.ndarray]:
    """{name: (n,) variance} of the PCRB at every log sample (after that sample's fusions).

    state: (n, 13) logged truth (p, q wxyz, v, w) at the log period; gps_fresh, mag_fresh: (n,)
    bool, a fresh sample of the sensor at that log sample; sensors: the vehicle's
    SensorsConfig (true noise; imu and gps needed, mag optional). Names: PCRB_STATES and
    Roll, Pitch, Yaw. See the module docstring for the model.
    """
    state = np.asarray(state, dtype=float)
    n = state.shape[0]
    imu, gps, mag = sensors.imu, sensors.gps, sensors.mag
    R_all = _rotations(state[:, 3:7])
    velocity = state[:, 7:10]
    accel = np.gradient(velocity, period, axis=0) if n > 1 else np.zeros((n, 3))
    u_N = accel - np.array([0.0, 0.0, GRAVITY])
    accel_psd = np.square(imu.accel_std) * dt_imu  # (m/s^2)^2 s
    gyro_psd = np.square(imu.gyro_std) * dt_imu
    H_gps = np.eye(6, 9)
    info_gps = H_gps.T @ np.diag(1.0 / np.square(list(gps.pos_std) + list(gps.vel_std))) @ H_gps
    J = np.diag(1.0 / np.square(PCRB_PRIOR_STD))
    variances = np.zeros((n, 9))
    euler_variances = np.zeros((n, 3))
    T = period
    for k in range(n):
        R = R_all[k]
        A = np.zeros((9, 9))
        A[0:3, 3:6] = np.eye(3)
        A[3:6, 6:9] = -_skew(u_N[k])
        F = np.eye(9) + A * T + (A @ A) * (0.5 * T * T)
        Ma = (R * accel_psd) @ R.T
        Mg = (R * gyro_psd) @ R.T
        Q = np.zeros((9, 9))
        Q[0:3, 0:3] = Ma * (T**3 / 3.0)
        Q[0:3, 3:6] = Q[3:6, 0:3] = Ma * (T * T / 2.0)
        Q[3:6, 3:6] = Ma * T
        Q[6:9, 6:9] = Mg * T
        if k > 0:
            J = np.linalg.inv(F @ np.linalg.inv(J) @ F.T + Q)
        if gps_fresh[k]:
            J = J + info_gps
        if mag is not None and mag_fresh[k] and mag.yaw_std > 0:
            r00, r10, r20 = R[0, 0], R[1, 0], R[2, 0]
            d = r00 * r00 + r10 * r10
            h = np.zeros(9)
            h[6:9] = (-r00 * r20 / d, -r10 * r20 / d, 1.0)
            J = J + np.outer(h, h) / mag.yaw_std**2
        P = np.linalg.inv(J)
        P = 0.5 * (P + P.T)
        variances[k] = np.diag(P)
        W = _euler_rate_matrix(R) @ R.T
        euler_variances[k] = np.diag(W @ P[6:9, 6:9] @ W.T)
    result = {name: variances[:, i] for i, name in enumerate(PCRB_STATES)}
    result.update({name: euler_variances[:, i] for i, name in enumerate(("Roll", "Pitch", "Yaw"))})
    return result


def euler_rate_entries(r20, r21, r22) -> tuple[float, float, float, float, float, float]:
    """The entries (sin r tan p, cos r tan p, cos r, -sin r, sin r / cos p, cos r / cos p) of W,
    d(roll, pitch, yaw)/dt = W w_B (ZYX angles r, p), from the last row of R_NB without the angles:
    (R21, R22) = cos p (sin r, cos r) and R20 = -sin p, with cos p >= 0."""
    cp = math.sqrt(r21 * r21 + r22 * r22)
    sr, cr, tp = r21 / cp, r22 / cp, -r20 / cp
    return sr * tp, cr * tp, cr, -sr, sr / cp, cr / cp


def _euler_rate_matrix(R):
    """W with d(roll, pitch, yaw)/dt = W w_B (ZYX angles) at the attitude R_NB."""
    e1, e2, e4, e5, e7, e8 = euler_rate_entries(R[2, 0], R[2, 1], R[2, 2])
    return np.array([[1.0, e1, e2], [0.0, e4, e5], [0.0, e7, e8]])
