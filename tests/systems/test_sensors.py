"""Sensor LeafSystems: ports, sample times and stamps, zero-noise exactness, seeded noise statistics."""

import math

import numpy as np
import pytest
from pydrake.common import RandomDistribution, RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import AddRandomInputs, LogVectorOutput, RandomSource

from quad_drake.config.schema import GpsParams, ImuParams, MagParams
from quad_drake.conventions import NO_SAMPLE_STAMP, ONBOARD_PERIOD, SENSOR_OFFSET, SLOW_SENSOR_OFFSET
from quad_drake.models import sensor_models
from quad_drake.models.rotations import quat_from_euler
from quad_drake.systems.sensors import Gps, Imu, Magnetometer

ROLL, PITCH, YAW = 0.3, -0.2, 1.1
STATE = np.concatenate(
    ([1.0, -2.0, -3.0], quat_from_euler(ROLL, PITCH, YAW), [0.5, -0.25, 0.1], [0.2, -0.1, 0.05])
)
ACCELERATION = np.array([0.4, -0.3, 0.2])


def _build(dut, seed=None, noise=None, log_period=None):
    """Diagram of dut with `state` (and `acceleration`) fixed; noise from a seeded RandomSource or fixed.

    Returns (simulator, diagram, source or None, logger or None).
    """
    builder = DiagramBuilder()
    builder.AddSystem(dut)
    source = None
    if noise is None:
        source = builder.AddSystem(
            RandomSource(RandomDistribution.kGaussian, dut.noise_size, dut.noise_period)
        )
        builder.Connect(source.get_output_port(0), dut.GetInputPort("noise"))
    else:
        builder.ExportInput(dut.GetInputPort("noise"), "noise")
    builder.ExportInput(dut.GetInputPort("state"), "state")
    if dut.HasInputPort("acceleration"):
        builder.ExportInput(dut.GetInputPort("acceleration"), "acceleration")
    logger = None
    if log_period is not None:
        logger = LogVectorOutput(dut.get_output_port(0), builder, log_period)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.GetInputPort("state").FixValue(context, STATE)
    if diagram.HasInputPort("acceleration"):
        diagram.GetInputPort("acceleration").FixValue(context, ACCELERATION)
    if noise is not None:
        diagram.GetInputPort("noise").FixValue(context, noise)
    else:
        diagram.SetRandomContext(context, RandomGenerator(seed))
    simulator.Initialize()
    return simulator, diagram, source, logger


def _random_input_count(system):
    """Number of input ports of system declared random (AddRandomInputs wires exactly those)."""
    builder = DiagramBuilder()
    builder.AddSystem(system)
    return AddRandomInputs(0.01, builder)


def _output(simulator, dut, t):
    simulator.AdvanceTo(t)
    return dut.get_output_port(0).Eval(dut.GetMyContextFromRoot(simulator.get_context())).copy()


def _noise(simulator, source):
    return source.get_output_port(0).Eval(source.GetMyContextFromRoot(simulator.get_context())).tolist()


def _check_statistics(samples, truth, std, what):
    """Per axis: exact truth where std = 0, else mean and sample std within 4 standard errors."""
    n = len(samples)
    for i, s in enumerate(std):
        column = samples[:, i]
        if s == 0.0:
            np.testing.assert_array_equal(column, truth[i], err_msg=f"{what} axis {i}")
            continue
        assert abs(column.mean() - truth[i]) < 4 * s / math.sqrt(n), f"{what} mean axis {i}"
        assert abs(column.std(ddof=1) - s) < 4 * s / math.sqrt(2 * n), f"{what} std axis {i}"


# ----- IMU ---------------------------------------------------------------------


def test_imu_ports_and_noise_wiring_attributes():
    assert _random_input_count(Imu(ImuParams())) == 1
    dut = Imu(ImuParams())
    assert [dut.get_input_port(i).get_name() for i in range(dut.num_input_ports())] == [
        "state",
        "noise",
        "acceleration",
    ]
    assert dut.GetInputPort("state").size() == 13
    assert dut.GetInputPort("acceleration").size() == 3
    assert dut.GetInputPort("noise").size() == 6
    assert dut.GetOutputPort("imu").size() == 6
    assert (dut.noise_size, dut.noise_period) == (6, ONBOARD_PERIOD)
    assert not dut.HasAnyDirectFeedthrough()


def test_imu_at_rest_level_reads_minus_g():
    dut = Imu(ImuParams(accel_std=[0.0] * 3, gyro_std=[0.0] * 3))
    simulator, diagram, _, _ = _build(dut, noise=np.full(6, 3.0))
    context = simulator.get_mutable_context()
    rest = np.zeros(13)
    rest[3] = 1.0
    diagram.GetInputPort("state").FixValue(context, rest)
    diagram.GetInputPort("acceleration").FixValue(context, np.zeros(3))
    np.testing.assert_array_equal(_output(simulator, dut, 0.01), [0, 0, -9.81, 0, 0, 0])


