"""The FCND E-sim reference cascade controller (SPEC §5), as pure scalar functions.

Frames: positions, velocities and accelerations are NED (z down); body rates and
moments are body FRD; ``R`` is R_NB (body to world) and ``Rij`` its 0-based entries.
Each loop takes plain floats/tuples and a :class:`quad_drake.config.ControllerParams`;
:func:`cascade_step` runs them in the order of the reference's ``RunControl``.
Everything is ``math`` on scalars: :func:`cascade_step` runs at 500 Hz.
"""

import math

from quad_drake.conventions import GRAVITY
from quad_drake.models.dynamics import thrusts_from_wrench
from quad_drake.models.fidelity import PHYSICAL
from quad_drake.models.rotations import wrap_to_pi


def altitude_control(z_ref, vz_ref, az_ff, z, vz, R22, integral, dt, params) -> tuple[float, float]:
    """Collective thrust (N, unclamped) and the new altitude-error integral (m s).

    z_ref, z in m (NED, down); vz_ref, vz in m/s; az_ff in m/s^2; R22 = R_NB[2, 2];
    integral accumulates (z_ref - z) dt before use; dt in s. The commanded vertical
    speed is clamped to [-max_ascent_rate, +max_descent_rate].
    """
    error = z_ref - z
    integral += error * dt
    vz_cmd = vz_ref + params.kp_pos_z * error
    vz_cmd = min(max(vz_cmd, -params.max_ascent_rate), params.max_descent_rate)
    az = params.kp_vel_z * (vz_cmd - vz) + params.ki_pos_z * integral + az_ff - GRAVITY
    return -az * params.mass / R22, integral


def collective_thrust_limits(params) -> tuple[float, float]:
    """(low, high) collective-thrust bounds, N: 4 (min + margin), 4 (max - margin).

    margin = 0.1 (max_motor_thrust - min_motor_thrust) is headroom for attitude control.
    """
    margin = 0.1 * (params.max_motor_thrust - params.min_motor_thrust)
    return 4.0 * (params.min_motor_thrust + margin), 4.0 * (params.max_motor_thrust - margin)


def clamp_collective_thrust(thrust, params) -> float:
    """Collective thrust (N) clamped to :func:`collective_thrust_limits`."""
    low, high = collective_thrust_limits(params)
    return min(max(thrust, low), high)


def lateral_position_control(
    p_ref_xy, v_ref_xy, a_ff_xy, p_xy, v_xy, params, vz=0.0, fidelity=PHYSICAL
) -> tuple[float, float]:
    """Horizontal acceleration command (ax, ay), m/s^2 in N, from xy position/velocity errors.

    The velocity command is rescaled to norm max_speed_xy and the acceleration command
    to norm max_horiz_accel when they exceed them (direction kept). The norm is that of
    (ax, ay); with ``fidelity.lateral_limit_3d`` it is the reference's 3-D norm of
    (ax, ay, -kp_vel_xy vz), vz the vehicle's vertical speed in m/s (SPEC §5 step 4),
    so a climbing or sinking vehicle gets a smaller lateral command.
    """
    vx = v_ref_xy[0] + params.kp_pos_xy * (p_ref_xy[0] - p_xy[0])
    vy = v_ref_xy[1] + params.kp_pos_xy * (p_ref_xy[1] - p_xy[1])
    speed = math.hypot(vx, vy)
    if speed > params.max_speed_xy:
        scale = params.max_speed_xy / speed
        vx *= scale
        vy *= scale
    ax = a_ff_xy[0] + params.kp_vel_xy * (vx - v_xy[0])
    ay = a_ff_xy[1] + params.kp_vel_xy * (vy - v_xy[1])
    if fidelity.lateral_limit_3d:
        accel = math.sqrt(ax * ax + ay * ay + (params.kp_vel_xy * vz) ** 2)
    else:
        accel = math.hypot(ax, ay)
    if accel > params.max_horiz_accel:
        scale = params.max_horiz_accel / accel
        ax *= scale
        ay *= scale
    return ax, ay


def _roll_pitch(ax, ay, thrust, R00, R01, R02, R10, R11, R12, R22, params):
    """(p_cmd, q_cmd) of :func:`roll_pitch_control` from the needed entries of R_NB."""
    if thrust > 0.0:
        c = thrust / params.mass
        tilt = params.max_tilt
        bx = -min(max(ax / c, -tilt), tilt)
        by = -min(max(ay / c, -tilt), tilt)
    else:
        bx = by = 0.0
    bx_dot = params.kp_bank * (bx - R02)
    by_dot = params.kp_bank * (by - R12)
    return (R10 * bx_dot - R00 * by_dot) / R22, (R11 * bx_dot - R01 * by_dot) / R22


