"""My estimator for the FCND estimation project: the course's six functions, in Python.

Write ``quad-drake grade --template DIR`` to get this file, fill in the parts marked
``STUDENT CODE`` step by step as the course's README asks (06 → 11), and grade it with
``quad-drake grade my_estimator.py``. As shipped, every scenario flies and 07-11 fail.

Conventions (the course's, SPEC §0.1, §2): world frame NED (z down, altitude 1 m is z = -1),
body frame FRD; Euler angles ZYX, R = Rz(yaw) Ry(pitch) Rx(roll) maps body to world. The
accelerometer reads the course's R^T (a + g ẑ): (0, 0, +9.81) m/s^2 level at rest; the gyro
the body rates p, q, r in rad/s. The EKF state is [x, y, z, vx, vy, vz, yaw] (m, m/s, rad);
roll and pitch live in the complementary filter.

**One call serves every vehicle.** The grader flies many seeds at once and calls each function
once per 2 ms tick with all vehicles' rows: every argument has a leading vehicle axis (n,),
e.g. ``accel`` (n, 3), ``ekf_state`` (n, 7), ``ekf_cov`` (n, 7, 7), ``roll_est`` (n,). Index
with ``...`` (``ekf_state[..., 6]`` is every vehicle's yaw) and multiply matrices with ``@`` or
:func:`rotate`; the helpers below (the course's Quaternion class and ``Update``) take such
arrays too. Return new arrays; do not change the arguments in place.
"""

import numpy as np

from quad_drake.grading.course_math import (  # noqa: F401 (the course's ready-made helpers)
    euler_from_quaternion,
    integrate_body_rate,
    quaternion_from_euler,
    rotate,
    rotation_matrix,
    update,
)

GRAVITY = 9.81  # m/s^2, CONST_GRAVITY
DT_IMU = 0.002  # s, the IMU period (dtIMU)
ATTITUDE_TAU = 100.0  # s, the complementary filter's time constant (attitudeTau)

# Step 1 (06_SensorNoise): the standard deviations you measure from the 06 logs
# (`quad-drake run 06_sensor_noise`, then `quad-drake noise-std RUN_DIR`, or numpy on the logs).
MEASURED_STD_DEV_GPS_POS_XY = 2.0  # m, GPS x (and y) position noise
MEASURED_STD_DEV_ACCEL_XY = 0.1  # m/s^2, accelerometer x (and y) noise

# The EKF's parameters (the course's QuadEstimatorEKF.txt); tune them in steps 3-5.
INIT_STD_DEVS = (0.1, 0.1, 0.3, 0.1, 0.1, 0.3, 0.05)  # m, m, m, m/s, m/s, m/s, rad
Q_POS_XY_STD = 0.05  # m/sqrt(s), process noise: Q = diag(std^2) * dt
Q_POS_Z_STD = 0.05  # m/sqrt(s)
Q_VEL_XY_STD = 0.05  # m/s/sqrt(s)
Q_VEL_Z_STD = 0.1  # m/s/sqrt(s)
Q_YAW_STD = 0.05  # rad/sqrt(s)
GPS_POS_XY_STD = 1.0  # m, what the filter assumes of the GPS
GPS_POS_Z_STD = 3.0  # m
GPS_VEL_XY_STD = 0.1  # m/s
GPS_VEL_Z_STD = 0.3  # m/s
MAG_YAW_STD = 0.1  # rad, what the filter assumes of the magnetometer


def update_from_imu(accel, gyro, roll_est, pitch_est, yaw_est, dt_imu=DT_IMU, attitude_tau=ATTITUDE_TAU):
    """Step 2 (07_AttitudeEstimation): the complementary filter (``UpdateFromIMU``).

    accel (n, 3) m/s^2 and gyro (n, 3) rad/s, body FRD; roll_est, pitch_est, yaw_est (n,) rad,
    the estimates before this sample; dt_imu s; attitude_tau s.
    Returns (roll_est, pitch_est, yaw_est), each (n,) rad; the grader stores the yaw in the EKF
    state (``ekfState(6)``).

    Predict the attitude from the gyro, then blend roll and pitch with the accelerometer's:
        φ̄, θ̄, ψ̄ = the attitude (φ̂, θ̂, ψ̂) turned by the body rate (p, q, r) for dt_imu
        φ_acc = atan2(a_y, a_z),  θ_acc = atan2(−a_x, g)
        φ̂ = τ/(τ + dt) φ̄ + dt/(τ + dt) φ_acc   (θ̂ likewise);   ψ̂ = ψ̄ wrapped into [−π, π]
    As shipped this is the course's small-angle integration, φ̄ = φ̂ + p dt, which is wrong
    once the vehicle is tilted (the Euler rates are not the body rates): replace it with a
    nonlinear one, e.g. quaternion_from_euler → integrate_body_rate → euler_from_quaternion.
    """
    # ---------------- STUDENT CODE: replace the small-angle integration ----------------
    predicted_roll = roll_est + dt_imu * gyro[..., 0]
    predicted_pitch = pitch_est + dt_imu * gyro[..., 1]
    yaw = yaw_est + dt_imu * gyro[..., 2]
    yaw = np.where(yaw > np.pi, yaw - 2 * np.pi, np.where(yaw < -np.pi, yaw + 2 * np.pi, yaw))
    # ---------------- END STUDENT CODE -------------------------------------------------
    accel_roll = np.arctan2(accel[..., 1], accel[..., 2])
    accel_pitch = np.arctan2(-accel[..., 0], GRAVITY)
    blend = attitude_tau / (attitude_tau + dt_imu)
    return (
        blend * predicted_roll + (1 - blend) * accel_roll,
        blend * predicted_pitch + (1 - blend) * accel_pitch,
        yaw,
    )


