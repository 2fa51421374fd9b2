"""Sensor LeafSystems (SPEC §2) of n vehicles: IMU, GPS, magnetometer (yaw or 3-axis) and
barometer, thin glue over ``sensor_models`` (compiled per vehicle by ``kernels.flight`` and
``kernels.sensors`` where they tick at 500 Hz or often).

Each sensor samples in one periodic discrete update, holds its last measurement in
discrete state and publishes it through a state output port (no feedthrough). Every port
carries the n per-vehicle vectors described below concatenated vehicle-major (size n k,
vehicle j at [j k, (j + 1) k)); n defaults to 1. Noise enters through a ``noise`` input port
declared ``kGaussian``; wire it with ``RandomSource(RandomDistribution.kGaussian, n
sensor.noise_size, sensor.noise_period)`` (or a ``systems.noise.NoiseStreamSource``).
A RandomSource redraws at t = k * noise_period (an unrestricted update, which Drake
applies before the discrete updates of the same time), so the IMU sampling at exactly
t = k * ONBOARD_PERIOD and the slow sensors sampling SLOW_SENSOR_OFFSET after their
redraw each read a fresh draw.

Inputs common to all: ``state`` (13): p_NB (m), q_NB (wxyz), v_NB (m/s), w_NB_B (rad/s).
"""

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import (
    BARO_SIZE,
    GPS_SIZE,
    IMU_SIZE,
    MAG_FIELD_SIZE,
    MAG_SIZE,
    NO_SAMPLE_STAMP,
    ONBOARD_PERIOD,
    SENSOR_OFFSET,
    SLOW_SENSOR_OFFSET,
    STATE_SIZE,
)
from quad_drake.kernels import flight as kernels
from quad_drake.kernels import sensors as sensor_kernels
from quad_drake.models import sensor_models
from quad_drake.models.fidelity import PHYSICAL
from quad_drake.systems._io import discrete_group, row_reader


class _Sensor(LeafSystem):
    """Shared declarations: the ``state`` and ``noise`` inputs of n vehicles, read as (n, 13) and
    (n, noise_size) arrays (``_read_state``, ``_read_noise``)."""

    noise_distribution = RandomDistribution.kGaussian

    def __init__(self, noise_size, n):
        super().__init__()
        self._n = n
        self._read_state = row_reader(self.DeclareVectorInputPort("state", n * STATE_SIZE), n)
        noise = self.DeclareVectorInputPort("noise", n * noise_size, random_type=self.noise_distribution)
        self._read_noise = row_reader(noise, n)


class Imu(_Sensor):
    """Accelerometer + gyro sampled every ONBOARD_PERIOD from t = SENSOR_OFFSET = 0.

    Inputs: ``state`` (13); ``acceleration`` (3): a_NB, kinematic NED acceleration, m/s^2;
    ``noise`` (6, unit Gaussian): 3 accelerometer then 3 gyro; ``bias_noise`` (6, unit
    Gaussian, only when ImuParams has a bias random walk): the walk's draws, same order.
    Output ``imu`` (6): specific force f_B = R_NB^T (a_NB - g_N) (m/s^2, FRD, saturated
    per axis to +-accel_limit) and gyro w_NB_B (rad/s), each plus its bias (discrete state,
    from ImuParams.accel_bias / gyro_bias; with a walk it first steps, then is applied).
    Zero before the first sample.
    With ``fidelity.reference_accelerometer`` the first three entries are the reference's
    R_NB^T (a_NB + g_N) instead (``sensor_models.reference_accelerometer``); with
    ``fidelity.float32_estimator`` the sample is rounded to float32.
    The sample is ``sensor_models.imu_measurement``'s compiled form (``kernels.flight.imu_samples``).
    With ImuParams.delta_velocity an input ``delta_velocity`` (3, m/s, FRD: the plant's output of
    that name) replaces ``acceleration``: the accelerometer reads delta_velocity / ONBOARD_PERIOD,
    the mean specific force over the sample interval. With ImuParams.gyro_limit > 0 the gyro
    saturates at +-gyro_limit. Output ``imu_saturation`` (2): the samples so far with an
    accelerometer axis at +-accel_limit, and with a gyro axis at +-gyro_limit.
    """

    noise_size = 6
    noise_period = ONBOARD_PERIOD

    def __init__(self, params, fidelity=PHYSICAL, n=1) -> None:
        super().__init__(self.noise_size, n)
        self._params = params
        self._frozen_params, self._frozen_fidelity = kernels.frozen(params), kernels.frozen(fidelity)
        motion = "delta_velocity" if params.delta_velocity else "acceleration"
        self._read_acceleration = row_reader(self.DeclareVectorInputPort(motion, n * 3), n)
        self._output = discrete_group(self, n * IMU_SIZE, "imu")
        self._saturation = discrete_group(self, n * 2, "imu_saturation")
        bias = np.tile(sensor_models.imu_initial_bias(params), (n, 1))
        self._bias_rows = bias  # constant without a random walk
        self._read_bias_noise = None
        if sensor_models.imu_has_bias_walk(params):
            port = self.DeclareVectorInputPort(
                "bias_noise", n * self.noise_size, random_type=self.noise_distribution
            )
            self._read_bias_noise = row_reader(port, n)
            self._bias = discrete_group(self, bias.ravel())
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, SENSOR_OFFSET, self._sample)

    def _sample(self, context, discrete_state):
        n, get, bias = self._n, discrete_state.get_mutable_value, self._bias_rows
        if self._read_bias_noise is not None:
            bias = get(self._bias).reshape(n, self.noise_size)
            bias[:] = kernels.imu_bias_step(bias, self._read_bias_noise(context), self._params)
        motion = self._read_acceleration(context)  # a_NB, or the delta-velocity
        kernels.imu_samples(
            self._read_state(context),
            motion,
            self._read_noise(context),
            self._frozen_params,
            self._frozen_fidelity,
            bias,
            get(self._output).reshape(n, IMU_SIZE),
            motion,
            ONBOARD_PERIOD,
            get(self._saturation).reshape(n, 2),
        )


