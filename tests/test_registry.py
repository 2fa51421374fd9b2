"""The estimator registry: every kind declared once, kind ``truth`` added by one entry, the
deprecated ``use_ideal_estimator`` rewritten into ``flies_on``, and the EKF7's deprecated ``ekf`` /
``attitude_filter`` blocks rewritten into its estimator config."""

import re
import textwrap
import typing
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from quad_drake.config.errors import ConfigError
from quad_drake.config.loader import load_scenario
from quad_drake.config.schema import VehicleConfig
from quad_drake.estimation import registry
from quad_drake.judging.signals import vehicle_log_names
from quad_drake.models.fidelity import PHYSICAL, REFERENCE
from quad_drake.running import catalog
from quad_drake.running.simulation import build_vehicle, run
from quad_drake.tuning.space import search_space


class AtRest:
    """The smallest custom estimator: a vehicle at rest at 1 m, whatever it measures."""

    state_names = ("X", "Y", "Z")

    def predict(self, dt, accel, gyro):
        pass

    def update_gps(self, position, velocity):
        pass

    def update_mag(self, yaw):
        pass

    def estimate(self):
        return np.array([0, 0, -1.0, 0, 0, 0, 0, 0, 0])

    def covariance(self):
        return np.eye(3)


EXAMPLE_CONFIGS = {
    "custom": {"factory": f"{Path(__file__).resolve()}:AtRest"},
    "course": {"module": str(Path(__file__).resolve().parent / "grading" / "correct_estimator.py")},
}
"""Fields a kind's config needs beyond its defaults to be flown."""


def test_every_kind_is_declared_once_and_consistently():
    members = typing.get_args(registry.EstimatorConfig)
    assert [kind.config_type for kind in registry.KINDS.values()] == list(members)
    for name, kind in registry.KINDS.items():
        config = kind.config_type(**EXAMPLE_CONFIGS.get(name, {}))
        assert kind.problem(config) is None, name
        assert config.kind == name
        assert registry.kind_of(config) is kind
        vocabulary = kind.vocabulary(config)
        assert (vocabulary is None) == (kind.builder is None), name  # a vocabulary iff it builds systems
        if kind.builder is not None:
            assert callable(kind.build_function())
            assert vocabulary.kind == name
        assert all(key.count(".") == 1 for key in kind.tuning_keys(config))
        assert kind.fidelity_problem(PHYSICAL) is None


def test_fidelity_support_is_the_registrys():
    assert registry.KINDS["eskf"].fidelity_problem(REFERENCE).startswith("the error-state EKF")
    assert registry.KINDS["ekf7"].fidelity_problem(REFERENCE) is None
    with pytest.raises(ConfigError, match="vehicles.0.estimator: the error-state EKF"):
        catalog.load("11_gps_update", None, ["fidelity=reference", "vehicles.0.estimator={kind: eskf}"])


def test_kind_truth_runs_no_estimator_and_flies_11_on_the_true_state():
    scenario = catalog.load("11_gps_update", None, ["vehicles.0.estimator={kind: truth}", "criteria=[]"])
    vehicle = scenario.vehicles[0]
    assert vehicle.flies_on == "estimate"  # 11's own setting: the truth kind's estimate is the truth
    assert registry.vehicle_vocabulary(vehicle) is None and not registry.flies_on_estimate(vehicle)
    names = vehicle_log_names(vehicle)
    assert {"imu", "gps", "mag"} <= set(names) and "estimated_state" not in names
    diagram = build_vehicle(vehicle)
    systems = {s.get_name() for s in diagram.GetSystems()}
    assert "estimator" not in systems and {"imu", "gps", "mag", "controller"} <= systems
    context = diagram.CreateDefaultContext()
    Simulator(diagram, context).AdvanceTo(0.05)
    controller = diagram.GetSubsystemByName("controller")
    seen = controller.GetInputPort("state").Eval(controller.GetMyContextFromRoot(context))
    np.testing.assert_array_equal(seen, diagram.GetOutputPort("state").Eval(context))

    result = run(scenario)  # the whole of 11: the safety verdicts judge the true flight
    assert result.criteria and result.passed, [r.to_dict() for r in result.criteria if not r.passed]
    with pytest.raises(ConfigError, match="no estimator to tune"):
        search_space(scenario)


