"""Sensor LeafSystems (SPEC §2): IMU, GPS and magnetometer, thin glue over ``sensor_models``.

Each sensor samples in one periodic discrete update, holds its last measurement in
discrete state and publishes it through a state output port (no feedthrough). Noise
enters through a ``noise`` input port declared ``kGaussian``; wire it with
``RandomSource(RandomDistribution.kGaussian, sensor.noise_size, sensor.noise_period)``.
A RandomSource redraws at t = k * noise_period (an unrestricted update, which Drake
applies before the discrete updates of the same time), so the IMU sampling at exactly
t = k * ONBOARD_PERIOD and the slow sensors sampling SLOW_SENSOR_OFFSET after their
redraw each read a fresh draw.

Inputs common to all: ``state`` (13): p_NB (m), q_NB (wxyz), v_NB (m/s), w_NB_B (rad/s).
"""

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import LeafSystem

from quad_drake import sensor_models
from quad_drake.conventions import (
    GPS_SIZE,
    IMU_SIZE,
    NO_SAMPLE_STAMP,
    ONBOARD_PERIOD,
    SENSOR_OFFSET,
    SLOW_SENSOR_OFFSET,
    STATE_SIZE,
)
from quad_drake.fidelity import PHYSICAL
from quad_drake.fleet import kernels
from quad_drake.systems._io import entries_reader, entry_reader, row_reader, scalar, set_scalar, vector_reader


