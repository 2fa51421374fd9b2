"""Pure: moving late GPS samples to the present with the estimator's own predicted motion.

A GPS sample measured at its stamp s reaches the estimator late, at t > s (a ``gps_delay``
fault). Fusing it as if measured now puts the estimate where the vehicle was t - s ago
(and destabilises a closed loop: 11 with a 0.2 s delay strikes the floor). The compensation
shifts the sample by the motion the estimator *predicted* over [s, t]:

    z_p' = z_p + (o_p(t) - o_p(s)),    z_v' = z_v + (o_v(t) - o_v(s)),

where o is the estimate's odometry: its position and velocity increments tick by tick with
the measurement corrections left out. The innovation formed now, z' - x_hat(t), then equals
z - (x_hat(s) + the corrections applied since s): the innovation against the past estimate
as it is known now, without counting the corrections of samples already in flight twice (a
plain z + x_hat(t) - x_hat(s) does, and diverges at 0.5 s). It is an approximation of fusing
at the measurement time (the gain uses the present covariance) that needs only the
estimate's history, so it fits every estimator that exports the ``estimated_state`` layout.

A tick's increment is the estimate's own (x_hat_k - x_hat_{k-1}) except on a tick where a
GPS sample was fused; there the correction is removed by taking the kinematic increment
(position: v_hat dt; velocity: the previous tick's velocity increment). Magnetometer
updates move the velocity only through the cross-covariance and are kept. The odometry is
stored in a ring of rows (time s, o_p (3) m, o_v (3) m/s) indexed by tick number; a sample
older than the ring passes unchanged.

The functions take one vehicle's vectors or N vehicles' rows alike (a leading axis of any
size; numpy, no per-vehicle loop): ``systems.faults.GpsDelayCompensator`` runs them for one
vehicle and for a fleet. Pure: numpy only, no pydrake.
"""

import math

import numpy as np

HISTORY_WIDTH = 7
"""A history row: time (s), odometry position (3, m, NED), odometry velocity (3, m/s, NED)."""

TIME_TOLERANCE = 1e-9
"""s; a stored row matches a stamp when their times agree to this."""


def history_capacity(max_lag, period) -> int:
    """Rows the history needs to reach `max_lag` s back at one row per `period` s."""
    return math.ceil(max_lag / period - TIME_TOLERANCE) + 2


def history_slot(time, period, capacity) -> int:
    """Ring index (0 .. capacity - 1) of the row for tick time `time` (s)."""
    return round(time / period) % capacity


def odometry_step(
    odometry, estimate, previous, previous_velocity_step, fused, period
) -> tuple[np.ndarray, np.ndarray]:
    """(odometry (..., 6), velocity step (..., 3)) after one tick of the estimator, its GPS
    correction left out.

    odometry (..., 6: o_p m, o_v m/s); estimate, previous (..., 6: p_hat m, v_hat m/s) now and one
    tick (``period`` s) before; previous_velocity_step (..., 3, m/s), the last tick's velocity
    increment; fused (...) bool: True where a GPS sample was fused in this tick.
    """
    odometry, estimate, previous = (np.asarray(a, dtype=float) for a in (odometry, estimate, previous))
    fused = np.asarray(fused, dtype=bool)[..., None]
    dp = np.where(fused, previous[..., 3:6] * period, estimate[..., 0:3] - previous[..., 0:3])
    dv = np.where(
        fused, np.asarray(previous_velocity_step, dtype=float), estimate[..., 3:6] - previous[..., 3:6]
    )
    return np.concatenate((odometry[..., 0:3] + dp, odometry[..., 3:6] + dv), axis=-1), dv


def predicted_odometry(odometry, velocity, velocity_step, period) -> np.ndarray:
    """(..., 6) odometry one tick (``period`` s) ahead, as the estimator predicts before it fuses:
    o_p += v dt, o_v += dv; velocity (..., 3) m/s, velocity_step (..., 3) m/s."""
    odometry = np.asarray(odometry, dtype=float)
    return np.concatenate(
        (odometry[..., 0:3] + np.asarray(velocity) * period, odometry[..., 3:6] + velocity_step), axis=-1
    )


def compensated_gps(sample, row_then, odometry_now) -> np.ndarray:
    """(..., 7) GPS samples (p m, v m/s, stamp s) shifted by the predicted motion since their stamps.

    row_then (..., 7): the history rows at the samples' stamps (time first); where its time does
    not match the stamp (a NaN time: no row, e.g. older than the history) the sample passes
    unchanged. odometry_now (..., 6): the odometry at the time of fusion. Stamps are kept.
    """
    sample, row_then = np.asarray(sample, dtype=float), np.asarray(row_then, dtype=float)
    match = (np.abs(row_then[..., 0] - sample[..., 6]) <= TIME_TOLERANCE)[..., None]
    out = np.array(sample)
    out[..., 0:6] = np.where(match, sample[..., 0:6] + odometry_now - row_then[..., 1:7], sample[..., 0:6])
    return out
