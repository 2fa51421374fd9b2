"""Bad input never costs work: refused (one line on stderr, exit 2) before anything flies; an
interrupt keeps the runs already finished."""

import json
import os
import signal
import subprocess
import sys
import tempfile

import pytest

from quad_drake.config.errors import ConfigError
from quad_drake.output.outdir import check_output_dir
from quad_drake.output.results import FORMAT_VERSION

BAD_CRITERION = """
description: a criterion on a signal no vehicle logs
end_time: 0.2
criteria:
  - {kind: window, signal: Quad.Pos.W, threshold: 1, window: 0.1}
"""


def assert_refused(result, *fragments):
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr
    for fragment in fragments:
        assert fragment in result.stderr
    assert result.stdout == ""  # in particular no "== NAME" line: nothing flew


@pytest.fixture
def unwritable_dir(tmp_path):
    """An existing folder this process cannot write in (root writes through chmod: use /sys)."""
    folder = tmp_path / "read_only"
    folder.mkdir()
    folder.chmod(0o500)
    candidates = [folder, "/sys"]
    for candidate in candidates:
        try:
            tempfile.TemporaryFile(dir=candidate).close()
        except OSError:
            yield candidate
            break
    else:
        pytest.skip("no folder here refuses writes to this user")
    folder.chmod(0o700)


def unusable_outs(tmp_path, unwritable_dir):
    a_file = tmp_path / "a_file"
    a_file.write_text("not a folder")
    return {
        "file": (a_file, "exists and is not a folder"),
        "missing_parent": (tmp_path / "no" / "such" / "out", "parent folder"),
        "unwritable": (os.path.join(unwritable_dir, "out"), "cannot write in"),
        "unwritable_existing": (unwritable_dir, "cannot write in"),
    }


def test_check_output_dir_accepts_a_new_or_existing_folder_and_leaves_nothing(tmp_path):
    assert check_output_dir(tmp_path) == tmp_path
    assert check_output_dir(tmp_path / "new") == tmp_path / "new"
    assert list(tmp_path.iterdir()) == []


def test_check_output_dir_refuses_unusable_folders(tmp_path, unwritable_dir):
    for path, message in unusable_outs(tmp_path, unwritable_dir).values():
        with pytest.raises(ConfigError, match=message) as info:
            check_output_dir(path)
        assert str(info.value).startswith(f"--out {path}: ") and "\n" not in str(info.value)


@pytest.mark.parametrize("kind", ["file", "missing_parent", "unwritable", "unwritable_existing"])
@pytest.mark.parametrize("command", ["run", "montecarlo"])
def test_an_unusable_out_is_refused_before_anything_flies(
    quad_drake_cli, tmp_path, unwritable_dir, command, kind
):
    path, message = unusable_outs(tmp_path, unwritable_dir)[kind]
    args = ["01_intro", "02_attitude_control"] if command == "run" else ["10_mag_update", "--runs", "2"]
    assert_refused(quad_drake_cli(command, *args, "--out", str(path)), f"--out {path}: {message}")


def test_an_unknown_signal_in_any_scenario_of_a_batch_is_reported_with_its_file_first(
    quad_drake_cli, tmp_path
):
    bad = tmp_path / "bad_signal.yaml"
    bad.write_text(BAD_CRITERION)
    out = tmp_path / "out"
    result = quad_drake_cli(
        "run", "01_intro", "02_attitude_control", str(bad), "--out", str(out), "--no-plots"
    )
    assert_refused(result, f"{bad}: criteria.0.signal: unknown signal 'Quad.Pos.W'")
    assert not out.exists()
    assert_refused(quad_drake_cli("montecarlo", str(bad), "--runs", "2", "--out", str(out)), str(bad))


