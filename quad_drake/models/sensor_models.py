"""Pure sensor models (SPEC §2): noise-free measurements and the application of noise.

Noise enters as unit-normal draws passed in by the caller; nothing here holds an RNG.
Conventions: NED world N, FRD body B, wxyz quaternion q_NB (body to world).

The accelerometer measures the physical specific force ``f_B = R_NB^T (a_NB - g_N)``
with ``g_N = (0, 0, +9.81)``, i.e. (0, 0, -9.81) when level at rest. This deliberately
differs from the reference simulator's ``R^T (a + g)`` (see DESIGN §4), which
``fidelity: reference`` switches on (:func:`reference_accelerometer`, SPEC §2).

The IMU functions work on Python scalars (they run at 500 Hz): pass sequences such as
lists, tuples or ``ndarray.tolist()`` results, and get tuples back (plain arithmetic, which
``kernels.flight`` compiles with numba and runs per vehicle).

With ``fidelity.float32_estimator`` every sample (and the GPS random walk) is rounded to
float32 once computed, as the reference stores its V3F and float samples (SPEC §2).
"""

import numpy as np

from quad_drake.conventions import GRAVITY
from quad_drake.models.dynamics import to_float32
from quad_drake.models.fidelity import PHYSICAL
from quad_drake.models.rotations import euler_from_quat, wrap_to_pi


def specific_force(q_NB, a_NB) -> tuple[float, float, float]:
    """Specific force f_B = R_NB^T (a_NB - g_N), m/s^2, body FRD (3).

    q_NB: wxyz quaternion (need not be exactly unit); a_NB: kinematic acceleration of B
    in N, expressed in N (NED), m/s^2.
    """
    return _rotate_to_body(q_NB, a_NB[0], a_NB[1], a_NB[2] - GRAVITY)


def reference_accelerometer(q_NB, a_NB) -> tuple[float, float, float]:
    """The reference simulator's accelerometer R_NB^T (a_NB + g_N), m/s^2, FRD (SPEC §2).

    (0, 0, +9.81) when level at rest; not the specific force once the body accelerates or
    tilts (at constant altitude with pitch 0.2 rad it reads ax = -3.90 m/s^2).
    """
    return _rotate_to_body(q_NB, a_NB[0], a_NB[1], a_NB[2] + GRAVITY)


def _rotate_to_body(q_NB, dx, dy, dz):
    """R_NB^T d (3) for a wxyz quaternion of any non-zero norm."""
    w, x, y, z = q_NB[0], q_NB[1], q_NB[2], q_NB[3]
    s = 2.0 / (w * w + x * x + y * y + z * z)
    # f = R^T d, with R the rotation matrix of the normalised quaternion.
    return (
        (1.0 - s * (y * y + z * z)) * dx + s * (x * y + w * z) * dy + s * (x * z - w * y) * dz,
        s * (x * y - w * z) * dx + (1.0 - s * (x * x + z * z)) * dy + s * (y * z + w * x) * dz,
        s * (x * z + w * y) * dx + s * (y * z - w * x) * dy + (1.0 - s * (x * x + y * y)) * dz,
    )


def _clamp(value, limit):
    return -limit if value < -limit else (limit if value > limit else value)


def delta_velocity_step(q_old, q_new, a_NB, dt) -> tuple[float, float, float]:
    """Body-frame delta-velocity of one physics step, m/s, FRD (3): the integral over the step of
    the specific force f_B = R_NB^T (a_NB - g_N), by the trapezoid rule on the attitude,
    dt/2 (R(q_old)^T + R(q_new)^T) (a_NB - g_N).

    q_old, q_new: wxyz quaternions at the start and the end of the step; a_NB: the step's mean
    NED acceleration (v_new - v_old)/dt, m/s^2, after the room limits (so the floor's support and
    a touchdown's impulse are in it, as is the drag); dt: s. What a real IMU integrates between
    two samples is the sum of these over its interval (``systems.plant``'s ``delta_velocity``).
    """
    dx, dy, dz = a_NB[0], a_NB[1], a_NB[2] - GRAVITY
    f0 = _rotate_to_body(q_old, dx, dy, dz)
    f1 = _rotate_to_body(q_new, dx, dy, dz)
    h = 0.5 * dt
    return (h * (f0[0] + f1[0]), h * (f0[1] + f1[1]), h * (f0[2] + f1[2]))