def max_commanded_tilt(params) -> float:
    """rad, the largest tilt of the thrust axis from the vertical that :func:`roll_pitch_control` ever
    commands: its targets for R02 and R12 are each clamped to +-max_tilt, so the horizontal part of
    the body z axis is at most sqrt(2) max_tilt (capped at 1): asin(min(1, sqrt(2) max_tilt))
    (81.9 deg for the default 0.7)."""
    return math.asin(min(1.0, math.sqrt(2.0) * params.max_tilt))


def roll_pitch_control(a_cmd_xy, thrust, R, params) -> tuple[float, float]:
    """Body roll/pitch rate commands (p, q), rad/s, that tilt the thrust toward a_cmd_xy.

    a_cmd_xy in m/s^2 (N); thrust in N (collective, clamped); R = R_NB (3x3 indexable).
    The targets for R02, R12 are -a/(thrust/mass) clamped to +-max_tilt (dimensionless),
    and 0 when thrust <= 0; they are reached with gain kp_bank.
    """
    return _roll_pitch(
        a_cmd_xy[0],
        a_cmd_xy[1],
        thrust,
        R[0][0],
        R[0][1],
        R[0][2],
        R[1][0],
        R[1][1],
        R[1][2],
        R[2][2],
        params,
    )


def yaw_control(yaw_ref, yaw, params) -> float:
    """Yaw rate command r, rad/s: kp_yaw * wrap_to_pi(yaw_ref - yaw); angles in rad."""
    return params.kp_yaw * wrap_to_pi(yaw_ref - yaw)


def body_rate_control(pqr_cmd, pqr, params) -> tuple[float, float, float]:
    """Body moment command (Mx, My, Mz), N m in B: I * kp_pqr * (pqr_cmd - pqr), elementwise.

    A non-finite measured rate pqr means none was measured (the estimators report NaN over an
    IMU dropout): the loop cannot close, so it commands no moment and the body keeps its angular
    momentum, rather than driving the motors against a stale rate with no feedback.
    """
    inertia, gain = params.inertia, params.kp_pqr
    if not (math.isfinite(pqr[0]) and math.isfinite(pqr[1]) and math.isfinite(pqr[2])):
        return (0.0, 0.0, 0.0)
    return (
        inertia[0] * gain[0] * (pqr_cmd[0] - pqr[0]),
        inertia[1] * gain[1] * (pqr_cmd[1] - pqr[1]),
        inertia[2] * gain[2] * (pqr_cmd[2] - pqr[2]),
    )


def cascade_step(
    state13, reference10, integral, dt, params, fidelity=PHYSICAL
) -> tuple[tuple[float, float, float, float], float]:
    """One controller tick (the reference's ``RunControl``): motor forces and new integral.

    state13: p_NB (m), q_NB (wxyz, normalised here), v_NB (m/s), w_NB_B (rad/s);
    reference10: p (m), v (m/s), a feed-forward (m/s^2), yaw (rad); integral: the
    altitude-error integral (m s); dt in s; fidelity: a :class:`~quad_drake.models.fidelity.Fidelity`
    (its ``lateral_limit_3d`` picks the lateral acceleration limit; without
    ``altitude_integral_windup`` the integral is held while the collective thrust is clamped).
    Returns (F0..F3 motor forces in N, not clamped: the plant clamps) and the updated integral.
    """
    px, py, pz, qw, qx, qy, qz, vx, vy, vz, wx, wy, wz = state13
    rx, ry, rz, rvx, rvy, rvz, rax, ray, raz, yaw_ref = reference10
    s = 2.0 / (qw * qw + qx * qx + qy * qy + qz * qz)
    R00 = 1.0 - s * (qy * qy + qz * qz)
    R01 = s * (qx * qy - qw * qz)
    R02 = s * (qx * qz + qw * qy)
    R10 = s * (qx * qy + qw * qz)
    R11 = 1.0 - s * (qx * qx + qz * qz)
    R12 = s * (qy * qz - qw * qx)
    R22 = 1.0 - s * (qx * qx + qy * qy)
    yaw = math.atan2(R10, R00)

    unclamped, integrated = altitude_control(rz, rvz, raz, pz, vz, R22, integral, dt, params)
    thrust = clamp_collective_thrust(unclamped, params)
    if thrust == unclamped or fidelity.altitude_integral_windup:
        integral = integrated  # anti-windup: no integration while the collective thrust is clamped
    ax, ay = lateral_position_control(
        (rx, ry), (rvx, rvy), (rax, ray), (px, py), (vx, vy), params, vz, fidelity
    )
    p_cmd, q_cmd = _roll_pitch(ax, ay, thrust, R00, R01, R02, R10, R11, R12, R22, params)
    r_cmd = yaw_control(yaw_ref, yaw, params)
    mx, my, mz = body_rate_control((p_cmd, q_cmd, r_cmd), (wx, wy, wz), params)
    return thrusts_from_wrench(thrust, mx, my, mz, params.arm_length, params.kappa), integral
