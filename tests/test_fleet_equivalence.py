"""Fleet vs per-vehicle path, end to end: whole vehicles' campaigns agree up to sampling error.

The two paths draw different noise (``models.random_streams`` vs Drake's RandomSource), so their
campaigns agree only statistically. What the noise itself is, system by system, is compared
sharply and cheaply in tests/test_fleet_noise.py (a 1.3x sigma in one sensor fails there at
p = 6e-50); the noiseless fleet is bit-identical to the per-vehicle Diagram (tests/test_fleet.py).
This is the integration check on top: one scenario that flies a closed loop on an EKF fusing
IMU, magnetometer and GPS (11_gps_update, shortened to SECONDS with its window criterion's
window to WINDOW: the same vehicle, sensors, estimator and wiring; the campaign statistics of
a shorter flight compare the paths as well), on seeds nobody tuned on (from 7000). Each judged
criterion's pass counts must not differ significantly (Fisher's exact test, two-sided
p >= 0.01; requiring each rate inside the other's 95 % interval fails on a rare event), and
the median RMS of the position and yaw errors and the NEES time mean must differ by at most 3.5
standard errors of their difference (bootstrap over runs, seeded).

The fleet flies FLEET_RUNS_PER_SINGLE times the per-vehicle runs: its runs cost about 1/60 of a
per-vehicle run's CPU, and a difference's standard error falls with 1/n_fleet + 1/n_single, so
17 against 170 fleet runs (1.1/17 = 0.065) resolves a difference as finely as 30 against 30
(2/30 = 0.067). Fisher's test and the bootstrap take unequal groups as they are. The
per-vehicle campaign flies on the session's process pool (conftest).
"""

import numpy as np
import pytest
from scipy.stats import fisher_exact

from quad_drake.campaigns import run_campaign
from quad_drake.running import catalog

SEED = 7000
BOOTSTRAP = 2000
MAX_STANDARD_ERRORS = 3.5
MIN_P_VALUE = 0.01
FLEET_RUNS_PER_SINGLE = 10
SECONDS = 12.0  # s flown (the scenario's 25)
WINDOW = 10.0  # s judged by its window criterion (its 20)


def bootstrap_se(a, b, statistic, rng):
    """Standard error of statistic(a) - statistic(b), resampling runs with replacement."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    draws = [
        statistic(a[rng.integers(0, a.size, a.size)]) - statistic(b[rng.integers(0, b.size, b.size)])
        for _ in range(BOOTSTRAP)
    ]
    return float(np.std(draws))


def per_run(campaign, key):
    """The compared per-run values: an error metric's RMS, or the run's NEES time mean."""
    if key == "NEES":
        return [nees for r in campaign.records for nees in r.nees_mean.values()]
    return [m["rms"] for r in campaign.records for name, m in r.metrics.items() if name.endswith(f".{key}")]


@pytest.mark.slow
def test_fleet_and_per_vehicle_campaigns_agree(process_pool):
    name, runs = "11_gps_update", 17
    scenario = catalog.load(name, None, [f"end_time={SECONDS}", f"criteria.0.window={WINDOW}"])
    fleet_runs = FLEET_RUNS_PER_SINGLE * runs
    fleet = run_campaign(scenario, fleet_runs, seed=SEED, progress=False, fleet_batch=fleet_runs)
    single = run_campaign(scenario, runs, runner=process_pool, seed=SEED, progress=False)
    assert [row["criterion"] for row in fleet.criteria] == [row["criterion"] for row in single.criteria]
    for a, b in zip(fleet.criteria, single.criteria, strict=True):
        print(f"{name} {a['criterion']}: fleet {a['passes']}/{fleet_runs}, per-vehicle {b['passes']}/{runs}")
        table = [[a["passes"], fleet_runs - a["passes"]], [b["passes"], runs - b["passes"]]]
        assert fisher_exact(table)[1] >= MIN_P_VALUE, (a, b)
    rng = np.random.default_rng(SEED)
    for key, statistic in (("Est.E.Pos", np.median), ("Est.E.Yaw", np.median), ("NEES", np.mean)):
        f, s = per_run(fleet, key), per_run(single, key)
        assert (len(f), len(s)) == (fleet_runs, runs)
        difference = statistic(np.asarray(f)) - statistic(np.asarray(s))
        se = bootstrap_se(f, s, statistic, rng)
        print(f"{name} {key}: fleet {statistic(f):.4g}, per-vehicle {statistic(s):.4g}, SE {se:.2g}")
        assert abs(difference) <= MAX_STANDARD_ERRORS * se, (key, difference, se)