def imu_saturated(sample, params) -> tuple[float, float]:
    """(accelerometer, gyro) 1.0 where any axis of the IMU `sample` (6) sits at its range limit
    (ImuParams.accel_limit, gyro_limit; gyro_limit 0: never), else 0.0; a NaN sample is not."""
    a_limit, g_limit = params.accel_limit, params.gyro_limit
    accel = abs(sample[0]) >= a_limit or abs(sample[1]) >= a_limit or abs(sample[2]) >= a_limit
    gyro = g_limit > 0.0 and (
        abs(sample[3]) >= g_limit or abs(sample[4]) >= g_limit or abs(sample[5]) >= g_limit
    )
    return (1.0 if accel else 0.0, 1.0 if gyro else 0.0)


NO_IMU_BIAS = (0.0,) * 6


def imu_measurement(
    q_NB, w_NB_B, a_NB, noise, params, fidelity=PHYSICAL, bias=NO_IMU_BIAS
) -> tuple[float, ...]:
    """Noisy IMU sample (f_B (3, m/s^2), gyro (3, rad/s)): 6 floats.

    noise: 6 unit-normal draws, 3 accelerometer then 3 gyro (SPEC §0.3 order).
    bias: 6, accelerometer (m/s^2) then gyro (rad/s) bias, added with the noise.
    params: ImuParams; f_B is saturated per axis to +-accel_limit after the noise.
    fidelity: with ``reference_accelerometer`` the accelerometer part is
    :func:`reference_accelerometer` instead of :func:`specific_force`; with
    ``float32_estimator`` the six values are rounded to float32.
    """
    if fidelity.reference_accelerometer:
        f = reference_accelerometer(q_NB, a_NB)
    else:
        f = specific_force(q_NB, a_NB)
    return imu_from_specific_force(f, w_NB_B, noise, params, fidelity, bias)


def imu_from_specific_force(
    f_B, w_NB_B, noise, params, fidelity=PHYSICAL, bias=NO_IMU_BIAS
) -> tuple[float, ...]:
    """Noisy IMU sample (6) of the specific force f_B (3, m/s^2, FRD) and the body rate w_NB_B
    (3, rad/s, FRD): each plus its bias and noise (as :func:`imu_measurement`), the accelerometer
    saturated per axis to +-accel_limit and, when ImuParams.gyro_limit > 0, the gyro to
    +-gyro_limit; rounded to float32 with ``fidelity.float32_estimator``."""
    f = f_B
    sa, sg, limit = params.accel_std, params.gyro_std, params.accel_limit
    sample = (
        _clamp(f[0] + bias[0] + sa[0] * noise[0], limit),
        _clamp(f[1] + bias[1] + sa[1] * noise[1], limit),
        _clamp(f[2] + bias[2] + sa[2] * noise[2], limit),
        w_NB_B[0] + bias[3] + sg[0] * noise[3],
        w_NB_B[1] + bias[4] + sg[1] * noise[4],
        w_NB_B[2] + bias[5] + sg[2] * noise[5],
    )
    g_limit = params.gyro_limit
    if g_limit > 0.0:
        sample = (
            sample[0],
            sample[1],
            sample[2],
            _clamp(sample[3], g_limit),
            _clamp(sample[4], g_limit),
            _clamp(sample[5], g_limit),
        )
    if fidelity.float32_estimator:
        return (
            to_float32(sample[0]),
            to_float32(sample[1]),
            to_float32(sample[2]),
            to_float32(sample[3]),
            to_float32(sample[4]),
            to_float32(sample[5]),
        )
    return sample


def imu_initial_bias(params) -> list[float]:
    """The IMU bias at t = 0 (6: accelerometer m/s^2, gyro rad/s) from ImuParams."""
    return list(params.accel_bias) + list(params.gyro_bias)


def imu_has_bias_walk(params) -> bool:
    """True iff ImuParams has a non-zero bias random walk (the IMU then needs a bias noise input)."""
    return any(s > 0 for s in list(params.accel_bias_walk_std) + list(params.gyro_bias_walk_std))


def imu_bias_step(bias, noise, params) -> list[float]:
    """The IMU bias (6) after one sample's random-walk step: bias + walk_std * noise.

    noise: 6 unit-normal draws, 3 accelerometer then 3 gyro; params: ImuParams (the
    ``*_bias_walk_std`` are per sample).
    """
    walk = list(params.accel_bias_walk_std) + list(params.gyro_bias_walk_std)
    return [b + s * n for b, s, n in zip(bias, walk, noise, strict=True)]


