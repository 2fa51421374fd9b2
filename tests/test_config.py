"""Scenario loading: every bundled scenario loads; every bad input is one clear line."""

import re
import textwrap

import pytest
from pydrake.common.yaml import yaml_load_typed

from quad_drake.config.errors import ConfigError
from quad_drake.config.loader import dump_scenario, load_scenario
from quad_drake.config.schema import ScenarioConfig
from quad_drake.running import catalog


def write(tmp_path, text, name="s.yaml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


GOOD = """
    end_time: 2
    vehicles:
      - &quad
        name: Quad1
        sensors: {imu: {}}
      - <<: *quad
        name: Quad2
"""


def test_every_bundled_scenario_loads_and_round_trips():
    paths = catalog.bundled_scenarios()
    # 12-18: the fault scenarios; 19-22: wind, drag and the IMU (22 with an _eskf twin); 23-25: the
    # barometer and the 3-axis magnetometer; 26-28: the EKF-GSF; 29: the no-aiding failsafe
    assert [n[:2] for n in paths if not n.endswith("_eskf")] == [f"{i:02d}" for i in range(1, 30)]
    assert "11_gps_update_eskf" in paths
    for name, path in paths.items():
        scenario = load_scenario(path)
        assert scenario.name == name
        again = yaml_load_typed(schema=ScenarioConfig, data=dump_scenario(scenario))
        assert again == scenario


def test_yaml_merge_keys_copy_a_vehicle(tmp_path):
    scenario = load_scenario(write(tmp_path, GOOD))
    assert [v.name for v in scenario.vehicles] == ["Quad1", "Quad2"]
    assert scenario.vehicles[1].sensors.imu is not None
    assert scenario.vehicles[1].sensors.gps is None


def test_overrides_reach_nested_fields(tmp_path):
    scenario = load_scenario(
        write(tmp_path, GOOD), ["vehicles.1.physics.mass=0.8", "seed=7", "vehicles.0.estimator.q_yaw_std=0.2"]
    )
    assert scenario.vehicles[1].physics.mass == 0.8
    assert scenario.vehicles[0].physics.mass == 0.5
    assert scenario.seed == 7
    assert scenario.vehicles[0].estimator.q_yaw_std == 0.2


@pytest.mark.parametrize(
    "overrides, expected",
    [
        (["vehicles.0.physics.mas=1"], "vehicles.0.physics.mas: unknown key"),
        (["end_time=abc"], "end_time: expected float, got 'abc'"),
        (["vehicles.0.initial_position=[1, 2]"], "vehicles.0.initial_position: expected 3 values, got 2"),
        (["vehicles.0.physics.mass=-1"], "vehicles.0.physics.mass: must be > 0"),
        (["vehicles.0.physics.mass=0"], "vehicles.0.physics.mass: must be > 0"),
        (
            ["vehicles.0.sensors.gps={period: 0}"],
            "vehicles.0.sensors.gps.period: must be a whole multiple of",
        ),
        (["vehicles.0.sensors.imu.accel_std=[0.5, -1, 0]"], "vehicles.0.sensors.imu.accel_std: must be >= 0"),
        (["vehicles.0.estimator.q_yaw_std=.nan"], "vehicles.0.estimator.q_yaw_std: must be finite"),
        (
            ["vehicles.0.trajectory={kind: file, file: nowhere.txt}"],
            "vehicles.0.trajectory.file: no such trajectory file 'nowhere.txt'",
        ),
        (
            ["vehicles.0.estimator.attitude_filter.variant=quaternionish"],
            "vehicles.0.estimator.attitude_filter.variant: 'quaternionish' is not one of nonlinear, "
            "small_angle",
        ),
        (["vehicles.1.name=Quad1"], "vehicles: names must be unique"),
        (["vehicles.0.flies_on=estimate"], "vehicles.0.flies_on: estimate needs imu, gps and mag sensors"),
        (["seed"], "--set 'seed': expected dotted.key=value"),
        (["=3"], "expected dotted.key=value"),
        (["vehicles.5.physics.mass=1"], "'5' is not an index of a list of 2"),
        (["vehicles.0.physics.mass=[1"], "value is not valid YAML"),
    ],
)
def test_bad_input_is_one_line_naming_file_and_field(tmp_path, overrides, expected):
    path = write(tmp_path, GOOD)
    with pytest.raises(ConfigError) as info:
        load_scenario(path, overrides)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path))
    assert expected in message


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="no such scenario file"):
        load_scenario(tmp_path / "absent.yaml")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_scenario(write(tmp_path, "vehicles: [\n"))
    with pytest.raises(ConfigError, match="expected a mapping of fields at the top level, got list"):
        load_scenario(write(tmp_path, "- 1\n- 2\n"))
    with pytest.raises(ConfigError, match="expected a mapping of fields at the top level, got str"):
        load_scenario(write(tmp_path, "just words\n"))
    for empty in ("", "# only a comment\n", "---\n"):
        with pytest.raises(ConfigError, match=r"s.yaml: the file is empty"):
            load_scenario(write(tmp_path, empty))