def predict_state(cur_state, dt, accel, gyro, roll_est, pitch_est):
    """Step 3 (08_PredictState): dead reckoning of the EKF state (``PredictState``).

    cur_state (n, 7) [x y z m, vx vy vz m/s NED, yaw rad]; dt s; accel (n, 3) m/s^2 and gyro
    (n, 3) rad/s, body FRD; roll_est, pitch_est (n,) rad. Returns the predicted state (n, 7).

        p ← p + v dt
        v ← v + (R(φ̂, θ̂, ψ) a − (0, 0, g)) dt      (R: body to world, rotation_matrix)
        ψ unchanged (update_from_imu already integrated it)
    """
    predicted = np.array(cur_state, dtype=float)
    # ---------------- STUDENT CODE ------------------------------------------------------
    # ---------------- END STUDENT CODE --------------------------------------------------
    return predicted


def get_rbg_prime(roll, pitch, yaw):
    """Step 3 (09_PredictCovariance): R'bg = ∂R/∂ψ, the derivative of the body-to-world
    rotation R = Rz(ψ) Ry(θ) Rx(φ) with respect to yaw (``GetRbgPrime``).

    roll, pitch, yaw (n,) rad. Returns (n, 3, 3):
        [[−cθ sψ, −sφ sθ sψ − cφ cψ, −cφ sθ sψ + sφ cψ],
         [ cθ cψ,  sφ sθ cψ − cφ sψ,  cφ sθ cψ + sφ sψ],
         [ 0,      0,                 0               ]]
    """
    rbg_prime = np.zeros(np.shape(roll) + (3, 3))
    # ---------------- STUDENT CODE ------------------------------------------------------
    # ---------------- END STUDENT CODE --------------------------------------------------
    return rbg_prime


def predict(ekf_state, ekf_cov, dt, accel, gyro, roll_est, pitch_est, q_std):
    """Step 3 (09_PredictCovariance): the EKF prediction (``Predict``).

    ekf_state (n, 7), ekf_cov (n, 7, 7); dt s; accel (n, 3) m/s^2, gyro (n, 3) rad/s;
    roll_est, pitch_est (n,) rad; q_std (7,) the process noise standard deviations of
    x y z vx vy vz yaw (Q_*_STD above, in that order). Returns (ekf_state, ekf_cov).

        G = I₇ with G[0,3] = G[1,4] = G[2,5] = dt and G[3:6, 6] = R'bg a dt
        Q = diag(q_std²) dt
        P ← G P Gᵀ + Q;   x ← predict_state(x, dt, accel, gyro, φ̂, θ̂)
    """
    g_prime = np.broadcast_to(np.eye(7), np.shape(ekf_cov)).copy()  # noqa: F841 (yours to fill and use)
    cov = np.array(ekf_cov, dtype=float)
    # ---------------- STUDENT CODE ------------------------------------------------------
    # ---------------- END STUDENT CODE --------------------------------------------------
    return predict_state(ekf_state, dt, accel, gyro, roll_est, pitch_est), cov


def update_from_mag(ekf_state, ekf_cov, mag_yaw, mag_std):
    """Step 4 (10_MagUpdate): fuse a magnetometer yaw (``UpdateFromMag``).

    ekf_state (n, 7), ekf_cov (n, 7, 7) of the vehicles with a fresh sample; mag_yaw (n,) rad;
    mag_std rad. Returns (ekf_state, ekf_cov) after ``update``:
        z = ψ_mag,  H = [0 0 0 0 0 0 1],  ẑ = ψ̂,  R = mag_std²
    Measure the difference the short way round: shift ẑ by ±2π when |z − ẑ| > π.
    """
    h = np.zeros((1, 7))
    z_from_x = np.zeros(np.shape(mag_yaw) + (1,))
    # ---------------- STUDENT CODE ------------------------------------------------------
    # ---------------- END STUDENT CODE --------------------------------------------------
    return update(ekf_state, ekf_cov, mag_yaw[..., None], h, np.array([[mag_std**2]]), z_from_x)


def update_from_gps(ekf_state, ekf_cov, pos, vel, gps_std):
    """Step 5 (11_GPSUpdate): fuse a GPS sample (``UpdateFromGPS``).

    ekf_state (n, 7), ekf_cov (n, 7, 7) of the vehicles with a fresh sample; pos (n, 3) m and
    vel (n, 3) m/s, NED; gps_std (6,) m, m/s (GPS_*_STD above: x y z vx vy vz). Returns
    (ekf_state, ekf_cov) after ``update``:
        z = [p; v],  H = [I₆ | 0₆ₓ₁],  ẑ = x[0:6],  R = diag(gps_std²)
    """
    z = np.concatenate([pos, vel], axis=-1)
    h = np.zeros((6, 7))
    z_from_x = np.zeros(np.shape(z))
    # ---------------- STUDENT CODE ------------------------------------------------------
    # ---------------- END STUDENT CODE --------------------------------------------------
    return update(ekf_state, ekf_cov, z, h, np.diag(np.square(gps_std)), z_from_x)
