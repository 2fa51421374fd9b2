"""Both estimators fusing the barometer and the 3-axis magnetometer in flights (issue 32): the
ports, one implementation for a single run and a fleet (noiseless, 1e-12), NIS per sensor in the
diagnostics, the gates against a baro step and a field disturbance, and what stays unchanged
without the new sensors."""

from pathlib import Path

import numpy as np
import pytest

from quad_drake.campaigns.fleet.diagram import run_fleet
from quad_drake.config.errors import ConfigError
from quad_drake.config.loader import load_scenario
from quad_drake.estimation.registry import nis_sensors
from quad_drake.running import catalog
from quad_drake.running.simulation import build_vehicle, run

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"
ESKF = "vehicles.0.estimator={kind: eskf, estimate_biases: false}"
BARO = "vehicles.0.sensors.baro={}"
FIELD = "vehicles.0.sensors.mag={three_axis: true}"


def _scenario(*overrides, name="11_gps_update"):
    return catalog.load(name, None, list(overrides))


@pytest.mark.parametrize("estimator", ["ekf7", "eskf"])
def test_estimator_inputs_follow_the_sensors(estimator):
    kind = [] if estimator == "ekf7" else [ESKF]
    plain = build_vehicle(_scenario(*kind).vehicles[0]).GetSubsystemByName("estimator")
    assert not plain.HasInputPort("baro") and plain.GetInputPort("mag").size() == 2
    aided = build_vehicle(_scenario(*kind, BARO, FIELD).vehicles[0]).GetSubsystemByName("estimator")
    assert aided.GetInputPort("baro").size() == 2 and aided.GetInputPort("mag").size() == 4
    assert nis_sensors(_scenario(*kind, BARO, FIELD).vehicles[0]) == (
        ("gps", "mag", "baro") if estimator == "ekf7" else ("gps", "field", "baro")
    )


def _noiseless(*overrides):
    scenario = _scenario("end_time=3", "criteria=[]", *overrides)
    vehicle = scenario.vehicles[0]
    vehicle.physics.motor_noise = 0.0
    vehicle.sensors.imu.accel_std = vehicle.sensors.imu.gyro_std = [0.0] * 3
    vehicle.sensors.gps.pos_std = vehicle.sensors.gps.vel_std = [0.0] * 3
    vehicle.sensors.mag.field_std = [0.0] * 3
    vehicle.sensors.baro.height_std = vehicle.sensors.baro.bias_walk_std = 0.0
    return scenario


@pytest.mark.parametrize("estimator", [[], [ESKF]], ids=["ekf7", "eskf"])
def test_a_noiseless_fleet_fuses_baro_and_field_as_the_single_run(estimator):
    """One implementation: the fleet's estimators (sized by n) fly every vehicle as the single
    run's, to 1e-12 on every log, with a barometer step rejected and reset and a field disturbance
    in the run (the step rejected from 0.5 s, the bias reset at 2.5 s)."""
    faults = (
        "vehicles.0.faults=[{kind: baro_step, start: 0.5, end: 3, offset: [5.0]}, "
        "{kind: mag_disturbance, start: 1.5, end: 2, offset: [0.0, 0.2, 0.0]}]"
    )
    scenario = _noiseless(*estimator, "vehicles.0.sensors.baro={bias: 0.3}", FIELD, faults)
    single = run(scenario)
    _, logs, _ = run_fleet(scenario, [5, 6])
    for log_name, data in single.logs["Quad"].items():
        for j in range(2):
            np.testing.assert_allclose(
                logs["Quad"][log_name][:, j, :], data, rtol=0, atol=1e-12, err_msg=log_name
            )
    signals = single.signals
    assert signals["Quad.Est.BaroGated"].values[-1] > 0 and signals["Quad.Est.BaroResets"].values[-1] >= 1
    nis = "Quad.Est.MagNIS" if not estimator else "Quad.Est.FieldNIS"
    assert signals[nis].fresh.sum() > 250 and signals["Quad.Est.BaroNIS"].fresh.sum() > 100


@pytest.mark.parametrize("estimator", [[], [ESKF]], ids=["ekf7", "eskf"])
def test_without_the_new_sensors_the_nis_and_bias_stay_empty(estimator):
    result = run(_scenario("end_time=1", "criteria=[]", *estimator))
    signals = result.signals
    for name in ("Quad.Est.BaroNIS", "Quad.Est.FieldNIS", "Quad.Est.BaroBias"):
        assert not signals[name].fresh.any() if name.endswith("NIS") else np.isnan(signals[name].values).all()
    assert signals["Quad.Est.MagNIS"].fresh.sum() > 50


def test_a_custom_estimator_cannot_take_a_three_axis_magnetometer():
    with pytest.raises(ConfigError, match="takes the yaw magnetometer only"):
        load_scenario(
            SCENARIOS / "11_gps_update.yaml",
            [FIELD, "vehicles.0.estimator={kind: custom, factory: 'quad_drake.estimation.custom:Missing'}"],
        )


EKF7_FAULT_TUNING = (
    "vehicles.0.estimator={kind: ekf7, q_pos_xy_std: 0.05, q_vel_xy_std: 0.35, q_vel_z_std: 0.2, "
    "q_yaw_std: 0.06, gps_pos_xy_std: 0.7, gps_pos_z_std: 2.0}"
)


@pytest.mark.slow
def test_a_gps_height_step_does_not_carry_the_ekf7_height_away():
    """The benchmark's 3 m GPS height step at 5 s with a barometer, flown by the EKF7 (the fault
    table's tuning, whose baro bias is still uncertain at the step) for 12 s: the GPS-height check
    catches the step and restores the bias it had before, so the height error from 8 s on stays at
    the no-step level. Seed 0 pinned (0.11 m); over seeds 1-20 the mean |Est.E.Z| over 8-12 s is
    0.07-0.33 m, with the earlier filtered-mean check (which kept what the bias learnt before it
    caught the step) 0.37-0.76 m (0.60 m at seed 0)."""
    scenario = load_scenario(
        Path(__file__).resolve().parent.parent / "benchmarks" / "scenarios" / "gps_height_step_baro.yaml",
        ["end_time=12", "criteria=[]", "seed=0", EKF7_FAULT_TUNING],
    )
    result = run(scenario)
    error = result.signals["Quad.Est.E.Z"].values
    times = result.times
    assert np.mean(np.abs(error[(times >= 8.0) & (times <= 12.0)])) < 0.35
