"""IMU biases (ImuParams): constant biases added to every sample, random walks through a Drake random port."""

import math

import numpy as np
from pydrake.common import RandomDistribution, RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import AddRandomInputs, LogVectorOutput, RandomSource

from quad_drake.config.schema import ImuParams
from quad_drake.conventions import ONBOARD_PERIOD
from quad_drake.models import sensor_models
from quad_drake.models.rotations import quat_from_euler
from quad_drake.systems.sensors import Imu

STATE = np.concatenate(
    ([1.0, -2.0, -3.0], quat_from_euler(0.3, -0.2, 1.1), [0.5, -0.25, 0.1], [0.2, -0.1, 0.05])
)
ACCELERATION = np.array([0.4, -0.3, 0.2])
QUIET = dict(accel_std=[0.0] * 3, gyro_std=[0.0] * 3)


def test_pure_bias_is_added_before_saturation_and_walk_steps_by_std_times_noise():
    params = ImuParams(**QUIET, accel_limit=10.0)
    bias = [0.1, -0.2, -5.0, 0.01, 0.02, -0.03]
    truth = sensor_models.imu_measurement(STATE[3:7], STATE[10:13], ACCELERATION, [0.0] * 6, params)
    out = sensor_models.imu_measurement(STATE[3:7], STATE[10:13], ACCELERATION, [0.0] * 6, params, bias=bias)
    np.testing.assert_allclose(out[:2], np.array(truth[:2]) + bias[:2], atol=1e-12)
    assert out[2] == -10.0  # f_z = -9.7 - 5 saturates at the limit
    np.testing.assert_allclose(out[3:], np.array(truth[3:]) + bias[3:], atol=1e-12)
    walk = ImuParams(accel_bias_walk_std=[0.1, 0.0, 0.2], gyro_bias_walk_std=[0.0, 0.01, 0.0])
    assert not sensor_models.imu_has_bias_walk(ImuParams())
    assert sensor_models.imu_has_bias_walk(walk)
    stepped = sensor_models.imu_bias_step(bias, [1.0, 2.0, -1.0, 3.0, 2.0, 1.0], walk)
    np.testing.assert_allclose(stepped, [0.2, -0.2, -5.2, 0.01, 0.04, -0.03], atol=1e-12)


def _simulate(params, t_end, seed=0):
    builder = DiagramBuilder()
    dut = builder.AddSystem(Imu(params))
    source = builder.AddSystem(RandomSource(RandomDistribution.kGaussian, 6, ONBOARD_PERIOD))
    builder.Connect(source.get_output_port(0), dut.GetInputPort("noise"))
    if dut.HasInputPort("bias_noise"):
        walk = builder.AddSystem(RandomSource(RandomDistribution.kGaussian, 6, ONBOARD_PERIOD))
        builder.Connect(walk.get_output_port(0), dut.GetInputPort("bias_noise"))
    builder.ExportInput(dut.GetInputPort("state"), "state")
    builder.ExportInput(dut.GetInputPort("acceleration"), "acceleration")
    logger = LogVectorOutput(dut.GetOutputPort("imu"), builder, ONBOARD_PERIOD)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.GetInputPort("state").FixValue(context, STATE)
    diagram.GetInputPort("acceleration").FixValue(context, ACCELERATION)
    diagram.SetRandomContext(context, RandomGenerator(seed))
    simulator.AdvanceTo(t_end)
    return dut, logger.FindLog(context).data().T[1:]  # the samples taken at 0, 2, 4 ... ms


def test_constant_bias_shifts_every_sample_and_needs_no_extra_noise_port():
    bias = dict(accel_bias=[0.3, -0.1, 0.2], gyro_bias=[0.01, -0.02, 0.005])
    dut, samples = _simulate(ImuParams(**QUIET, **bias), 0.02)
    assert not dut.HasInputPort("bias_noise")
    truth = sensor_models.imu_measurement(
        STATE[3:7], STATE[10:13], ACCELERATION, [0.0] * 6, ImuParams(**QUIET)
    )
    expected = np.array(truth) + np.array(bias["accel_bias"] + bias["gyro_bias"])
    np.testing.assert_allclose(samples, np.tile(expected, (len(samples), 1)), atol=1e-12)


def test_bias_random_walk_variance_grows_linearly_seeded():
    std = 0.01
    params = ImuParams(**QUIET, accel_bias_walk_std=[std, 0.0, std], gyro_bias_walk_std=[0.0, std, 0.0])
    n_runs, n_samples = 40, 250
    builder = DiagramBuilder()
    builder.AddSystem(Imu(params))
    assert AddRandomInputs(ONBOARD_PERIOD, builder) == 2  # noise and bias_noise are random ports
    finals = []
    for seed in range(n_runs):
        dut, samples = _simulate(params, n_samples * ONBOARD_PERIOD - 1e-4, seed)
        finals.append(samples[-1])
    truth = sensor_models.imu_measurement(
        STATE[3:7], STATE[10:13], ACCELERATION, [0.0] * 6, ImuParams(**QUIET)
    )
    drift = np.array(finals) - truth
    np.testing.assert_array_equal(drift[:, [1, 3, 5]], 0.0)  # axes without a walk stay exact
    expected = std * math.sqrt(n_samples)  # n_samples steps of std each
    measured = np.sqrt(np.mean(drift[:, [0, 2, 4]] ** 2))
    # 120 draws of a zero-mean normal: RMS within 25 % (> 3 standard errors of an RMS estimate)
    assert abs(measured / expected - 1.0) < 0.25, (measured, expected)