@pytest.mark.parametrize(
    "text, value",
    [("1e9", 1e9), ("2.5e-1", 0.25), ("-3e2", -300.0), ("1E3", 1000.0), ("+1e3", 1000.0), ("1.e3", 1000.0)],
)
def test_numbers_as_people_write_them_are_numbers_in_files_and_overrides(tmp_path, text, value):
    vehicle = f"{{initial_velocity: [{text}, 0, 0], trajectory: {{yaw: {text}}}}}"
    from_file = load_scenario(write(tmp_path, f"vehicles: [{vehicle}]\n"))
    assert (
        from_file.vehicles[0].initial_velocity[0] == value and from_file.vehicles[0].trajectory.yaw == value
    )
    overrides = [f"vehicles.0.initial_velocity=[{text}, 0, 0]", f"vehicles.0.trajectory.yaw={text}"]
    from_set = load_scenario(write(tmp_path, GOOD), overrides)
    assert from_set.vehicles[0].initial_velocity[0] == value and from_set.vehicles[0].trajectory.yaw == value
    assert load_scenario(write(tmp_path, GOOD), ["end_time=2e1"]).end_time == 20.0


def test_quoted_numbers_and_words_stay_strings(tmp_path):
    assert load_scenario(write(tmp_path, GOOD), ["description='1e9'"]).description == "1e9"
    with pytest.raises(ConfigError, match="end_time: expected float, got '1e9x'"):
        load_scenario(write(tmp_path, GOOD), ["end_time=1e9x"])
    with pytest.raises(ConfigError, match="end_time: expected float, got '1e9'"):
        load_scenario(write(tmp_path, GOOD), ["end_time='1e9'"])


TICK = "whole multiple of the 2 ms onboard tick"


@pytest.mark.parametrize(
    "override, expected",
    [
        (
            "vehicles.0.sensors.mag={period: 1.0e-7}",
            f"vehicles.0.sensors.mag.period: must be a {TICK}, at least",
        ),
        (
            "vehicles.0.sensors.mag={period: 0.001}",
            f"mag.period: must be a {TICK}, at least 0.002 s, got 0.001",
        ),
        ("vehicles.0.sensors.mag={period: 0.005}", f"mag.period: must be a {TICK}"),
        ("vehicles.0.sensors.mag={period: 0}", f"mag.period: must be a {TICK}"),
        ("vehicles.0.sensors.mag={period: -0.01}", f"mag.period: must be a {TICK}"),
        ("vehicles.0.sensors.gps={period: 0.003}", f"vehicles.0.sensors.gps.period: must be a {TICK}"),
        ("vehicles.0.sensors.mag={first_sample_time: 0.001}", f"first_sample_time: must be a {TICK}, got"),
        ("vehicles.0.sensors.mag={first_sample_time: -0.002}", f"first_sample_time: must be a {TICK}, got"),
    ],
)
def test_sensor_periods_off_the_onboard_tick_are_rejected(tmp_path, override, expected):
    with pytest.raises(ConfigError, match=expected.replace(".", r"\.")):
        load_scenario(write(tmp_path, GOOD), [override])


def test_sensor_periods_on_the_tick_are_accepted(tmp_path):
    scenario = load_scenario(
        write(tmp_path, GOOD),
        [
            "vehicles.0.sensors.mag={period: 0.002, first_sample_time: 0}",
            "vehicles.0.sensors.gps={period: 0.1}",
        ],
    )
    assert scenario.vehicles[0].sensors.mag.period == 0.002
    assert scenario.vehicles[0].sensors.gps.period == 0.1  # 50.000000000000004 ticks in binary


@pytest.mark.parametrize(
    "override",
    [
        "vehicles.0.estimator.q_vel_xy_std=1.0e+200",  # Q = std^2 dt overflows: P turns inf, then NaN
        "vehicles.0.estimator.gps_pos_xy_std=1e-200",  # R underflows to 0: S = H P H^T + R singular, P0 = 0
        "vehicles.0.estimator.mag_yaw_std=1e-101",
        "vehicles.0.estimator.init_std=[0, 0, 0, 0, 0, 0, 1e101]",
        "vehicles.0.sensors.imu={accel_std: [0.5, 1e300, 1]}",
    ],
)
def test_noise_stds_whose_square_is_no_usable_covariance_are_rejected(tmp_path, override):
    with pytest.raises(ConfigError, match=r"a noise std must be 0 or within \[1e-100, 1e\+100\]"):
        load_scenario(write(tmp_path, GOOD), [override])


