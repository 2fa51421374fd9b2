"""Fleet LeafSystems: N vehicles of one VehicleConfig advanced at once over ``fleet.kernels``.

Each system mirrors the per-vehicle system of the same name without ``Fleet``
(``systems/plant.py``, ``sensors.py``, ``controller.py``, ``trajectory.py``): the same
ports, periods and within-tick offsets (``conventions``), every vector port carrying the N
per-vehicle vectors concatenated vehicle-major (size N k, vehicle j at [j k, (j + 1) k)),
each in the per-vehicle layout. The per-vehicle docstrings
give units and frames. Noise comes from :class:`FleetNoiseSource` (``fleet.streams``), not
from Drake's RandomSource, so the noise inputs are plain vector inputs.
"""

import copy
import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from quad_drake import faults, sensor_models
from quad_drake.conventions import (
    CONTROLLER_OFFSET,
    FAULT_LAG,
    GPS_SIZE,
    GRAVITY,
    IMU_SIZE,
    NO_SAMPLE_STAMP,
    NUM_MOTORS,
    ONBOARD_PERIOD,
    PHYSICS_PERIOD,
    PLANT_OFFSET,
    REFERENCE_SIZE,
    SENSOR_OFFSET,
    SLOW_SENSOR_OFFSET,
    STATE_SIZE,
)
from quad_drake.fidelity import PHYSICAL
from quad_drake.fleet import kernels
from quad_drake.fleet.streams import NoiseStreams, sample_index
from quad_drake.systems._io import declare_state_output
from quad_drake.systems.plant import step_plants
from quad_drake.trajectories import lookup_time


def _discrete(system, initial, output=None):
    """Declare a discrete-state group (and the state output port `output` of it); its int index."""
    index = system.DeclareDiscreteState(initial)
    if output is not None:
        declare_state_output(system, output, index, initial if isinstance(initial, int) else len(initial))
    return int(index)


def _reader(port, n, size):
    """``read(context) -> (n, size) array`` of the vector input `port`: a read-only view of the
    value (no copy; valid inside the event handler that reads it)."""
    evaluate = port.EvalBasicVector
    return lambda context: evaluate(context).get_value().reshape(n, size)


class FleetNoiseSource(LeafSystem):
    """Noise of N vehicles from :class:`~quad_drake.fleet.streams.NoiseStreams`, the fleet's
    RandomSource: output ``noise`` (N size) at time t is sample k = floor(t / period) of every
    vehicle's stream, what a RandomSource holds after its redraw at t = k period (applied before
    the discrete updates at t). Unlike RandomSource it has no state and no event: the output is a
    function of the time (cached on Drake's time ticket), so a tick neither copies nor swaps a
    noise state. A block of one simulated second is drawn, into one buffer reused from block to
    block, when a reading first needs a sample of it (``NoiseStreams.block``: in any order)."""

    def __init__(self, seeds, name, size, period, distribution):
        super().__init__()
        self.period = float(period)
        self._per_block = max(1, int(round(1.0 / self.period)))
        self._streams = NoiseStreams(seeds, name, size, distribution, self._per_block)
        self._block, self._block_index = None, -1
        self.DeclareVectorOutputPort(
            "noise", len(seeds) * int(size), self._calc, prerequisites_of_calc={self.time_ticket()}
        )

    def release_memory(self):
        """Drop the block in hand (a Python system in a Diagram is never garbage-collected:
        pydrake's C++ side keeps it alive)."""
        self._block, self._block_index = None, -1

    def _calc(self, context, output):
        block, row = divmod(sample_index(context.get_time(), self.period), self._per_block)
        if block != self._block_index:
            self._block = self._streams.block(block, out=self._block)
            self._block_index = block
        n, _, size = self._block.shape
        output.get_mutable_value().reshape(n, size)[:] = self._block[:, row]


