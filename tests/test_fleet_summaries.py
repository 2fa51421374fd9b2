"""A fleet batch's records, made while it flies (``campaigns.fleet.runner.fly_batch``: a
``campaigns.fleet.streaming.BatchSummarizer`` folds the signals chunk by chunk), against the per-run
functions on each run's full logs (``campaigns.fleet.diagram.run_fleet`` keeps them), record field by
field; any chunk size gives the same records; the batched forms of the per-run functions
(they take (n, N, width) logs) against the per-run calls, column by column."""

import dataclasses

import numpy as np
import pytest

from quad_drake.campaigns.fleet.diagram import run_fleet
from quad_drake.campaigns.fleet.runner import BatchTask, batch_logs, fly_batch
from quad_drake.campaigns.fleet.summaries import summarize_logs
from quad_drake.campaigns.records import summarize_run
from quad_drake.config.schema import GpsParams, ImuParams, MagParams, SensorsConfig
from quad_drake.estimation.registry import vehicle_vocabulary
from quad_drake.judging import consistency as cons
from quad_drake.judging.signals import stamp_fresh, vehicle_signals
from quad_drake.kernels.bounds import PcrbStream, posterior_crbs
from quad_drake.output.results import result_from_logs
from quad_drake.running import catalog

RTOL = 1e-12
SEEDS = (3, 4, 5, 6)
OUTAGE_AT_3 = [
    "vehicles.0.faults.0.start=3",
    "vehicles.0.faults.0.end=5",
    "criteria.0.start=3",
    "criteria.0.end=5",
    "criteria.1.start=5",
]
SCENARIOS = {
    "11_gps_update": ["end_time=2.6"],  # EKF7: NEES, NIS gps and mag, PCRB, window criteria
    "11_gps_update_eskf": ["end_time=3"],
    "09_predict_covariance": ["end_time=1.1"],  # several vehicles, a fleet_sigma criterion
    "06_sensor_noise": ["end_time=4.3"],  # sigma criteria (2 s windows) on fresh GPS samples
    # a fault: bound and recovery criteria, GPS gaps: the 2 s outage and its criteria moved from
    # 10-12 s to 3-5 s, the flight ends after the 3 s recovery window (so the recovery is judged:
    # at 14.3 s, inside the window, it was "no samples" whatever the fold held)
    "12_gps_outage": ["end_time=8.3", *OUTAGE_AT_3],
    "03_position_control": ["end_time=2"],  # no estimator
}
"""Flights as short as keep what each brings: a record is the same function of the logs on a
shorter flight, and the chunk-size comparisons cost per sample (chunk 1: 1-2 ms of CPU per sample
and vehicle; with 09's 2 s, 06's 10 s and 12's 14.3 s the file took 28-32 s of CPU, now 17-20 s,
measured 2026-12-06 on the shared 2-core machine)."""


@pytest.fixture(scope="module", params=list(SCENARIOS))
def batch(request):
    """(scenario, times, logs, wall time) of a fleet batch of SEEDS with full logs; 11, 09, 06 and 12
    end inside a chunk of CHUNK_SAMPLES (the last flush is a partial one)."""
    scenario = catalog.load(request.param, None, SCENARIOS[request.param])
    return (scenario, *run_fleet(scenario, SEEDS))


@pytest.fixture(scope="module")
def per_run_records(batch):
    """The per-run functions' records of `batch` (each run's full logs), what the fast paths must
    equal: made once per scenario for the four tests that compare with them."""
    return _per_run_records(*batch)


def close(actual, expected, where):
    """Equal to RTOL (relative), NaN where NaN; anything but numbers exactly equal."""
    if isinstance(expected, dict):
        assert actual.keys() == expected.keys(), where
        for key in expected:
            close(actual[key], expected[key], f"{where}.{key}")
    elif isinstance(expected, (list, tuple)):
        assert len(actual) == len(expected), where
        for i, (a, e) in enumerate(zip(actual, expected, strict=True)):
            close(a, e, f"{where}[{i}]")
    elif isinstance(expected, (float, np.ndarray)):
        np.testing.assert_allclose(actual, expected, rtol=RTOL, atol=0, equal_nan=True, err_msg=where)
    else:
        assert actual == expected, where


def _per_run_records(scenario, times, logs, wall):
    records = []
    for j, seed in enumerate(SEEDS):
        result = result_from_logs(dataclasses.replace(scenario, seed=seed), times, batch_logs(logs, j), wall)
        records.append(summarize_run(result, 10 + j))  # its own PCRB: accuracy_bound.posterior_crb
    return records


def _same_records(actual, expected):
    assert len(actual) == len(expected)
    for j, (fast, slow) in enumerate(zip(actual, expected, strict=True)):
        for field in dataclasses.fields(slow):
            if field.name != "wall_time":
                close(getattr(fast, field.name), getattr(slow, field.name), f"run {j} {field.name}")


