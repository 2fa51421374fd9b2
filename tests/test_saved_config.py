"""A run's and a replay's config.yaml name every setting, and a later quad_drake says which
settings an earlier one's file lacks (quad_drake/config/saved.py) instead of flying them silently
with its own defaults."""

import dataclasses
import warnings

import numpy as np
import pytest
from pydrake.common.yaml import yaml_dump_typed

from quad_drake.cli import main
from quad_drake.config.loader import dump_scenario, load_scenario, load_yaml
from quad_drake.config.saved import SAVED_MARK, SavedConfigWarning, absent_settings
from quad_drake.flightlogs.settings import dump_replay, load_replay
from quad_drake.running import catalog


def _without(text, line):
    """`text` with the one line `line` (a setting, with its indentation) taken out."""
    assert text.count(line + "\n") == 1, line
    return text.replace(line + "\n", "")


@pytest.mark.parametrize("name", list(catalog.bundled_scenarios()))
def test_a_saved_scenario_names_every_setting_and_loads_back_equal(name, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a bundled (hand-written) scenario gets no warning
        scenario = catalog.load(name)
        text = dump_scenario(scenario)
        assert text.startswith(SAVED_MARK)
        assert absent_settings(load_yaml(text), scenario) == []  # null ones included
        (tmp_path / "config.yaml").write_text(text)
        assert load_scenario(tmp_path / "config.yaml") == scenario


@pytest.mark.parametrize("text", ["1e3", "-2.5E-3", "yes", "null", "~", "0x10", "12:30", "a: b"])
def test_a_saved_text_that_reads_as_another_type_unquoted_stays_text(text, tmp_path):
    scenario = dataclasses.replace(catalog.load("01_intro"), description=text)
    (tmp_path / "config.yaml").write_text(dump_scenario(scenario))
    assert load_scenario(tmp_path / "config.yaml").description == text


@pytest.mark.parametrize("kind", ["ekf7", "eskf"])
def test_a_saved_replay_names_every_setting_and_loads_back_equal(kind, tmp_path):
    config = load_replay("sitl_takeoff_land_gps", f"{{kind: {kind}}}")
    text = dump_replay(config)
    assert "gps_delay: null\n" in text  # Drake's dump leaves a None out
    assert absent_settings(load_yaml(text), config) == []
    (tmp_path / "config.yaml").write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_replay(tmp_path / "config.yaml") == config


def test_a_saved_replay_without_a_setting_added_since_names_it(tmp_path):
    # As a replay folder written before the IMU gap bridge and the gravity fusion existed.
    text = dump_replay(load_replay("sitl_takeoff_land_gps", "{kind: eskf}"))
    text = _without(_without(text, "imu_gap_bridge: 0.05"), "  gravity_std: 1.0")
    (tmp_path / "config.yaml").write_text(text)
    with pytest.warns(SavedConfigWarning) as caught:
        load_replay(tmp_path / "config.yaml")
    (warning,) = caught
    assert str(warning.message).endswith(": estimator.gravity_std, imu_gap_bridge")
    assert "2 setting(s)" in str(warning.message) and "\n" not in str(warning.message)
    # given on the command line, a setting is not absent
    with pytest.warns(SavedConfigWarning, match=r"1 setting\(s\).*: estimator.gravity_std$"):
        load_replay(tmp_path / "config.yaml", overrides=["imu_gap_bridge=0"])


def test_run_flies_an_old_run_folders_config_and_says_in_one_line_what_it_lacked(tmp_path, capsys):
    """A run folder written before the mark (Drake's dump, which leaves out every None): a
    setting it gave is absent now; the None ones (01 has no sensors) are not named."""
    folder = tmp_path / "out" / "01_intro"
    folder.mkdir(parents=True)
    scenario = catalog.load("01_intro", overrides=["end_time=1.5"])
    old = _without(yaml_dump_typed(scenario), "  gps_delay_compensation: 0.0")
    (folder / "config.yaml").write_text(old)
    (folder / "summary.json").write_text('{"kind": "run"}')
    code = main(["run", str(folder / "config.yaml"), "--no-plots", "--out", str(tmp_path / "again")])
    err = capsys.readouterr().err
    assert code == 0, err
    (line,) = [line for line in err.splitlines() if "saved by an earlier quad_drake" in line]
    assert line.startswith("quad-drake: warning: ") and line.endswith(": vehicles.0.gps_delay_compensation")
    # the same file written by hand (no summary.json beside it) leaves settings out on purpose
    (folder / "summary.json").unlink()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_scenario(folder / "config.yaml").end_time == 1.5


def test_a_numpy_number_left_in_a_field_is_saved_as_the_number_it_is(tmp_path):
    scenario = dataclasses.replace(catalog.load("01_intro"), end_time=np.float64(1.5))
    text = dump_scenario(scenario)
    assert "\nend_time: 1.5\n" in text
    (tmp_path / "config.yaml").write_text(text)
    assert load_scenario(tmp_path / "config.yaml").end_time == 1.5