class FleetPlant(LeafSystem):
    """N :class:`~quad_drake.systems.plant.QuadrotorPlant`: inputs ``motor_thrusts`` (N 4),
    ``motor_noise`` (N 8, uniforms); outputs ``state`` (N 13), ``acceleration`` (N 3),
    ``motor_forces`` (N 4), ``contacts`` (N 3). initial_state: (13,) for every vehicle."""

    noise_size = 2 * NUM_MOTORS
    noise_period = ONBOARD_PERIOD

    def __init__(self, params, initial_state, n, fidelity=PHYSICAL):
        super().__init__()
        self._params, self._n = copy.deepcopy(params), n
        self._frozen_params, self._frozen_fidelity = kernels.frozen(self._params), kernels.frozen(fidelity)
        initial = np.tile(np.asarray(initial_state, dtype=float), (n, 1))
        self._read_commands = _reader(
            self.DeclareVectorInputPort("motor_thrusts", n * NUM_MOTORS), n, NUM_MOTORS
        )
        self._read_noise = _reader(
            self.DeclareVectorInputPort("motor_noise", n * self.noise_size), n, self.noise_size
        )
        floor = kernels.on_floor(initial, self._params).astype(float)
        contacts = np.stack([floor, np.zeros(n), np.zeros(n)], axis=1)
        self._state = _discrete(self, initial.ravel(), "state")
        self._acceleration = _discrete(self, 3 * n, "acceleration")
        self._forces = _discrete(self, NUM_MOTORS * n, "motor_forces")
        self._started = _discrete(self, 1)
        self._contacts = _discrete(self, contacts.ravel(), "contacts")
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, PLANT_OFFSET, self._first_step)
        self.DeclarePeriodicDiscreteUpdateEvent(
            ONBOARD_PERIOD, PHYSICS_PERIOD + PLANT_OFFSET, self._second_step
        )

    def _first_step(self, context, discrete_state):
        self._step(context, discrete_state, 0)

    def _second_step(self, context, discrete_state):
        self._step(context, discrete_state, NUM_MOTORS)

    def _step(self, context, discrete_state, column):
        """One physics step of every vehicle on the noise columns column..column + 3, in place."""
        step_plants(
            discrete_state,
            (self._state, self._acceleration, self._forces, self._started, self._contacts),
            self._read_commands(context),
            self._read_noise(context),
            column,
            self._frozen_params,
            self._frozen_fidelity,
        )


class FleetImu(LeafSystem):
    """N :class:`~quad_drake.systems.sensors.Imu`: inputs ``state`` (N 13), ``acceleration``
    (N 3), ``noise`` (N 6) and, with a bias walk, ``bias_noise`` (N 6); output ``imu`` (N 6)."""

    noise_size = 6
    noise_period = ONBOARD_PERIOD

    def __init__(self, params, n, fidelity=PHYSICAL):
        super().__init__()
        self._params, self._n = params, n
        self._frozen_params, self._frozen_fidelity = kernels.frozen(params), kernels.frozen(fidelity)
        self._read_state = _reader(self.DeclareVectorInputPort("state", n * STATE_SIZE), n, STATE_SIZE)
        self._read_acceleration = _reader(self.DeclareVectorInputPort("acceleration", n * 3), n, 3)
        self._read_noise = _reader(
            self.DeclareVectorInputPort("noise", n * self.noise_size), n, self.noise_size
        )
        self._read_bias_noise = None
        if sensor_models.imu_has_bias_walk(params):
            self._read_bias_noise = _reader(
                self.DeclareVectorInputPort("bias_noise", n * self.noise_size), n, self.noise_size
            )
        self._output = _discrete(self, n * IMU_SIZE, "imu")
        self._bias = _discrete(self, np.tile(sensor_models.imu_initial_bias(params), n))
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, SENSOR_OFFSET, self._sample)

    def _sample(self, context, discrete_state):
        n = self._n
        bias = discrete_state.get_mutable_value(self._bias).reshape(n, 6)
        if self._read_bias_noise is not None:
            bias[:] = kernels.imu_bias_step(bias, self._read_bias_noise(context), self._params)
        kernels.imu_samples(
            self._read_state(context),
            self._read_acceleration(context),
            self._read_noise(context),
            self._frozen_params,
            self._frozen_fidelity,
            bias,
            discrete_state.get_mutable_value(self._output).reshape(n, IMU_SIZE),
        )


