"""Complementary attitude filter (SPEC §4 UpdateFromIMU), written for the physical accelerometer.

The accelerometer reads the specific force f_B = R_NB^T (a_NB - g_N), i.e.
9.81 (sin(pitch), -sin(roll) cos(pitch), -cos(roll) cos(pitch)) at rest, so the tilt
seen by gravity is roll = atan2(-f_y, -f_z), pitch = atan2(f_x, hypot(f_y, f_z)); both
are exact at rest for |pitch| < pi/2 (the reference's atan2(-a_x, 9.81) is atan(sin(pitch))).
With ``reference_accelerometer`` (``fidelity: reference``) the reading is the reference's
R_NB^T (a_NB + g_N) and the tilt is the reference's roll = atan2(f_y, f_z),
pitch = atan2(-f_x, 9.81) (SPEC §4).

Every function here is plain float arithmetic: ``kernels/attitude.py`` compiles their own code
(:func:`complementary_step` and its callees) with numba, so a single run, a fleet and a call
from Python run one formula.
"""

import math

from quad_drake.conventions import GRAVITY
from quad_drake.models.rotations import euler_from_quat, quat_from_euler_tuple, quat_product, wrap_to_pi

VARIANTS = ("nonlinear", "small_angle")


def accel_roll_pitch(f_B, reference_accelerometer=False) -> tuple[float, float]:
    """(roll, pitch) in rad that gravity alone would produce from the specific force f_B (m/s^2, FRD).

    With ``reference_accelerometer`` f_B is the reference's reading and the formulas are its own.
    """
    fx, fy, fz = float(f_B[0]), float(f_B[1]), float(f_B[2])
    if reference_accelerometer:
        return math.atan2(fy, fz), math.atan2(-fx, GRAVITY)
    return math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))


def integrate_euler_exact(roll, pitch, yaw, w_B, dt) -> tuple[float, float, float]:
    """ZYX angles (rad) after rotating for dt s at the constant body rate w_B (rad/s).

    q(roll, pitch, yaw) * exp(w_B dt / 2), then extracted; the same result as
    ``rotations.quat_integrate_body_rate`` (its test reference) in scalar arithmetic.
    """
    wx, wy, wz = float(w_B[0]), float(w_B[1]), float(w_B[2])
    rate = math.sqrt(wx * wx + wy * wy + wz * wz)
    s = math.sin(0.5 * rate * dt) / rate if rate > 1e-12 else 0.5 * dt
    increment = (math.cos(0.5 * rate * dt), wx * s, wy * s, wz * s)
    return euler_from_quat(quat_product(quat_from_euler_tuple(roll, pitch, yaw), increment))


def complementary_update(
    roll, pitch, yaw, f_B, w_B, dt, tau, variant, reference_accelerometer=False
) -> tuple[float, float, float]:
    """One filter step: integrate the gyro over dt, then blend roll/pitch with the accelerometer.

    roll, pitch, yaw: prior ZYX angles, rad. f_B: specific force, m/s^2 (FRD). w_B: gyro
    w_NB_B, rad/s. dt: step, s. tau: blend time constant, s. variant: ``"small_angle"``
    (angles += dt * body rates, as shipped by the reference) or ``"nonlinear"`` (exact
    quaternion integration of the constant body rate). Returns (roll, pitch, yaw) in rad;
    yaw is integrated only (not blended) and wrapped to [-pi, pi). reference_accelerometer:
    f_B is the reference's reading (see :func:`accel_roll_pitch`). The step is
    :func:`complementary_step`.
    """
    return complementary_step(
        roll, pitch, yaw, f_B, w_B, dt, tau, is_nonlinear(variant), reference_accelerometer
    )


def is_nonlinear(variant) -> bool:
    """True for the ``"nonlinear"`` variant, False for ``"small_angle"``; ValueError otherwise."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown attitude filter variant {variant!r}; expected one of {VARIANTS}")
    return variant == "nonlinear"


def complementary_step(
    roll, pitch, yaw, f_B, w_B, dt, tau, nonlinear, reference_accelerometer
) -> tuple[float, float, float]:
    """:func:`complementary_update` with the variant as a bool (``nonlinear``): plain float
    arithmetic, the code the compiled attitude kernel runs (``kernels/attitude.py``)."""
    if nonlinear:
        roll_pred, pitch_pred, yaw_pred = integrate_euler_exact(roll, pitch, yaw, w_B, dt)
    else:
        roll_pred = roll + dt * float(w_B[0])
        pitch_pred = pitch + dt * float(w_B[1])
        yaw_pred = yaw + dt * float(w_B[2])
    roll_acc, pitch_acc = accel_roll_pitch(f_B, reference_accelerometer)
    gyro_weight = tau / (tau + dt)
    accel_weight = dt / (tau + dt)
    return (
        gyro_weight * roll_pred + accel_weight * roll_acc,
        gyro_weight * pitch_pred + accel_weight * pitch_acc,
        wrap_to_pi(yaw_pred),
    )
