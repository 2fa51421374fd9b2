"""The barometer and the 3-axis magnetometer (issue 32): ports, stamps, zero-noise exactness,
seeded noise statistics, the compiled kernel against the pure model, and the wiring in a flight."""

import math
from pathlib import Path

import numpy as np
import pytest
from pydrake.common import RandomDistribution, RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, RandomSource

from quad_drake.config.errors import ConfigError
from quad_drake.config.loader import load_scenario
from quad_drake.config.schema import BaroParams, MagParams
from quad_drake.conventions import NO_SAMPLE_STAMP, SLOW_SENSOR_OFFSET
from quad_drake.kernels import sensors as sensor_kernels
from quad_drake.models import sensor_models
from quad_drake.models.rotations import quat_from_euler, rotation_from_quat
from quad_drake.systems.sensors import Barometer, Magnetometer

ELEVEN = Path(__file__).resolve().parents[2] / "scenarios" / "11_gps_update.yaml"
STATE = np.concatenate(
    ([1.0, -2.0, -3.0], quat_from_euler(0.3, -0.2, 1.1), [0.5, -0.25, 0.1], [0.2, -0.1, 0.05])
)


def _build(dut, seed=None, noise=None, state=STATE, log_period=None):
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
    logger = LogVectorOutput(dut.get_output_port(0), builder, log_period) if log_period else None
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.GetInputPort("state").FixValue(context, state)
    if noise is not None:
        diagram.GetInputPort("noise").FixValue(context, noise)
    else:
        diagram.SetRandomContext(context, RandomGenerator(seed))
    simulator.Initialize()
    return simulator, logger


def _output(simulator, dut, t):
    simulator.AdvanceTo(t)
    return dut.get_output_port(0).Eval(dut.GetMyContextFromRoot(simulator.get_context())).copy()


# ----- barometer -------------------------------------------------------------------------------


def test_barometer_ports_and_stamps_at_multiples_of_its_period():
    params = BaroParams(height_std=0.0, bias=0.4, bias_walk_std=0.0)
    dut = Barometer(params)
    assert (dut.noise_size, dut.noise_period) == (2, 0.02)
    assert dut.GetInputPort("noise").size() == 2 and dut.GetOutputPort("baro").size() == 2
    assert not dut.HasAnyDirectFeedthrough()
    simulator, _ = _build(dut, noise=np.array([3.0, -2.0]))
    np.testing.assert_array_equal(_output(simulator, dut, 0.0), [0.0, NO_SAMPLE_STAMP])
    np.testing.assert_array_equal(_output(simulator, dut, 0.02), [0.0, NO_SAMPLE_STAMP])  # not yet
    # noise-free: -z + bias, stamped with the nominal time k * period
    np.testing.assert_allclose(
        _output(simulator, dut, 0.02 + 2 * SLOW_SENSOR_OFFSET), [3.0 + 0.4, 0.02], atol=1e-15
    )
    np.testing.assert_allclose(_output(simulator, dut, 0.1 + 2 * SLOW_SENSOR_OFFSET), [3.4, 0.1], atol=1e-15)


def test_barometer_ground_effect_fades_to_zero_at_its_height():
    params = BaroParams(height_std=0.0, bias_walk_std=0.0, ground_effect_height=0.5, ground_effect_error=-0.2)
    for z, expected in ((0.0, -0.2), (-0.25, -0.1), (-0.5, 0.0), (-1.0, 0.0), (0.3, -0.2)):
        assert sensor_models.baro_ground_effect(z, params) == pytest.approx(expected, abs=1e-15)
    assert sensor_models.baro_ground_effect(-0.1, BaroParams(ground_effect_error=-0.2)) == 0.0  # off
    state = STATE.copy()
    state[2] = -0.25
    dut = Barometer(params)
    simulator, _ = _build(dut, noise=np.zeros(2), state=state)
    assert _output(simulator, dut, 0.021)[0] == pytest.approx(0.25 - 0.1, abs=1e-15)
    # measured from the room's floor (z_bounds[1]), here 1 m below the datum
    dut = Barometer(params, floor_z=1.0)
    state[2] = 0.75
    simulator, _ = _build(dut, noise=np.zeros(2), state=state)
    assert _output(simulator, dut, 0.021)[0] == pytest.approx(-0.75 - 0.1, abs=1e-15)


