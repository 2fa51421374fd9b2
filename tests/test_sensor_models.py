"""Pure sensor models: specific-force sign, noise application, saturation, random walk, yaw wrap."""

import math

import numpy as np
import pytest

from quad_drake.config.schema import GpsParams, ImuParams, MagParams
from quad_drake.conventions import GRAVITY
from quad_drake.models import sensor_models
from quad_drake.models.rotations import quat_from_euler, rotation_from_quat

LEVEL = [1.0, 0.0, 0.0, 0.0]
G_N = np.array([0.0, 0.0, GRAVITY])


def test_specific_force_level_at_rest_reads_minus_g():
    assert sensor_models.specific_force(LEVEL, [0.0, 0.0, 0.0]) == (0.0, 0.0, -9.81)


def test_specific_force_free_fall_reads_zero():
    f = sensor_models.specific_force(quat_from_euler(0.3, -0.2, 1.0), [0.0, 0.0, GRAVITY])
    np.testing.assert_allclose(f, [0.0, 0.0, 0.0], atol=1e-14)


@pytest.mark.parametrize(
    "roll, pitch, yaw", [(0.4, 0.0, 0.0), (0.0, -0.3, 0.0), (0.5, 0.25, 2.0), (-1.2, 0.7, -3.0)]
)
def test_specific_force_tilted_at_rest(roll, pitch, yaw):
    f = sensor_models.specific_force(quat_from_euler(roll, pitch, yaw), [0.0, 0.0, 0.0])
    expected = -GRAVITY * np.array(
        [-math.sin(pitch), math.sin(roll) * math.cos(pitch), math.cos(roll) * math.cos(pitch)]
    )
    np.testing.assert_allclose(f, expected, atol=1e-13)


def test_specific_force_matches_rotation_matrix_and_ignores_quaternion_scale():
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        a = rng.normal(scale=5.0, size=3)
        expected = rotation_from_quat(q).T @ (a - G_N)
        np.testing.assert_allclose(sensor_models.specific_force(q.tolist(), a.tolist()), expected, atol=1e-12)
        np.testing.assert_allclose(
            sensor_models.specific_force((1.01 * q).tolist(), a.tolist()), expected, atol=1e-12
        )


def test_imu_measurement_adds_scaled_noise_per_axis():
    params = ImuParams(accel_std=[0.5, 0.0, 1.5], gyro_std=[0.1, 0.2, 0.0])
    q = quat_from_euler(0.1, 0.2, 0.3)
    w, a, n = [0.3, -0.2, 0.1], [1.0, -2.0, 0.5], [1.0, -2.0, 3.0, -1.5, 0.5, 7.0]
    out = sensor_models.imu_measurement(q, w, a, n, params)
    f = sensor_models.specific_force(q, a)
    np.testing.assert_allclose(out, [f[0] + 0.5, f[1], f[2] + 4.5, 0.3 - 0.15, -0.2 + 0.1, 0.1], atol=1e-14)


def test_imu_zero_std_is_exact_truth():
    params = ImuParams(accel_std=[0.0] * 3, gyro_std=[0.0] * 3)
    q = quat_from_euler(0.2, -0.1, 0.5)
    w, a = [0.3, -0.2, 0.1], [1.0, -2.0, 0.5]
    out = sensor_models.imu_measurement(q, w, a, [5.0, -4.0, 3.0, 2.0, -1.0, 9.0], params)
    assert out == sensor_models.specific_force(q, a) + tuple(w)


def test_imu_saturates_each_axis_after_noise():
    params = ImuParams(accel_std=[1.0, 1.0, 1.0], accel_limit=20.0)
    out = sensor_models.imu_measurement(
        LEVEL, [0.0] * 3, [25.0, -19.5, 0.0], [0.0, -1.0, 0.0, 0, 0, 0], params
    )
    assert out[:3] == (20.0, -20.0, -9.81)


def test_gps_measurement_applies_random_walk_first():
    params = GpsParams(pos_std=[0.7, 0.0, 2.0], vel_std=[0.1, 0.1, 0.0], pos_random_walk_std=[0.5, 0.0, 1.0])
    noise = [1.0, 2.0, -1.0, 1.0, 3.0, -0.5, 2.0, -1.0, 4.0]
    position, velocity, rw = sensor_models.gps_measurement(
        [1.0, 2.0, -3.0], [0.5, -0.5, 0.1], [0.1, 0.2, 0.3], noise, params
    )
    np.testing.assert_allclose(rw, [0.6, 0.2, -0.7], atol=1e-15)
    np.testing.assert_allclose(position, [1.0 + 0.6 + 0.7, 2.0 + 0.2, -3.0 - 0.7 - 1.0], atol=1e-15)
    np.testing.assert_allclose(velocity, [0.5 + 0.2, -0.5 - 0.1, 0.1], atol=1e-15)


def test_gps_zero_std_is_exact_truth():
    params = GpsParams(pos_std=[0.0] * 3, vel_std=[0.0] * 3, pos_random_walk_std=[0.0] * 3)
    p, v = [1.5, -2.0, -3.25], [0.5, -0.5, 0.125]
    position, velocity, rw = sensor_models.gps_measurement(p, v, [0.0] * 3, [3.0] * 9, params)
    assert (position, velocity, rw) == (p, v, [0.0, 0.0, 0.0])


def test_gps_random_walk_variance_grows_linearly():
    """Ensemble of 1000 walks: Var(position error) = k sigma^2 after k samples, within 4 SE."""
    sigma = np.array([0.2, 0.5, 0.0])
    params = GpsParams(pos_std=[0.0] * 3, vel_std=[0.0] * 3, pos_random_walk_std=sigma.tolist())
    rng = np.random.default_rng(11)
    walks, steps = 1000, 25
    errors = np.empty((steps, walks, 3))
    for j in range(walks):
        rw = [0.0, 0.0, 0.0]
        for k, noise in enumerate(rng.normal(size=(steps, 9)).tolist()):
            position, _, rw = sensor_models.gps_measurement([0.0] * 3, [0.0] * 3, rw, noise, params)
            errors[k, j] = position
    for k in (1, 5, 25):
        variance = errors[k - 1].var(axis=0)
        expected = k * sigma**2
        np.testing.assert_allclose(variance, expected, rtol=4 * math.sqrt(2 / walks), atol=0)


def test_magnetometer_yaw_truth_noise_and_wrap():
    q = quat_from_euler(0.3, -0.2, 1.0)
    assert sensor_models.magnetometer_yaw(q, 5.0, MagParams(yaw_std=0.0)) == pytest.approx(1.0, abs=1e-14)
    assert sensor_models.magnetometer_yaw(q, -2.0, MagParams(yaw_std=0.1)) == pytest.approx(0.8, abs=1e-14)
    near_pi = quat_from_euler(0.0, 0.0, math.pi - 0.05)
    assert sensor_models.magnetometer_yaw(near_pi, 1.0, MagParams(yaw_std=0.1)) == pytest.approx(
        -math.pi + 0.05, abs=1e-12
    )
    near_minus_pi = quat_from_euler(0.0, 0.0, -math.pi + 0.05)
    assert sensor_models.magnetometer_yaw(near_minus_pi, -1.0, MagParams(yaw_std=0.1)) == pytest.approx(
        math.pi - 0.05, abs=1e-12
    )