def write(tmp_path, text):
    path = tmp_path / "s.yaml"
    path.write_text(textwrap.dedent(text))
    return path


DEPRECATED = """
    end_time: 1
    vehicles:
      - name: Quad
        use_ideal_estimator: {ideal}
        sensors: {{imu: {{}}, gps: {{}}, mag: {{}}}}
        {extra}
"""


@pytest.mark.parametrize("ideal, flies_on", [("false", "estimate"), ("true", "truth")])
def test_use_ideal_estimator_still_works_with_a_deprecation_message(tmp_path, ideal, flies_on):
    path = write(tmp_path, DEPRECATED.format(ideal=ideal, extra=""))
    with pytest.warns(
        FutureWarning, match=f"use_ideal_estimator is deprecated: write vehicles.0.flies_on: {flies_on}"
    ):
        scenario = load_scenario(path)
    assert scenario.vehicles[0].flies_on == flies_on


def test_use_ideal_estimator_contradicting_flies_on_is_one_line(tmp_path):
    path = write(tmp_path, DEPRECATED.format(ideal="false", extra="flies_on: truth"))
    with pytest.raises(ConfigError, match=r"use_ideal_estimator: contradicts vehicles.0.flies_on") as error:
        load_scenario(path)
    assert "\n" not in str(error.value)


OLD_EKF7 = """
    end_time: 1
    vehicles:
      - name: Quad
        sensors: {{imu: {{}}, gps: {{}}, mag: {{}}, baro: {{}}}}
        ekf: {{q_yaw_std: 0.3, init_std: [1, 1, 1, 1, 1, 1, 0.2], baro: {{gate_sigma: 0}}}}
        attitude_filter: {{tau: 0.5}}
        {extra}
"""
NEW_EKF7 = """
    end_time: 1
    vehicles:
      - name: Quad
        sensors: {imu: {}, gps: {}, mag: {}, baro: {}}
        estimator:
          kind: ekf7
          q_yaw_std: 0.3
          init_std: [1, 1, 1, 1, 1, 1, 0.2]
          baro: {gate_sigma: 0}
          attitude_filter: {tau: 0.5}
"""


def test_the_old_ekf_and_attitude_filter_blocks_load_into_the_ekf7_config_with_a_warning(tmp_path):
    with pytest.warns(FutureWarning) as caught:
        old = load_scenario(write(tmp_path, OLD_EKF7.format(extra="")))
    messages = [str(w.message) for w in caught]
    assert messages == [
        "vehicles.0.ekf is deprecated: write its fields in vehicles.0.estimator "
        "(vehicles.0.estimator: {kind: ekf7, ...})",
        "vehicles.0.attitude_filter is deprecated: write its fields in vehicles.0.estimator.attitude_filter "
        "(vehicles.0.estimator: {kind: ekf7, ...})",
    ]
    (tmp_path / "new").mkdir()
    new = load_scenario(write(tmp_path / "new", NEW_EKF7))
    assert old == new
    assert (new.vehicles[0].estimator.q_yaw_std, new.vehicles[0].estimator.attitude_filter.tau) == (0.3, 0.5)
    assert (
        new.vehicles[0].estimator.baro.gate_sigma == 0.0 and new.vehicles[0].estimator.baro.height_std == 0.1
    )


def test_an_old_block_agreeing_with_the_estimator_loads_and_contradicting_it_is_one_line(tmp_path):
    agreeing = "estimator: {kind: ekf7, q_yaw_std: 0.3, attitude_filter: {variant: small_angle}}"
    with (
        pytest.warns(FutureWarning, match="vehicles.0.ekf is deprecated"),
        pytest.warns(FutureWarning, match="vehicles.0.attitude_filter is deprecated"),
    ):
        estimator = load_scenario(write(tmp_path, OLD_EKF7.format(extra=agreeing))).vehicles[0].estimator
    assert (estimator.q_yaw_std, estimator.attitude_filter.variant, estimator.attitude_filter.tau) == (
        0.3,
        "small_angle",
        0.5,
    )
    path = write(tmp_path, OLD_EKF7.format(extra="estimator: {kind: ekf7, q_yaw_std: 0.2}"))
    with pytest.raises(
        ConfigError, match=r"vehicles.0.ekf.q_yaw_std: contradicts vehicles.0.estimator.q_yaw_std"
    ):
        load_scenario(path)
    from quad_drake.cli import main

    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()