def test_streamed_batch_records_equal_the_per_run_functions(batch, per_run_records):
    scenario = batch[0]
    expected = per_run_records
    if vehicle_vocabulary(scenario.vehicles[0]) is not None and scenario.name.startswith("11"):
        assert expected[0].nees and expected[0].pcrb and expected[0].nis  # the fields compared are filled
    _same_records(fly_batch(BatchTask(scenario, 10, SEEDS)), expected)


@pytest.mark.parametrize("chunk", [1, 7, 10_000])
def test_any_chunk_size_gives_the_same_records(batch, per_run_records, chunk):
    """BatchSummary fed the full logs chunk by chunk (row 0: the sample before) gives the
    whole-log records."""
    scenario, _, logs, wall = batch
    summary = summarize_logs(scenario, SEEDS, logs, chunk)
    _same_records(summary.records(10, wall), per_run_records)


def test_a_pcrb_stream_gives_the_whole_log_bound_for_any_split():
    rng = np.random.default_rng(9)
    n, runs = 60, 3
    q = rng.normal(size=(n, runs, 4))
    states = np.concatenate(
        [
            rng.normal(size=(n, runs, 3)),
            q / np.linalg.norm(q, axis=-1, keepdims=True),
            rng.normal(size=(n, runs, 6)),
        ],
        axis=-1,
    )
    gps, mag = rng.random((n, runs)) < 0.2, rng.random((n, runs)) < 0.5
    sensors = SensorsConfig(imu=ImuParams(), gps=GpsParams(), mag=MagParams())
    whole = posterior_crbs(states, gps, mag, sensors)
    for cuts in ([0, n], [0, 1, 2, 3, n], [0, 1, n], [0, 17, 18, 40, n]):
        stream = PcrbStream(sensors, runs)
        parts = [
            stream.update(states[a:b], gps[a:b], mag[a:b]) for a, b in zip(cuts[:-1], cuts[1:], strict=True)
        ]
        parts.append(stream.finish())
        for name, values in whole.items():
            np.testing.assert_array_equal(np.concatenate([p[name] for p in parts]), values, err_msg=str(cuts))
    for length in (1, 2):  # the ends: one sample (no force), two (both one-sided)
        stream = PcrbStream(sensors, runs)
        parts = [stream.update(states[:length], gps[:length], mag[:length]), stream.finish()]
        short = posterior_crbs(states[:length], gps[:length], mag[:length], sensors)
        for name, values in short.items():
            np.testing.assert_array_equal(np.concatenate([p[name] for p in parts]), values)


def test_signals_of_a_batch_are_the_runs_signals(batch):
    scenario, _, logs, _ = batch
    vehicle = scenario.vehicles[0]
    vocabulary = vehicle_vocabulary(vehicle)
    batched = vehicle_signals(vehicle.name, logs[vehicle.name], vocabulary)
    for j in range(len(SEEDS)):
        single = vehicle_signals(vehicle.name, batch_logs(logs, j)[vehicle.name], vocabulary)
        assert single.keys() == batched.keys()
        for name, signal in single.items():
            np.testing.assert_allclose(batched[name].values[:, j], signal.values, rtol=RTOL, atol=0)
            np.testing.assert_array_equal(batched[name].fresh[:, j], signal.fresh)
        if vocabulary is None:
            continue
        errors = vocabulary.errors(batch_logs(logs, j)[vehicle.name])
        np.testing.assert_allclose(vocabulary.errors(logs[vehicle.name])[:, j], errors, rtol=RTOL, atol=0)


def test_stamp_fresh_of_columns():
    stamps = np.array([[-1.0, 0.1], [0.1, 0.1], [0.1, 0.2], [0.2, 0.2]])
    columns = np.column_stack([stamp_fresh(stamps[:, j]) for j in range(2)])
    np.testing.assert_array_equal(stamp_fresh(stamps), columns)
    np.testing.assert_array_equal(columns[:, 0], [False, True, False, True])


def test_nees_by_cholesky_equals_the_lu_solution():
    rng = np.random.default_rng(77)
    A = rng.normal(size=(500, 7, 7))
    P = A @ A.transpose(0, 2, 1) + 1e-3 * np.eye(7)
    e = rng.normal(size=(500, 7))
    expected = np.einsum("ij,ij->i", e, np.linalg.solve(P, e[:, :, None])[:, :, 0])
    np.testing.assert_allclose(cons.nees(e, P), expected, rtol=RTOL, atol=0)
    # batched: (n, N, k) errors, (n, N, k, k) covariances give (n, N)
    np.testing.assert_allclose(
        cons.nees(e.reshape(100, 5, 7), P.reshape(100, 5, 7, 7)), expected.reshape(100, 5)
    )


def test_nees_of_an_indefinite_covariance_with_positive_determinant_follows_the_lu_rule():
    P = np.diag([1.0, -2.0, -0.5])  # det > 0, not positive definite: no Cholesky factor
    e = np.array([[1.0, 1.0, 2.0]])
    assert cons.nees(e, P[None])[0] == pytest.approx(1.0 - 0.5 - 8.0, rel=1e-15)
    P[2, 2] = 0.5  # det < 0: NaN, as before
    assert np.isnan(cons.nees(e, P[None])[0])
