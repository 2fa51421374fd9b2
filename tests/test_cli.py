"""The command-line contract: ``main()`` in this process, what the console script runs (the
``quad_drake_cli`` fixture), and a real subprocess where the process itself is under test (an
exit status through a new interpreter, the modules it imports, the working folder it inherits)."""

import json
import subprocess
import sys

import pytest


def cli(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "quad_drake.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=600
    )


def test_list_names_every_scenario_with_a_description(quad_drake_cli):
    result = quad_drake_cli("list")
    assert result.returncode == 0
    lines = result.stdout.strip().splitlines()
    # 01-11, 11 eskf, faults 12-18, the air 19-22 (+ eskf), aiding 23-25, GSF 26-28, failsafe 29
    assert len(lines) == 31
    assert lines[0].startswith("01_intro") and "hover" in lines[0].lower()
    names = [line.split()[0] for line in lines]
    columns = {len(line) - len(line[len(name) :].lstrip()) for line, name in zip(lines, names, strict=True)}
    assert columns == {max(map(len, names)) + 2}  # every description in one column, after the longest name


def test_the_run_table_fits_a_long_scenario_name():
    from quad_drake.cli import _table

    row = {
        "criteria": [{"passed": True}],
        "passed": True,
        "seed": 0,
        "wall_time_s": 1.0,
        "real_time_factor": 9.0,
    }
    rows = [{**row, "scenario": "a_rather_long_scenario_name_of_forty_chars"}, {**row, "scenario": "short"}]
    header, _, *lines = _table(rows).splitlines()
    assert len({len(header), *map(len, lines)}) == 1 and header.index("seed") == lines[0].index("    0") + 1


def test_run_prints_reference_lines_and_writes_results(quad_drake_cli, tmp_path):
    result = quad_drake_cli("run", "01_intro", "02_attitude_control", "--out", str(tmp_path), "--no-plots")
    assert result.returncode == 0, result.stderr
    expected = "PASS: ABS(Quad.PosFollowErr) was less than 0.500000 for at least 0.800000 seconds"
    assert expected in result.stdout
    assert "PASS: ABS(Quad.Omega.X) was less than 2.500000" in result.stdout
    assert "02_attitude_control" in result.stdout.splitlines()[-1]
    for name in ("01_intro", "02_attitude_control"):
        run_dir = tmp_path / name
        assert (run_dir / "logs.npz").is_file() and (run_dir / "config.yaml").is_file()
        assert json.loads((run_dir / "summary.json").read_text())["passed"] is True
    summaries = json.loads((tmp_path / "summary.json").read_text())
    assert [s["scenario"] for s in summaries] == ["01_intro", "02_attitude_control"]


def test_run_accepts_a_yaml_path_seed_and_overrides(quad_drake_cli, tmp_path):
    from quad_drake.running import catalog

    path = catalog.bundled_scenarios()["01_intro"]
    result = quad_drake_cli(
        "run", str(path), "--seed", "9", "--set", "end_time=0.5", "--out", str(tmp_path), "--no-plots"
    )
    from quad_drake.output.results import variant_name

    run_dir = tmp_path / variant_name("01_intro", 9, ["end_time=0.5"])  # 01_intro-seed9-set<hash>
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["seed"] == 9 and summary["end_time"] == 0.5
    assert "end_time: 0.5" in (run_dir / "config.yaml").read_text()
    assert result.returncode == 1  # a 0.8 s window cannot pass in a 0.5 s run
    assert "FAIL: ABS(Quad.PosFollowErr)" in result.stdout


@pytest.mark.slow
def test_noise_std_measures_the_configured_noise(quad_drake_cli, tmp_path):
    assert quad_drake_cli("run", "06_sensor_noise", "--out", str(tmp_path), "--no-plots").returncode == 0
    result = quad_drake_cli("noise-std", str(tmp_path / "06_sensor_noise"))
    assert result.returncode == 0, result.stderr
    values = dict(line.split(": ") for line in result.stdout.strip().splitlines())
    assert abs(float(values["Quad.GPS.X"]) - 0.7) < 0.15  # ~100 samples: 4 standard errors
    assert abs(float(values["Quad.IMU.AX"]) - 0.5) < 0.03  # 2000 samples


@pytest.mark.parametrize(
    "args, message",
    [
        (["run", "no_such_scenario"], "unknown scenario 'no_such_scenario'"),
        (["run", "missing.yaml"], "missing.yaml: no such scenario file"),
        (["run", "01_intro", "--set", "end_time"], "expected dotted.key=value"),
        (["run", "01_intro", "--set", "vehicles.0.physics.mas=1"], "vehicles.0.physics.mas: unknown key"),
        (["run", "01_intro", "--set", "end_time=soon"], "end_time: expected float, got 'soon'"),
        (["run", "01_intro", "--set", "vehicles.0.initial_position=[0, 1]"], "expected 3 values, got 2"),
        (["run", "01_intro", "--set", "vehicles.0.sensors.gps={period: -1}"], "gps.period: must be a whole"),
        (["run", "01_intro", "--set", "vehicles.0.sensors.imu={gyro_std: [0, -1, 0]}"], "must be >= 0"),
        (["run", "01_intro", "--set", "vehicles.0.physics.mass=-0.5"], "physics.mass: must be > 0"),
        (
            ["run", "01_intro", "--set", "vehicles.0.trajectory={kind: file, file: nope.txt}"],
            "no such trajectory file 'nope.txt'",
        ),
        (["run", "01_intro", "--seed", "-1"], "--seed: seeds must lie in [0, 4294967295]"),
        (["run"], "name at least one scenario"),
        (["noise-std", "/nonexistent/run"], "no logs.npz"),
        (["export", "/nonexistent/run"], "/nonexistent/run: no logs.npz"),
    ],
)
def test_bad_input_is_one_line_on_stderr_with_exit_2(quad_drake_cli, args, message):
    result = quad_drake_cli(*args)  # in this process: the same main() as the console script
    assert result.returncode == 2
    assert message in result.stderr
    assert "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert result.stdout == ""


