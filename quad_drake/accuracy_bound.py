"""Pure: the steady-state Kalman (Riccati) accuracy bound of a vehicle's sensors.

The best accuracy any estimator could reach with the scenario's TRUE sensor noise
(``sensors`` config, not the EKF's assumed Q and R), from a linear time-invariant model
at hover:

- position/velocity, per NED axis i: a double integrator [p, v] driven by the
  accelerometer noise, ``accel_std[i]`` per IMU sample held over the IMU period dt
  (state increment G n with G = [dt^2/2, dt]); the GPS measures p and v of that axis
  every GPS period with ``pos_std[i]`` and ``vel_std[i]``;
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
accel_std x = y); roll and pitch errors coupling gravity into the velocity error are
ignored; yaw rate = body z rate; the GPS position random walk (``pos_random_walk_std``)
and accelerometer saturation are ignored; the trajectory's own accelerations do not
matter (the model is linear in the noise).
"""

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_discrete_are

from .conventions import ONBOARD_PERIOD

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


def steady_state_kalman(F, Q, H, R, steps):
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
        StateBound(float(np.sqrt(posterior[i, i])), float(np.sqrt(prior[i, i])), float(np.sqrt(mean[i, i])))
        for i in range(posterior.shape[0])
    ]


def position_velocity_bound(accel_std, pos_std, vel_std, gps_period, dt=ONBOARD_PERIOD):
    """(position, velocity) StateBound of one axis: double integrator, GPS p and v."""
    F = np.array([[1.0, dt], [0.0, 1.0]])
    G = np.array([[0.5 * dt * dt], [dt]])
    Q = G @ G.T * accel_std**2
    R = np.diag([pos_std**2, vel_std**2])
    position, velocity = _bounds(*steady_state_kalman(F, Q, np.eye(2), R, _steps(gps_period, dt)))
    return position, velocity


def yaw_bound(gyro_std, yaw_std, mag_period, dt=ONBOARD_PERIOD):
    """StateBound of yaw: gyro random walk, direct magnetometer measurement."""
    (bound,) = _bounds(
        *steady_state_kalman(
            [[1.0]], [[(gyro_std * dt) ** 2]], [[1.0]], [[yaw_std**2]], _steps(mag_period, dt)
        )
    )
    return bound


def accuracy_bound(vehicle):
    """{state name: StateBound} for the EKF states a VehicleConfig's sensors make observable.

    Names as the ``Est.E.*`` signals: X, Y, Z, VX, VY, VZ (needs imu and gps) and Yaw
    (needs imu and mag). Empty without an IMU.
    """
    sensors = vehicle.sensors
    bounds = {}
    if sensors.imu is None:
        return bounds
    if sensors.gps is not None:
        gps = sensors.gps
        pairs = [
            position_velocity_bound(sensors.imu.accel_std[i], gps.pos_std[i], gps.vel_std[i], gps.period)
            for i in range(3)
        ]
        bounds.update({axis: pair[0] for axis, pair in zip(AXES, pairs, strict=True)})
        bounds.update({"V" + axis: pair[1] for axis, pair in zip(AXES, pairs, strict=True)})
    if sensors.mag is not None:
        bounds["Yaw"] = yaw_bound(sensors.imu.gyro_std[2], sensors.mag.yaw_std, sensors.mag.period)
    return bounds
