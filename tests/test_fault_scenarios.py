"""Fault scenarios 12-18: what each fault does to the flight and what its mitigation changes.

Every criterion of every bundled scenario, 12-18 included, is run at its default seed by
``test_scenarios.py``; these tests pin the mechanism behind each verdict on short runs.
"""

import numpy as np
import pytest

from quad_drake import catalog
from quad_drake.simulation import run

pytestmark = pytest.mark.slow


def _run(name, *overrides, end_time):
    return run(catalog.load(name, None, [f"end_time={end_time}", *overrides]))


def test_the_gate_rejects_the_outlier_and_accepts_the_rest():
    result = _run("13_gps_outlier", end_time=14.0)
    gated = result.signals["Quad.Est.GpsGated"].values
    assert gated[-1] == 1  # one sample rejected in 14 s: the outlier at 12.0 s
    assert np.all(gated[result.times < 12.0] == 0)
    assert result.signals["Quad.Est.E.Pos"].values.max() < 1.0
    ungated = _run("13_gps_outlier", "vehicles.0.ekf.gps_gate_sigma=0", end_time=14.0)
    assert ungated.signals["Quad.Est.GpsGated"].values[-1] == 0
    assert ungated.signals["Quad.Est.E.Pos"].values.max() > 1.0  # the 50 m sample is fused


def test_without_delay_compensation_the_late_gps_leaves_a_larger_error():
    compensated = _run("14_gps_delay", end_time=12.0)
    plain = _run("14_gps_delay", "vehicles.0.gps_delay_compensation=0", end_time=12.0)
    error = {k: r.signals["Quad.Est.E.Pos"].values for k, r in (("on", compensated), ("off", plain))}
    assert error["on"].max() < 1.0
    assert np.sqrt(np.mean(error["off"] ** 2)) > 1.5 * np.sqrt(np.mean(error["on"] ** 2))


def test_the_eskf_estimates_the_imu_biases_of_17():
    result = _run("17_imu_bias", end_time=20.0)
    bias = result.logs["Quad"]["imu_bias"][-1]  # b_a (m/s^2), b_g (rad/s)
    imu = result.scenario.vehicles[0].sensors.imu
    np.testing.assert_allclose(bias[3:5], imu.gyro_bias[0:2], atol=0.01)
    assert result.signals["Quad.Est.E.Pos"].values.max() < 1.0
