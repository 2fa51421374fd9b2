"""The complementary attitude filter of N vehicles: ``estimation.complementary``'s own code, compiled.

Each tick a vehicle's roll, pitch and yaw (rad) take :func:`quad_drake.estimation.complementary
.complementary_step` (the gyro w_B integrated over dt, roll and pitch blended with the tilt of
the specific force f_B with the weight dt / (tau + dt), yaw integrated and wrapped), the pure
function's code compiled by numba and run per vehicle on (N, ...) views of the system's ports
and state; over an IMU dropout it integrates the running mean of the IMU (``imu_hold``).

Shapes: attitude (N, 3) roll, pitch, yaw rad; f_B, w_B (N, 3) m/s^2, rad/s (FRD); imu (N, 6).
Pure: numba, no pydrake.
"""

import collections
import math

import numpy as np

from quad_drake.estimation import complementary
from quad_drake.kernels import rotations
from quad_drake.kernels.imu_hold import IMU_FINITE, IMU_MISSING, bridge_imu_row, hold_weight
from quad_drake.kernels.jit import compiled, njit_cached

Model = collections.namedtuple("Model", ["dt", "tau", "nonlinear", "reference_accelerometer"])
"""The filter's constants: dt s, the blend time constant tau s, the variant (nonlinear: True for
``"nonlinear"``, ``complementary.is_nonlinear``) and the accelerometer's sign convention."""

_step = compiled(
    complementary.complementary_step,
    integrate_euler_exact=compiled(
        complementary.integrate_euler_exact,
        quat_from_euler_tuple=rotations.quat_from_euler,
        quat_product=rotations.quat_product,
        euler_from_quat=rotations.euler_from_quat,
    ),
    accel_roll_pitch=compiled(complementary.accel_roll_pitch),
    wrap_to_pi=rotations.wrap_to_pi,
)


@njit_cached
def _update_rows(attitude, f_B, w_B, dt, tau, nonlinear, reference_accelerometer):
    out = np.empty((attitude.shape[0], 3))
    for i in range(attitude.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = _step(
            attitude[i, 0], attitude[i, 1], attitude[i, 2], (f_B[i, 0], f_B[i, 1], f_B[i, 2]),
            (w_B[i, 0], w_B[i, 1], w_B[i, 2]), dt, tau, nonlinear, reference_accelerometer,
        )  # fmt: skip
    return out


@njit_cached
def tick(attitude, rate, hold, imu, ekf_state, dt, tau, nonlinear, reference_accelerometer) -> None:
    """One tick of N attitude filters IN PLACE (``systems.estimators.ComplementaryFilter``).

    attitude (N, 3) roll, pitch, yaw rad; rate (N, 3) the gyro sample rad/s (NaN while the IMU is
    out); hold (N, imu_hold.HOLD_SIZE): updated. imu (N, 6: f_B m/s^2, w_B rad/s); ekf_state (N,
    7), whose yaw is the prior yaw: the tick's samples. dt ... reference_accelerometer: the
    fields of the filter's :class:`Model` (``tick(attitude, rate, hold, imu, ekf_state,
    *model)``: numba runs a loop over flat arguments about a third faster than over the fields
    of a namedtuple). A vehicle takes :func:`complementary_update` and its gyro sample as rate;
    over a non-finite IMU sample it takes the update with its running mean of the IMU
    (``imu_hold.IMU_HOLD_TIME``) and a NaN rate (no rate measured: the controller then commands
    no body moment); before its first finite sample it keeps its roll and pitch and takes the
    prior yaw.
    """
    weight = hold_weight(dt)
    for i in range(attitude.shape[0]):
        yaw = ekf_state[i, 6]
        status = bridge_imu_row(imu, hold, i, weight)
        for k in range(3):
            rate[i, k] = imu[i, 3 + k] if status == IMU_FINITE else math.nan
        if status == IMU_MISSING:
            attitude[i, 2] = yaw
            continue
        s = imu if status == IMU_FINITE else hold  # the sample, or the running mean
        f_B, w_B = (s[i, 0], s[i, 1], s[i, 2]), (s[i, 3], s[i, 4], s[i, 5])
        roll, pitch = attitude[i, 0], attitude[i, 1]
        attitude[i, 0], attitude[i, 1], attitude[i, 2] = _step(
            roll, pitch, yaw, f_B, w_B, dt, tau, nonlinear, reference_accelerometer
        )


def complementary_update(attitude, f_B, w_B, dt, tau, variant, reference_accelerometer=False) -> np.ndarray:
    """(N, 3) roll, pitch, yaw after one filter step from the prior ``attitude`` (N, 3), rad.

    ``complementary.complementary_update`` per row; f_B, w_B (N, 3); dt, tau s; variant
    ``"nonlinear"`` or ``"small_angle"``.
    """
    nonlinear = complementary.is_nonlinear(variant)
    return _update_rows(attitude, f_B, w_B, float(dt), float(tau), nonlinear, bool(reference_accelerometer))


def model(dt, tau, variant, reference_accelerometer=False) -> Model:
    """The :class:`Model` of the step dt s, tau s, the variant name and the accelerometer convention."""
    return Model(float(dt), float(tau), complementary.is_nonlinear(variant), bool(reference_accelerometer))


def round_to_float32(*arrays) -> None:
    """Round every entry of each float64 array IN PLACE to the nearest float32 (kept float64).

    ``Fidelity.float32_estimator``: the reference stores its attitude filter's angles
    (``rollEst``, ``pitchEst``), its last gyro sample and its EKF's state and covariance
    (``VectorXf``, ``MatrixXf``) in float, so after each 500 Hz tick they take the nearest
    float32 (SPEC §4). Any shapes: (N, 3) attitudes, (N, 7) states, (N, 7, 7) covariances.
    """
    for values in arrays:
        np.copyto(values, values.astype(np.float32))