class FleetGps(LeafSystem):
    """N :class:`~quad_drake.systems.sensors.Gps`: inputs ``state`` (N 13), ``noise`` (N 9);
    output ``gps`` (N 7), every vehicle with the same stamp."""

    noise_size = 9

    def __init__(self, params, n, fidelity=PHYSICAL):
        super().__init__()
        self._params, self._n, self._fidelity = params, n, fidelity
        self.noise_period = params.period
        self._read_state = _reader(self.DeclareVectorInputPort("state", n * STATE_SIZE), n, STATE_SIZE)
        self._read_noise = _reader(
            self.DeclareVectorInputPort("noise", n * self.noise_size), n, self.noise_size
        )
        initial = np.tile([0.0] * (GPS_SIZE - 1) + [NO_SAMPLE_STAMP], n)
        self._output = _discrete(self, initial, "gps")
        self._walk = _discrete(self, 3 * n)
        self._count = _discrete(self, 1)
        self.DeclarePeriodicDiscreteUpdateEvent(
            params.period, params.period + SLOW_SENSOR_OFFSET, self._sample
        )

    def _sample(self, context, discrete_state):
        x = self._read_state(context)
        walk = discrete_state.value(self._walk).reshape(self._n, 3)
        count = float(discrete_state.value(self._count)[0]) + 1.0
        position, velocity, walk = kernels.gps_measurements(
            x[:, 0:3], x[:, 7:10], walk, self._read_noise(context), self._params, self._fidelity
        )
        stamps = np.full((self._n, 1), count * self._params.period)
        discrete_state.set_value(self._output, np.concatenate([position, velocity, stamps], axis=1).ravel())
        discrete_state.set_value(self._walk, walk.ravel())
        discrete_state.set_value(self._count, np.array([count]))


class FleetMagnetometer(LeafSystem):
    """N :class:`~quad_drake.systems.sensors.Magnetometer`: inputs ``state`` (N 13), ``noise``
    (N 1); output ``mag`` (N 2), every vehicle with the same stamp."""

    noise_size = 1

    def __init__(self, params, n, fidelity=PHYSICAL):
        super().__init__()
        self._params, self._frozen_params, self._n = params, kernels.frozen(params), n
        self._frozen_fidelity = kernels.frozen(fidelity)
        self.noise_period = params.period
        self._read_state = _reader(self.DeclareVectorInputPort("state", n * STATE_SIZE), n, STATE_SIZE)
        self._read_noise = _reader(self.DeclareVectorInputPort("noise", n), n, 1)
        self._output = _discrete(self, np.tile([0.0, NO_SAMPLE_STAMP], n), "mag")
        self._count = _discrete(self, 1)
        self.DeclarePeriodicDiscreteUpdateEvent(
            params.period, params.first_sample_time + SLOW_SENSOR_OFFSET, self._sample
        )

    def _sample(self, context, discrete_state):
        count = discrete_state.get_mutable_value(self._count)
        kernels.magnetometer_samples(
            self._read_state(context),
            self._read_noise(context),
            self._frozen_params,
            self._frozen_fidelity,
            self._params.first_sample_time + count[0] * self._params.period,
            discrete_state.get_mutable_value(self._output).reshape(self._n, 2),
        )
        count[0] += 1.0


class FleetController(LeafSystem):
    """N :class:`~quad_drake.systems.controller.CascadeController`: inputs ``state`` (N 13),
    ``reference`` (N 10); output ``motor_thrusts`` (N 4), mass g / 4 each before the first tick."""

    def __init__(self, params, n, fidelity=PHYSICAL):
        super().__init__()
        self._params, self._fidelity, self._n = kernels.frozen(params), kernels.frozen(fidelity), n
        self._read_state = _reader(self.DeclareVectorInputPort("state", n * STATE_SIZE), n, STATE_SIZE)
        self._read_reference = _reader(
            self.DeclareVectorInputPort("reference", n * REFERENCE_SIZE), n, REFERENCE_SIZE
        )
        self._integral = _discrete(self, n)
        hover = params.mass * GRAVITY / NUM_MOTORS
        self._thrusts = _discrete(self, np.full(n * NUM_MOTORS, hover), "motor_thrusts")
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, CONTROLLER_OFFSET, self._update)

    def _update(self, context, discrete_state):
        kernels.cascade_steps(
            self._read_state(context),
            self._read_reference(context),
            discrete_state.get_mutable_value(self._integral),
            ONBOARD_PERIOD,
            self._params,
            self._fidelity,
            discrete_state.get_mutable_value(self._thrusts).reshape(self._n, NUM_MOTORS),
        )


