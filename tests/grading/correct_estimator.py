"""The finished student template (``quad_drake/grading/student_template.py``): the course's six
functions done right, the 06 sigmas measured, the EKF tuned. Graded by ``tests/test_grading.py``
and ``benchmarks/grading_campaign.py``; its mistakes are ``tests/grading/mistakes.py``."""

import numpy as np

from quad_drake.grading.course_math import (
    euler_from_quaternion,
    integrate_body_rate,
    quaternion_from_euler,
    rotate,
    rotation_matrix,
    update,
)

GRAVITY = 9.81  # m/s^2
DT_IMU = 0.002  # s
ATTITUDE_TAU = 100.0  # s

MEASURED_STD_DEV_GPS_POS_XY = 0.7  # m
MEASURED_STD_DEV_ACCEL_XY = 0.5  # m/s^2

INIT_STD_DEVS = (0.1, 0.1, 0.3, 0.1, 0.1, 0.3, 0.05)
Q_POS_XY_STD = 0.01  # m/sqrt(s)
Q_POS_Z_STD = 0.01  # m/sqrt(s)
Q_VEL_XY_STD = 0.15  # m/s/sqrt(s)
Q_VEL_Z_STD = 0.1  # m/s/sqrt(s)
Q_YAW_STD = 0.1  # rad/sqrt(s)
GPS_POS_XY_STD = 0.7  # m
GPS_POS_Z_STD = 2.0  # m
GPS_VEL_XY_STD = 0.1  # m/s
GPS_VEL_Z_STD = 0.3  # m/s
MAG_YAW_STD = 0.1  # rad


def update_from_imu(accel, gyro, roll_est, pitch_est, yaw_est, dt_imu=DT_IMU, attitude_tau=ATTITUDE_TAU):
    q = integrate_body_rate(quaternion_from_euler(roll_est, pitch_est, yaw_est), gyro, dt_imu)
    predicted_roll, predicted_pitch, yaw = euler_from_quaternion(q)
    accel_roll = np.arctan2(accel[..., 1], accel[..., 2])
    accel_pitch = np.arctan2(-accel[..., 0], GRAVITY)
    blend = attitude_tau / (attitude_tau + dt_imu)
    roll = blend * predicted_roll + (1.0 - blend) * accel_roll
    pitch = blend * predicted_pitch + (1.0 - blend) * accel_pitch
    return roll, pitch, yaw


def predict_state(cur_state, dt, accel, gyro, roll_est, pitch_est):
    predicted = np.array(cur_state, dtype=float)
    accel_world = rotate(rotation_matrix(roll_est, pitch_est, cur_state[..., 6]), accel)
    predicted[..., 0:3] += cur_state[..., 3:6] * dt
    predicted[..., 3:5] += accel_world[..., 0:2] * dt
    predicted[..., 5] += (accel_world[..., 2] - GRAVITY) * dt
    return predicted


def get_rbg_prime(roll, pitch, yaw):
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    zero = np.zeros_like(cr * cp * cy)
    rows = [
        [-cp * sy, -sr * sp * sy - cr * cy, -cr * sp * sy + sr * cy],
        [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
        [zero, zero, zero],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def predict(ekf_state, ekf_cov, dt, accel, gyro, roll_est, pitch_est, q_std):
    rbg_prime = get_rbg_prime(roll_est, pitch_est, ekf_state[..., 6])
    g_prime = np.broadcast_to(np.eye(7), ekf_cov.shape).copy()
    g_prime[..., 0, 3] = g_prime[..., 1, 4] = g_prime[..., 2, 5] = dt
    g_prime[..., 3:6, 6] = rotate(rbg_prime, accel) * dt
    q = np.diag(np.square(q_std)) * dt
    cov = g_prime @ ekf_cov @ np.swapaxes(g_prime, -1, -2) + q
    return predict_state(ekf_state, dt, accel, gyro, roll_est, pitch_est), cov


def update_from_mag(ekf_state, ekf_cov, mag_yaw, mag_std):
    h = np.zeros((1, 7))
    h[0, 6] = 1.0
    z_from_x = ekf_state[..., 6:7].copy()
    difference = mag_yaw[..., None] - z_from_x
    z_from_x[difference > np.pi] += 2 * np.pi
    z_from_x[difference < -np.pi] -= 2 * np.pi
    return update(ekf_state, ekf_cov, mag_yaw[..., None], h, np.array([[mag_std**2]]), z_from_x)


def update_from_gps(ekf_state, ekf_cov, pos, vel, gps_std):
    h = np.eye(6, 7)
    z = np.concatenate([pos, vel], axis=-1)
    return update(ekf_state, ekf_cov, z, h, np.diag(np.square(gps_std)), ekf_state[..., 0:6])
