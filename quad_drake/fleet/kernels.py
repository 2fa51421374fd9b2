"""Batched kernels: the array form of the scalar pure functions, leading axis N (vehicles).

Each function here is the array form of the scalar function it names (``dynamics``,
``sensor_models``, ``control.cascade``), which stays the reference implementation;
``tests/test_fleet_kernels.py`` checks every one against it on seeded random inputs to
1e-12. Where a scalar helper is plain arithmetic it is called as is on rows of the
transposed arrays (one kernel per concept); only the parts written with ``math`` or with
branches are re-written here with numpy (``np.sqrt``, ``np.where``, ``np.clip``).

Shapes: ``state`` (N, 13) in the ``conventions`` layout (p_NB m NED, q_NB wxyz, v_NB m/s,
w_NB_B rad/s); motor forces (N, 4) N; IMU samples (N, 6); references (N, 10). Parameters
are the scalar dataclasses (one set for the whole fleet). Pure: no RNG, no pydrake.
"""

import numpy as np

from quad_drake.conventions import GRAVITY, SQRT2
from quad_drake.dynamics import _coefficients, _rates, thrusts_from_wrench
from quad_drake.fidelity import PHYSICAL
from quad_drake.rotations import euler_from_quats, wrap_angles
from quad_drake.sensor_models import gps_measurement, reference_accelerometer, specific_force

# ----- dynamics ---------------------------------------------------------------


def clamped_noisy_commands(commands, noise_unit, min_thrust, max_thrust, noise_half_width):
    """(N, 4) of :func:`quad_drake.dynamics.clamped_noisy_commands`."""
    return np.clip(commands, min_thrust, max_thrust) + noise_half_width * (2.0 * noise_unit - 1.0)


def motor_lag_step(forces_old, forces_cmd, dt, tau_up, tau_down):
    """(N, 4) of :func:`quad_drake.dynamics.motor_lag_step`."""
    tau = np.where(forces_cmd >= forces_old, tau_up, tau_down)
    return (forces_cmd * dt + forces_old * tau) / (dt + tau)


def wrench_from_thrusts(forces, arm_length, kappa, com_offset=(0.0, 0.0)):
    """(T, Mx, My, Mz), each (N,), of :func:`quad_drake.dynamics.wrench_from_thrusts`."""
    f0, f1, f2, f3 = forces.T
    arm = arm_length / SQRT2
    thrust = f0 + f1 + f2 + f3
    return (
        thrust,
        arm * (f0 - f1 + f2 - f3) + com_offset[1] * thrust,
        arm * (f0 + f1 - f2 - f3) - com_offset[0] * thrust,
        kappa * (-f0 + f1 + f2 - f3),
    )


