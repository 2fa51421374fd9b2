"""Log-playback LeafSystem: a recorded flight's sensor samples, emitted as the simulated sensors emit
theirs, so an estimator sub-Diagram runs on them unchanged.

Thin glue over ``flightlogs.schedule`` (which schedules each sample on its first onboard tick at
or after its time and derives the yaw-only magnetometer sample).
"""

import numpy as np
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import ONBOARD_PERIOD, SENSOR_OFFSET
from quad_drake.systems._io import discrete_group, scalar, set_scalar


class LogPlayback(LeafSystem):
    """The samples of one recorded flight, one output port per stream of
    ``flightlogs.schedule.playback_streams``, each a state output port with the layout of the
    simulated sensor of that name (one vehicle):

    - ``imu`` (6): f_B specific force (m/s^2) and w_NB_B gyro (rad/s), FRD;
    - ``gps`` (7): p_N (m, NED from the first fix), v_N (m/s, NED), stamp (s);
    - ``mag`` (2): tilt-compensated heading (rad, [-pi, pi)), stamp (s);
    - ``mag_field`` (4): body field (gauss, FRD), stamp (s);
    - ``baro`` (2): pressure altitude (m, up), stamp (s).

    One periodic update every ONBOARD_PERIOD at SENSOR_OFFSET (with the simulated IMU, before the
    attitude filter and the EKF of the same tick) writes, for every stream with a sample due at
    tick k (t_k = k ONBOARD_PERIOD), its latest due sample. A stamp is the sample's own time (s
    since the log's first IMU sample), so consumers see each sample fresh once. Before a stream's
    first sample its output is zero with stamp NO_SAMPLE_STAMP; a sensor the log lacks never
    samples. The tick counter k and each stream's next sample index are discrete state.

    One log is one flight, so the system plays one vehicle (the simulated sensors' n = 1).
    """

    def __init__(self, streams):
        super().__init__()
        self._streams = list(streams.items())
        self._outputs = [discrete_group(self, stream.initial(), name) for name, stream in self._streams]
        self._next = discrete_group(self, len(self._streams))  # index of each stream's next sample
        self._tick = discrete_group(self, 1)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, SENSOR_OFFSET, self._emit)

    def _emit(self, context, discrete_state):
        tick = scalar(discrete_state, self._tick)
        following = discrete_state.get_mutable_value(self._next)
        for i, (_, stream) in enumerate(self._streams):
            start = int(following[i])
            if start == len(stream.first_tick) or stream.first_tick[start] > tick:
                continue
            due = start + int(np.searchsorted(stream.first_tick[start:], tick, side="right"))
            if due > start:
                discrete_state.set_value(self._outputs[i], stream.rows[due - 1])
                following[i] = due
        set_scalar(discrete_state, self._tick, tick + 1.0)
