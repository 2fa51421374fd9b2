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

``odometry_step``, ``predicted_odometry`` and ``compensated_gps`` (one vehicle, lists of floats)
are the REFERENCE ORACLES of the running implementation, ``kernels/odometry.py`` (N vehicles,
numpy), tested against them to 1e-12; no simulation calls them (``tests/test_oracles.py``).
"""

import math

HISTORY_WIDTH = 7
"""A history row: time (s), odometry position (3, m, NED), odometry velocity (3, m/s, NED)."""

TIME_TOLERANCE = 1e-9
"""s; a stored row matches a stamp when their times agree to this."""


def history_capacity(max_lag, period):
    """Rows the history needs to reach `max_lag` s back at one row per `period` s."""
    return math.ceil(max_lag / period - TIME_TOLERANCE) + 2


def history_slot(time, period, capacity):
    """Ring index (0 .. capacity - 1) of the row for tick time `time` (s)."""
    return round(time / period) % capacity


def odometry_step(odometry, estimate, previous, previous_velocity_step, fused, period):
    """(odometry, velocity step) after one tick of the estimator, its GPS correction left out.

    odometry: 6 (o_p m, o_v m/s); estimate, previous: 6 (p_hat, v_hat) now and one tick
    (``period`` s) before; previous_velocity_step: 3 (m/s), the last tick's velocity
    increment; fused: True if a GPS sample was fused in this tick. Lists of floats.
    """
    if fused:
        dp = [previous[3 + i] * period for i in range(3)]
        dv = list(previous_velocity_step)
    else:
        dp = [estimate[i] - previous[i] for i in range(3)]
        dv = [estimate[3 + i] - previous[3 + i] for i in range(3)]
    return [odometry[i] + dp[i] for i in range(3)] + [odometry[3 + i] + dv[i] for i in range(3)], dv


def predicted_odometry(odometry, velocity, velocity_step, period):
    """The odometry one tick ahead (6), as the estimator predicts before it fuses: p += v dt, v += dv."""
    return [odometry[i] + velocity[i] * period for i in range(3)] + [
        odometry[3 + i] + velocity_step[i] for i in range(3)
    ]


def compensated_gps(sample, row_then, odometry_now):
    """The GPS sample (7: p m, v m/s, stamp s) shifted by the predicted motion since its stamp.

    ``row_then``: the history row at the sample's stamp (time first), or None; without a
    row for that time (e.g. older than the history) the sample is returned unchanged.
    ``odometry_now``: 6, the odometry at the time of fusion. The stamp is kept.
    """
    if row_then is None or not abs(row_then[0] - sample[6]) <= TIME_TOLERANCE:
        return list(sample)
    return [sample[i] + odometry_now[i] - row_then[1 + i] for i in range(6)] + [sample[6]]