@pytest.mark.parametrize(
    "override, message",
    [
        (
            "vehicles.0.sensors.mag.period=1.0e-7",
            "mag.period: must be a whole multiple of the 2 ms onboard tick",
        ),
        (
            "vehicles.0.sensors.gps.period=0.0031",
            "gps.period: must be a whole multiple of the 2 ms onboard tick",
        ),
        (
            "vehicles.0.estimator.q_vel_xy_std=1.0e+200",
            "q_vel_xy_std: a noise std must be 0 or within [1e-100, 1e+100]",
        ),
        ("vehicles.0.estimator.gps_pos_xy_std=1e-200", "gps_pos_xy_std: a noise std must be 0 or within"),
    ],
)
def test_values_that_would_hang_or_break_the_filter_are_refused(quad_drake_cli, override, message):
    assert_refused(quad_drake_cli("run", "11_gps_update", "--set", override, "--no-plots"), message)


@pytest.mark.parametrize("command", ["run", "montecarlo"])
def test_the_reference_fidelity_on_an_error_state_ekf_is_refused(quad_drake_cli, command):
    result = quad_drake_cli(command, "11_gps_update_eskf", "--set", "fidelity=reference", "--no-plots")
    assert_refused(
        result, "vehicles.0.estimator: the error-state EKF is written for the physical accelerometer"
    )


@pytest.mark.slow
def test_the_edges_of_the_accepted_noise_range_fly_without_a_traceback(quad_drake_cli, tmp_path):
    # Zero P0 and Q with the smallest accepted R, then the largest accepted Q: the filter's
    # covariance stays usable, so the flight ends with a verdict (0 or 1), never a traceback.
    singular_once = ["vehicles.0.estimator.init_std=[0, 0, 0, 0, 0, 0, 0]"]
    singular_once += [
        f"vehicles.0.estimator.q_{s}_std=0" for s in ("pos_xy", "pos_z", "vel_xy", "vel_z", "yaw")
    ]
    singular_once += [
        f"vehicles.0.estimator.{f}=1e-100" for f in ("gps_pos_xy_std", "gps_vel_z_std", "mag_yaw_std")
    ]
    huge_q = ["vehicles.0.estimator.q_vel_xy_std=1e100", "vehicles.0.estimator.q_yaw_std=1e100"]
    for overrides in (singular_once, huge_q):
        sets = [a for o in ["end_time=1.5", *overrides] for a in ("--set", o)]
        result = quad_drake_cli("run", "11_gps_update", *sets, "--no-plots", "--out", str(tmp_path))
        assert result.returncode in (0, 1), result.stderr  # in-process: a traceback fails the test


