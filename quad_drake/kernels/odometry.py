"""The GPS delay compensation of N vehicles: ``delay_compensation``'s odometry in (N, ...) array form.

The running implementation of ``systems.faults.GpsDelayCompensator`` for one vehicle and for a
fleet: numpy over the vehicles (no per-vehicle loop; these run once a tick). The list forms of
``delay_compensation`` (``odometry_step``, ``predicted_odometry``, ``compensated_gps``) are its
reference oracles, tested against it row by row to 1e-12 (``tests/test_estimator_kernels.py``);
no simulation calls them (``tests/test_oracles.py``). Units and frames as there: p m, v m/s,
NED; a history row is (time s, odometry position (3), odometry velocity (3)). Pure: no pydrake.
"""

import numpy as np

from quad_drake.delay_compensation import TIME_TOLERANCE


def odometry_step(
    odometry, estimate, previous, previous_velocity_step, fused, period
) -> tuple[np.ndarray, np.ndarray]:
    """(odometry (N, 6), velocity step (N, 3)) after one tick (``delay_compensation.odometry_step`` per row).

    odometry, estimate, previous (N, 6: p m, v m/s); previous_velocity_step (N, 3); fused (N,) bool.
    """
    fused = fused[:, None]
    dp = np.where(fused, previous[:, 3:6] * period, estimate[:, 0:3] - previous[:, 0:3])
    dv = np.where(fused, previous_velocity_step, estimate[:, 3:6] - previous[:, 3:6])
    return np.concatenate((odometry[:, 0:3] + dp, odometry[:, 3:6] + dv), axis=1), dv


def predicted_odometry(odometry, velocity, velocity_step, period) -> np.ndarray:
    """(N, 6) odometry one tick ahead (``delay_compensation.predicted_odometry`` per row)."""
    return np.concatenate((odometry[:, 0:3] + velocity * period, odometry[:, 3:6] + velocity_step), axis=1)


def compensated_gps(sample, row_then, odometry_now) -> np.ndarray:
    """(N, 7) GPS samples shifted by the predicted motion since their stamps (``compensated_gps`` per row).

    sample (N, 7); row_then (N, 7) the history rows at the stamps (a NaN time: no row);
    odometry_now (N, 6). Rows whose history time does not match the stamp pass unchanged.
    """
    out = np.array(sample, dtype=float)
    match = np.abs(row_then[:, 0] - sample[:, 6]) <= TIME_TOLERANCE
    out[match, 0:6] = sample[match, 0:6] + odometry_now[match] - row_then[match, 1:7]
    return out