class _Sensor(LeafSystem):
    """Shared declarations: the ``state`` and ``noise`` inputs (``_state_port``, ``_noise_port``);
    each sensor makes the readers of them it uses (``systems._io``)."""

    def __init__(self, noise_size):
        super().__init__()
        self._state_port = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._noise_port = self.DeclareVectorInputPort(
            "noise", noise_size, random_type=RandomDistribution.kGaussian
        )


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
    The sample is ``sensor_models.imu_measurement``'s compiled form for one vehicle
    (``fleet.kernels.imu_samples`` with N = 1).
    """

    noise_size = 6
    noise_period = ONBOARD_PERIOD

    def __init__(self, params, fidelity=PHYSICAL):
        super().__init__(self.noise_size)
        self._params = params
        self._frozen_params, self._frozen_fidelity = kernels.frozen(params), kernels.frozen(fidelity)
        self._read_state = row_reader(self._state_port)
        self._read_noise = row_reader(self._noise_port)
        self._read_acceleration = row_reader(self.DeclareVectorInputPort("acceleration", 3))
        group = self.DeclareDiscreteState(IMU_SIZE)
        self.DeclareStateOutputPort("imu", group)
        self._output_group = int(group)
        bias = np.array(sensor_models.imu_initial_bias(params), dtype=float)
        self._bias_row = bias.reshape(1, self.noise_size)  # constant without a random walk
        self._read_bias_noise = None
        if sensor_models.imu_has_bias_walk(params):
            self._read_bias_noise = vector_reader(
                self.DeclareVectorInputPort(
                    "bias_noise", self.noise_size, random_type=RandomDistribution.kGaussian
                )
            )
            self._bias_group = int(self.DeclareDiscreteState(bias))
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, SENSOR_OFFSET, self._sample)

    def _sample(self, context, discrete_state):
        bias = self._bias_row
        if self._read_bias_noise is not None:
            step = sensor_models.imu_bias_step(
                discrete_state.value(self._bias_group).tolist(), self._read_bias_noise(context), self._params
            )
            bias = np.array(step).reshape(1, self.noise_size)
            discrete_state.set_value(self._bias_group, bias[0])
        kernels.imu_samples(
            self._read_state(context),
            self._read_acceleration(context),
            self._read_noise(context),
            self._frozen_params,
            self._frozen_fidelity,
            bias,
            discrete_state.get_mutable_value(self._output_group).reshape(1, IMU_SIZE),
        )


class Gps(_Sensor):
    """GPS position and velocity (NED) sampled at t = k * period + SLOW_SENSOR_OFFSET, k >= 1.

    Inputs: ``state`` (13); ``noise`` (9, unit Gaussian): 3 random walk, 3 position,
    3 velocity. Output ``gps`` (7): p (m), v (m/s), stamp (s) = k * period, the nominal
    time of the sample. Before the first sample p = v = 0 and stamp = NO_SAMPLE_STAMP
    (consumers judge freshness by the stamp only). The random-walk position bias (m) is
    discrete state; the sample counter k is discrete state so stamps are exact multiples.
    With ``fidelity.float32_estimator`` p, v and the bias are rounded to float32.
    """

    noise_size = 9

    def __init__(self, params, fidelity=PHYSICAL):
        super().__init__(self.noise_size)
        self._params, self._fidelity = params, fidelity
        self.noise_period = params.period
        self._read_state = vector_reader(self._state_port)
        self._read_noise = vector_reader(self._noise_port)
        initial = [0.0] * (GPS_SIZE - 1) + [NO_SAMPLE_STAMP]
        output = self.DeclareDiscreteState(initial)
        self._bias_group = int(self.DeclareDiscreteState(3))
        self._count_group = int(self.DeclareDiscreteState(1))
        self.DeclareStateOutputPort("gps", output)
        self._output_group = int(output)
        self.DeclarePeriodicDiscreteUpdateEvent(
            params.period, params.period + SLOW_SENSOR_OFFSET, self._sample
        )

    def _sample(self, context, discrete_state):
        x = self._read_state(context)
        noise = self._read_noise(context)
        bias = discrete_state.value(self._bias_group).tolist()
        count = scalar(discrete_state, self._count_group) + 1.0
        position, velocity, bias = sensor_models.gps_measurement(
            x[0:3], x[7:10], bias, noise, self._params, self._fidelity
        )
        discrete_state.set_value(
            self._output_group, np.array(position + velocity + [count * self._params.period])
        )
        discrete_state.set_value(self._bias_group, np.array(bias))
        set_scalar(discrete_state, self._count_group, count)


class Magnetometer(_Sensor):
    """Magnetometer yaw sampled at t = first_sample_time + k * period + SLOW_SENSOR_OFFSET, k >= 0.

    Inputs: ``state`` (13); ``noise`` (1, unit Gaussian). Output ``mag`` (2): yaw (rad,
    wrapped to [-pi, pi)), stamp (s) = first_sample_time + k * period, the nominal time
    of the sample. Before the first sample yaw = 0 and stamp = NO_SAMPLE_STAMP. With
    ``fidelity.float32_estimator`` the yaw is rounded to float32.
    """

    noise_size = 1

    def __init__(self, params, fidelity=PHYSICAL):
        super().__init__(self.noise_size)
        self._params, self._fidelity = params, fidelity
        self.noise_period = params.period
        output = self.DeclareDiscreteState([0.0, NO_SAMPLE_STAMP])
        self._count_group = int(self.DeclareDiscreteState(1))
        self.DeclareStateOutputPort("mag", output)
        self._output_group = int(output)
        self._read_quaternion = entries_reader(self._state_port, 3, 7)
        self._read_noise = entry_reader(self._noise_port, 0)
        self.DeclarePeriodicDiscreteUpdateEvent(
            params.period, params.first_sample_time + SLOW_SENSOR_OFFSET, self._sample
        )

    def _sample(self, context, discrete_state):
        count = scalar(discrete_state, self._count_group)
        yaw = sensor_models.magnetometer_yaw(
            self._read_quaternion(context), self._read_noise(context), self._params, self._fidelity
        )
        stamp = self._params.first_sample_time + count * self._params.period
        discrete_state.set_value(self._output_group, np.array([yaw, stamp]))
        set_scalar(discrete_state, self._count_group, count + 1.0)
