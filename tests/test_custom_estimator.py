"""A user's own estimator (``estimator: {kind: custom}``): the manual's example flies 11 and a
20-run campaign; a wrong one (defined below) is one line and exit 2 before any flight."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from quad_drake.cli import main
from quad_drake.config.errors import ConfigError
from quad_drake.estimation import custom
from quad_drake.estimation.registry import vehicle_vocabulary
from quad_drake.running import catalog
from quad_drake.running.simulation import run

ESTIMATORS_GUIDE = Path(__file__).resolve().parent.parent / "docs" / "guide" / "04_estimators.md"
HERE = Path(__file__).resolve()


def manual_estimator(folder):
    """The manual's "Bring your own estimator" example (docs/guide), written to folder/my_ekf.py."""
    section = ESTIMATORS_GUIDE.read_text(encoding="utf-8").split("## Bring your own estimator", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    path = folder / "my_ekf.py"
    path.write_text(code)
    return path


def custom_override(factory, params=""):
    return f'vehicles.0.estimator={{kind: custom, factory: "{factory}"{params}}}'


@pytest.mark.slow
def test_the_manual_example_flies_11(tmp_path, monkeypatch):
    manual_estimator(tmp_path)
    monkeypatch.chdir(tmp_path)  # the manual runs it from the folder that holds my_ekf.py
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
def test_the_manual_example_flies_a_campaign_on_the_process_pool(tmp_path, monkeypatch, capsys):
    # Two runs per worker: each worker imports the user's file and flies more than one run of it
    # (20 runs before 2026-12-06 flew the same path ten times per worker, 32 s CPU against 13).
    # 3 s flights, the window 2 s (6 and 4 until 2026-12-06; what is checked is that the user's
    # file flies on the workers, not for how long): each of seeds 0-23 passed it.
    manual_estimator(tmp_path)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    code = main(
        ["montecarlo", "11_gps_update", "--runs", "4", "--jobs", "2", "--no-plots", "--out", str(out),
         "--set", "end_time=3", "--set", "criteria.0.window=2", "--set", custom_override("my_ekf.py:MyEkf")]
    )  # fmt: skip
    printed = capsys.readouterr().out
    assert code in (0, 1), printed  # 1: a consistency criterion failed (short flights start cautious)
    (summary,) = out.glob("*/summary.json")
    summary = json.loads(summary.read_text())
    assert summary["runs"] == 4 and "process-pool" in printed
    every = summary["criteria"][-1]
    assert every["criterion"] == "all criteria" and every["passes"] == 4, every  # each run flew and passed


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
    manual_estimator(tmp_path)
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

    manual_estimator(tmp_path)
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


def test_each_context_flies_its_own_estimator_objects(tmp_path):
    # The objects advance in place (no deep copy per tick), yet each context holds its own.
    from conftest import assert_each_context_flies_its_own

    from quad_drake.systems.custom_estimator import PythonEstimator

    manual_estimator(tmp_path)
    factory = f"{tmp_path / 'my_ekf.py'}:MyEkf"
    vehicle = catalog.load("11_gps_update", None, [custom_override(factory)]).vehicles[0]
    assert_each_context_flies_its_own(PythonEstimator(vehicle.estimator, vehicle.sensors, n=2))


def test_check_runs_one_step_of_each_method(tmp_path):
    manual_estimator(tmp_path)
    names = custom.check_estimator(f"{tmp_path / 'my_ekf.py'}:MyEkf", {}, 0.002)
    assert names == ("X", "Y", "Z", "VX", "VY", "VZ", "Yaw")


USER_HELPERS = """
def check_tick(ticks, limit):
    if ticks > limit:
        raise ZeroDivisionError(f"my bug at tick {ticks}")
"""

USER_ESTIMATOR = '''
from my_ekf import MyEkf
from user_helpers import check_tick  # a sibling module of this file


class FailsAtTick(MyEkf):
    """The README's estimator, whose predict() raises (in a sibling module) after `limit` ticks."""

    def __init__(self, limit=50, **params):
        super().__init__(**params)
        self.ticks, self.limit = 0, limit

    def predict(self, dt, accel, gyro):
        self.ticks += 1
        check_tick(self.ticks, self.limit)
        super().predict(dt, accel, gyro)
'''


def user_folder(folder):
    """A user's folder: the README's my_ekf.py and user_estimator.py, whose FailsAtTick imports
    its sibling modules (my_ekf, user_helpers) and raises at the 51st IMU tick (t = 0.1 s)."""
    folder.mkdir(exist_ok=True)
    manual_estimator(folder)
    (folder / "user_helpers.py").write_text(USER_HELPERS)
    (folder / "user_estimator.py").write_text(USER_ESTIMATOR)
    return folder


def test_a_factory_file_imports_its_sibling_modules(tmp_path, monkeypatch):
    user_folder(tmp_path / "mine")
    monkeypatch.chdir(tmp_path)  # the factory's folder is not the working directory
    made = custom.load_factory(str(tmp_path / "mine" / "user_estimator.py") + ":FailsAtTick")
    assert made(limit=3).limit == 3


FLIGHT_SETS = ["end_time=1", "criteria.0.window=0.5"]
COMMANDS = {
    "run": ["run", "--no-plots"],
    "montecarlo": ["montecarlo", "--runs", "2", "--jobs", "1", "--no-plots", "--quiet"],
    "montecarlo --fleet": [
        "montecarlo",
        "--runs",
        "3",
        "--jobs",
        "1",
        "--fleet",
        "--batch",
        "3",
        "--no-plots",
    ],
}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_an_estimator_raising_mid_flight_is_one_line_then_the_users_frames_and_exit_4(
    tmp_path, monkeypatch, capsys, command
):
    user_folder(tmp_path)
    monkeypatch.chdir(tmp_path)
    sets = [*FLIGHT_SETS, custom_override("user_estimator.py:FailsAtTick")]
    argv = [*COMMANDS[command], "11_gps_update", "--out", str(tmp_path / "out")]
    code = main(argv + [arg for text in sets for arg in ("--set", text)])
    err = capsys.readouterr().err.splitlines()
    assert code == 4, err
    (first,) = [i for i, line in enumerate(err) if line.startswith("quad-drake: at t")]
    line, frames = err[first], err[first + 1 :]
    assert line.startswith("quad-drake: at t = 0.100 s of the flight, Quad's estimator ")
    assert "predict() raised ZeroDivisionError: my bug at tick 51; seed 0" in line
    if command != "run":  # the hint reproduces the failing run: every --set, its seed
        hint = "reproduce with quad-drake run 11_gps_update " + " ".join(f"--set '{s}'" for s in sets)
        hint = hint.replace("'end_time=1'", "end_time=1").replace(
            "'criteria.0.window=0.5'", "criteria.0.window=0.5"
        )
        assert line.endswith(f"{hint} --seed 0"), line
    assert frames[0] == "Traceback (most recent call last):" and frames[-1].startswith("ZeroDivisionError")
    files = [text.split('"')[1] for text in frames if text.startswith('  File "')]
    # theirs only (user_helpers is the first test's module of that name: Python caches it)
    assert [Path(f).name for f in files] == ["user_estimator.py", "user_helpers.py"], frames


def test_the_campaign_page_reproduces_a_run_with_every_set(tmp_path, monkeypatch):
    import html
    import shlex

    manual_estimator(tmp_path)  # a pure-Python filter: no kernel to compile
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    sets = ["end_time=0.5", "criteria.0.window=0.2", custom_override("my_ekf.py:MyEkf")]
    argv = [
        "montecarlo",
        "11_gps_update",
        "--runs",
        "1",
        "--jobs",
        "1",
        "--no-plots",
        "--quiet",
        "--out",
        str(out),
    ]
    main(argv + [arg for text in sets for arg in ("--set", text)])
    (page,) = out.glob("*/report.html")
    command = (
        "quad-drake run 11_gps_update" + "".join(f" --set {shlex.quote(s)}" for s in sets) + " --seed SEED"
    )
    assert command in html.unescape(page.read_text())


PLAIN_SCRIPT = """
from quad_drake.running import catalog
from quad_drake.campaigns import ProcessPoolRunner, run_campaign

scenario = catalog.load("11_gps_update", None, ["end_time=0.2", "criteria.0.window=0.1"])
run_campaign(scenario, 2, runner=ProcessPoolRunner(2), progress=False)
"""


@pytest.mark.slow
def test_a_process_pool_campaign_in_a_script_without_the_main_guard_says_so(tmp_path):
    import os
    import subprocess
    import sys

    script = tmp_path / "plain.py"
    script.write_text(PLAIN_SCRIPT)
    import quad_drake

    env = {**os.environ, "PYTHONPATH": str(Path(quad_drake.__file__).parent.parent)}  # the tree under test
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=300)
    last = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 1 and "BrokenProcessPool" not in done.stderr, done.stderr
    assert (
        last.startswith("quad_drake.campaigns.runners.WorkersDied: ") and 'if __name__ == "__main__":' in last
    )
    worker_lines = [text for text in done.stderr.splitlines() if text.startswith("quad-drake worker: ")]
    # each worker says it in one line (one may be stopped before it does, once the pool is broken)
    assert 1 <= len(worker_lines) <= 2 and "Traceback" not in done.stderr.split("quad-drake worker")[0]