class Gps(_Sensor):
    """GPS position and velocity (NED) sampled at t = k * period + SLOW_SENSOR_OFFSET, k >= 1.

    Inputs: ``state`` (13); ``noise`` (9, unit Gaussian): 3 random walk, 3 position,
    3 velocity. Output ``gps`` (7): p (m), v (m/s), stamp (s) = k * period, the nominal
    time of the sample (every vehicle's the same). Before the first sample p = v = 0 and
    stamp = NO_SAMPLE_STAMP (consumers judge freshness by the stamp only). The random-walk
    position bias (m) is discrete state; the sample counter k is discrete state so stamps are
    exact multiples. With ``fidelity.float32_estimator`` p, v and the bias are rounded to float32.
    The sample is ``sensor_models.gps_measurement``'s compiled form (``kernels.flight.gps_samples``).
    """

    noise_size = 9

    def __init__(self, params, fidelity=PHYSICAL, n=1) -> None:
        super().__init__(self.noise_size, n)
        self._params = params
        self._frozen_params, self._frozen_fidelity = kernels.frozen(params), kernels.frozen(fidelity)
        self.noise_period = params.period
        initial = np.tile([0.0] * (GPS_SIZE - 1) + [NO_SAMPLE_STAMP], n)
        self._output = discrete_group(self, initial, "gps")
        self._walk = discrete_group(self, 3 * n)
        self._count = discrete_group(self, 1)
        self.DeclarePeriodicDiscreteUpdateEvent(
            params.period, params.period + SLOW_SENSOR_OFFSET, self._sample
        )

    def _sample(self, context, discrete_state):
        n, get = self._n, discrete_state.get_mutable_value
        count = get(self._count)
        count[0] += 1.0
        kernels.gps_samples(
            self._read_state(context),
            get(self._walk).reshape(n, 3),
            self._read_noise(context),
            self._frozen_params,
            self._frozen_fidelity,
            count[0] * self._params.period,
            get(self._output).reshape(n, GPS_SIZE),
        )


