"""Pure rotation helpers: quaternions (wxyz, Hamilton, body-to-world), ZYX Euler
angles (R_NB = Rz(yaw) Ry(pitch) Rx(roll)), yaw wrapping.

Scalar trigonometry uses ``math`` (these run inside 500 Hz handlers); every
function takes and returns plain floats or small numpy arrays.
"""

import math

import numpy as np

TWO_PI = 2.0 * math.pi


def wrap_to_pi(angle) -> float:
    """Angle wrapped into [-pi, pi), rad. The one place yaw differences are wrapped."""
    return (angle + math.pi) % TWO_PI - math.pi


def wrap_angles(a) -> np.ndarray:
    """Array version of :func:`wrap_to_pi` (its formula, elementwise): into [-pi, pi)."""
    return wrap_to_pi(a)


def euler_from_quats(q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(roll, pitch, yaw) arrays of shape (...) of a (..., 4) array of wxyz quaternions (SPEC §0.1)."""
    w, x, y, z = np.array(np.moveaxis(q, -1, 0))  # one contiguous copy: q may be a strided view
    roll = np.arctan2(2 * (y * z + w * x), w * w - x * x - y * y + z * z)
    pitch = np.arcsin(np.clip(-2 * (x * z - w * y), -1.0, 1.0))
    return roll, pitch, _yaw_of(w, x, y, z)


def yaw_from_quats(q) -> np.ndarray:
    """The yaw array (...) of a (..., 4) array of wxyz quaternions, rad: :func:`euler_from_quats`'
    yaw without its roll and pitch."""
    w, x, y, z = np.moveaxis(np.asarray(q), -1, 0)
    return _yaw_of(w, x, y, z)


def _yaw_of(w, x, y, z):
    """Yaw, rad, of quaternion components (arrays of one shape): the one yaw formula."""
    return np.arctan2(2 * (x * y + w * z), w * w + x * x - y * y - z * z)


def quat_from_euler_tuple(roll, pitch, yaw) -> tuple[float, float, float, float]:
    """Quaternion (w, x, y, z) of R = Rz(yaw) Ry(pitch) Rx(roll) as a tuple of floats; angles in rad."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def quat_from_euler(roll, pitch, yaw) -> np.ndarray:
    """Quaternion wxyz (4,) of R = Rz(yaw) Ry(pitch) Rx(roll); angles in rad."""
    return np.array(quat_from_euler_tuple(roll, pitch, yaw))


def euler_from_quat(q) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in rad of a wxyz quaternion (need not be unit)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    n2 = w * w + x * x + y * y + z * z
    roll = math.atan2(2.0 * (y * z + w * x), w * w - x * x - y * y + z * z)
    sin_pitch = max(-1.0, min(1.0, -2.0 * (x * z - w * y) / n2))
    pitch = math.asin(sin_pitch)
    yaw = math.atan2(2.0 * (x * y + w * z), w * w + x * x - y * y - z * z)
    return roll, pitch, yaw


def rotation_entries(qw, qx, qy, qz) -> tuple[float, float, float, float, float, float, float, float, float]:
    """The 9 entries of R_NB (row-major floats) of a unit wxyz quaternion: the one formula of
    :func:`rotation_from_quat`, in plain float arithmetic (the compiled kernels call it)."""
    return (
        1 - 2 * (qy * qy + qz * qz),
        2 * (qx * qy - qw * qz),
        2 * (qx * qz + qw * qy),
        2 * (qx * qy + qw * qz),
        1 - 2 * (qx * qx + qz * qz),
        2 * (qy * qz - qw * qx),
        2 * (qx * qz - qw * qy),
        2 * (qy * qz + qw * qx),
        1 - 2 * (qx * qx + qy * qy),
    )


def rotation_from_quat(q) -> np.ndarray:
    """R_NB (3x3) of a unit wxyz quaternion q_NB."""
    return np.array(rotation_entries(q[0], q[1], q[2], q[3])).reshape(3, 3)


def rotation_from_euler(roll, pitch, yaw) -> np.ndarray:
    """R_NB = Rz(yaw) Ry(pitch) Rx(roll) (3x3); angles in rad."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
            [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
            [-sp, sr * cp, cr * cp],
        ]
    )


def rotation_yaw_derivative(roll, pitch, yaw) -> np.ndarray:
    """dR_NB/dyaw (3x3) of R = Rz(yaw) Ry(pitch) Rx(roll); the EKF's R'."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [-cp * sy, -sr * sp * sy - cr * cy, -cr * sp * sy + sr * cy],
            [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
            [0.0, 0.0, 0.0],
        ]
    )


def quat_product(a, b) -> tuple[float, float, float, float]:
    """Hamilton product a (x) b of two wxyz 4-sequences, as a 4-tuple (plain float arithmetic:
    the compiled kernels call it)."""
    aw, ax, ay, az = a[0], a[1], a[2], a[3]
    bw, bx, by, bz = b[0], b[1], b[2], b[3]
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_multiply(a, b) -> np.ndarray:
    """Hamilton product a * b of wxyz quaternions, (4,) (:func:`quat_product`)."""
    return np.array(quat_product(a, b))


def quat_integrate_body_rate(q, w_B, dt) -> np.ndarray:
    """q_NB after rotating for dt s at constant body rate w_B (rad/s): q * exp(w dt / 2).

    Exact for constant w_B; the result is normalised.
    """
    wx, wy, wz = w_B[0], w_B[1], w_B[2]
    rate = math.sqrt(wx * wx + wy * wy + wz * wz)
    half_angle = 0.5 * rate * dt
    if rate > 1e-12:
        s = math.sin(half_angle) / rate
        dq = (math.cos(half_angle), wx * s, wy * s, wz * s)
    else:
        dq = (1.0, 0.5 * dt * wx, 0.5 * dt * wy, 0.5 * dt * wz)
    out = quat_multiply(q, dq)
    return out / math.sqrt(out @ out)


def skew(v) -> np.ndarray:
    """Cross-product matrix [v]x with [v]x u = v x u."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
