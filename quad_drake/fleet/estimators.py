"""The estimator side of a GPS delay for a fleet: :class:`FleetGpsDelayCompensator`, the fleet form
of ``systems.faults.GpsDelayCompensator`` (every vector port carries the N per-vehicle vectors
vehicle-major, each in the scalar system's layout; the maths is ``fleet/estimation_kernels.py``).
The estimators themselves are sized by n in ``systems/estimators.py``.
"""

import numpy as np
from pydrake.systems.framework import LeafSystem

from quad_drake import delay_compensation
from quad_drake.conventions import (
    EKF_OFFSET,
    FAULT_LAG,
    GPS_SIZE,
    NO_SAMPLE_STAMP,
    ONBOARD_PERIOD,
    P_SLICE,
    STATE_SIZE,
    V_SLICE,
)
from quad_drake.fleet import estimation_kernels as kernels


def _reader(port):
    """``read(context)``: the value of the vector input `port` as a read-only numpy view (no copy)."""
    evaluate = port.EvalBasicVector
    return lambda context: evaluate(context).get_value()


def _tiled(vector, n):
    return np.tile(np.asarray(vector, dtype=float), n)


class FleetGpsDelayCompensator(LeafSystem):
    """N vehicles' late GPS samples moved to the present (``systems.faults.GpsDelayCompensator`` per vehicle).

    Inputs ``gps`` (N*7) and ``estimated_state`` (N*13); output ``gps`` (N*7, feedthrough): each
    sample with p and v shifted by its vehicle's odometry since its stamp, stamp kept. Books every
    ONBOARD_PERIOD at EKF_OFFSET + FAULT_LAG into a ring of ``history_capacity(max_lag)`` rows per
    vehicle. A sample without a stamp, or with a non-finite one, passes unchanged.
    """

    def __init__(self, max_lag, n):
        super().__init__()
        self._n = n
        self._capacity = delay_compensation.history_capacity(max_lag, ONBOARD_PERIOD)
        self._read_gps = _reader(self.DeclareVectorInputPort("gps", n * GPS_SIZE))
        self._read_estimate = _reader(self.DeclareVectorInputPort("estimated_state", n * STATE_SIZE))
        width = delay_compensation.HISTORY_WIDTH
        self._history = self.DeclareDiscreteState(np.full(n * self._capacity * width, np.nan))
        # per vehicle: previous p_hat, v_hat (6; NaN before the first tick), velocity step (3),
        # odometry (6), last GPS stamp read (1), as the scalar system's memory
        self._memory = self.DeclareDiscreteState(_tiled([np.nan] * 6 + [0.0] * 9 + [NO_SAMPLE_STAMP], n))
        self.DeclareVectorOutputPort(
            "gps",
            n * GPS_SIZE,
            self._calc,
            prerequisites_of_calc={self.all_input_ports_ticket(), self.xd_ticket()},
        )
        self._offset = EKF_OFFSET + FAULT_LAG
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, self._offset, self._book)

    def _estimate(self, context):
        x = self._read_estimate(context).reshape(self._n, STATE_SIZE)
        return np.concatenate((x[:, P_SLICE], x[:, V_SLICE]), axis=1)

    def _book(self, context, discrete_state):
        n = self._n
        estimate = self._estimate(context)
        stamp = self._read_gps(context).reshape(n, GPS_SIZE)[:, 6]
        memory = discrete_state.get_mutable_value(self._memory).reshape(n, 16)
        previous = np.where(np.isnan(memory[:, 0:1]), estimate, memory[:, 0:6])
        fused = (stamp != memory[:, 15]) & (stamp != NO_SAMPLE_STAMP)
        odometry, velocity_step = kernels.odometry_step(
            memory[:, 9:15], estimate, previous, memory[:, 6:9], fused, ONBOARD_PERIOD
        )
        memory[:, 0:6], memory[:, 6:9], memory[:, 9:15], memory[:, 15] = (
            estimate,
            velocity_step,
            odometry,
            stamp,
        )
        tick = round((context.get_time() - self._offset) / ONBOARD_PERIOD) * ONBOARD_PERIOD
        slot = delay_compensation.history_slot(tick, ONBOARD_PERIOD, self._capacity)
        history = discrete_state.get_mutable_value(self._history).reshape(n, self._capacity, -1)
        history[:, slot, 0] = tick
        history[:, slot, 1:] = odometry

    def _calc(self, context, output):
        n = self._n
        sample = self._read_gps(context).reshape(n, GPS_SIZE)
        out = np.array(sample)
        stamped = (sample[:, 6] != NO_SAMPLE_STAMP) & np.isfinite(sample[:, 6])
        if stamped.any():
            rows = np.flatnonzero(stamped)
            memory = context.get_discrete_state(self._memory).value().reshape(n, 16)[rows]
            now = kernels.predicted_odometry(memory[:, 9:15], memory[:, 3:6], memory[:, 6:9], ONBOARD_PERIOD)
            slots = np.rint(sample[rows, 6] / ONBOARD_PERIOD).astype(int) % self._capacity
            history = context.get_discrete_state(self._history).value().reshape(n, self._capacity, -1)
            out[rows] = kernels.compensated_gps(sample[rows], history[rows, slots], now)
        output.get_mutable_value()[:] = out.ravel()
