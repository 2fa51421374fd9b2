"""Fleet mode: the fleet Diagram against the per-vehicle one, run i the same in any batch and
on any runner, the campaign outputs, the CLI's --fleet/--batch and its refusals."""

import json

import numpy as np
import pytest

from quad_drake import catalog
from quad_drake.campaigns import ProcessPoolRunner, run_campaign, table
from quad_drake.config import ConfigError
from quad_drake.fleet.runner import RUNNER, batches, default_batch_size, simulate_batch
from quad_drake.fleet.simulation import batch_bytes, run_fleet
from quad_drake.simulation import run


def noiseless(name, *overrides):
    """A scenario with every noise source off, so a fleet and a per-vehicle run must agree exactly."""
    scenario = catalog.load(name, None, list(overrides))
    for vehicle in scenario.vehicles:
        vehicle.physics.motor_noise = 0.0
        sensors = vehicle.sensors
        for params in (sensors.imu, sensors.gps):
            for field in ("accel_std", "gyro_std", "pos_std", "vel_std"):
                if params is not None and hasattr(params, field):
                    setattr(params, field, [0.0, 0.0, 0.0])
        if sensors.mag is not None:
            sensors.mag.yaw_std = 0.0
    return scenario


@pytest.mark.parametrize(
    "name, overrides",
    [
        ("03_position_control", ()),
        ("05_trajectory_follow", ("end_time=3",)),
        ("02_attitude_control", ("fidelity=reference",)),
    ],
)
def test_noiseless_fleet_flies_every_vehicle_as_the_per_vehicle_diagram(name, overrides):
    """Same tick order and kernels: every logged signal of every fleet vehicle equals the
    per-vehicle Diagram's to 1e-12 (in practice bit for bit), in both fidelity modes."""
    scenario = noiseless(name, *overrides)
    single = run(scenario)
    times, logs, _ = run_fleet(scenario, [11, 12, 13])
    np.testing.assert_array_equal(times, single.times)
    for vehicle, vehicle_logs in single.logs.items():
        assert set(logs[vehicle]) == set(vehicle_logs)
        for log_name, data in vehicle_logs.items():
            assert logs[vehicle][log_name].shape == (data.shape[0], 3, data.shape[1])
            for j in range(3):
                np.testing.assert_allclose(logs[vehicle][log_name][:, j, :], data, rtol=0, atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize(
    "name, end_time",
    [("11_gps_update", 3), ("12_gps_outage", 10.5), ("16_mag_disturbance", 10.5), ("18_imu_dropout", 10.2)],
)
def test_noiseless_fleet_with_estimators_and_faults_matches_the_per_vehicle_diagram(name, end_time):
    """The estimators (``fleet.estimators``) and the sensor faults too: 1e-12 on every log
    (the compiled ESKF kernels differ from the scalar maths by rounding, ~1e-13)."""
    scenario = noiseless(name, f"end_time={end_time}")
    single = run(scenario)
    _, logs, _ = run_fleet(scenario, [5, 6])
    for vehicle, vehicle_logs in single.logs.items():
        for log_name, data in vehicle_logs.items():
            for j in range(2):
                np.testing.assert_allclose(logs[vehicle][log_name][:, j, :], data, rtol=0, atol=1e-12)


def records_key(records):
    return [(r.index, r.seed, r.passed, r.criteria, r.metrics) for r in records]


def test_run_i_is_the_same_in_any_batch():
    scenario = catalog.load("03_position_control", None, ["end_time=1"])
    whole = simulate_batch(batches(scenario, 5, 40, 5)[0])
    split = [r for task in batches(scenario, 5, 40, 2) for r in simulate_batch(task)]
    assert [t.seeds for t in batches(scenario, 5, 40, 2)] == [(40, 41), (42, 43), (44,)]
    assert records_key(whole) == records_key(split)
    # the motor noise differs between runs: the runs are not copies of each other
    assert len({r.metrics["Quad1.PosFollowErr"]["rms"] for r in whole}) == 5


@pytest.mark.slow
def test_fleet_campaign_is_the_same_on_the_process_pool():
    scenario = catalog.load("03_position_control", None, ["end_time=1"])
    serial = run_campaign(scenario, 4, seed=3, progress=False, fleet_batch=4)
    pooled = run_campaign(scenario, 4, runner=ProcessPoolRunner(2), seed=3, progress=False, fleet_batch=2)
    assert records_key(serial.records) == records_key(pooled.records)
    assert table(serial) == table(pooled)
    assert serial.runner == "fleet (batch 4) on in-process"
    assert pooled.runner == "fleet (batch 2) on process-pool x2"


def test_fleet_campaign_outputs(quad_drake_cli, out_dir):
    result = quad_drake_cli("montecarlo", "01_intro", "--runs", "3", "--fleet", "--batch", "2", "--jobs", "1",
                            "--out", out_dir, "--no-plots", "--quiet")  # fmt: skip
    assert result.returncode == 0, result.stderr
    folder = out_dir / "01_intro_montecarlo"
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["runner"] == "fleet (batch 2) on in-process"
    assert summary["runs"] == 3 and summary["first_seed"] == catalog.load("01_intro", None, []).seed
    assert (folder / "runs.csv").read_text().count("\n") == 4
    assert (folder / "report.html").is_file() and (folder / "table.txt").read_text() in result.stdout


def test_fleet_run_summaries_name_their_runner():
    scenario = catalog.load("01_intro", None, ["end_time=0.2"])
    times, logs, wall = run_fleet(scenario, [1])
    from quad_drake.fleet.runner import batch_logs
    from quad_drake.results import result_from_logs

    result = result_from_logs(scenario, times, batch_logs(logs, 0), wall, RUNNER)
    assert result.summary()["runner"] == "drake-fleet"


def test_bad_fleet_arguments_are_one_line_errors(quad_drake_cli, out_dir):
    no_fleet = quad_drake_cli("montecarlo", "01_intro", "--runs", "2", "--batch", "2", "--out", out_dir)
    assert no_fleet.returncode == 2 and no_fleet.stderr.strip().count("\n") == 0
    assert "--batch needs --fleet" in no_fleet.stderr
    zero = quad_drake_cli(
        "montecarlo", "01_intro", "--runs", "2", "--fleet", "--batch", "0", "--out", out_dir
    )
    assert zero.returncode == 2 and "--batch must be >= 1" in zero.stderr
    assert not out_dir.exists()


def test_default_batch_is_bounded_by_memory():
    scenario = catalog.load("05_trajectory_follow", None, [])
    size = default_batch_size(scenario, 10_000)
    assert 1 <= size <= 1000
    assert batch_bytes(scenario, size) <= 1 << 30
    assert default_batch_size(scenario, 10, jobs=2) == 5


def test_unsupported_scenarios_are_refused_with_one_line():
    scenario = catalog.load("14_gps_delay", None, [])
    with pytest.raises(ConfigError, match="fleet mode cannot fly 14_gps_delay"):
        run_campaign(scenario, 2, progress=False, fleet_batch=2)