def rigid_body_step(state, thrust, moment, mass, inertia, dt):
    """((N, 13), a_NB (N, 3)) of :func:`quad_drake.dynamics.rigid_body_step` (RK4)."""
    px, py, pz, qw, qx, qy, qz, vx, vy, vz, wx, wy, wz = state.T
    k = _coefficients(thrust, moment, mass, inertia)
    h = 0.5 * dt
    qw1, qx1, qy1, qz1, wx1, wy1, wz1, ax1, ay1, az1 = _rates(qw, qx, qy, qz, wx, wy, wz, *k)
    qw2, qx2, qy2, qz2, wx2, wy2, wz2, ax2, ay2, az2 = _rates(
        qw + h * qw1, qx + h * qx1, qy + h * qy1, qz + h * qz1, wx + h * wx1, wy + h * wy1, wz + h * wz1, *k
    )
    qw3, qx3, qy3, qz3, wx3, wy3, wz3, ax3, ay3, az3 = _rates(
        qw + h * qw2, qx + h * qx2, qy + h * qy2, qz + h * qz2, wx + h * wx2, wy + h * wy2, wz + h * wz2, *k
    )
    qw4, qx4, qy4, qz4, wx4, wy4, wz4, ax4, ay4, az4 = _rates(
        qw + dt * qw3,
        qx + dt * qx3,
        qy + dt * qy3,
        qz + dt * qz3,
        wx + dt * wx3,
        wy + dt * wy3,
        wz + dt * wz3,
        *k,
    )
    d6 = dt / 6.0
    qw = qw + d6 * (qw1 + 2.0 * (qw2 + qw3) + qw4)
    qx = qx + d6 * (qx1 + 2.0 * (qx2 + qx3) + qx4)
    qy = qy + d6 * (qy1 + 2.0 * (qy2 + qy3) + qy4)
    qz = qz + d6 * (qz1 + 2.0 * (qz2 + qz3) + qz4)
    n = 1.0 / np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    ax = (ax1 + 2.0 * (ax2 + ax3) + ax4) / 6.0
    ay = (ay1 + 2.0 * (ay2 + ay3) + ay4) / 6.0
    az = (az1 + 2.0 * (az2 + az3) + az4) / 6.0
    p2 = dt * d6
    new = np.stack(
        [
            px + dt * vx + p2 * (ax1 + ax2 + ax3),
            py + dt * vy + p2 * (ay1 + ay2 + ay3),
            pz + dt * vz + p2 * (az1 + az2 + az3),
            qw * n,
            qx * n,
            qy * n,
            qz * n,
            vx + dt * ax,
            vy + dt * ay,
            vz + dt * az,
            wx + d6 * (wx1 + 2.0 * (wx2 + wx3) + wx4),
            wy + d6 * (wy1 + 2.0 * (wy2 + wy3) + wy4),
            wz + d6 * (wz1 + 2.0 * (wz2 + wz3) + wz4),
        ],
        axis=1,
    )
    return new, np.stack([ax, ay, az], axis=1)


def rigid_body_step_semi_implicit(state, thrust, moment, mass, inertia, dt):
    """((N, 13), a_NB (N, 3)) of :func:`quad_drake.dynamics.rigid_body_step_semi_implicit`."""
    px, py, pz, qw, qx, qy, qz, vx, vy, vz, wx, wy, wz = state.T
    qdw, qdx, qdy, qdz, wdx, wdy, wdz, ax, ay, az = _rates(
        qw, qx, qy, qz, wx, wy, wz, *_coefficients(thrust, moment, mass, inertia)
    )
    vx, vy, vz = vx + dt * ax, vy + dt * ay, vz + dt * az
    qw, qx, qy, qz = qw + dt * qdw, qx + dt * qdx, qy + dt * qdy, qz + dt * qdz
    n = 1.0 / np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    new = np.stack(
        [
            px + dt * vx,
            py + dt * vy,
            pz + dt * vz,
            qw * n,
            qx * n,
            qy * n,
            qz * n,
            vx,
            vy,
            vz,
            wx + dt * wdx,
            wy + dt * wdy,
            wz + dt * wdz,
        ],
        axis=1,
    )
    return new, np.stack([ax, ay, az], axis=1)


def apply_room_constraints(state_new, state_old, params):
    """(N, 13) of :func:`quad_drake.dynamics.apply_room_constraints` (inputs not modified)."""
    s = state_new.copy()
    z_min, z_max = params.z_bounds
    floor = s[:, 2] >= z_max
    if floor.any():
        s[floor, 0:2] = state_old[floor, 0:2]
        s[floor, 2] = z_max
        s[floor, 7:9] = 0.0
        s[floor, 9] = np.minimum(0.0, s[floor, 9])
        s[floor, 10:13] = 0.0
    x_min, x_max = params.x_bounds
    wall_x = (s[:, 0] < x_min) | (s[:, 0] > x_max)
    s[wall_x, 0], s[wall_x, 7] = state_old[wall_x, 0], 0.0
    y_min, y_max = params.y_bounds
    wall_y = (s[:, 1] < y_min) | (s[:, 1] > y_max)
    s[wall_y, 1], s[wall_y, 8] = state_old[wall_y, 1], 0.0
    ceiling = s[:, 2] < z_min
    s[ceiling, 2], s[ceiling, 9] = state_old[ceiling, 2], 0.0
    return s


