"""Bad input never costs work: refused (one line on stderr, exit 2) before anything flies; an
interrupt keeps the runs already finished."""

import json
import os
import signal
import subprocess
import sys
import tempfile

import pytest

from quad_drake.config import ConfigError
from quad_drake.outdir import check_output_dir

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
            "vehicles.0.ekf.q_vel_xy_std=1.0e+200",
            "q_vel_xy_std: a noise std must be 0 or within [1e-100, 1e+100]",
        ),
        ("vehicles.0.ekf.gps_pos_xy_std=1e-200", "gps_pos_xy_std: a noise std must be 0 or within"),
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
    singular_once = ["vehicles.0.ekf.init_std=[0, 0, 0, 0, 0, 0, 0]"]
    singular_once += [f"vehicles.0.ekf.q_{s}_std=0" for s in ("pos_xy", "pos_z", "vel_xy", "vel_z", "yaw")]
    singular_once += [
        f"vehicles.0.ekf.{f}=1e-100" for f in ("gps_pos_xy_std", "gps_vel_z_std", "mag_yaw_std")
    ]
    huge_q = ["vehicles.0.ekf.q_vel_xy_std=1e100", "vehicles.0.ekf.q_yaw_std=1e100"]
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
    from quad_drake import simulation

    def breaks_down(scenario):
        raise FloatingPointError("covariance P is not finite at t = 1.234 s")

    monkeypatch.setattr(simulation, "run", breaks_down)
    result = quad_drake_cli("run", "11_gps_update", "--no-plots", "--out", tmp_path / "out")
    assert result.returncode == 2
    assert result.stderr.strip() == (
        "quad-drake: 11_gps_update: the simulation broke down numerically (FloatingPointError: "
        "covariance P is not finite at t = 1.234 s); check the noise and covariance settings"
    )
    assert not (tmp_path / "out" / "11_gps_update").exists()