def test_a_saved_config_names_the_factory_relative_to_its_folder_and_moves_with_it(tmp_path, monkeypatch):
    import shutil

    from quad_drake.config import dump_scenario, load_scenario

    project = tmp_path / "project"
    user_folder(project)
    monkeypatch.chdir(project)
    scenario = catalog.load("11_gps_update", None, [custom_override("user_estimator.py:FailsAtTick")])
    assert scenario.vehicles[0].estimator.factory == f"{project / 'user_estimator.py'}:FailsAtTick"
    (project / "out" / "tune").mkdir(parents=True)
    saved = project / "out" / "tune" / "tuned.yaml"  # as quad-drake tune saves its tuned.yaml
    saved.write_text(dump_scenario(scenario, saved.parent))
    assert "factory: ../../user_estimator.py:FailsAtTick" in saved.read_text()
    assert str(tmp_path) not in saved.read_text()
    moved = shutil.move(project, tmp_path / "elsewhere")  # the project moves (or is cloned) whole
    monkeypatch.chdir(tmp_path)
    again = load_scenario(Path(moved) / "out" / "tune" / "tuned.yaml")
    assert (
        again.vehicles[0].estimator.factory == f"{tmp_path / 'elsewhere' / 'user_estimator.py'}:FailsAtTick"
    )


