"""benchmarks/nees_over_time.py: its NEES is the mean over runs of e^T P^-1 e over the NEES states
(computed here directly with numpy, not through ``consistency``), and its e^2/P the mean of each
run's."""

import importlib.util
from pathlib import Path

import numpy as np

from quad_drake.campaigns.fleet.diagram import run_fleet
from quad_drake.campaigns.fleet.runner import batch_logs
from quad_drake.judging import consistency as cons
from quad_drake.running import catalog

SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "nees_over_time.py"


def test_over_time_is_the_mean_over_runs_of_each_runs_nees_and_normalised_errors():
    spec = importlib.util.spec_from_file_location("nees_over_time", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    scenario = catalog.load("11_gps_update_eskf", None, ["end_time=1.0"])
    times, vehicles = module.over_time(scenario, 3, 40)
    vocabulary, ratios, nees = vehicles["Quad"]
    _, logs, _ = run_fleet(scenario, [40, 41, 42])
    runs = [batch_logs(logs, j)["Quad"] for j in range(3)]
    assert times.shape == nees.shape == (200,) and ratios.shape == (200, vocabulary.size)
    states = list(vocabulary.nees_states)
    direct = []
    for r in runs:
        errors = vocabulary.errors(r)[:, states]
        k = vocabulary.size
        P = np.asarray(r["covariance"]).reshape(-1, k, k)[:, states][:, :, states]
        direct.append([e @ np.linalg.solve(P_t, e) for e, P_t in zip(errors, P, strict=True)])
    np.testing.assert_allclose(nees, np.mean(direct, axis=0), rtol=1e-9)
    np.testing.assert_allclose(nees, np.mean([cons.nees_of(vocabulary, r) for r in runs], axis=0), rtol=1e-12)
    first = cons.normalized_squared_errors(
        vocabulary.errors(runs[0]), cons.covariance_matrices(runs[0]["covariance"])
    )
    assert np.all(np.isfinite(ratios)) and not np.allclose(ratios, first)  # a mean of three different runs