def test_imu_zero_noise_is_exact_truth_tilted():
    dut = Imu(ImuParams(accel_std=[0.0] * 3, gyro_std=[0.0] * 3))
    simulator, diagram, _, _ = _build(dut, noise=np.array([1.0, -2.0, 3.0, -4.0, 5.0, -6.0]))
    out = _output(simulator, dut, 0.01)
    assert np.all(np.isfinite(out))
    force = sensor_models.specific_force(STATE[3:7].tolist(), ACCELERATION.tolist())
    truth = list(force) + STATE[10:13].tolist()
    np.testing.assert_array_equal(out, truth)
    # Independent check of the physical sign: f_B = R^T (a - g).
    s_p, c_p, s_r, c_r = math.sin(PITCH), math.cos(PITCH), math.sin(ROLL), math.cos(ROLL)
    diagram.GetInputPort("acceleration").FixValue(simulator.get_mutable_context(), np.zeros(3))
    out = _output(simulator, dut, 0.02)
    np.testing.assert_allclose(out[:3], -9.81 * np.array([-s_p, s_r * c_p, c_r * c_p]), atol=1e-12)


def test_imu_samples_every_tick_from_zero_with_fresh_noise():
    params = ImuParams()
    dut = Imu(params)
    simulator, _, source, _ = _build(dut, seed=7)
    assert SENSOR_OFFSET == 0.0  # samples at t_k itself, with the noise redrawn at t_k
    previous = dut.get_output_port(0).Eval(dut.GetMyContextFromRoot(simulator.get_context())).copy()
    assert np.all(previous == 0.0)  # nothing sampled before the first step
    for k in range(4):
        t = k * ONBOARD_PERIOD
        if k > 0:
            np.testing.assert_array_equal(_output(simulator, dut, t - 0.5e-6), previous)  # held
        after = _output(simulator, dut, t + 0.5e-6)
        expected = sensor_models.imu_measurement(
            STATE[3:7].tolist(),
            STATE[10:13].tolist(),
            ACCELERATION.tolist(),
            _noise(simulator, source),
            params,
        )
        np.testing.assert_array_equal(after, expected)
        assert np.all(after != previous)
        previous = after


def test_imu_noise_statistics_20s_seeded():
    params = ImuParams(accel_std=[0.5, 0.0, 1.5], gyro_std=[0.3, 0.5, 0.0])
    dut = Imu(params)
    simulator, _, _, logger = _build(dut, seed=1234, log_period=ONBOARD_PERIOD)
    simulator.AdvanceTo(20.0)
    log = logger.FindLog(simulator.get_context())
    samples = log.data().T[1:]  # the row logged at t = 0 precedes the first sample
    assert len(samples) == 10000
    force = sensor_models.specific_force(STATE[3:7].tolist(), ACCELERATION.tolist())
    truth = list(force) + STATE[10:13].tolist()
    _check_statistics(samples, truth, params.accel_std + params.gyro_std, "imu")
    # Consecutive samples are independent draws.
    centered = samples[:, 0] - samples[:, 0].mean()
    lag1 = centered[1:] @ centered[:-1] / (centered @ centered)
    assert abs(lag1) < 4 / math.sqrt(len(samples))


def test_imu_same_seed_is_bit_identical():
    runs = []
    for seed in (5, 5, 6):
        dut = Imu(ImuParams())
        simulator, _, _, logger = _build(dut, seed=seed, log_period=ONBOARD_PERIOD)
        simulator.AdvanceTo(0.1)
        runs.append(logger.FindLog(simulator.get_context()).data())
    np.testing.assert_array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])


# ----- GPS ---------------------------------------------------------------------


def test_gps_ports_and_stamps():
    params = GpsParams()
    dut = Gps(params)
    assert dut.GetInputPort("noise").size() == 9
    assert _random_input_count(Gps(params)) == 1
    assert dut.GetOutputPort("gps").size() == 7
    assert (dut.noise_size, dut.noise_period) == (9, 0.1)
    assert not dut.HasAnyDirectFeedthrough()
    simulator, _, source, _ = _build(dut, seed=3)
    initial = _output(simulator, dut, 0.1 - 1e-4)
    np.testing.assert_array_equal(initial, [0, 0, 0, 0, 0, 0, NO_SAMPLE_STAMP])
    for k in range(1, 5):
        t = k * 0.1
        held = _output(simulator, dut, t + SLOW_SENSOR_OFFSET - 0.5e-6)
        assert held[6] == (NO_SAMPLE_STAMP if k == 1 else (k - 1) * 0.1)
        sample = _output(simulator, dut, t + SLOW_SENSOR_OFFSET + 0.5e-6)
        assert sample[6] == k * 0.1  # exact: the stamp is counter * period
        assert np.all(sample[:6] != held[:6])
        position, velocity, _ = sensor_models.gps_measurement(  # the draw made at t = k period
            STATE[0:3].tolist(), STATE[7:10].tolist(), [0.0] * 3, _noise(simulator, source), params
        )
        np.testing.assert_array_equal(sample[:6], position + velocity)


