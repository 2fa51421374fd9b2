"""Diagram-level behaviour: seeds, the within-tick order, multi-vehicle wiring, logs."""

import numpy as np
import pytest
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator

from quad_drake import conventions as c
from quad_drake.config.saved import SAVED_MARK
from quad_drake.control.cascade import cascade_step
from quad_drake.judging.signals import vehicle_log_names
from quad_drake.models.dynamics import motor_lag_step
from quad_drake.output.results import load_logs, save_run
from quad_drake.running import catalog
from quad_drake.running.simulation import build_diagram, build_vehicle, read_logs, run


def short(name, end_time, *overrides, seed=None):
    return catalog.load(name, seed, [f"end_time={end_time}", *overrides])


def test_same_seed_gives_identical_logs_and_another_seed_differs():
    first = run(short("06_sensor_noise", 0.5, seed=3))
    second = run(short("06_sensor_noise", 0.5, seed=3))
    other = run(short("06_sensor_noise", 0.5, seed=4))
    for name, data in first.logs["Quad"].items():
        np.testing.assert_array_equal(data, second.logs["Quad"][name], err_msg=name)
    assert not np.array_equal(first.logs["Quad"]["imu"], other.logs["Quad"]["imu"])
    assert not np.array_equal(first.logs["Quad"]["state"], other.logs["Quad"]["state"])


def test_logs_are_sampled_at_the_reference_frames():
    result = run(short("01_intro", 1.0))
    np.testing.assert_allclose(result.times, 0.005 * np.arange(1, 201), atol=1e-12)
    assert result.logs["Quad"]["state"].shape == (200, 13)


def test_multi_vehicle_scenarios_get_independent_noise():
    result = run(short("09_predict_covariance", 0.2))
    assert len(result.logs) == 10
    imu = [result.logs[f"Quad{i}"]["imu"] for i in (1, 2)]
    assert not np.array_equal(imu[0], imu[1])


def test_within_tick_order_sensors_filter_ekf_controller_plant():
    """At tick t_k every system reads what the previous one wrote in the same tick."""
    vehicle = short(
        "11_gps_update",
        1.0,
        "vehicles.0.physics.motor_noise=0",
        "vehicles.0.sensors.imu={accel_std: [0, 0, 0], gyro_std: [0, 0, 0]}",
    ).vehicles[0]
    diagram = build_vehicle(vehicle)
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.SetRandomContext(context, RandomGenerator(0))
    controller = diagram.GetSubsystemByName("controller")
    t_k = 0.040  # no GPS or magnetometer sample at this tick
    simulator.AdvanceTo(t_k - 0.0015)
    integral_before = (
        controller.GetMyContextFromRoot(context).get_discrete_state(controller.integral_index()).GetAtIndex(0)
    )
    simulator.AdvanceTo(t_k + 0.5 * (c.CONTROLLER_OFFSET + c.PLANT_OFFSET))

    def out(name):
        return diagram.GetOutputPort(name).Eval(context).copy()

    state, imu, attitude, ekf_state = out("state"), out("imu"), out("attitude"), out("ekf_state")
    np.testing.assert_array_equal(imu[3:], state[c.W_SLICE])  # IMU sampled the state at t_k
    assert ekf_state[6] == attitude[2]  # EKF took this tick's CF yaw
    estimate = out("estimated_state")  # the estimator sub-Diagram's export, what the controller reads
    reference = out("reference")
    forces, _ = cascade_step(
        estimate.tolist(), reference.tolist(), integral_before, c.ONBOARD_PERIOD, vehicle.controller
    )
    commands = controller.GetOutputPort("motor_thrusts").Eval(controller.GetMyContextFromRoot(context))
    np.testing.assert_allclose(commands, forces, rtol=1e-12)  # controller used this tick's EKF

    forces_before = out("motor_forces")
    simulator.AdvanceTo(t_k + c.PLANT_OFFSET + 1e-7)
    physics = vehicle.physics
    expected = motor_lag_step(
        forces_before.tolist(),
        np.clip(commands, physics.min_motor_thrust, physics.max_motor_thrust).tolist(),
        c.PHYSICS_PERIOD,
        physics.motor_tau_up,
        physics.motor_tau_down,
    )
    np.testing.assert_allclose(out("motor_forces"), expected, rtol=1e-12)  # plant used it next


