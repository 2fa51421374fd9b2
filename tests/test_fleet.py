"""Fleet mode: the fleet Diagram against the per-vehicle one, run i the same in any batch and
on any runner, the campaign outputs, the CLI's --fleet/--batch and its refusals."""

import json
import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from quad_drake import conventions as c
from quad_drake.campaigns import run_campaign, table
from quad_drake.campaigns.fleet.diagram import run_fleet
from quad_drake.campaigns.fleet.runner import BATCH_MEMORY, MAX_BATCH, batches, default_batch_size, fly_batch
from quad_drake.campaigns.fleet.summaries import summary_bytes
from quad_drake.config.schema import FaultConfig
from quad_drake.running import catalog
from quad_drake.running.simulation import run
from quad_drake.systems.faults import SensorFaults


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
        ("11_gps_update", ("fidelity=reference", "end_time=3")),
        # wind (mean and a gust; the turbulence is noise, off here), drag, a delta-velocity IMU
        ("20_gust_figure_eight", ("end_time=8", "vehicles.0.wind.turbulence=none")),
    ],
)
def test_noiseless_fleet_flies_every_vehicle_as_the_per_vehicle_diagram(name, overrides):
    """Same tick order and kernels: every logged signal of every fleet vehicle equals the
    per-vehicle Diagram's to 1e-12 (in practice bit for bit), in both fidelity modes (the
    reference's float32 sensors and EKF7 and its tick-held truth and reference included)."""
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
    "name, end_time, overrides",
    [
        ("11_gps_update", 3, ()),
        # the faults moved from 10 s to 2 s (bundled: 10 s), each begun and ended in the flight
        ("12_gps_outage", 4.5, ("vehicles.0.faults.0.start=2", "vehicles.0.faults.0.end=4")),
        ("16_mag_disturbance", 3, ("vehicles.0.faults.0.start=2", "vehicles.0.faults.0.end=2.5")),
        ("18_imu_dropout", 2.2, ("vehicles.0.faults.0.start=2", "vehicles.0.faults.0.end=2.02")),
        ("14_gps_delay", 5, ()),
        ("14_gps_delay", 3, ("vehicles.0.gps_delay_compensation=0",)),
        ("14_gps_delay", 3, ("vehicles.0.estimator={kind: ekf7}",)),
    ],
)
def test_noiseless_fleet_with_estimators_and_faults_matches_the_per_vehicle_diagram(
    name, end_time, overrides
):
    """The estimators (sized by n), the sensor faults and the GPS delay compensation
    too: 1e-12 on every log (the compiled ESKF kernels differ from the scalar maths by rounding,
    ~1e-17 at first). 14 without compensation is flown for 3 s only: its closed loop
    oscillates, and that rounding difference grows about tenfold per second after t = 2 s
    (measured: 3e-14 at 3 s, 1e-12 at 5 s, 4e-12 at 7 s)."""
    scenario = noiseless(name, f"end_time={end_time}", *overrides)
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
    whole = fly_batch(batches(scenario, 5, 40, 5)[0])
    split = [r for task in batches(scenario, 5, 40, 2) for r in fly_batch(task)]
    assert [t.seeds for t in batches(scenario, 5, 40, 2)] == [(40, 41), (42, 43), (44,)]
    assert records_key(whole) == records_key(split)
    # the motor noise differs between runs: the runs are not copies of each other
    assert len({r.metrics["Quad1.PosFollowErr"]["rms"] for r in whole}) == 5


def test_windy_run_i_is_the_same_in_any_batch_and_its_turbulence_its_own():
    """The turbulence draws from the run's own stream (``<vehicle>/wind``): run i flies the same
    wind in any batch, and two runs fly different winds."""
    scenario = catalog.load("19_windy_hover", None, ["end_time=1"])
    whole = fly_batch(batches(scenario, 3, 70, 3)[0])
    split = [r for task in batches(scenario, 3, 70, 1) for r in fly_batch(task)]
    assert records_key(whole) == records_key(split)
    _, logs, _ = run_fleet(scenario, [70, 71, 70])
    wind = logs["Quad"]["wind"]
    np.testing.assert_array_equal(wind[:, 0], wind[:, 2])
    assert np.abs(wind[:, 0] - wind[:, 1]).max() > 0.1


@pytest.mark.slow
def test_fleet_campaign_is_the_same_on_the_process_pool(process_pool):
    scenario = catalog.load("03_position_control", None, ["end_time=1"])
    serial = run_campaign(scenario, 4, seed=3, progress=False, fleet_batch=4)
    pooled = run_campaign(scenario, 4, runner=process_pool, seed=3, progress=False, fleet_batch=2)
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


def test_bad_fleet_arguments_are_one_line_errors(quad_drake_cli, out_dir):
    no_fleet = quad_drake_cli("montecarlo", "01_intro", "--runs", "2", "--batch", "2", "--out", out_dir)
    assert no_fleet.returncode == 2 and no_fleet.stderr.strip().count("\n") == 0
    assert "--batch needs --fleet" in no_fleet.stderr
    zero = quad_drake_cli(
        "montecarlo", "01_intro", "--runs", "2", "--fleet", "--batch", "0", "--out", out_dir
    )
    assert zero.returncode == 2 and "--batch must be >= 1" in zero.stderr
    assert not out_dir.exists()