def test_an_old_block_beside_another_kind_was_never_read_and_is_dropped_with_a_warning(tmp_path):
    path = write(tmp_path, OLD_EKF7.format(extra="estimator: {kind: eskf}"))
    with (
        pytest.warns(
            FutureWarning, match="vehicles.0.ekf is deprecated and ignored: .* vehicles.0.estimator is eskf"
        ),
        pytest.warns(
            FutureWarning,
            match="vehicles.0.attitude_filter is deprecated and ignored: .* vehicles.0.estimator is eskf",
        ),
    ):
        scenario = load_scenario(path)
    assert scenario.vehicles[0].estimator == registry.EskfEstimatorConfig()


def test_an_old_set_key_sets_the_ekf7_field_and_wins_over_the_file(tmp_path):
    with pytest.warns(FutureWarning, match=r"--set vehicles.0.ekf.q_yaw_std is deprecated") as caught:
        scenario = catalog.load("11_gps_update", None, ["vehicles.0.ekf.q_yaw_std=0.4"])
    assert "write --set vehicles.0.estimator.q_yaw_std" in str(caught[0].message)
    assert scenario.vehicles[0].estimator.q_yaw_std == 0.4  # the file says 0.022
    assert scenario.vehicles[0].estimator.q_vel_z_std == 0.067  # the rest of the file's block stays
    with pytest.warns(FutureWarning):
        whole = catalog.load("01_intro", None, ["vehicles.0.ekf={q_yaw_std: 0.4, gps_gate_sigma: 0}"])
    assert (whole.vehicles[0].estimator.q_yaw_std, whole.vehicles[0].estimator.gps_gate_sigma) == (0.4, 0.0)
    with pytest.warns(FutureWarning):
        tau = catalog.load("01_intro", None, ["vehicles.0.attitude_filter.tau=2"]).vehicles[0].estimator
    assert tau.attitude_filter.tau == 2.0
    with pytest.warns(FutureWarning, match="ignored: it sets an ekf7 parameter and the estimator is eskf"):
        eskf = catalog.load("11_gps_update_eskf", None, ["vehicles.0.ekf.gps_gate_sigma=0"])
    assert eskf.vehicles[0].estimator.gps_gate_sigma == 5.0
    fresh = catalog.load("01_intro", None, ["vehicles.0.estimator.q_yaw_std=0.4"])  # names no kind: ekf7's
    assert fresh.vehicles[0].estimator.q_yaw_std == 0.4


def test_an_old_tuning_key_is_read_as_the_ekf7_field():
    scenario = catalog.load("11_gps_update")
    with pytest.warns(FutureWarning, match="--params ekf.q_yaw_std is deprecated: write estimator.q_yaw_std"):
        (old,) = search_space(scenario, ["ekf.q_yaw_std"])
    (new,) = search_space(scenario, ["estimator.q_yaw_std"])
    assert old == new and new.targets == ((0, ("estimator", "q_yaw_std")),)


def test_flies_on_estimate_needs_the_sensors_unless_the_kind_is_truth():
    assert VehicleConfig().flies_on == "truth"  # the reference's default
    with pytest.raises(ConfigError, match="flies_on: estimate needs imu, gps and mag sensors"):
        catalog.load("01_intro", None, ["vehicles.0.flies_on=estimate"])
    catalog.load("01_intro", None, ["vehicles.0.flies_on=estimate", "vehicles.0.estimator={kind: truth}"])


