"""Steady-state Kalman accuracy bound: closed forms, brute-force Riccati, simulated errors."""

import math

import numpy as np
import pytest

from quad_drake.config.schema import GpsParams, ImuParams, MagParams, SensorsConfig, VehicleConfig
from quad_drake.judging.signals import stamp_fresh
from quad_drake.models.accuracy_bound import (
    accuracy_bound,
    euler_rate_entries,
    position_velocity_bound,
    position_velocity_tilt_bound,
    posterior_crb,
    steady_state_kalman,
    yaw_bound,
)
from quad_drake.models.rotations import quat_from_euler

DT = 0.002


def test_yaw_bound_matches_the_scalar_riccati_closed_form():
    gyro_std, yaw_std, steps = 0.5, 0.1, 5
    q_step = (gyro_std * DT) ** 2
    q, r = steps * q_step, yaw_std**2
    prior = (q + math.sqrt(q * q + 4 * q * r)) / 2  # P- = P+ + q, P+ = P- r / (P- + r)
    posterior = prior * r / (prior + r)
    bound = yaw_bound(gyro_std, yaw_std, steps * DT)
    assert bound.prior_std == pytest.approx(math.sqrt(prior), rel=1e-9)
    assert bound.posterior_std == pytest.approx(math.sqrt(posterior), rel=1e-9)
    assert bound.mean_std == pytest.approx(math.sqrt(posterior + q_step * (steps - 1) / 2), rel=1e-9)
    assert bound.posterior_std == pytest.approx(0.01487, abs=1e-5)  # the reference's sensors


def brute_force(F, Q, H, R, steps, periods=5000):
    """Iterate (predict `steps` IMU steps, update) until the covariance stops changing."""
    transition, accumulated = np.eye(F.shape[0]), np.zeros_like(Q)
    for _ in range(steps):
        transition, accumulated = F @ transition, F @ accumulated @ F.T + Q
    P = np.eye(F.shape[0])
    for _ in range(periods):
        prior = transition @ P @ transition.T + accumulated
        K = prior @ H.T @ np.linalg.inv(H @ prior @ H.T + R)
        P = (np.eye(F.shape[0]) - K @ H) @ prior
    return P, prior


@pytest.mark.parametrize(
    "accel_std, pos_std, vel_std, steps", [(0.5, 0.7, 0.1, 50), (1.5, 2.0, 0.3, 50), (0.2, 0.3, 1.0, 10)]
)
def test_position_velocity_bound_matches_iterated_riccati(accel_std, pos_std, vel_std, steps):
    F = np.array([[1.0, DT], [0.0, 1.0]])
    G = np.array([[0.5 * DT * DT], [DT]])
    Q, R = G @ G.T * accel_std**2, np.diag([pos_std**2, vel_std**2])
    posterior, prior = brute_force(F, Q, np.eye(2), R, steps)
    p, v = position_velocity_bound(accel_std, pos_std, vel_std, steps * DT)
    assert (p.posterior_std, v.posterior_std) == pytest.approx(np.sqrt(np.diag(posterior)), rel=1e-6)
    assert (p.prior_std, v.prior_std) == pytest.approx(np.sqrt(np.diag(prior)), rel=1e-6)
    assert p.posterior_std < p.mean_std < p.prior_std
    assert v.posterior_std < v.mean_std < v.prior_std


def test_time_averaged_sigma_is_the_rms_error_of_a_simulated_kalman_filter():
    accel_std, steps = 0.5, 50
    F = np.array([[1.0, DT], [0.0, 1.0]])
    G = np.array([0.5 * DT * DT, DT])
    R = np.diag([0.49, 0.01])
    posterior, prior, _ = steady_state_kalman(F, np.outer(G, G) * accel_std**2, np.eye(2), R, steps)
    K = prior @ np.linalg.inv(prior + R)
    rng = np.random.default_rng(11)
    runs, periods = 4000, 50  # from the steady state: no transient
    e = rng.multivariate_normal([0.0, 0.0], posterior, size=runs)
    squares = np.zeros(2)
    for k in range(periods * steps):
        squares += np.sum(e * e, axis=0)
        e = e @ F.T + accel_std * rng.normal(size=(runs, 1)) * G
        if (k + 1) % steps == 0:  # e+ = e + K (v - e)
            e = e + (rng.normal(size=(runs, 2)) * np.sqrt(np.diag(R)) - e) @ K.T
    rms = np.sqrt(squares / (runs * periods * steps))
    p, v = position_velocity_bound(accel_std, 0.7, 0.1, steps * DT)
    assert rms == pytest.approx([p.mean_std, v.mean_std], rel=0.03)


def vehicle(imu=True, gps=True, mag=True, **imu_fields):
    return VehicleConfig(
        sensors=SensorsConfig(
            imu=ImuParams(**imu_fields) if imu else None,
            gps=GpsParams() if gps else None,
            mag=MagParams() if mag else None,
        )
    )


def test_accuracy_bound_covers_the_states_the_sensors_observe():
    full = ["X", "Y", "Z", "VX", "VY", "VZ", "Pitch", "Roll", "Yaw"]
    assert list(accuracy_bound(vehicle())) == full
    assert list(accuracy_bound(vehicle(gps=False))) == ["Yaw"]
    assert list(accuracy_bound(vehicle(mag=False))) == full[:-1]
    assert accuracy_bound(vehicle(imu=False)) == {}