class FleetTrajectory(LeafSystem):
    """N :class:`~quad_drake.systems.trajectory.TrajectorySource` of one trajectory: output
    ``reference`` (N 10), the same sample for every vehicle."""

    def __init__(self, trajectory, n, fidelity=PHYSICAL):
        super().__init__()
        self._trajectory, self._fidelity, self._n = trajectory, fidelity, n
        self.DeclareVectorOutputPort(
            "reference", n * REFERENCE_SIZE, self._calc, prerequisites_of_calc={self.time_ticket()}
        )

    def _calc(self, context, output):
        sample = self._trajectory.sample(lookup_time(context.get_time(), self._fidelity))
        output.get_mutable_value().reshape(self._n, REFERENCE_SIZE)[:] = sample


class FleetSensorFaults(LeafSystem):
    """N :class:`~quad_drake.systems.faults.SensorFaults` of one sensor: input and output
    ``<sensor>`` (N size, a state port), on the scalar system's schedule: at
    first_sample + FAULT_LAG + k period, or with a gps_delay of D s every ONBOARD_PERIOD at
    SLOW_SENSOR_OFFSET + FAULT_LAG, queueing each new sample (after the other faults) and
    publishing it at the first tick at or after stamp + D, stamp unchanged (a queue of
    ceil(D / period) + 2 samples of N vehicles, discrete state).

    The faults are the scalar ``faults.apply_faults`` and ``faults.delay_queue_step`` run once on
    the sample's columns (each entry an (N,) array, the stamp a float): a fault's decision
    and a sample's release time depend only on its measurement time, which every vehicle of
    a fleet shares (its sensors sample together), so one queue holds every vehicle's samples.
    """

    def __init__(self, sensor, size, fault_list, period, first_sample, n):
        super().__init__()
        self._faults = faults.sample_faults(fault_list, sensor)
        self._stamped = faults.STAMPED[sensor]
        self._period, self._first_sample = float(period), float(first_sample)
        self._delay = faults.gps_delay_of(fault_list) if sensor == "gps" else 0.0
        self._n, self._size = n, size
        self._read = _reader(self.DeclareVectorInputPort(sensor, n * size), n, size)
        initial = np.zeros((n, size))
        if self._stamped:
            initial[:, -1] = NO_SAMPLE_STAMP
        self._output = _discrete(self, initial.ravel(), sensor)
        if self._delay > 0:
            self._capacity = math.ceil(self._delay / self._period) + 2
            self._pending = _discrete(self, np.full(self._capacity * n * size, np.nan))
            self._last_stamp = _discrete(self, [NO_SAMPLE_STAMP])
            self._tick_offset = SLOW_SENSOR_OFFSET + FAULT_LAG  # the GPS's offset in every tick
            self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, self._tick_offset, self._delayed)
        else:
            self.DeclarePeriodicDiscreteUpdateEvent(
                self._period, self._first_sample + FAULT_LAG, self._sample
            )

    def _columns(self, sample):
        """(N, size) samples as the list of their columns, the stamp (shared) as one float."""
        columns = list(sample.T)
        if self._stamped:
            columns[-1] = float(sample[0, -1])
        return columns

    def _rows(self, columns):
        """The inverse of :meth:`_columns`: (N, size); a float entry is every vehicle's value."""
        return np.column_stack([np.broadcast_to(c, (self._n,)) for c in columns])

    def _faulted(self, columns, time):
        return faults.apply_faults(self._faults, columns, time, self._period)

    def _sample(self, context, discrete_state):
        columns = self._columns(self._read(context))
        if self._stamped:
            time = columns[-1]
        else:
            ticks = round((context.get_time() - FAULT_LAG - self._first_sample) / self._period)
            time = self._first_sample + ticks * self._period
        discrete_state.set_value(self._output, self._rows(self._faulted(columns, time)).ravel())

    def _delayed(self, context, discrete_state):
        shape = (self._capacity, self._n, self._size)
        stored = discrete_state.value(self._pending).reshape(shape)
        pending = [self._columns(rows) for rows in stored if not np.isnan(rows[0, -1])]
        last_stamp = discrete_state.value(self._last_stamp)[0]
        now = round((context.get_time() - self._tick_offset) / ONBOARD_PERIOD) * ONBOARD_PERIOD
        due, queued, stamp = faults.delay_queue_step(
            pending,
            self._columns(self._read(context)),
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
            queue = np.full(shape, np.nan)
            for slot, entry in enumerate(queued):
                queue[slot] = self._rows(entry)
            discrete_state.set_value(self._pending, queue.ravel())