@pytest.mark.parametrize("kind", ["ekf7", "eskf"])
def test_controller_flies_on_truth_or_estimate_as_configured(kind):
    for ideal in (True, False):
        scenario = short(
            "11_gps_update",
            0.1,
            f"vehicles.0.flies_on={'truth' if ideal else 'estimate'}",
            f"vehicles.0.estimator={{kind: {kind}}}",
        )
        vehicle = build_vehicle(scenario.vehicles[0])
        names = {s.get_name() for s in vehicle.GetSystems()}
        assert {"imu", "gps", "mag", "estimator", "controller", "plant"} <= names
        inner = {s.get_name() for s in vehicle.GetSubsystemByName("estimator").GetSystems()}
        assert inner == ({"attitude_filter", "ekf", "estimated_state"} if kind == "ekf7" else {"eskf"})
        context = vehicle.CreateDefaultContext()
        Simulator(vehicle, context).AdvanceTo(0.05)
        controller = vehicle.GetSubsystemByName("controller")
        seen = controller.GetInputPort("state").Eval(controller.GetMyContextFromRoot(context))
        flown = vehicle.GetOutputPort("state" if ideal else "estimated_state").Eval(context)
        np.testing.assert_array_equal(seen, flown)


def test_vehicle_without_sensors_exports_only_truth_signals():
    scenario = short("01_intro", 0.1)
    assert vehicle_log_names(scenario.vehicles[0]) == ["state", "reference", "motor_forces", "contacts"]


def test_results_save_and_reload(tmp_path):
    result = run(short("10_mag_update", 0.3))
    save_run(result, tmp_path)
    times, logs = load_logs(tmp_path)
    np.testing.assert_array_equal(times, result.times)
    np.testing.assert_array_equal(logs["Quad"]["covariance"], result.logs["Quad"]["covariance"])
    mark, first_setting = (tmp_path / "config.yaml").read_text().splitlines()[:2]
    assert mark.startswith(SAVED_MARK) and first_setting == "name: 10_mag_update"
    assert '"passed"' in (tmp_path / "summary.json").read_text()


def test_unknown_signal_in_a_criterion_is_a_config_error():
    from quad_drake.config.errors import ConfigError
    from quad_drake.config.loader import load_scenario

    # Loading through the catalog reports it with the file; run() checks a scenario built otherwise.
    with pytest.raises(
        ConfigError, match=r"01_intro.yaml: criteria.0.signal: unknown signal 'Quad.Est.E.Pos'"
    ):
        short("01_intro", 0.1, "criteria.0.signal=Quad.Est.E.Pos")
    scenario = load_scenario(catalog.resolve("01_intro"), ["criteria.0.signal=Quad.Est.E.Pos"])
    with pytest.raises(ConfigError, match="criteria.0.signal: unknown signal 'Quad.Est.E.Pos'"):
        run(scenario)


def test_log_samples_show_the_values_held_before_the_events_at_their_time():
    """The IMU samples at t_k itself; a 5 ms log sample at t = t_k still shows the previous sample."""
    diagram, loggers = build_diagram(short("11_gps_update", 0.02))
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.SetRandomContext(context, RandomGenerator(1))
    quad = diagram.GetSubsystemByName("Quad")

    def out(name):
        return quad.GetOutputPort(name).Eval(quad.GetMyContextFromRoot(context)).copy()

    simulator.AdvanceTo(0.010 - 1e-7)
    held = {name: out(name) for name in ("imu", "state", "ekf_state")}
    simulator.AdvanceTo(0.010 + c.PLANT_OFFSET + 1e-7)
    times, logs = read_logs(loggers, context, 2)
    assert times[1] == 0.010
    for name, value in held.items():
        np.testing.assert_array_equal(logs["Quad"][name][1], value, err_msg=name)
        log = loggers["Quad"][name].FindLog(context)  # the VectorLogSink look-alike agrees
        assert log.sample_times()[2] == 0.010 and loggers["Quad"][name].get_input_port().size() == value.size
        np.testing.assert_array_equal(log.data()[:, 2], value)
        assert not np.array_equal(out(name), value), name  # every one of them changed at t = 0.010


def test_onboard_ticks_coincide_exactly_with_log_times():
    """Drake times periodic events as offset + k period: the IMU (offset 0) fires at exactly the
    even-millisecond log times (so a log sample never sees a sample taken at its own time), and
    every other system fires at least a microsecond away from any log time (checked for 1 h)."""
    j = np.arange(0, int(3600 / c.LOG_PERIOD) + 1, 2)
    np.testing.assert_array_equal((j * 5 // 2) * c.ONBOARD_PERIOD, j * c.LOG_PERIOD)
    assert c.SENSOR_OFFSET == 0.0
    offsets = [
        c.SLOW_SENSOR_OFFSET,
        c.ATTITUDE_FILTER_OFFSET,
        c.EKF_OFFSET,
        c.CONTROLLER_OFFSET,
        c.PLANT_OFFSET,
    ]
    assert min(offsets) >= 1e-6 and max(offsets) + 1e-6 <= c.PHYSICS_PERIOD / 2
    assert sorted(offsets[1:]) == offsets[1:] and len(set(offsets[1:])) == 4