def gps_measurement(
    p_NB, v_NB, random_walk, noise, params, fidelity=PHYSICAL
) -> tuple[list[float], list[float], list[float]]:
    """Noisy GPS sample: (position (3, m), velocity (3, m/s), new random-walk bias (3, m)), NED.

    The bias first takes its step, rw += pos_random_walk_std * n_rw, then
    position = p + rw + pos_std * n_p and velocity = v + vel_std * n_v.
    noise: 9 unit-normal draws, 3 random walk, 3 position, 3 velocity (SPEC §0.3 order).
    params: GpsParams; fidelity: with ``float32_estimator`` all three are rounded to float32.
    Returns three lists of 3 (floats, or arrays when the inputs' entries are arrays).
    """
    rw_std, pos_std, vel_std = params.pos_random_walk_std, params.pos_std, params.vel_std
    rw = [random_walk[i] + rw_std[i] * noise[i] for i in range(3)]
    position = [p_NB[i] + rw[i] + pos_std[i] * noise[3 + i] for i in range(3)]
    velocity = [v_NB[i] + vel_std[i] * noise[6 + i] for i in range(3)]
    if fidelity.float32_estimator:
        return _float32_entries(position), _float32_entries(velocity), _float32_entries(rw)
    return position, velocity, rw


def _float32_entries(values):
    """The floats (or arrays) in `values`, each rounded to float32 (as float64)."""
    return [np.float64(np.float32(value)) for value in values]


def magnetometer_yaw(q_NB, noise, params, fidelity=PHYSICAL) -> float:
    """Noisy yaw sample, rad, wrapped to [-pi, pi): yaw(q_NB) + yaw_std * noise.

    noise: one unit-normal draw; params: MagParams; fidelity: with ``float32_estimator`` the
    sample is rounded to float32.
    """
    yaw = wrap_to_pi(euler_from_quat(q_NB)[2] + params.yaw_std * noise)
    if fidelity.float32_estimator:
        return to_float32(yaw)
    return yaw


def baro_ground_effect(z_NB, params, floor_z=0.0) -> float | np.ndarray:
    """Ground-effect error of a barometer (m): ``ground_effect_error`` on the floor, fading
    linearly to 0 at ``ground_effect_height`` m above it, 0 higher up or when the height is 0.

    z_NB: the vehicle's z (m, NED, down); floor_z: the floor's z (m, NED); params: BaroParams.
    Plain arithmetic on floats or arrays (a fleet's column).
    """
    if params.ground_effect_height <= 0.0:
        return 0.0 * z_NB
    above = np.maximum(floor_z - z_NB, 0.0)  # m above the floor
    return params.ground_effect_error * np.maximum(1.0 - above / params.ground_effect_height, 0.0)


def baro_measurement(z_NB, bias, noise, params, floor_z=0.0) -> tuple[float, float]:
    """Noisy barometer sample: (height (m), new bias (m)).

    The bias first takes its random-walk step, bias += bias_walk_std * n_walk, then
    height = -z_NB + bias + ground effect (:func:`baro_ground_effect`) + height_std * n_height:
    the pressure altitude above the datum z_N = 0 (m, up). z_NB: the vehicle's z (m, NED);
    noise: 2 unit-normal draws (walk, height); params: BaroParams; floor_z: the floor's z (m,
    NED). Floats, or (N,) arrays of a fleet's columns.
    """
    bias = bias + params.bias_walk_std * noise[0]
    ground = baro_ground_effect(z_NB, params, floor_z)
    return -z_NB + bias + ground + params.height_std * noise[1], bias


def world_field(strength, declination, inclination) -> tuple[float, float, float]:
    """The world magnetic field m_N (3-tuple, gauss, NED): strength (gauss), declination (rad,
    east of true north), inclination (rad, below the horizontal, positive in the northern
    hemisphere): strength (cos I cos D, cos I sin D, sin I)."""
    horizontal = strength * float(np.cos(inclination))
    return (
        horizontal * float(np.cos(declination)),
        horizontal * float(np.sin(declination)),
        strength * float(np.sin(inclination)),
    )


def magnetometer_field(q_NB, m_N, hard_iron, noise, field_std) -> tuple[float, float, float]:
    """Noisy 3-axis magnetometer sample m_B = R_NB^T m_N + hard_iron + field_std * noise (3-tuple,
    gauss, body FRD).

    q_NB: wxyz quaternion (any non-zero norm); m_N: the world field (3, gauss, NED;
    :func:`world_field`); hard_iron: (3, gauss, body) offset; noise: 3 unit-normal draws;
    field_std: (3, gauss) per sample. Plain arithmetic (``kernels.sensors`` compiles it).
    """
    b = _rotate_to_body(q_NB, m_N[0], m_N[1], m_N[2])
    return (
        b[0] + hard_iron[0] + field_std[0] * noise[0],
        b[1] + hard_iron[1] + field_std[1] * noise[1],
        b[2] + hard_iron[2] + field_std[2] * noise[2],
    )