def test_barometer_noise_and_bias_walk_statistics():
    params = BaroParams(height_std=0.3, bias=0.0, bias_walk_std=0.05)
    dut = Barometer(params)
    simulator, logger = _build(dut, seed=11, log_period=0.02)
    simulator.AdvanceTo(40.0)
    log = logger.FindLog(simulator.get_context())
    data = log.data()
    fresh = np.flatnonzero(np.diff(data[1]) != 0) + 1
    samples = data[0, fresh] - 3.0  # height - truth = bias + noise
    assert len(samples) > 1900
    increments = np.diff(samples)  # walk step + difference of two white draws: var = 0.05^2 + 2 * 0.3^2
    expected = math.sqrt(0.05**2 + 2 * 0.3**2)
    assert np.std(increments) == pytest.approx(expected, rel=4 / math.sqrt(2 * len(increments)))
    # the walk: the lag-1 autocovariance of the increments is -height_std^2 (the walk adds none)
    lag1 = np.mean((increments[1:] - increments.mean()) * (increments[:-1] - increments.mean()))
    assert lag1 == pytest.approx(-(0.3**2), abs=4 * 0.2 / math.sqrt(len(increments)))


# ----- 3-axis magnetometer ---------------------------------------------------------------------


def test_three_axis_magnetometer_reads_the_rotated_world_field_plus_hard_iron():
    params = MagParams(
        three_axis=True, hard_iron=[0.05, -0.02, 0.01], field_std=[0.0, 0.0, 0.0], declination=0.3
    )
    dut = Magnetometer(params)
    assert (dut.noise_size, dut.GetOutputPort("mag").size()) == (3, 4)
    simulator, _ = _build(dut, noise=np.array([1.0, 2.0, 3.0]))
    out = _output(simulator, dut, 0.008 + 2 * SLOW_SENSOR_OFFSET)
    m_N = sensor_models.world_field(0.5, 0.3, 1.1)
    expected = rotation_from_quat(STATE[3:7]).T @ m_N + [0.05, -0.02, 0.01]
    np.testing.assert_allclose(out, list(expected) + [0.008], atol=1e-15)
    assert np.linalg.norm(m_N) == pytest.approx(0.5)
    assert m_N[2] == pytest.approx(0.5 * math.sin(1.1))  # down: the northern hemisphere's dip


def test_three_axis_noise_statistics_per_axis():
    std = [0.01, 0.02, 0.005]
    dut = Magnetometer(MagParams(three_axis=True, field_std=std))
    simulator, logger = _build(dut, seed=4, log_period=0.01)
    simulator.AdvanceTo(20.0)
    data = logger.FindLog(simulator.get_context()).data()
    fresh = np.flatnonzero(np.diff(data[3]) != 0) + 1
    truth = rotation_from_quat(STATE[3:7]).T @ sensor_models.world_field(0.5, 0.0, 1.1)
    errors = data[:3, fresh].T - truth
    for axis in range(3):
        assert abs(errors[:, axis].mean()) < 4 * std[axis] / math.sqrt(len(fresh))
        assert errors[:, axis].std() == pytest.approx(std[axis], rel=4 / math.sqrt(2 * len(fresh)))