def test_bad_input_in_a_new_process_exits_2_with_one_line():
    result = cli("run", "no_such_scenario")
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.startswith("quad-drake: unknown scenario 'no_such_scenario' (known: 01_intro, ")
    assert len(result.stderr.strip().splitlines()) == 1


def test_malformed_trajectory_file_names_file_and_line(quad_drake_cli, tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("0, 0, 0, -1\n1, 0, zero, -1\n")
    result = quad_drake_cli("run", "01_intro", "--set", f"vehicles.0.trajectory={{kind: file, file: {bad}}}")
    assert result.returncode == 2
    assert f"{bad}:2" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.slow
def test_run_writes_plots_report_replay_and_index(quad_drake_cli, tmp_path):
    result = quad_drake_cli(
        "run", "09_predict_covariance", "01_intro", "--set", "end_time=0.3", "--out", str(tmp_path)
    )
    assert result.returncode in (0, 1), result.stderr  # short runs may fail a criterion
    assert "Traceback" not in result.stderr
    from quad_drake.output.results import variant_name

    fleet, intro = (
        variant_name(name, None, ["end_time=0.3"]) for name in ("09_predict_covariance", "01_intro")
    )
    for name in ("fleet_errors.png", "report.html", "replay.html", "logs.npz"):
        assert (tmp_path / fleet / name).is_file(), name
    assert (tmp_path / intro / "criterion_1.png").is_file()
    index = (tmp_path / "index.html").read_text()
    assert f"{fleet}/report.html" in index and f"{intro}/report.html" in index


HEAVY_MODULES = ("scipy.stats", "scipy.optimize", "matplotlib", "cma", "dask")
"""Imported only by the commands that need them (campaigns, tuning, plots); a run needs only
``scipy.special`` (the gates' chi-square threshold) and numba (its handlers' compiled kernels)."""


def test_a_run_without_plots_imports_no_heavy_module(tmp_path):
    code = (
        "import sys\n"
        "from quad_drake.cli import main\n"
        f"args = ['run', '11_gps_update', '--no-plots', '--set', 'end_time=1', '--out', {str(tmp_path)!r}]\n"
        "status = main(args)\n"
        f"print('heavy:', *sorted(m for m in {HEAVY_MODULES!r} if m in sys.modules))\n"
        "sys.exit(status)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert result.returncode == 1, result.stderr  # a verdict: 1 s cannot pass 11's 20 s criterion
    assert result.stdout.splitlines()[-1] == "heavy:", result.stdout


def test_a_run_without_out_writes_into_the_working_folder_not_the_checkout(tmp_path):
    # The suite's own guard (conftest): the tests run in a temporary working folder, so the
    # default ``out`` of a subprocess lands there and the checkout's out/ stays as the user left it.
    from conftest import REPOSITORY_OUT, folder_snapshot

    before = folder_snapshot(REPOSITORY_OUT)
    result = cli("run", "01_intro", "--no-plots")
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "out" / "01_intro" / "summary.json").is_file()
    assert folder_snapshot(REPOSITORY_OUT) == before


def test_bare_quad_drake_prints_the_help_with_the_exit_codes(quad_drake_cli):
    bare = quad_drake_cli()
    assert bare.returncode == 0 and bare.stdout.startswith("usage: quad-drake") and bare.stderr == ""
    assert "exit codes:" in bare.stdout
    for code in ("  0 ", "  1 ", "  2 ", "  3 ", "  130 "):
        assert code in bare.stdout, code


@pytest.mark.parametrize(
    "args, hint",
    [
        (["run", "11_gps_updat"], "(did you mean '11_gps_update'"),
        (["run", "01_intro", "--set", "vehicles.0.physics.mas=1"], "(did you mean 'mass'?)"),
        (
            ["run", "01_intro", "--set", "criteria.0.signal=Quad.PosFolowErr"],
            "(did you mean 'Quad.PosFollowErr'",
        ),
        (["tune", "11_gps_update", "--params", "estimator.q_yaw_sd"], "(did you mean 'q_yaw_std'"),
    ],
)
def test_a_misspelt_name_gets_a_did_you_mean(quad_drake_cli, tmp_path, args, hint):
    result = quad_drake_cli(*args, "--out", tmp_path / "out")
    assert result.returncode == 2 and hint in result.stderr and len(result.stderr.splitlines()) == 1


def test_argument_limits_are_checked_before_the_heavy_imports():
    code = (
        "import sys\nfrom quad_drake.cli import main\n"
        "runs, batch = ['--runs', '0'], ['--fleet', '--batch', '0']\n"
        "for argv in (['montecarlo', '01_intro', *runs], ['montecarlo', '01_intro', *batch]):\n"
        "    assert main(argv) == 2\n"
        "print(sorted(m for m in ('quad_drake.campaigns', 'pydrake.systems', 'numba') if m in sys.modules))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"
    assert (
        "--runs and --jobs must be >= 1" in result.stderr and "--batch must be >= 1, got 0" in result.stderr
    )
