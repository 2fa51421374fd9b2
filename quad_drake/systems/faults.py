"""Sensor fault LeafSystems: one sensor's samples after its configured faults, on the wire between
the sensor and the estimators (thin glue over the pure ``quad_drake.models.faults``), and the
estimator-side compensation of late GPS samples (``quad_drake.estimation.delay_compensation``).

The sensors stay truth + white noise; a vehicle with faults gets one ``SensorFaults`` per
faulted sensor. It fires FAULT_LAG after each sample of its sensor (conventions), so the
estimators read the faulted sample in the same tick as they would read the sensor's: a fault
system adds no delay of its own. The output is a state port (no feedthrough).
"""

import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import (
    EKF_OFFSET,
    FAULT_LAG,
    GPS_SIZE,
    NO_SAMPLE_STAMP,
    ONBOARD_PERIOD,
    P_SLICE,
    SLOW_SENSOR_OFFSET,
    STATE_SIZE,
    V_SLICE,
)
from quad_drake.estimation import delay_compensation
from quad_drake.kernels.fusion import fresh
from quad_drake.models import faults
from quad_drake.systems._io import discrete_group, row_reader


class SensorFaults(LeafSystem):
    """The samples of one sensor of n vehicles (default 1) after its faults, in the sensor's own
    layout and port name.

    ``sensor``: "imu", "gps" or "mag"; ``size``: its sample width; ``fault_list``: FaultConfig
    of the vehicle (those of other sensors are ignored); ``period`` (s) and ``first_sample``
    (s, the event time of the sensor's first sample, offset included): the sensor's schedule.
    Input ``<sensor>`` (n size) and output ``<sensor>`` (n size, state port), e.g. ``gps``, the
    n samples vehicle-major.

    Without a gps_delay it fires at first_sample + FAULT_LAG + k period and publishes the
    current sample after the single-sample faults (``faults.apply_faults``), measured at its
    stamp (GPS, magnetometer) or at its nominal sampling time (IMU). With a gps_delay of D s
    it fires every ONBOARD_PERIOD (at SLOW_SENSOR_OFFSET + FAULT_LAG), queues each new
    sample (after the other faults) and publishes it at the first tick at or after
    stamp + D, stamp unchanged; the queue is discrete state of ceil(D / period) + 2 samples
    of the n vehicles.

    The faults are the scalar ``faults.apply_faults`` and ``faults.delay_queue_step`` run once on
    the sample's entries: floats for one vehicle, each entry an (n,) array (the stamp a float) for
    several. A fault's decision and a sample's release time depend only on its measurement time,
    which the n vehicles share (their sensors sample together), so one queue holds every vehicle's
    samples.
    """

    def __init__(self, sensor, size, fault_list, period, first_sample, n=1) -> None:
        super().__init__()
        self._faults = faults.sample_faults(fault_list, sensor)
        self._stamped = faults.STAMPED[sensor]
        self._period, self._first_sample = float(period), float(first_sample)
        self._delay = faults.gps_delay_of(fault_list) if sensor == "gps" else 0.0
        self._n, self._size = n, size
        self._read = row_reader(self.DeclareVectorInputPort(sensor, n * size), n)
        initial = np.zeros((n, size))
        if self._stamped:
            initial[:, -1] = NO_SAMPLE_STAMP
        self._output = discrete_group(self, initial.ravel(), sensor)
        if self._delay > 0:
            self._capacity = math.ceil(self._delay / self._period) + 2
            self._pending = discrete_group(self, np.full(self._capacity * n * size, math.nan))
            self._last_stamp = discrete_group(self, [NO_SAMPLE_STAMP])
            self._tick_offset = SLOW_SENSOR_OFFSET + FAULT_LAG  # the GPS's offset in every tick
            self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, self._tick_offset, self._delayed)
        else:
            self.DeclarePeriodicDiscreteUpdateEvent(
                self._period, self._first_sample + FAULT_LAG, self._sample
            )

    def _entries(self, sample):
        """The (n, size) `sample` as its `size` entries: floats for n = 1, else the (n,) columns
        with the (shared) stamp as one float."""
        if self._n == 1:
            return sample[0].tolist()
        entries = list(sample.T)
        if self._stamped:
            entries[-1] = float(sample[0, -1])
        return entries

    def _rows(self, entries):
        """The inverse of :meth:`_entries`: (n, size); a float entry is every vehicle's value."""
        if self._n == 1:
            return np.array(entries, dtype=float)
        return np.column_stack([np.broadcast_to(e, (self._n,)) for e in entries])

    def _sample(self, context, discrete_state):
        entries = self._entries(self._read(context))
        if self._stamped:
            time = entries[-1]
        else:
            ticks = round((context.get_time() - FAULT_LAG - self._first_sample) / self._period)
            time = self._first_sample + ticks * self._period
        faulted = faults.apply_faults(self._faults, entries, time, self._period)
        discrete_state.set_value(self._output, self._rows(faulted).ravel())

    def _delayed(self, context, discrete_state):
        shape = (self._capacity, self._n, self._size)
        stored = discrete_state.value(self._pending).reshape(shape)
        pending = [self._entries(rows) for rows in stored if not math.isnan(rows[0, -1])]
        last_stamp = discrete_state.value(self._last_stamp)[0]
        now = round((context.get_time() - self._tick_offset) / ONBOARD_PERIOD) * ONBOARD_PERIOD
        due, queued, stamp = faults.delay_queue_step(
            pending,
            self._entries(self._read(context)),
            last_stamp,
            now,
            self._delay,
            self._capacity,
            self._faults,
            self._period,
        )
        if stamp != last_stamp:
            discrete_state.set_value(self._last_stamp, [stamp])
        if due:
            discrete_state.set_value(self._output, self._rows(due[-1]).ravel())
        if due or len(queued) != len(pending):  # the queue changed: rewrite it, else keep it as is
            queue = np.full(shape, math.nan)
            for slot, entry in enumerate(queued):
                queue[slot] = self._rows(entry).reshape(self._n, self._size)
            discrete_state.set_value(self._pending, queue.ravel())