def test_accuracy_bound_of_the_default_sensors_includes_the_tilt_random_walk():
    bounds = accuracy_bound(vehicle())
    # Issue 10: with the tilt driven by 11's gyro noise, sigma_v = 0.062 m/s, sigma_theta = 0.0166 rad.
    assert bounds["VX"].mean_std == pytest.approx(0.062, abs=5e-4)
    assert bounds["Pitch"].mean_std == pytest.approx(0.0166, abs=5e-5)
    assert bounds["Y"] == bounds["X"] and bounds["Roll"] == bounds["Pitch"]
    assert bounds["X"].mean_std == pytest.approx(0.0837, abs=2e-4)
    assert bounds["Z"].mean_std == pytest.approx(0.2431, abs=2e-4)  # accel 1.5, GPS 2.0 / 0.3, no tilt
    assert bounds["Yaw"].mean_std == pytest.approx(0.01494, abs=2e-5)
    # Without gyro noise the tilt stays known and the double-integrator bound comes back.
    _, v_no_tilt = position_velocity_bound(0.5, 0.7, 0.1, 0.1)
    _, v_quiet_gyro, _ = position_velocity_tilt_bound(0.5, 0.0, 0.7, 0.1, 0.1)
    assert v_quiet_gyro.mean_std == pytest.approx(v_no_tilt.mean_std, rel=1e-6)
    assert v_no_tilt.mean_std == pytest.approx(0.0264, abs=2e-4)


def hover_samples(n=4000, period=0.005):
    """A truth log at rest (level, z = -1) with the GPS (10 Hz) and mag (100 Hz) freshness masks."""
    state = np.zeros((n, 13))
    state[:, 2], state[:, 3] = -1.0, 1.0
    t = np.arange(1, n + 1) * period
    gps = stamp_fresh(np.where(t >= 0.1 - 1e-9, np.floor(t / 0.1 + 1e-9) * 0.1, -1.0))
    mag = stamp_fresh(np.floor((t - 0.008) / 0.01 + 1e-9) * 0.01 + 0.008)
    return state, gps, mag


def test_posterior_crb_at_hover_converges_to_the_hover_riccati_bound():
    state, gps, mag = hover_samples()
    sensors = vehicle().sensors
    pcrb = posterior_crb(state, gps, mag, sensors)
    bounds = accuracy_bound(vehicle())
    steady = slice(1000, None)  # after 5 s
    pairs = [("X", "X"), ("VX", "VX"), ("Z", "Z"), ("VZ", "VZ"), ("AttE", "Pitch"), ("AttN", "Roll")]
    pairs += [("AttD", "Yaw"), ("Pitch", "Pitch"), ("Yaw", "Yaw")]
    for crb_name, bound_name in pairs:
        # The PCRB steps at the 5 ms log period, the Riccati bound at the 2 ms IMU period.
        assert math.sqrt(np.mean(pcrb[crb_name][steady])) == pytest.approx(
            bounds[bound_name].mean_std, rel=0.02
        )
    assert (np.diff(pcrb["X"][:200]) < 1e-9).sum() > 0  # GPS updates lower the variance


def test_posterior_crb_grows_without_measurements_and_needs_the_true_noise():
    state, gps, mag = hover_samples(n=400)
    sensors = vehicle().sensors
    blind = posterior_crb(state, np.zeros(400, bool), np.zeros(400, bool), sensors)
    assert np.all(np.diff(blind["VX"]) > 0)  # dead reckoning: velocity variance only grows
    loud = posterior_crb(state, gps, mag, vehicle(accel_std=[2.0, 2.0, 2.0]).sensors)
    assert np.mean(loud["VX"][200:]) > np.mean(posterior_crb(state, gps, mag, sensors)["VX"][200:])


def test_accuracy_bound_grows_with_the_imu_noise_and_vanishes_without_it():
    quiet = accuracy_bound(vehicle(accel_std=[0.1, 0.1, 0.1]))
    loud = accuracy_bound(vehicle(accel_std=[2.0, 2.0, 2.0]))
    assert quiet["X"].mean_std < loud["X"].mean_std
    assert quiet["VZ"].mean_std < loud["VZ"].mean_std
    noiseless = accuracy_bound(vehicle(accel_std=[0.0, 0.0, 0.0], gyro_std=[0.0, 0.0, 0.0]))
    assert all(b.mean_std == 0.0 for b in noiseless.values())


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="positive definite"):
        position_velocity_bound(0.5, 0.0, 0.1, 0.1)
    with pytest.raises(ValueError, match="shorter"):
        yaw_bound(0.5, 0.1, 0.0005)


def test_euler_rate_entries_are_the_trigonometric_ones_of_the_angles():
    rng = np.random.default_rng(1203)
    for roll, pitch, yaw in rng.uniform([-3.1, -1.5, -3.1], [3.1, 1.5, 3.1], size=(200, 3)):
        w, x, y, z = quat_from_euler(roll, pitch, yaw)
        r20, r21, r22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
        sr, cr, cp, tp = math.sin(roll), math.cos(roll), math.cos(pitch), math.tan(pitch)
        expected = (sr * tp, cr * tp, cr, -sr, sr / cp, cr / cp)
        np.testing.assert_allclose(euler_rate_entries(r20, r21, r22), expected, rtol=1e-12, atol=1e-13)