def test_gps_zero_noise_is_exact_truth():
    params = GpsParams(pos_std=[0.0] * 3, vel_std=[0.0] * 3, pos_random_walk_std=[0.0] * 3, period=0.25)
    dut = Gps(params)
    assert dut.noise_period == 0.25
    simulator, _, _, _ = _build(dut, noise=np.full(9, 2.5))
    out = _output(simulator, dut, 0.8)
    np.testing.assert_array_equal(out, np.concatenate((STATE[0:3], STATE[7:10], [0.75])))


def test_gps_noise_statistics_seeded():
    params = GpsParams(pos_std=[0.7, 0.0, 2.0], vel_std=[0.1, 0.3, 0.0])
    dut = Gps(params)
    simulator, _, _, logger = _build(dut, seed=99, log_period=params.period)
    simulator.AdvanceTo(200.0)
    data = logger.FindLog(simulator.get_context()).data().T
    samples = data[data[:, 6] >= 0]
    assert len(samples) == 1999
    assert np.all(np.diff(samples[:, 6]) > 0)  # one fresh sample per row
    truth = np.concatenate((STATE[0:3], STATE[7:10]))
    _check_statistics(samples[:, :6], truth, params.pos_std + params.vel_std, "gps")


def test_gps_random_walk_accumulates_in_state():
    """Position error is a random walk: increments iid N(0, sigma^2), error = sum of increments."""
    sigma = [0.2, 0.0, 0.4]
    params = GpsParams(pos_std=[0.0] * 3, vel_std=[0.0] * 3, pos_random_walk_std=sigma)
    dut = Gps(params)
    simulator, _, _, logger = _build(dut, seed=21, log_period=params.period)
    simulator.AdvanceTo(100.0)
    data = logger.FindLog(simulator.get_context()).data().T
    errors = data[data[:, 6] >= 0][:, 0:3] - STATE[0:3]
    increments = np.diff(np.vstack((np.zeros(3), errors)), axis=0)
    _check_statistics(increments, [0.0, 0.0, 0.0], sigma, "random-walk increment")
    np.testing.assert_array_equal(errors[:, 1], 0.0)
    assert np.max(np.abs(errors[:, 2])) > 3 * sigma[2]  # it wanders, unlike white noise


# ----- magnetometer ------------------------------------------------------------


def test_magnetometer_ports_and_stamps():
    params = MagParams()
    dut = Magnetometer(params)
    assert dut.GetInputPort("noise").size() == 1
    assert _random_input_count(Magnetometer(params)) == 1
    assert dut.GetOutputPort("mag").size() == 2
    assert (dut.noise_size, dut.noise_period) == (1, 0.01)
    assert not dut.HasAnyDirectFeedthrough()
    simulator, _, _, _ = _build(dut, seed=4)
    np.testing.assert_array_equal(
        _output(simulator, dut, 0.008 + SLOW_SENSOR_OFFSET - 0.5e-6), [0.0, NO_SAMPLE_STAMP]
    )
    for k in range(4):
        t = 0.008 + k * 0.01
        held = _output(simulator, dut, t + SLOW_SENSOR_OFFSET - 0.5e-6)
        sample = _output(simulator, dut, t + SLOW_SENSOR_OFFSET + 0.5e-6)
        assert sample[1] == 0.008 + k * 0.01
        assert sample[1] == pytest.approx(t, abs=1e-15)
        assert sample[0] != held[0]


def test_magnetometer_zero_noise_exact_and_wraps_near_pi():
    dut = Magnetometer(MagParams(yaw_std=0.0))
    simulator, _, _, _ = _build(dut, noise=np.array([4.0]))
    assert _output(simulator, dut, 0.05)[0] == pytest.approx(YAW, abs=1e-14)

    dut = Magnetometer(MagParams(yaw_std=0.1))
    simulator, diagram, _, _ = _build(dut, noise=np.array([1.0]))
    state = STATE.copy()
    state[3:7] = quat_from_euler(ROLL, PITCH, math.pi - 0.05)
    diagram.GetInputPort("state").FixValue(simulator.get_mutable_context(), state)
    assert _output(simulator, dut, 0.05)[0] == pytest.approx(-math.pi + 0.05, abs=1e-12)


def test_magnetometer_noise_statistics_seeded():
    params = MagParams(yaw_std=0.1)
    dut = Magnetometer(params)
    simulator, _, _, logger = _build(dut, seed=17, log_period=params.period)
    simulator.AdvanceTo(20.0)
    data = logger.FindLog(simulator.get_context()).data().T
    samples = data[data[:, 1] >= 0]
    assert len(samples) == 2000
    np.testing.assert_allclose(np.diff(samples[:, 1]), 0.01, atol=1e-12)
    _check_statistics(samples[:, :1], [YAW], [0.1], "mag")
