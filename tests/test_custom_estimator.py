"""A user's own estimator (``estimator: {kind: custom}``): the README's example flies 11 and a
20-run campaign; a wrong one (defined below) is one line and exit 2 before any flight."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from quad_drake import catalog
from quad_drake.cli import main
from quad_drake.config import ConfigError
from quad_drake.estimation import custom
from quad_drake.estimation.registry import vehicle_vocabulary
from quad_drake.simulation import run

README = Path(__file__).resolve().parent.parent / "README.md"
HERE = Path(__file__).resolve()


def readme_estimator(folder):
    """The README's "Bring your own estimator" example, written to folder/my_ekf.py."""
    section = README.read_text().split("### Bring your own estimator", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    path = folder / "my_ekf.py"
    path.write_text(code)
    return path


def custom_override(factory, params=""):
    return f'vehicles.0.estimator={{kind: custom, factory: "{factory}"{params}}}'


@pytest.mark.slow
def test_the_readme_example_flies_11(tmp_path, monkeypatch):
    readme_estimator(tmp_path)
    monkeypatch.chdir(tmp_path)  # the README runs it from the folder that holds my_ekf.py
    scenario = catalog.load("11_gps_update", None, [custom_override("my_ekf.py:MyEkf")])
    assert scenario.vehicles[0].estimator.factory == f"{tmp_path / 'my_ekf.py'}:MyEkf"  # made absolute
    vocabulary = vehicle_vocabulary(scenario.vehicles[0])
    assert vocabulary.state_names == ("X", "Y", "Z", "VX", "VY", "VZ", "Yaw")
    result = run(scenario)
    assert result.passed, [r.to_dict() for r in result.criteria if not r.passed]
    diagnostics = result.logs["Quad"]["diagnostics"]
    assert np.isfinite(diagnostics[-1, 0]) and np.isfinite(diagnostics[-1, 2])  # GPS and mag NIS reported
    assert result.logs["Quad"]["covariance"].shape[1] == 49


@pytest.mark.slow
def test_the_readme_example_flies_a_20_run_campaign_on_the_process_pool(tmp_path, monkeypatch, capsys):
    readme_estimator(tmp_path)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    code = main(
        ["montecarlo", "11_gps_update", "--runs", "20", "--jobs", "2", "--no-plots", "--out", str(out),
         "--set", "end_time=6", "--set", "criteria.0.window=4", "--set", custom_override("my_ekf.py:MyEkf")]
    )  # fmt: skip
    printed = capsys.readouterr().out
    assert code in (0, 1), printed  # 1: a consistency criterion failed (6 s flights start cautious)
    (summary,) = out.glob("*/summary.json")
    summary = json.loads(summary.read_text())
    assert summary["runs"] == 20 and "process-pool" in printed
    every = summary["criteria"][-1]
    assert every["criterion"] == "all criteria" and every["passes"] == 20, every  # each run flew and passed


class MissingUpdateMag:
    state_names = ("X", "Y", "Z")

    def predict(self, dt, accel, gyro):
        pass

    def update_gps(self, position, velocity):
        pass

    def estimate(self):
        return np.zeros(9)

    def covariance(self):
        return np.eye(3)


class WrongCovarianceSize(MissingUpdateMag):
    def update_mag(self, yaw):
        pass

    def covariance(self):
        return np.eye(2)


class RaisesInUpdate(WrongCovarianceSize):
    def covariance(self):
        return np.eye(3)

    def update_gps(self, position, velocity):
        raise np.linalg.LinAlgError("Singular matrix")


@pytest.mark.parametrize(
    "factory, message",
    [
        (f"{HERE}:MissingUpdateMag", "the estimator has no method update_mag"),
        (f"{HERE}:WrongCovarianceSize", "covariance() returned shape (2, 2), expected (3, 3)"),
        (f"{HERE}:RaisesInUpdate", "update_gps() raised LinAlgError: Singular matrix"),
        (f"{HERE}:NoSuchClass", "has no callable 'NoSuchClass'"),
        ("no_such_module_here:Make", "cannot import no_such_module_here: ModuleNotFoundError"),
        ("nowhere.py:Make", "no such file nowhere.py"),
        ("without_a_name", "expected 'module:name' or 'path/to/file.py:name'"),
    ],
)
def test_a_wrong_estimator_is_one_line_and_exit_2_before_any_flight(tmp_path, capsys, factory, message):
    out = tmp_path / "out"
    code = main(["run", "11_gps_update", "--no-plots", "--out", str(out), "--set", custom_override(factory)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.startswith("quad-drake: ") and "\n" not in err and message in err, err
    assert "vehicles.0.estimator" in err
    assert not out.exists()  # nothing flew


def test_wrong_params_are_one_line(tmp_path):
    readme_estimator(tmp_path)
    factory = f"{tmp_path / 'my_ekf.py'}:MyEkf"
    with pytest.raises(
        ConfigError, match=r"MyEkf\(\*\*params\) raised TypeError: .*unexpected keyword argument 'q_vel'"
    ):
        catalog.load("11_gps_update", None, [custom_override(factory, ", params: {q_vel: 0.5}")])
    with pytest.raises(ConfigError, match="kind custom needs a factory"):
        catalog.load("11_gps_update", None, ["vehicles.0.estimator={kind: custom}"])


def test_the_adapter_fuses_each_sample_once_gates_and_counts(tmp_path):
    from pydrake.systems.analysis import Simulator

    from quad_drake.estimation.vocabulary import DIAG
    from quad_drake.systems.custom_estimator import PythonEstimator

    readme_estimator(tmp_path)
    factory = f"{tmp_path / 'my_ekf.py'}:MyEkf"
    vehicle = catalog.load("11_gps_update", None, [custom_override(factory)]).vehicles[0]
    system = PythonEstimator(vehicle.estimator, vehicle.sensors, n=2)
    context = system.CreateDefaultContext()
    imu = np.tile([0.0, 0.0, -9.81, 0.0, 0.0, 0.0], 2)
    imu[6:] = np.nan  # vehicle 1: its IMU is out
    system.GetInputPort("imu").FixValue(context, imu)
    gps = np.array([0.0, 0.0, -1.0, 0, 0, 0, 0.1, 50.0, 0.0, -1.0, 0, 0, 0, 0.1])  # vehicle 1: 50 m off
    system.GetInputPort("gps").FixValue(context, gps)
    system.GetInputPort("mag").FixValue(context, np.array([0.0, 0.008, np.nan, 0.008]))
    Simulator(system, context).AdvanceTo(0.2)  # 100 ticks, one GPS and one mag sample each
    diagnostics = system.GetOutputPort("diagnostics").Eval(context).reshape(2, -1)
    assert (
        diagnostics[0, DIAG["gps_gated"]] == 0 and diagnostics[1, DIAG["gps_gated"]] == 1
    )  # once, not per tick
    assert diagnostics[0, DIAG["gps_stamp"]] == 0.1 and diagnostics[0, DIAG["mag_stamp"]] == 0.008
    assert diagnostics[1, DIAG["nonfinite_samples"]] == 100 + 1  # every IMU tick, the one mag sample
    estimate = system.GetOutputPort("estimated_state").Eval(context).reshape(2, 13)
    assert (
        np.isnan(estimate[1, 10:13]).all() and np.isfinite(estimate[0]).all()
    )  # no body rate without an IMU


def test_check_runs_one_step_of_each_method(tmp_path):
    readme_estimator(tmp_path)
    names = custom.check_estimator(f"{tmp_path / 'my_ekf.py'}:MyEkf", {}, 0.002)
    assert names == ("X", "Y", "Z", "VX", "VY", "VZ", "Yaw")