def test_an_estimator_raising_in_a_tune_is_exit_4_and_its_hint_carries_the_candidates_values(
    tmp_path, monkeypatch, capsys
):
    user_folder(tmp_path)
    monkeypatch.chdir(tmp_path)
    sets = [*FLIGHT_SETS, custom_override("user_estimator.py:FailsAtTick", ", params: {q_vel_std: 0.5}")]
    argv = [
        "tune",
        "11_gps_update",
        "--budget",
        "2",
        "--seeds",
        "1",
        "--holdout",
        "1",
        "--jobs",
        "1",
        "--quiet",
    ]
    code = main([*argv, "--out", str(tmp_path / "tune")] + [arg for text in sets for arg in ("--set", text)])
    err = capsys.readouterr().err.splitlines()
    assert code == 4, err
    (line,) = [text for text in err if text.startswith("quad-drake: at t = 0.100 s of the flight")]
    assert "reproduce with quad-drake run 11_gps_update --set end_time=1 --set criteria.0.window=0.5 " in line
    assert "--set vehicles.0.estimator.params.q_vel_std=" in line and line.endswith(
        "in a candidate of the tune"
    )


NO_AID_ESTIMATOR = '''
import numpy as np


class Recording:
    """A do-nothing estimator that books what the adapter hands it."""

    state_names = ("X", "Y", "Z")

    def __init__(self):
        self.calls = []

    def predict(self, dt, accel, gyro):
        pass

    def update_gps(self, position, velocity):
        self.calls.append(("gps", position, velocity))

    def update_mag(self, yaw):
        pass

    def estimate(self):
        return np.zeros(9)

    def covariance(self):
        return np.eye(3)


class RecordingNoAid(Recording):
    def update_no_aid(self, position, velocity, std):
        self.calls.append(("no_aid", position, velocity, std))
'''


@pytest.mark.parametrize("own_method", [True, False])
def test_a_replays_no_aiding_samples_reach_update_no_aid_with_their_std_else_update_gps(tmp_path, own_method):
    """A replay's no-aiding samples (PX4's fake position / zero velocity while not GPS-aided) on
    the ``no_aid`` input: ``update_no_aid(position, velocity, std)`` once per sample where the
    estimator has it, else ``update_gps`` (its own GPS noise), as the replay's note says."""
    from pydrake.systems.analysis import Simulator

    from quad_drake.config import GpsParams, ImuParams, SensorsConfig
    from quad_drake.estimation.registry import CustomEstimatorConfig
    from quad_drake.systems.custom_estimator import PythonEstimator

    (tmp_path / "recording.py").write_text(NO_AID_ESTIMATOR)
    name = "RecordingNoAid" if own_method else "Recording"
    config = CustomEstimatorConfig(factory=f"{tmp_path / 'recording.py'}:{name}")
    sensors = SensorsConfig(imu=ImuParams(), gps=GpsParams(), no_aid=True)
    system = PythonEstimator(config, sensors)
    context = system.CreateDefaultContext()
    system.GetInputPort("imu").FixValue(context, [0.0, 0.0, -9.81, 0.0, 0.0, 0.0])
    system.GetInputPort("gps").FixValue(context, [0.0] * 6 + [-1.0])
    std = [0.01, 0.01, np.inf, 0.2, 0.2, 0.2]
    system.GetInputPort("no_aid").FixValue(context, [1.0, 2.0, 0.0, 0.0, 0.0, 0.0] + std + [0.1])
    Simulator(system, context).AdvanceTo(0.1)  # 50 ticks, one no-aiding sample
    (estimator,) = context.get_abstract_state(0).get_value()
    (call,) = estimator.calls
    assert call[0] == ("no_aid" if own_method else "gps")
    np.testing.assert_array_equal(call[1], [1.0, 2.0, 0.0])
    if own_method:
        np.testing.assert_array_equal(call[3], std)