def on_floor(state, params):
    """(N,) bool of :func:`quad_drake.dynamics.on_floor`."""
    return state[:, 2] >= params.z_bounds[1]


def outside_room(state, params):
    """(N,) bool of :func:`quad_drake.dynamics.outside_room`."""
    x_min, x_max = params.x_bounds
    y_min, y_max = params.y_bounds
    x, y = state[:, 0], state[:, 1]
    return (x < x_min) | (x > x_max) | (y < y_min) | (y > y_max) | (state[:, 2] < params.z_bounds[0])


def plant_step(state, forces_old, commands, noise_unit, params, dt, fidelity=PHYSICAL):
    """(state_new (N, 13), a_NB (N, 3), forces (N, 4), hit_wall (N,) bool) of
    :func:`quad_drake.dynamics.plant_step`; noise_unit (N, 4) uniforms in [0, 1]."""
    targets = clamped_noisy_commands(
        commands, noise_unit, params.min_motor_thrust, params.max_motor_thrust, params.motor_noise
    )
    forces = motor_lag_step(forces_old, targets, dt, params.motor_tau_up, params.motor_tau_down)
    thrust, mx, my, mz = wrench_from_thrusts(forces, params.arm_length, params.kappa, params.com_offset)
    body_step = rigid_body_step_semi_implicit if fidelity.semi_implicit_euler else rigid_body_step
    new, _ = body_step(state, thrust, (mx, my, mz), params.mass, params.inertia, dt)
    hit_wall = outside_room(new, params)
    new = apply_room_constraints(new, state, params)
    accel = (new[:, 7:10] - state[:, 7:10]) / dt
    if fidelity.float32_state:
        new = new.astype(np.float32).astype(float)
    return new, accel, forces, hit_wall


# ----- sensors ----------------------------------------------------------------


def imu_measurement(q_NB, w_NB_B, a_NB, noise, params, fidelity=PHYSICAL, bias=None):
    """(N, 6) of :func:`quad_drake.sensor_models.imu_measurement`; q_NB (N, 4), w_NB_B (N, 3),
    a_NB (N, 3), noise (N, 6), bias (N, 6) or None (zero)."""
    accelerometer = reference_accelerometer if fidelity.reference_accelerometer else specific_force
    f = np.stack(accelerometer(q_NB.T, a_NB.T), axis=1)
    sa, sg = np.asarray(params.accel_std), np.asarray(params.gyro_std)
    bias = np.zeros((q_NB.shape[0], 6)) if bias is None else bias
    accel = f + bias[:, 0:3] + sa * noise[:, 0:3]
    gyro = w_NB_B + bias[:, 3:6] + sg * noise[:, 3:6]
    limit = params.accel_limit
    return np.concatenate([np.clip(accel, -limit, limit), gyro], axis=1)


def imu_bias_step(bias, noise, params):
    """(N, 6) of :func:`quad_drake.sensor_models.imu_bias_step`."""
    walk = np.asarray(list(params.accel_bias_walk_std) + list(params.gyro_bias_walk_std))
    return bias + walk * noise


def gps_measurements(p_NB, v_NB, random_walk, noise, params):
    """(position (N, 3), velocity (N, 3), random walk (N, 3)) of
    :func:`quad_drake.sensor_models.gps_measurement` (which runs here on the rows)."""
    position, velocity, walk = gps_measurement(p_NB.T, v_NB.T, random_walk.T, noise.T, params)
    return np.stack(position, axis=1), np.stack(velocity, axis=1), np.stack(walk, axis=1)


def magnetometer_yaws(q_NB, noise, params):
    """(N,) of :func:`quad_drake.sensor_models.magnetometer_yaw`; noise (N,)."""
    return wrap_angles(euler_from_quats(q_NB)[2] + params.yaw_std * noise)