def test_compiled_field_kernel_equals_the_pure_model():
    rng = np.random.default_rng(32)
    n = 7
    state = np.zeros((n, 13))
    for i in range(n):
        state[i, 3:7] = quat_from_euler(*rng.uniform(-1, 1, 3))
    noise = rng.normal(size=(n, 3))
    m_N, hard_iron, std = (0.2, -0.05, 0.45), (0.01, 0.02, -0.03), (0.01, 0.02, 0.03)
    out = np.empty((n, 4))
    sensor_kernels.magnetometer_field_samples(state, noise, m_N, hard_iron, std, 1.25, out)
    for i in range(n):
        expected = sensor_models.magnetometer_field(
            state[i, 3:7].tolist(), m_N, hard_iron, noise[i].tolist(), std
        )
        np.testing.assert_allclose(out[i, :3], expected, rtol=0, atol=1e-12)
    assert (out[:, 3] == 1.25).all()


# ----- in a flight -------------------------------------------------------------------------------


def test_a_flight_logs_baro_and_field_signals_and_their_faults(tmp_path):
    from quad_drake.running.simulation import run

    scenario = load_scenario(
        ELEVEN,
        [
            "end_time=3",
            "criteria=[]",
            "vehicles.0.flies_on=truth",
            "vehicles.0.sensors.baro={bias: 0.5, bias_walk_std: 0.0}",
            "vehicles.0.sensors.mag={three_axis: true, hard_iron: [0.1, 0, 0]}",
            "vehicles.0.faults=[{kind: baro_step, start: 1, end: 2, offset: [3.0]}, "
            "{kind: baro_outage, start: 2.5, end: 3}, "
            "{kind: mag_disturbance, start: 1, end: 2, offset: [0, 0.2, 0]}]",
        ],
    )
    result = run(scenario)
    signals = result.signals
    assert "Quad.MagYaw" not in signals
    height, z = signals["Quad.Baro.Height"], signals["Quad.Pos.Z"].values
    t = result.times
    error = height.values + z - 0.5  # minus the bias
    calm = (t > 0.2) & (t < 1.0) & height.fresh
    stepped = (t > 1.05) & (t < 2.0) & height.fresh
    assert abs(np.mean(error[calm])) < 0.05
    assert np.mean(error[stepped]) == pytest.approx(3.0, abs=0.05)
    assert not height.fresh[(t > 2.55) & (t <= 3.0)].any()  # the outage
    assert np.isnan(height.values[-1])
    field_y = signals["Quad.Mag.Y"]
    disturbed = (t > 1.05) & (t < 2.0) & field_y.fresh
    before = (t > 0.2) & (t < 1.0) & field_y.fresh
    assert np.mean(field_y.values[disturbed]) - np.mean(field_y.values[before]) == pytest.approx(
        0.2, abs=0.02
    )


@pytest.mark.parametrize(
    "faults, expected",
    [
        ("[{kind: mag_disturbance, start: 1, end: 2, offset: [0, 0, 1]}]", "needs a 3-axis"),
        ("[{kind: baro_step, start: 1, end: 2, offset: [1]}]", "needs a baro sensor"),
        ("[{kind: baro_outage, start: 2, end: 1}]", "must be > start"),
        ("[{kind: baro_step, start: 1, end: 2, offset: [1, 2]}]", "takes 1 values"),
    ],
)
def test_aiding_faults_are_checked(faults, expected):
    extra = [] if "needs" in expected else ["vehicles.0.sensors.baro={}"]
    with pytest.raises(ConfigError, match=expected):
        load_scenario(ELEVEN, [f"vehicles.0.faults={faults}"] + extra)


def test_mag_bias_needs_the_yaw_magnetometer_and_baro_period_the_tick():
    with pytest.raises(ConfigError, match="needs a yaw"):
        load_scenario(
            ELEVEN,
            [
                "vehicles.0.sensors.mag={three_axis: true}",
                "vehicles.0.faults=[{kind: mag_bias, start: 1, end: 2, offset: [1]}]",
            ],
        )
    with pytest.raises(ConfigError, match="sensors.baro.period"):
        load_scenario(ELEVEN, ["vehicles.0.sensors.baro={period: 0.003}"])
