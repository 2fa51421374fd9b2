"""Log-playback LeafSystem: a recorded flight's sensor samples, emitted as the simulated sensors emit
theirs, so an estimator sub-Diagram runs on them unchanged.

Thin glue over ``flightlogs.schedule`` (which schedules each sample on its first onboard tick at
or after its time and derives the yaw-only magnetometer sample); sized by n flights like every
other system.
"""

import numpy as np
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import ONBOARD_PERIOD, SENSOR_OFFSET
from quad_drake.flightlogs.schedule import output_changes
from quad_drake.systems._io import discrete_group, scalar, set_scalar


class LogPlayback(LeafSystem):
    """The samples of n recorded flights, one output port per stream of
    ``flightlogs.schedule.playback_streams``, each a state output port with the layout of the
    simulated sensor of that name, for n vehicles vehicle-major (vehicle i at [i k, (i + 1) k)):

    - ``imu`` (n*6): f_B specific force (m/s^2) and w_NB_B gyro (rad/s), FRD;
    - ``gps`` (n*7): p_N (m, NED from the first fix), v_N (m/s, NED), stamp (s);
    - ``mag`` (n*2): heading (rad, [-pi, pi)), stamp (s);
    - ``mag_field`` (n*4): body field (gauss, FRD), stamp (s);
    - ``baro`` (n*2): pressure altitude (m, up), stamp (s).

    flights: one {stream name: Stream} per vehicle (each flight's own samples and schedule, the
    same stream names in each); a single dict plays one flight (n = 1).

    One periodic update every ONBOARD_PERIOD at SENSOR_OFFSET (with the simulated IMU, before the
    attitude filter and the EKF of the same tick) writes, for every vehicle and stream with a
    sample due at tick k (t_k = k ONBOARD_PERIOD), its latest due sample. A stamp is the sample's
    own time (s since its log's first IMU sample), so consumers see each sample fresh once. Before
    a stream's first sample its output is zero with stamp NO_SAMPLE_STAMP; a sensor a log lacks
    never samples. The flights may differ in length and in each stream's sample times: all play
    on the common tick, each vehicle's samples at its own ticks, and a flight past its end emits
    nothing more. Each stream's changes over the n flights are one schedule sorted by tick
    (``schedule.output_changes``), so a tick costs a search per stream, not a loop over the vehicles; the
    tick counter k and each stream's next change are discrete state.
    """

    def __init__(self, flights):
        super().__init__()
        flights = [flights] if isinstance(flights, dict) else list(flights)
        names = list(flights[0])
        if any(list(f) != names for f in flights):
            raise ValueError("every flight of a LogPlayback needs the same streams")
        self._n = len(flights)
        per_stream = [[flight[name] for flight in flights] for name in names]  # [stream][vehicle]
        self._schedules = [output_changes(per_vehicle) for per_vehicle in per_stream]
        self._widths = [flights[0][name].width for name in names]
        self._outputs = [
            discrete_group(self, np.concatenate([s.initial() for s in per_vehicle]), name)
            for name, per_vehicle in zip(names, per_stream, strict=True)
        ]
        self._next = discrete_group(self, len(names))  # each stream's next change in its schedule
        self._tick = discrete_group(self, 1)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, SENSOR_OFFSET, self._emit)

    def _emit(self, context, discrete_state):
        tick = scalar(discrete_state, self._tick)
        due = int(tick)  # an int against the int ticks: a float would convert the whole schedule each tick
        following = discrete_state.get_mutable_value(self._next)
        for j, (ticks, vehicles, rows) in enumerate(self._schedules):
            start = int(following[j])
            if start == len(ticks) or ticks[start] > due:
                continue
            end = start + int(np.searchsorted(ticks[start:], due, side="right"))
            output = discrete_state.get_mutable_value(self._outputs[j]).reshape(self._n, self._widths[j])
            output[vehicles[start:end]] = rows[start:end]  # at most one change per vehicle and tick
            following[j] = end
        set_scalar(discrete_state, self._tick, tick + 1.0)