# ----- cascade controller -----------------------------------------------------


def cascade_step(state, reference, integral, dt, params, fidelity=PHYSICAL):
    """(forces (N, 4), integral (N,)) of :func:`quad_drake.control.cascade.cascade_step`;
    state (N, 13), reference (N, 10), integral (N,) m s."""
    px, py, pz, qw, qx, qy, qz, vx, vy, vz, wx, wy, wz = state.T
    rx, ry, rz, rvx, rvy, rvz, rax, ray, raz, yaw_ref = reference.T
    s = 2.0 / (qw * qw + qx * qx + qy * qy + qz * qz)
    R00 = 1.0 - s * (qy * qy + qz * qz)
    R01 = s * (qx * qy - qw * qz)
    R02 = s * (qx * qz + qw * qy)
    R10 = s * (qx * qy + qw * qz)
    R11 = 1.0 - s * (qx * qx + qz * qz)
    R12 = s * (qy * qz - qw * qx)
    R22 = 1.0 - s * (qx * qx + qy * qy)
    yaw = np.arctan2(R10, R00)

    # altitude_control, then clamp_collective_thrust
    error = rz - pz
    integral = integral + error * dt
    vz_cmd = np.minimum(
        np.maximum(rvz + params.kp_pos_z * error, -params.max_ascent_rate), params.max_descent_rate
    )
    az = params.kp_vel_z * (vz_cmd - vz) + params.ki_pos_z * integral + raz - GRAVITY
    thrust = -az * params.mass / R22
    margin = 0.1 * (params.max_motor_thrust - params.min_motor_thrust)
    low, high = 4.0 * (params.min_motor_thrust + margin), 4.0 * (params.max_motor_thrust - margin)
    thrust = np.minimum(np.maximum(thrust, low), high)

    # lateral_position_control
    cvx = rvx + params.kp_pos_xy * (rx - px)
    cvy = rvy + params.kp_pos_xy * (ry - py)
    speed = np.hypot(cvx, cvy)
    fast = speed > params.max_speed_xy
    scale = np.where(fast, params.max_speed_xy / np.where(fast, speed, 1.0), 1.0)
    cvx, cvy = np.where(fast, cvx * scale, cvx), np.where(fast, cvy * scale, cvy)
    ax = rax + params.kp_vel_xy * (cvx - vx)
    ay = ray + params.kp_vel_xy * (cvy - vy)
    if fidelity.lateral_limit_3d:
        accel = np.sqrt(ax * ax + ay * ay + (params.kp_vel_xy * vz) ** 2)
    else:
        accel = np.hypot(ax, ay)
    limited = accel > params.max_horiz_accel
    scale = np.where(limited, params.max_horiz_accel / np.where(limited, accel, 1.0), 1.0)
    ax, ay = np.where(limited, ax * scale, ax), np.where(limited, ay * scale, ay)

    # _roll_pitch
    c = thrust / params.mass
    tilt = params.max_tilt
    positive = thrust > 0.0
    bx = np.where(positive, -np.minimum(np.maximum(ax / c, -tilt), tilt), 0.0)
    by = np.where(positive, -np.minimum(np.maximum(ay / c, -tilt), tilt), 0.0)
    bx_dot = params.kp_bank * (bx - R02)
    by_dot = params.kp_bank * (by - R12)
    p_cmd = (R10 * bx_dot - R00 * by_dot) / R22
    q_cmd = (R11 * bx_dot - R01 * by_dot) / R22
    r_cmd = params.kp_yaw * wrap_angles(yaw_ref - yaw)

    # body_rate_control
    inertia, gain = params.inertia, params.kp_pqr
    mx = inertia[0] * gain[0] * (p_cmd - wx)
    my = inertia[1] * gain[1] * (q_cmd - wy)
    mz = inertia[2] * gain[2] * (r_cmd - wz)
    forces = thrusts_from_wrench(thrust, mx, my, mz, params.arm_length, params.kappa)
    return np.stack(forces, axis=1), integral