def test_the_command_line_prints_the_deprecation_as_one_line(tmp_path, capsys):
    from quad_drake.cli import main

    path = write(tmp_path, DEPRECATED.format(ideal="false", extra=""))
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) in (0, 1)
    lines = [line for line in capsys.readouterr().err.splitlines() if "deprecated" in line]
    deprecated = "vehicles.0.use_ideal_estimator is deprecated: write vehicles.0.flies_on: estimate"
    assert lines == [f"quad-drake: warning: {deprecated}"]


def test_no_module_outside_the_registry_switches_on_an_estimator_kind():
    """A kind is the whole truth of its registry entry: nothing else compares a kind with a name."""
    names = "|".join(registry.KINDS)
    switch = re.compile(
        rf"""[=!]=\s*["']({names})["']|["']({names})["']\s*[=!]=|\bin\s*\(\s*["']({names})["']"""
    )
    package = Path(registry.__file__).resolve().parents[1]
    found = [
        f"{path.relative_to(package)}:{number}: {line.strip()}"
        for path in sorted(package.rglob("*.py"))
        if path.name != "registry.py"
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if switch.search(line)
    ]
    assert found == []
    assert switch.search('if estimator.kind == "eskf":') and switch.search(
        "if 'truth' != kind:"
    )  # it can fail


def test_every_builder_lives_on_the_systems_side():
    for kind in registry.KINDS.values():
        if kind.builder is None:
            continue
        module, _, name = kind.builder.partition(":")
        assert module.startswith("quad_drake.systems."), kind.name
        assert callable(kind.build_function()) and kind.build_function().__name__ == name


def test_replay_defaults_and_the_start_from_a_log_are_the_entry_s():
    eskf = registry.KINDS["eskf"]
    config = eskf.replay_config()
    # PX4's GPS noise: the vertical 1.5 times the horizontal, as PX4 fuses it
    assert (config.gps_pos_std, config.gps_vel_std) == ([0.5, 0.5, 0.75], [0.3, 0.3, 0.45])
    started = eskf.started_from_log(config, 0.1, 0.2, 0.3)
    assert started.init_ypr == [0.3, 0.2, 0.1]
    assert eskf.assuming_gps_noise(started, 10.0, 1e3).gps_vel_std == [1e3] * 3
    from quad_drake.flightlogs.reader import ImuBiasStart

    biases = ImuBiasStart((0.01, -0.02, 0.03), (0.001, 0.002, -0.003), (0.013, 0.014, 0.004), None)
    warm = eskf.started_with_biases(started, biases)
    assert (warm.init_accel_bias, warm.init_gyro_bias) == ([0.01, -0.02, 0.03], [0.001, 0.002, -0.003])
    assert warm.init_accel_bias_std == [0.013, 0.014, 0.004]  # PX4's stds where logged
    assert warm.init_gyro_bias_std == started.init_gyro_bias_std  # else the config's
    assert registry.KINDS["ekf7"].started_with_biases is None  # no bias states to start
    ekf7 = registry.KINDS["ekf7"]  # its parameters are its config's, as the ESKF's are
    config = ekf7.replay_config()
    noise = registry.PX4_NOISE
    assert (config.gps_pos_xy_std, config.gps_pos_z_std) == (noise["gps_pos_std"], 0.75)
    assert (config.gps_vel_xy_std, config.gps_vel_z_std) == (noise["gps_vel_std"], 0.45)
    assert config.mag_yaw_std == noise["heading_std"] and config.baro.height_std == noise["baro_height_std"]
    assert config.baro.datum_from_first_sample  # a log's baro datum: its first sample, as PX4's offset
    assert config.attitude_filter.tau == 0.5 and config != registry.Ekf7EstimatorConfig()
    started = ekf7.started_from_log(config, 0.1, 0.2, 0.3)
    assert started.init_state == [0.0] * 6 + [0.3]  # roll and pitch: the attitude filter finds them
    faked = ekf7.assuming_gps_noise(started, 10.0, 1e3)
    assert (faked.gps_pos_xy_std, faked.gps_pos_z_std, faked.gps_vel_xy_std, faked.gps_vel_z_std) == (
        10.0,
        10.0,
        1e3,
        1e3,
    )
