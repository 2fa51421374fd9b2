"""A fleet batch's post-processing (``fleet.runner.simulate_batch``: signals, NEES, normalised
squared errors and PCRB computed for the N runs at once) against the per-run functions on each
run's slice of the same logs, record field by field; the batched forms of the per-run
functions (they take (n, N, width) logs) against the per-run calls, column by column."""

import dataclasses

import numpy as np
import pytest

from quad_drake import catalog
from quad_drake import consistency as cons
from quad_drake.campaigns.records import summarize_run
from quad_drake.estimation.vocabulary import vehicle_vocabulary
from quad_drake.fleet.runner import RUNNER, FleetBatch, batch_logs, summarize_batch
from quad_drake.fleet.simulation import run_fleet
from quad_drake.results import result_from_logs
from quad_drake.signals import stamp_fresh, vehicle_signals

RTOL = 1e-12
SEEDS = (3, 4, 5, 6)


@pytest.fixture(scope="module", params=["11_gps_update", "11_gps_update_eskf"])
def batch(request):
    """(scenario, times, logs, wall time) of a fleet batch of SEEDS, 3 s each."""
    scenario = catalog.load(request.param, None, ["end_time=3"])
    return (scenario, *run_fleet(scenario, SEEDS))


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


def test_batch_records_equal_the_per_run_functions(batch):
    scenario, times, logs, wall = batch
    fast = summarize_batch(FleetBatch(scenario, 10, SEEDS), times, logs, wall)
    assert len(fast) == len(SEEDS)
    for j, seed in enumerate(SEEDS):
        run_scenario = dataclasses.replace(scenario, seed=seed)
        result = result_from_logs(run_scenario, times, batch_logs(logs, j), wall / len(SEEDS), RUNNER)
        expected = summarize_run(result, 10 + j)  # its own PCRB: accuracy_bound.posterior_crb
        assert expected.nees and expected.pcrb and expected.nis  # the fields compared are filled
        for field in dataclasses.fields(expected):
            close(getattr(fast[j], field.name), getattr(expected, field.name), f"run {j} {field.name}")


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
