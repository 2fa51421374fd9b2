"""The estimators' IMU input over a dropout: a running mean of the finite samples to dead-reckon on.

Shared by the three estimator kernels (``attitude``, ``ekf7``, ``eskf``): each tick a vehicle's
finite IMU sample (f_B m/s^2, w_B rad/s, FRD) moves its running mean; over a non-finite sample
the estimators integrate that mean instead (``bridge_imu_row``). Shapes: imu (N, 6), hold (N,
HOLD_SIZE). Pure: numba, no pydrake.
"""

import math

import numpy as np

from quad_drake.kernels.jit import njit_cached

IMU_HOLD_TIME = 0.02
"""s: time constant of an estimator's running mean of its finite IMU samples (a 20 ms mean of
10 samples at 500 Hz: 1/sqrt(10) of one sample's noise, and the lag of a manoeuvre's rate change
is under one tick's worth). Over an IMU dropout the estimators dead-reckon with this mean, so
their attitude, velocity and position keep moving as the vehicle did before the gap."""
HOLD_SIZE = 7
"""Columns of a hold (N, HOLD_SIZE): the running mean of f_B (m/s^2) and w_B (rad/s), then 1.0
once a finite sample has started it (0.0 before)."""
IMU_FINITE, IMU_HELD, IMU_MISSING = 0, 1, 2
"""What :func:`bridge_imu_row` found: a finite sample (the mean takes it), a non-finite one with
a mean to dead-reckon on, a non-finite one before any finite sample."""


def initial_hold() -> np.ndarray:
    """One vehicle's hold before its first IMU sample (not started)."""
    return np.zeros(HOLD_SIZE)


@njit_cached
def hold_weight(dt) -> float:
    """The weight of a sample in the running mean at the filter step dt s: dt / (IMU_HOLD_TIME + dt)."""
    return dt / (IMU_HOLD_TIME + dt)


@njit_cached
def row_finite(values, i) -> bool:
    """True if every entry of row i of a 2-D array is finite (one NaN or inf makes their sum NaN or inf)."""
    total = 0.0
    for k in range(values.shape[1]):
        total += values[i, k]
    return math.isfinite(total)


@njit_cached
def bridge_imu_row(imu, hold, i, weight) -> int:
    """IMU_FINITE, IMU_HELD or IMU_MISSING for vehicle i's sample imu (N, 6); a finite sample moves
    the running mean hold (N, HOLD_SIZE) by weight (:func:`hold_weight`; the first one starts it)."""
    if row_finite(imu, i):
        started = hold[i, 6] > 0.0
        for k in range(6):
            hold[i, k] = hold[i, k] + weight * (imu[i, k] - hold[i, k]) if started else imu[i, k]
        hold[i, 6] = 1.0
        return IMU_FINITE
    return IMU_HELD if hold[i, 6] > 0.0 else IMU_MISSING