@pytest.mark.slow
def test_ctrl_c_in_a_batch_keeps_the_finished_runs_and_exits_130(tmp_path):
    out = tmp_path / "out"
    process = subprocess.Popen(
        [sys.executable, "-m", "quad_drake", "run", "01_intro", "08_predict_state", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # a job started in the background inherits SIGINT ignored, and Python then installs no
        # KeyboardInterrupt handler: restore the default so the test sends what Ctrl-C sends
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    for line in process.stdout:  # 08 flies 40 s of simulated time: several seconds of wall time
        if line.startswith("== 08_predict_state"):
            break
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    assert (
        stderr.strip() == f"quad-drake: interrupted; kept the 1 finished run(s) in {out}/, {out}/index.html"
    )
    assert (out / "01_intro" / "logs.npz").is_file() and not (out / "08_predict_state").exists()
    assert [s["scenario"] for s in json.loads((out / "summary.json").read_text())] == ["01_intro"]
    assert "01_intro/report.html" in (out / "index.html").read_text()


def test_a_numerical_breakdown_during_a_flight_is_one_line_with_exit_2(quad_drake_cli, monkeypatch, tmp_path):
    # What validation lets through but a filter cannot carry (the EKF raises FloatingPointError
    # on a non-finite covariance; plain float code raises ZeroDivisionError or OverflowError).
    from quad_drake.running import simulation

    def breaks_down(scenario, progress=None):
        raise FloatingPointError("covariance P is not finite at t = 1.234 s")

    monkeypatch.setattr(simulation, "run", breaks_down)
    result = quad_drake_cli("run", "11_gps_update", "--no-plots", "--out", tmp_path / "out")
    assert result.returncode == 2
    assert result.stderr.strip() == (
        "quad-drake: 11_gps_update: the simulation broke down numerically (FloatingPointError: "
        "covariance P is not finite at t = 1.234 s); check the noise and covariance settings"
    )
    assert not (tmp_path / "out" / "11_gps_update").exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--set", "name=../../escape"], "name: '../../escape' is not a usable name"),
        (["--set", "name=/tmp/elsewhere"], "name: '/tmp/elsewhere' is not a usable name"),
        (["--set", "vehicles.0.name=../x"], "vehicles.0.name: '../x' is not a usable name"),
        (["--set", "vehicles.0.name=Quad.1"], "vehicles.0.name: 'Quad.1' is not a usable name"),
        (["--seed", "4294967296"], "--seed: seeds must lie in [0, 4294967295]"),
        (["--seed", "-1"], "--seed: seeds must lie in [0, 4294967295]"),
        (["--set", "seed=99999999999999999999"], "seed: must be <= 4294967295"),
        (["--set", "vehicles.0.physics.x_bounds=[5, -5]"], "x_bounds: must be [min, max] with min < max"),
        (["--set", "vehicles.0.initial_position=[0, 0, 1]"], "initial_position: z = 1 m is outside the room"),
        (["--set", "end_tme=3"], "end_tme: unknown key"),
    ],
)
def test_names_seeds_and_rooms_that_cannot_work_are_refused(quad_drake_cli, tmp_path, args, message):
    result = quad_drake_cli("run", "01_intro", *args, "--no-plots", "--out", str(tmp_path / "out"))
    assert_refused(result, message)
    if args[0] == "--set":
        assert result.stderr.strip().endswith(f"(--set {args[1]})")  # the mistake is on the command line
    assert not (tmp_path / "out").exists() and not (tmp_path.parent / "escape").exists()


def test_a_campaign_whose_last_seed_passes_the_limit_is_refused(quad_drake_cli, tmp_path):
    args = ["--runs", "2", "--seed", "4294967295", "--out", str(tmp_path)]
    result = quad_drake_cli("montecarlo", "01_intro", *args)
    assert_refused(result, "got 4294967295 to 4294967296")


def test_two_scenarios_of_one_name_or_names_with_all_are_refused(quad_drake_cli, tmp_path):
    copy = tmp_path / "01_intro.yaml"
    copy.write_text("end_time: 0.2\n")
    out = tmp_path / "out"
    assert_refused(quad_drake_cli("run", "01_intro", str(copy), "--out", str(out)), "two scenarios are named")
    assert_refused(quad_drake_cli("run", "01_intro", "--all", "--out", str(out)), "not both")
    assert not out.exists()


def test_a_diagram_path_that_cannot_be_written_is_refused(quad_drake_cli, tmp_path):
    assert_refused(quad_drake_cli("diagram", "01_intro", "-o", str(tmp_path)), "name a .svg file")
    assert_refused(quad_drake_cli("diagram", "01_intro", "-o", str(tmp_path / "d.png")), "name a .svg file")
    missing = tmp_path / "no" / "such" / "d.svg"
    assert_refused(quad_drake_cli("diagram", "01_intro", "-o", str(missing)), "parent folder")


@pytest.mark.parametrize("content", [b"not a zip", b"PK\x03\x04 truncated"])
@pytest.mark.parametrize("command", ["export", "noise-std"])
def test_a_damaged_log_file_is_one_line(quad_drake_cli, tmp_path, command, content):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "summary.json").write_text(json.dumps({"format_version": FORMAT_VERSION, "kind": "run"}))
    (run_dir / "logs.npz").write_bytes(content)
    assert_refused(quad_drake_cli(command, str(run_dir)), "logs.npz: not a readable quad_drake log")