def test_default_batch_is_bounded_by_memory_and_split_evenly_over_the_jobs():
    eleven = catalog.load("11_gps_update", None, [])
    assert default_batch_size(eleven, 10_000) == MAX_BATCH  # 0.27 GiB of summaries
    assert default_batch_size(eleven, 10_000, jobs=2) == MAX_BATCH  # 5 full rounds of 2
    assert default_batch_size(eleven, 10, jobs=2) == 5
    assert default_batch_size(eleven, 3000, jobs=2) == 750  # 2 full rounds, not 1000 x 3 (one idle)
    assert default_batch_size(eleven, 2500, jobs=2) == 625
    assert default_batch_size(eleven, 2500) == 834  # 834 + 834 + 832, not 1000 + 1000 + 500
    long = catalog.load("11_gps_update", None, ["end_time=600"])
    most = BATCH_MEMORY // summary_bytes(long, 1)  # summary_bytes is proportional to the runs
    assert most < MAX_BATCH
    size = default_batch_size(long, 10_000)
    assert summary_bytes(long, size) <= BATCH_MEMORY
    assert math.ceil(10_000 / size) == math.ceil(10_000 / most)  # as few batches as the memory allows


def test_summary_bytes_counts_what_a_batch_holds():
    """The estimate against the arrays a BatchSummary and its BatchSummarizer keep after a flight."""
    from quad_drake.campaigns.fleet.diagram import build_fleet_diagram, fly
    from quad_drake.campaigns.fleet.streaming import BatchSummarizer

    scenario = catalog.load("11_gps_update", None, ["end_time=2.3"])
    seeds = (1, 2, 3)
    diagram, summarizer = build_fleet_diagram(
        scenario, list(seeds), lambda signals, samples: BatchSummarizer(scenario, seeds, signals, samples)
    )
    fly(diagram, scenario.end_time)
    records = summarizer.records(0, 0.0)
    held = sum(b.nbytes for logs in summarizer._buffers.values() for b in logs.values())
    held += sum(r.nees["Quad"].nbytes for r in records)
    held += sum(stamps.nbytes + nis.nbytes for r in records for stamps, nis in r.nis.values())
    assert 0.95 * summary_bytes(scenario, 3) <= held <= summary_bytes(scenario, 3)


def test_gps_delay_queue_of_n_vehicles_matches_n_one_vehicle_sensor_faults_tick_by_tick():
    """A gps_delay (not a multiple of the GPS period) composed with an outage and an outlier:
    every tick, each vehicle's output of a SensorFaults of n = 3 (the faults on (n,) columns)
    equals its own one-vehicle SensorFaults' (on floats) bit for bit."""
    n, period, ticks = 3, 0.1, 600
    fault_list = [
        FaultConfig(kind="gps_delay", delay=0.25),
        FaultConfig(kind="gps_outage", start=0.35, end=0.55),
        FaultConfig(kind="gps_outlier", time=0.6, offset=[4.0, -2.0, 1.0]),
    ]
    first = period + c.SLOW_SENSOR_OFFSET
    builder = DiagramBuilder()
    systems = {"fleet": SensorFaults("gps", c.GPS_SIZE, fault_list, period, first, n)}
    systems.update(
        {f"scalar{i}": SensorFaults("gps", c.GPS_SIZE, fault_list, period, first) for i in range(n)}
    )
    for tag, system in systems.items():
        system.set_name(tag)
        builder.AddSystem(system)
        builder.ExportInput(system.GetInputPort("gps"), f"{tag}.gps")
        builder.ExportOutput(system.GetOutputPort("gps"), f"{tag}.gps")
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    rng = np.random.default_rng(2024)
    gps = np.tile([0.0] * 6 + [c.NO_SAMPLE_STAMP], (n, 1))
    released = set()
    for k in range(1, ticks + 1):
        t = k * c.ONBOARD_PERIOD
        if k % round(period / c.ONBOARD_PERIOD) == 0:  # a new sample, held for one period as a sensor would
            gps = np.column_stack([rng.normal(size=(n, 6)), np.full(n, t)])
        diagram.GetInputPort("fleet.gps").FixValue(context, gps.ravel())
        for i in range(n):
            diagram.GetInputPort(f"scalar{i}.gps").FixValue(context, gps[i])
        simulator.AdvanceTo(t + c.EKF_OFFSET)
        fleet = diagram.GetOutputPort("fleet.gps").Eval(context).reshape(n, c.GPS_SIZE)
        for i in range(n):
            scalar = diagram.GetOutputPort(f"scalar{i}.gps").Eval(context)
            np.testing.assert_array_equal(fleet[i], scalar, err_msg=f"t = {t} s, vehicle {i}")
        released.add(round(float(fleet[0, -1]), 6))
    # samples 0.1 .. 0.95 s out (released at stamp + 0.25 s), the outage's 0.4 and 0.5 never
    assert {0.1, 0.3, 0.6, 0.9} <= released and not {0.4, 0.5} & released
    assert len(set(fleet[:, 0])) == n  # the vehicles carry their own samples


def test_every_bundled_scenario_flies_as_a_fleet():
    """Every bundled scenario builds as a fleet Diagram and flies its first ticks."""
    for name in catalog.bundled_scenarios():
        scenario = catalog.load(name, None, ["end_time=0.02"])
        times, logs, _ = run_fleet(scenario, [1, 2])
        assert len(times) == 4 and set(logs) == {v.name for v in scenario.vehicles}, name
