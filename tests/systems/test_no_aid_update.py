"""A replay's no-aiding samples (PX4's fake position and zero velocity while not GPS-aided) reach
the estimators on their own input with their own std (``systems/updates.py``'s ``NoAidUpdate``,
``flightlogs.schedule.no_aid_samples``): at rest a zero velocity at 0.2 m/s, not the GPS noise
the estimator assumes (main fused them as GPS samples, at 0.3 m/s and 0.5 m, in every axis)."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from quad_drake.config import GpsParams, ImuParams, SensorsConfig, VehicleConfig
from quad_drake.conventions import GRAVITY, NO_SAMPLE_STAMP, ONBOARD_PERIOD
from quad_drake.estimation.registry import Ekf7EstimatorConfig, EskfEstimatorConfig
from quad_drake.flightlogs.reader import Samples
from quad_drake.flightlogs.schedule import NoAidNoise, RestTest, no_aid_samples
from quad_drake.systems.estimators import build_estimator

AT_REST = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0.01, math.inf, 0.2, 0.2, 0.2]
"""One no-aiding sample at rest (p, v, their stds): PX4's fake position and zero velocity."""


def _one_sample(config, sample):
    """(P before, P after) the estimator's first tick with a no-aiding `sample` (12) fresh."""
    vehicle = VehicleConfig(
        sensors=SensorsConfig(imu=ImuParams(), gps=GpsParams(), no_aid=True), estimator=config
    )
    diagram = build_estimator(vehicle)
    context = diagram.CreateDefaultContext()
    diagram.GetInputPort("imu").FixValue(context, [0.0, 0.0, -GRAVITY, 0.0, 0.0, 0.0])
    diagram.GetInputPort("gps").FixValue(context, [0.0] * 6 + [NO_SAMPLE_STAMP])
    no_aid = diagram.GetInputPort("no_aid")
    no_aid.FixValue(context, [0.0] * 12 + [NO_SAMPLE_STAMP])
    simulator = Simulator(diagram, context)
    covariance = diagram.GetOutputPort("covariance")
    simulator.AdvanceTo(ONBOARD_PERIOD)
    k = round(math.sqrt(covariance.Eval(context).size))
    before = covariance.Eval(context).reshape(k, k).copy()
    no_aid.FixValue(context, list(sample) + [2 * ONBOARD_PERIOD])
    simulator.AdvanceTo(2 * ONBOARD_PERIOD)
    return before, covariance.Eval(context).reshape(k, k)


@pytest.mark.parametrize(
    "config",
    [EskfEstimatorConfig(init_vel_std=[1.0] * 3, init_pos_std=[1.0] * 3), Ekf7EstimatorConfig()],
    ids=["eskf", "ekf7"],
)
def test_a_sample_at_rest_is_fused_with_its_own_std_and_only_in_the_axes_it_carries(config):
    before, after = _one_sample(config, AT_REST)
    # one tick's prediction adds a little: the posterior of a scalar update with that prior
    for axis, std in ((0, 0.01), (1, 0.01), (3, 0.2), (4, 0.2), (5, 0.2)):
        prior = before[axis, axis]
        assert after[axis, axis] == pytest.approx(prior * std**2 / (prior + std**2), rel=0.05), axis
    # the height is not fused (inf): its variance moves only through its correlations
    assert after[2, 2] > 0.9 * before[2, 2]


def test_at_rest_is_a_second_without_motion_on_the_imu():
    times = np.arange(0.0, 4.0, 0.004)
    values = np.tile([0.0, 0.0, -GRAVITY, 0.0, 0.0, 0.0], (len(times), 1))
    values[(times > 2.0) & (times < 2.2), 3] = 0.2  # a roll at 0.2 rad/s (over PX4's 3°/s)
    rest = RestTest.of(Samples(times, values)).at([0.5, 1.5, 2.1, 2.9, 3.3])
    np.testing.assert_array_equal(rest, [False, True, False, False, True])


def test_at_rest_also_needs_the_logs_land_detector_to_say_landed_where_it_has_one():
    times = np.arange(0.0, 4.0, 0.004)
    imu = Samples(times, np.tile([0.0, 0.0, -GRAVITY, 0.0, 0.0, 0.0], (len(times), 1)))
    landed = Samples(np.array([2.0, 3.0]), np.array([[1.0], [0.0]]))  # in the air from 3 s
    checked = [0.5, 1.5, 2.9, 3.0, 3.3]  # 1.5: before the detector's first sample, its first value
    np.testing.assert_array_equal(RestTest.of(imu).at(checked), [False, True, True, True, True])
    np.testing.assert_array_equal(RestTest.of(imu, landed).at(checked), [False, True, True, False, False])


def test_no_aid_samples_carry_pxs_std_at_rest_and_in_flight():
    times = np.arange(0.0, 4.0, 0.004)
    values = np.tile([0.0, 0.0, -GRAVITY, 0.0, 0.0, 0.0], (len(times), 1))
    values[times > 2.0, 3] = 0.2  # turning from 2 s on: not at rest
    samples = no_aid_samples(RestTest.of(Samples(times, values)), [1.5, 3.0], NoAidNoise(10.0, 0.01, 0.2))
    np.testing.assert_array_equal(samples.values[:, 0:6], 0.0)
    np.testing.assert_array_equal(samples.values[0, 6:], [0.01, 0.01, math.inf, 0.2, 0.2, 0.2])
    np.testing.assert_array_equal(samples.values[1, 6:], [10.0, 10.0, math.inf] + [math.inf] * 3)


def test_a_scenario_cannot_carry_no_aiding_samples():
    from quad_drake.config.errors import ConfigError
    from quad_drake.running import catalog

    with pytest.raises(ConfigError, match="sensors.no_aid: only a flight log's replay"):
        catalog.load("11_gps_update", None, ["vehicles.0.sensors.no_aid=true"])
