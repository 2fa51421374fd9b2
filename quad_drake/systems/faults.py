"""Sensor fault LeafSystem: one sensor's samples after its configured faults, on the wire between
the sensor and the estimators; thin glue over the pure ``quad_drake.faults``.

The sensors stay truth + white noise; a vehicle with faults gets one ``SensorFaults`` per
faulted sensor. It fires FAULT_LAG after each sample of its sensor (conventions), so the
estimators read the faulted sample in the same tick as they would read the sensor's: a fault
system adds no delay of its own. The output is a state port (no feedthrough).
"""

import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from quad_drake import faults
from quad_drake.conventions import FAULT_LAG, NO_SAMPLE_STAMP, ONBOARD_PERIOD
from quad_drake.systems._io import vector_reader


class SensorFaults(LeafSystem):
    """The samples of one sensor after its faults, in the sensor's own layout and port name.

    ``sensor``: "imu", "gps" or "mag"; ``size``: its sample width; ``fault_list``: FaultConfig
    of the vehicle (those of other sensors are ignored); ``period`` (s) and ``first_sample``
    (s, the event time of the sensor's first sample, offset included): the sensor's schedule.
    Input ``<sensor>`` (size) and output ``<sensor>`` (size, state port), e.g. ``gps``.

    Without a gps_delay it fires at first_sample + FAULT_LAG + k period and publishes the
    current sample after the single-sample faults (``faults.apply_faults``), measured at its
    stamp (GPS, magnetometer) or at its nominal sampling time (IMU). With a gps_delay of D s
    it fires every ONBOARD_PERIOD (same lag), queues each new sample (after the other faults)
    and publishes it at the first tick at or after stamp + D, stamp unchanged; the queue is
    discrete state of ceil(D / period) + 2 samples.
    """

    def __init__(self, sensor, size, fault_list, period, first_sample):
        super().__init__()
        self._faults = faults.sample_faults(fault_list, sensor)
        self._stamped = faults.STAMPED[sensor]
        self._period = float(period)
        self._first_sample = float(first_sample)
        self._delay = faults.gps_delay_of(fault_list) if sensor == "gps" else 0.0
        self._read = vector_reader(self.DeclareVectorInputPort(sensor, size))
        initial = [0.0] * size
        if self._stamped:
            initial[-1] = NO_SAMPLE_STAMP
        self._output = self.DeclareDiscreteState(np.array(initial))
        self.DeclareStateOutputPort(sensor, self._output)
        if self._delay > 0:
            self._size = size
            self._capacity = math.ceil(self._delay / self._period) + 2
            self._pending = self.DeclareDiscreteState(np.full(self._capacity * size, math.nan))
            self._last_stamp = self.DeclareDiscreteState([NO_SAMPLE_STAMP])
            self._tick_offset = (first_sample % ONBOARD_PERIOD) + FAULT_LAG
            self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, self._tick_offset, self._delayed)
        else:
            self.DeclarePeriodicDiscreteUpdateEvent(self._period, first_sample + FAULT_LAG, self._sample)

    def _faulted(self, sample, time):
        return faults.apply_faults(self._faults, sample, time, self._period)

    def _sample(self, context, discrete_state):
        sample = self._read(context)
        if self._stamped:
            time = sample[-1]
        else:
            ticks = round((context.get_time() - FAULT_LAG - self._first_sample) / self._period)
            time = self._first_sample + ticks * self._period
        discrete_state.set_value(self._output, np.array(self._faulted(sample, time)))

    def _delayed(self, context, discrete_state):
        sample = self._read(context)
        rows = discrete_state.value(self._pending).reshape(self._capacity, self._size)
        pending = [row.tolist() for row in rows if not math.isnan(row[-1])]
        stamp = sample[-1]
        if stamp != NO_SAMPLE_STAMP and stamp != discrete_state.value(self._last_stamp)[0]:
            discrete_state.set_value(self._last_stamp, [stamp])
            faulted = self._faulted(sample, stamp)
            if faulted[-1] != NO_SAMPLE_STAMP:
                pending.append(faulted)
        now = round((context.get_time() - self._tick_offset) / ONBOARD_PERIOD) * ONBOARD_PERIOD
        due, pending = faults.release_due(pending, now, self._delay)
        if due:
            discrete_state.set_value(self._output, np.array(due[-1]))
        if len(pending) > self._capacity:
            raise RuntimeError(f"gps_delay queue overflow at t = {now} s ({len(pending)} samples)")
        queue = np.full((self._capacity, self._size), math.nan)
        if pending:
            queue[: len(pending)] = pending
        discrete_state.set_value(self._pending, queue.ravel())
