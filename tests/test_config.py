"""Scenario loading: every bundled scenario loads; every bad input is one clear line."""

import textwrap

import pytest
from pydrake.common.yaml import yaml_load_typed

from quad_drake import catalog
from quad_drake.config import ConfigError, ScenarioConfig, dump_scenario, load_scenario


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
    assert [n[:2] for n in paths] == [f"{i:02d}" for i in range(1, 12)]
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
        write(tmp_path, GOOD), ["vehicles.1.physics.mass=0.8", "seed=7", "vehicles.0.ekf.q_yaw_std=0.2"]
    )
    assert scenario.vehicles[1].physics.mass == 0.8
    assert scenario.vehicles[0].physics.mass == 0.5
    assert scenario.seed == 7
    assert scenario.vehicles[0].ekf.q_yaw_std == 0.2


@pytest.mark.parametrize(
    "overrides, expected",
    [
        (["vehicles.0.physics.mas=1"], "vehicles.0.physics.mas: unknown key"),
        (["end_time=abc"], "end_time: expected float, got 'abc'"),
        (["vehicles.0.initial_position=[1, 2]"], "vehicles.0.initial_position: expected 3 values, got 2"),
        (["vehicles.0.physics.mass=-1"], "vehicles.0.physics.mass: must be > 0"),
        (["vehicles.0.physics.mass=0"], "vehicles.0.physics.mass: must be > 0"),
        (["vehicles.0.sensors.gps={period: 0}"], "vehicles.0.sensors.gps.period: must be > 0"),
        (["vehicles.0.sensors.imu.accel_std=[0.5, -1, 0]"], "vehicles.0.sensors.imu.accel_std: must be >= 0"),
        (["vehicles.0.ekf.q_yaw_std=.nan"], "vehicles.0.ekf.q_yaw_std: must be finite"),
        (
            ["vehicles.0.trajectory={kind: file, file: nowhere.txt}"],
            "vehicles.0.trajectory.file: no such trajectory file 'nowhere.txt'",
        ),
        (
            ["vehicles.0.attitude_filter.variant=quaternionish"],
            "vehicles.0.attitude_filter.variant: 'quaternionish' is not one of nonlinear, small_angle",
        ),
        (["vehicles.1.name=Quad1"], "vehicles: names must be unique"),
        (["vehicles.0.use_ideal_estimator=false"], "needs imu, gps and mag sensors"),
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
    with pytest.raises(ConfigError, match="the file: expected a mapping"):
        load_scenario(write(tmp_path, "- 1\n- 2\n"))
