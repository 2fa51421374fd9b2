"""Drag in the plant (``dynamics.drag_force_body``, ``drag_acceleration``, ``plant_step`` with
wind) and the IMU's delta-velocity and range limits (``sensor_models``), pure."""

import dataclasses

import numpy as np
import pytest

from quad_drake.config.schema import ImuParams, PhysicsParams
from quad_drake.conventions import GRAVITY
from quad_drake.models import dynamics, sensor_models
from quad_drake.models.rotations import quat_from_euler, rotation_from_quat

DRAG = PhysicsParams(rotor_drag=[0.22, 0.25, 0.44], parasitic_drag=[0.005, 0.006, 0.01])
HOVER = 0.5 * GRAVITY / 4


def state(position=(0.0, 0.0, -1.0), euler=(0.0, 0.0, 0.0), velocity=(0.0, 0.0, 0.0)):
    return [*position, *quat_from_euler(*euler), *velocity, 0.0, 0.0, 0.0]


def test_drag_force_opposes_the_air_relative_velocity():
    v = (3.0, -1.0, 0.5)
    f = dynamics.drag_force_body(v, DRAG.rotor_drag, DRAG.parasitic_drag)
    speed = np.linalg.norm(v)
    expected = [
        -(k + c * speed) * vi for k, c, vi in zip(DRAG.rotor_drag, DRAG.parasitic_drag, v, strict=True)
    ]
    np.testing.assert_allclose(f, expected, rtol=1e-15)
    assert np.dot(f, v) < 0
    assert dynamics.drag_force_body((0.0, 0.0, 0.0), DRAG.rotor_drag, DRAG.parasitic_drag) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("v", [(3.0, -1.0, 0.5), (0.0, 0.0, 0.0), (1e-3, 2.0, -7.0)])
def test_drag_jacobian_matches_central_differences(v):
    jacobian = np.array(dynamics.drag_force_jacobian(v, DRAG.rotor_drag, DRAG.parasitic_drag))
    h = 1e-6
    numeric = np.empty((3, 3))
    for j in range(3):
        plus, minus = list(v), list(v)
        plus[j] += h
        minus[j] -= h
        f_plus = dynamics.drag_force_body(plus, DRAG.rotor_drag, DRAG.parasitic_drag)
        f_minus = dynamics.drag_force_body(minus, DRAG.rotor_drag, DRAG.parasitic_drag)
        numeric[:, j] = (np.array(f_plus) - np.array(f_minus)) / (2 * h)
    np.testing.assert_allclose(jacobian, numeric, atol=1e-7)


def test_drag_acceleration_is_the_body_force_turned_into_ned():
    x = state(euler=(0.3, -0.2, 1.1), velocity=(1.0, 2.0, -0.5))
    wind = (4.0, -1.0, 0.2)
    q = np.array(x[3:7])
    R = rotation_from_quat(q)
    v_rel_B = R.T @ (np.array(x[7:10]) - wind)
    f_B = np.array(dynamics.drag_force_body(v_rel_B, DRAG.rotor_drag, DRAG.parasitic_drag))
    np.testing.assert_allclose(dynamics.drag_acceleration(x, wind, DRAG), R @ f_B / DRAG.mass, atol=1e-14)
    # moving with the air: no drag
    assert np.allclose(dynamics.drag_acceleration(state(velocity=wind), wind, DRAG), 0.0, atol=1e-15)


def test_no_drag_is_the_old_step_bit_for_bit_and_wind_does_not_act():
    x = state(euler=(0.1, 0.2, 0.3), velocity=(1.0, -2.0, 0.5))
    plain = dynamics.plant_step(x, [HOVER] * 4, [HOVER] * 4, [0.5] * 4, PhysicsParams(), 0.001)
    windy = dynamics.plant_step(
        x, [HOVER] * 4, [HOVER] * 4, [0.5] * 4, PhysicsParams(), 0.001, wind=(5.0, 0, 0)
    )
    assert plain == windy
    assert not dynamics.has_drag(PhysicsParams()) and dynamics.has_drag(DRAG)


def test_steady_wind_drives_a_drifting_vehicle_to_the_wind_speed():
    """A level vehicle holding its weight, in a 4 m/s wind, accelerates to the wind's speed with
    the time constant m / (k + c |v|): after a long time it moves with the air."""
    x, forces = state(), [HOVER] * 4
    params = dataclasses.replace(DRAG, motor_noise=0.0, x_bounds=[-1000.0, 1000.0])
    first = None
    for _ in range(60_000):  # 60 s
        x, a, forces, _ = dynamics.plant_step(
            x, forces, [HOVER] * 4, [0.5] * 4, params, 0.001, wind=(4.0, 0.0, 0.0)
        )
        first = a if first is None else first
    assert first[0] == pytest.approx(0.22 * 4.0 / 0.5 + 0.005 * 16.0 / 0.5, rel=1e-3)
    assert x[7] == pytest.approx(4.0, abs=1e-3)
    assert abs(x[9]) < 1e-9


def test_delta_velocity_step_is_the_specific_force_integral():
    q = quat_from_euler(0.2, -0.1, 0.5)
    a = (1.0, -2.0, 3.0)
    dv = sensor_models.delta_velocity_step(q, q, a, 0.001)
    np.testing.assert_allclose(np.array(dv) / 0.001, sensor_models.specific_force(q, a), atol=1e-12)
    # resting level: -g on body z; free fall: 0
    level = quat_from_euler(0.0, 0.0, 0.0)
    np.testing.assert_allclose(
        sensor_models.delta_velocity_step(level, level, (0, 0, 0), 0.002), (0, 0, -GRAVITY * 0.002)
    )
    np.testing.assert_allclose(
        sensor_models.delta_velocity_step(level, level, (0, 0, GRAVITY), 0.002), 0.0, atol=1e-15
    )
    # the trapezoid on the attitude: the mean of the two ends' rotations
    q2 = quat_from_euler(0.25, -0.1, 0.5)
    both = np.array(sensor_models.delta_velocity_step(q, q2, a, 0.001))
    ends = (np.array(sensor_models.specific_force(q, a)) + sensor_models.specific_force(q2, a)) / 2 * 0.001
    np.testing.assert_allclose(both, ends, atol=1e-15)


def test_range_limits_and_saturation_flags():
    params = ImuParams(accel_std=[0.0] * 3, gyro_std=[0.0] * 3, accel_limit=16 * GRAVITY, gyro_limit=34.9)
    sample = sensor_models.imu_from_specific_force(
        (-1500.0, 3.0, 200.0), (42.6, -1.0, -50.0), [0.0] * 6, params
    )
    assert sample == (-16 * GRAVITY, 3.0, 16 * GRAVITY, 34.9, -1.0, -34.9)
    assert sensor_models.imu_saturated(sample, params) == (1.0, 1.0)
    calm = sensor_models.imu_from_specific_force((1.0, 3.0, -9.8), (0.1, -1.0, 0.5), [0.0] * 6, params)
    assert sensor_models.imu_saturated(calm, params) == (0.0, 0.0)
    # gyro_limit 0: the gyro never clips (the default, the 46.8 rad/s read at 42.6)
    free = dataclasses.replace(params, gyro_limit=0.0)
    assert sensor_models.imu_from_specific_force((0, 0, 0), (46.8, 0, 0), [0.0] * 6, free)[3] == 46.8
    assert sensor_models.imu_saturated((0, 0, 0, 1e9, 0, 0), free) == (0.0, 0.0)
    assert sensor_models.imu_saturated((float("nan"),) * 6, params) == (0.0, 0.0)