class GpsDelayCompensator(LeafSystem):
    """n vehicles' late GPS samples moved to the present by each estimator's predicted motion since
    their stamp (``estimation/delay_compensation.py``): the estimator side of a ``gps_delay``.

    Inputs ``gps`` (n*7: p m, v m/s, stamp s; e.g. from a SensorFaults with a gps_delay) and
    ``estimated_state`` (n*13, the truth layout: p m, q wxyz, v m/s, w rad/s), vehicle-major.
    Output ``gps`` (n*7): each sample with p and v shifted by its vehicle's odometry since its
    stamp, stamp kept; a feedthrough output (its inputs come from state ports) that the estimator
    reads in the same tick; the odometry "now" is the last tick's carried one tick forward, as
    the estimator predicts before it fuses. A sample without a stamp, or with a non-finite one,
    passes unchanged.

    Every ONBOARD_PERIOD at EKF_OFFSET + FAULT_LAG (after the estimator, before the
    controller) it books the tick: the estimate's increment (the kinematic one where the GPS
    sample it just read had a new stamp, i.e. was fused) into the odometry, and the odometry
    into a ring of ``history_capacity(max_lag)`` rows per vehicle (discrete state); a sample
    more than ``max_lag`` s late passes unchanged. The maths is ``estimation/delay_compensation.py``'s
    ``odometry_step``, ``predicted_odometry`` and ``compensated_gps`` over the n vehicles' rows.
    """

    def __init__(self, max_lag, n=1):
        super().__init__()
        self._n = n
        self._capacity = delay_compensation.history_capacity(max_lag, ONBOARD_PERIOD)
        self._read_gps = row_reader(self.DeclareVectorInputPort("gps", n * GPS_SIZE), n)
        self._read_estimate = row_reader(self.DeclareVectorInputPort("estimated_state", n * STATE_SIZE), n)
        width = delay_compensation.HISTORY_WIDTH
        self._history = self.DeclareDiscreteState(np.full(n * self._capacity * width, np.nan))
        # per vehicle: previous p_hat, v_hat (6; NaN before the first tick), velocity step (3),
        # odometry (6), last GPS stamp read (1)
        self._memory = self.DeclareDiscreteState(np.tile([np.nan] * 6 + [0.0] * 9 + [NO_SAMPLE_STAMP], n))
        self.DeclareVectorOutputPort(
            "gps",
            n * GPS_SIZE,
            self._calc,
            prerequisites_of_calc={self.all_input_ports_ticket(), self.xd_ticket()},
        )
        self._offset = EKF_OFFSET + FAULT_LAG
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, self._offset, self._book)

    def _estimate(self, context):
        x = self._read_estimate(context)
        return np.concatenate((x[:, P_SLICE], x[:, V_SLICE]), axis=1)

    def _book(self, context, discrete_state):
        n = self._n
        estimate = self._estimate(context)
        stamp = self._read_gps(context)[:, 6]
        memory = discrete_state.get_mutable_value(self._memory).reshape(n, 16)
        previous = np.where(np.isnan(memory[:, 0:1]), estimate, memory[:, 0:6])
        fused = fresh(stamp, memory[:, 15])
        odometry, velocity_step = delay_compensation.odometry_step(
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
        sample = self._read_gps(context)
        out = np.array(sample)
        stamped = (sample[:, 6] != NO_SAMPLE_STAMP) & np.isfinite(sample[:, 6])
        if stamped.any():
            rows = np.flatnonzero(stamped)
            memory = context.get_discrete_state(self._memory).value().reshape(n, 16)[rows]
            now = delay_compensation.predicted_odometry(
                memory[:, 9:15], memory[:, 3:6], memory[:, 6:9], ONBOARD_PERIOD
            )
            slots = np.rint(sample[rows, 6] / ONBOARD_PERIOD).astype(int) % self._capacity
            history = context.get_discrete_state(self._history).value().reshape(n, self._capacity, -1)
            out[rows] = delay_compensation.compensated_gps(sample[rows], history[rows, slots], now)
        output.get_mutable_value()[:] = out.ravel()
