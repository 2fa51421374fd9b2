"""Pure: what the course hands the student ready-made, for a fleet of n vehicles at once.

The FCND estimation project gives its students a ``Quaternion`` class (``FromEuler123_RPY``,
``IntegrateBodyRate``, ``Roll/Pitch/Yaw``, ``Rotate_BtoI``) and the generic EKF ``Update``
(SPEC §4); these are their batched equivalents. Every argument carries a leading vehicle axis
(``...``): angles (n,) rad, quaternions (n, 4) wxyz (Hamilton, body FRD to world NED), vectors
(n, 3), states (n, 7), covariances (n, 7, 7). A single vehicle (no leading axis) works too.
"""

import numpy as np


def quaternion_from_euler(roll, pitch, yaw) -> np.ndarray:
    """(..., 4) wxyz quaternion of R = Rz(yaw) Ry(pitch) Rx(roll) (``FromEuler123_RPY``); rad."""
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    q = np.empty(np.shape(cr * cp * cy) + (4,))
    q[..., 0] = cr * cp * cy + sr * sp * sy
    q[..., 1] = sr * cp * cy - cr * sp * sy
    q[..., 2] = cr * sp * cy + sr * cp * sy
    q[..., 3] = cr * cp * sy - sr * sp * cy
    return q


def euler_from_quaternion(q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(roll, pitch, yaw), each (...) rad, of (..., 4) wxyz quaternions (``Roll() Pitch() Yaw()``,
    SPEC §0.1)."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = np.arctan2(2 * (y * z + w * x), w * w - x * x - y * y + z * z)
    pitch = np.arcsin(np.clip(-2 * (x * z - w * y), -1.0, 1.0))
    yaw = np.arctan2(2 * (x * y + w * z), w * w + x * x - y * y - z * z)
    return roll, pitch, yaw


def integrate_body_rate(q, gyro, dt) -> np.ndarray:
    """(..., 4) q ⊗ exp(½ ω dt): the attitude q (body to world) turned by the body rate `gyro`
    (..., 3) rad/s (FRD) held for dt s (``IntegrateBodyRate``), normalised."""
    rotation = np.asarray(gyro, dtype=float) * dt
    angle = np.linalg.norm(rotation, axis=-1)
    half = 0.5 * angle
    scale = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    q = np.asarray(q, dtype=float)
    w1, x1, y1, z1 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    w2 = np.cos(half)
    x2, y2, z2 = (rotation[..., i] * scale for i in range(3))
    out = np.empty(np.broadcast_shapes(q.shape, rotation.shape[:-1] + (4,)))
    out[..., 0] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    out[..., 1] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    out[..., 2] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
    out[..., 3] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    return out / np.sqrt(np.sum(out * out, axis=-1, keepdims=True))


def rotation_matrix(roll, pitch, yaw) -> np.ndarray:
    """(..., 3, 3) R_NB = Rz(yaw) Ry(pitch) Rx(roll), body FRD to world NED (``Rotate_BtoI``)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    R = np.empty(np.shape(cr * cp * cy) + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 0, 2] = cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy
    R[..., 1, 0], R[..., 1, 1], R[..., 1, 2] = cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy
    R[..., 2, 0], R[..., 2, 1], R[..., 2, 2] = -sp, sr * cp, cr * cp
    return R


def rotate(matrices, vectors) -> np.ndarray:
    """(..., 3) M v of (..., 3, 3) matrices and (..., 3) vectors."""
    return (np.asarray(matrices) @ np.asarray(vectors)[..., None])[..., 0]


def update(ekf_state, ekf_cov, z, H, R, z_from_x) -> tuple[np.ndarray, np.ndarray]:
    """The course's generic EKF update (``QuadEstimatorEKF::Update``, SPEC §4), n at once.

    ekf_state (n, 7), ekf_cov (n, 7, 7); z, z_from_x (n, m) the measurement and its prediction;
    H (m, 7) or (n, m, 7); R (m, m). S = H P Hᵀ + R, K = P Hᵀ S⁻¹, x + K (z − ẑ), (I − K H) P.
    Returns (ekf_state, ekf_cov), new arrays.
    """
    H = np.broadcast_to(H, ekf_cov.shape[:-2] + np.shape(H)[-2:])
    PHt = ekf_cov @ np.swapaxes(H, -1, -2)
    S = H @ PHt + R
    K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)
    state = ekf_state + rotate(K, np.asarray(z) - np.asarray(z_from_x))
    cov = ekf_cov - K @ H @ ekf_cov
    return state, cov