class Magnetometer(_Sensor):
    """Magnetometer sampled at t = first_sample_time + k * period + SLOW_SENSOR_OFFSET, k >= 0.

    Inputs: ``state`` (13); ``noise`` (unit Gaussian; 1, or 3 with ``three_axis``). Output
    ``mag``, by the model of MagParams:

    - yaw (the default, the reference's): (2) yaw (rad, wrapped to [-pi, pi)), stamp (s). The yaw
      is ``sensor_models.magnetometer_yaw``'s compiled form (``kernels.flight.magnetometer_samples``);
      with ``fidelity.float32_estimator`` it is rounded to float32.
    - ``three_axis``: (MAG_FIELD_SIZE = 4) m_B = R_NB^T m_N + hard_iron + noise (3, gauss, body
      FRD) of the world field m_N (``sensor_models.world_field``: strength, declination,
      inclination; NED), stamp (s); ``sensor_models.magnetometer_field``'s compiled form
      (``kernels.sensors.magnetometer_field_samples``).

    The stamp is first_sample_time + k * period, the nominal time of the sample (every
    vehicle's the same). Before the first sample the values are 0 and stamp = NO_SAMPLE_STAMP.
    """

    def __init__(self, params, fidelity=PHYSICAL, n=1) -> None:
        self.three_axis = bool(params.three_axis)
        self.noise_size = 3 if self.three_axis else 1
        super().__init__(self.noise_size, n)
        self._params, self._frozen_params = params, kernels.frozen(params)
        self._frozen_fidelity = kernels.frozen(fidelity)
        self.noise_period = params.period
        self.sample_size = MAG_FIELD_SIZE if self.three_axis else MAG_SIZE
        initial = np.zeros((n, self.sample_size))
        initial[:, -1] = NO_SAMPLE_STAMP
        self._output = discrete_group(self, initial.ravel(), "mag")
        self._count = discrete_group(self, 1)
        if self.three_axis:
            self._field = (
                sensor_models.world_field(params.field_strength, params.declination, params.inclination),
                tuple(float(v) for v in params.hard_iron),
                tuple(float(v) for v in params.field_std),
            )
        self.DeclarePeriodicDiscreteUpdateEvent(
            params.period, params.first_sample_time + SLOW_SENSOR_OFFSET, self._sample
        )

    def _sample(self, context, discrete_state):
        count = discrete_state.get_mutable_value(self._count)
        stamp = self._params.first_sample_time + count[0] * self._params.period
        out = discrete_state.get_mutable_value(self._output).reshape(self._n, self.sample_size)
        if self.three_axis:
            m_N, hard_iron, field_std = self._field
            sensor_kernels.magnetometer_field_samples(
                self._read_state(context), self._read_noise(context), m_N, hard_iron, field_std, stamp, out
            )
        else:
            kernels.magnetometer_samples(
                self._read_state(context),
                self._read_noise(context),
                self._frozen_params,
                self._frozen_fidelity,
                stamp,
                out,
            )
        count[0] += 1.0


class Barometer(_Sensor):
    """Barometric height of n vehicles sampled at t = k * period + SLOW_SENSOR_OFFSET, k >= 1.

    Inputs: ``state`` (13); ``noise`` (2, unit Gaussian): the bias walk's draw, then the height's.
    Output ``baro`` (BARO_SIZE = 2): height (m, up: the pressure altitude above the datum z_N =
    0) = -z_NB + bias + ground effect + height_std * n, and stamp (s) = k * period, the nominal
    time of the sample (every vehicle's the same). Before the first sample height = 0 and stamp
    = NO_SAMPLE_STAMP. The bias (m) is discrete state, starting at BaroParams.bias and stepping
    by bias_walk_std * n before each sample; the ground effect (``sensor_models.baro_ground_effect``)
    is measured from the floor at ``floor_z`` (m, NED z; the room's z_bounds[1]). The sample is
    ``sensor_models.baro_measurement`` run on the vehicles' columns
    (``kernels.sensors.baro_measurements``). The reference simulator has no barometer.
    """

    noise_size = 2

    def __init__(self, params, floor_z=0.0, n=1) -> None:
        super().__init__(self.noise_size, n)
        self._params, self._floor_z = params, float(floor_z)
        self.noise_period = params.period
        self._output = discrete_group(self, np.tile([0.0, NO_SAMPLE_STAMP], n), "baro")
        self._bias = discrete_group(self, np.full(n, float(params.bias)))
        self._count = discrete_group(self, 1)
        self.DeclarePeriodicDiscreteUpdateEvent(
            params.period, params.period + SLOW_SENSOR_OFFSET, self._sample
        )

    def _sample(self, context, discrete_state):
        count = float(discrete_state.value(self._count)[0]) + 1.0
        height, bias = sensor_kernels.baro_measurements(
            self._read_state(context)[:, 2],
            discrete_state.value(self._bias),
            self._read_noise(context),
            self._params,
            self._floor_z,
        )
        out = discrete_state.get_mutable_value(self._output).reshape(self._n, BARO_SIZE)
        out[:, 0] = height
        out[:, 1] = count * self._params.period
        discrete_state.set_value(self._bias, bias)
        discrete_state.set_value(self._count, np.array([count]))