def test_zero_noise_and_the_edges_of_the_noise_range_are_accepted(tmp_path):
    edges = [
        "vehicles.0.estimator.q_yaw_std=0",
        "vehicles.0.estimator.gps_pos_xy_std=1e-100",
        "vehicles.0.estimator.q_vel_xy_std=1e100",
    ]
    ekf7 = load_scenario(write(tmp_path, GOOD), edges).vehicles[0].estimator
    assert (ekf7.q_yaw_std, ekf7.gps_pos_xy_std, ekf7.q_vel_xy_std) == (0, 1e-100, 1e100)
    with pytest.raises(ConfigError, match="dt_imu: must be <= 1.0"):
        load_scenario(write(tmp_path, GOOD), ["vehicles.0.estimator.dt_imu=10"])


def test_estimator_choice_loads_by_kind_with_one_line_errors(tmp_path):
    from quad_drake.estimation.registry import EskfEstimatorConfig

    def load(text, *overrides):
        path = tmp_path / "s.yaml"
        path.write_text("vehicles:\n  - name: Q\n    " + text + "\n")
        return load_scenario(path, overrides)

    scenario = load("estimator: {kind: eskf, gps_gate_sigma: 4, estimate_biases: false}")
    estimator = scenario.vehicles[0].estimator
    assert isinstance(estimator, EskfEstimatorConfig)
    assert (estimator.gps_gate_sigma, estimator.estimate_biases) == (4.0, False)
    (tmp_path / "dumped.yaml").write_text(dump_scenario(scenario))
    assert load_scenario(tmp_path / "dumped.yaml") == scenario
    assert load("sensors: {imu: {}}").vehicles[0].estimator.kind == "ekf7"  # the default
    assert load("sensors: {}", "vehicles.0.estimator.kind=eskf").vehicles[0].estimator.kind == "eskf"
    for text, message in (
        ("estimator: {kind: ukf}", "vehicles.0.estimator.kind: 'ukf' is not one of ekf7, eskf"),
        ("estimator: {gps_gate_sigma: 3}", "vehicles.0.estimator.kind: missing; one of ekf7, eskf"),
        ("estimator: {kind: ekf7, accel_std: [1, 1, 1]}", "vehicles.0.estimator.accel_std: unknown key"),
        (
            "estimator: {kind:eskf}",
            "vehicles.0.estimator.kind:eskf: unknown key: YAML reads 'kind:eskf' as one key; "
            "write 'kind: eskf' (a space after the colon)",
        ),
        (
            "estimator: {kind: eskf, gps_gate_sigma:4}",
            "vehicles.0.estimator.gps_gate_sigma:4: unknown key: YAML reads 'gps_gate_sigma:4'",
        ),
        ("estimator: {kind: eskf, init_pos_std: [1, 1]}", "vehicles.0.estimator.init_pos_std: expected 3"),
        ("estimator: {kind: eskf, gyro_std: [1, -1, 1]}", "vehicles.0.estimator.gyro_std: must be >= 0"),
        ("estimator: eskf", "vehicles.0.estimator: expected a mapping"),
        (
            "estimator: {kind: ekf7, q_vel_xy_std: 1.0e+200}",
            "vehicles.0.estimator.q_vel_xy_std: a noise std must be 0 or within",
        ),
        (
            "estimator: {kind: eskf, accel_bias_rw_std: 1e200}",
            "vehicles.0.estimator.accel_bias_rw_std: a noise",
        ),
    ):
        with pytest.raises(
            ConfigError, match="^" + re.escape(str(tmp_path / "s.yaml") + ": " + message)
        ) as e:
            load(text)
        assert "\n" not in str(e.value)


def test_the_config_package_reexports_each_modules_names_from_where_they_live():
    import importlib

    import quad_drake.config as package

    homes = {module: importlib.import_module(f"quad_drake.config.{module}") for module in package._EXPORTS}
    for module, names in package._EXPORTS.items():
        for name in names:
            assert getattr(package, name) is getattr(homes[module], name), name
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        package.nothing_here  # noqa: B018


@pytest.mark.parametrize("sensor, what", [("no_aid", "no-aiding samples"), ("gps_accuracy", "accuracy")])
def test_what_only_a_replay_supplies_is_refused_on_a_simulated_vehicle(tmp_path, sensor, what):
    expected = rf"vehicles\.0\.sensors\.{sensor}: only a flight log's replay .*{what}"
    with pytest.raises(ConfigError, match=expected):
        load_scenario(write(tmp_path, GOOD), [f"vehicles.0.sensors.{sensor}=true"])
