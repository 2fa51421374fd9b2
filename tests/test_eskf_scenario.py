"""11_gps_update_eskf closed loop: seeded consistency of the error-state EKF in the full diagram."""

import numpy as np
import pytest

from quad_drake import catalog
from quad_drake import consistency as cons
from quad_drake.estimation.vocabulary import ESKF9, health_counts, health_line, vehicle_vocabulary
from quad_drake.simulation import run


@pytest.mark.slow
def test_eskf_closed_loop_run_is_consistent_and_healthy():
    scenario = catalog.load("11_gps_update_eskf", 3, ["end_time=15", "criteria.0.window=10"])
    assert vehicle_vocabulary(scenario.vehicles[0]) is ESKF9  # 11's IMU has no bias to estimate
    result = run(scenario)
    assert result.passed
    logs = result.logs["Quad"]
    settled = result.times >= 5.0
    nees = cons.nees_of(ESKF9, logs)[settled]
    # One run, strongly time-correlated: the time mean of a chi^2(9) NEES within +-35 %.
    assert 0.65 * 9 < np.mean(nees) < 1.35 * 9
    _, gps_nis = cons.fresh_nis(logs["diagnostics"], "gps")
    assert 0.6 * 6 < np.mean(gps_nis) < 1.4 * 6
    for angle in ("Roll", "Pitch"):  # the complementary filter's are ~0.08 rad
        assert np.sqrt(np.mean(result.signals[f"Quad.Est.E.{angle}"].values[settled] ** 2)) < 0.03
    counts = health_counts(logs["diagnostics"])
    assert counts == dict.fromkeys(counts, 0)
    assert health_line("Quad", "eskf", counts).startswith("Quad estimator eskf: 0 GPS")


def test_health_line_warns_on_repairs_and_resets():
    counts = {
        "nonfinite_samples": 0,
        "gps_gated": 3,
        "mag_gated": 0,
        "gps_resets": 0,
        "covariance_repairs": 0,
    }
    assert not health_line("Q", "ekf7", counts).startswith("WARNING")
    assert health_line("Q", "ekf7", dict(counts, covariance_repairs=1)).startswith(
        "WARNING: Q estimator ekf7"
    )
    assert health_line("Q", "ekf7", dict(counts, gps_resets=1)).startswith("WARNING")
