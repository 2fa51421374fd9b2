"""Fleet vs per-vehicle path: the same statistics up to sampling error (issue 12 item 4).

The two paths draw different noise (``models.random_streams`` vs Drake's RandomSource), so their
campaigns agree only statistically. On seeds nobody tuned on (from 7000), each judged
criterion's pass counts must not differ significantly (Fisher's exact test, two-sided
p >= 0.01; requiring each rate inside the other's 95 % interval fails on a rare event, e.g.
one floor touchdown in 30 runs against none, whose interval excludes 100 %), and
the median RMS of the position and yaw errors and the NEES time mean must
differ by at most 3.5 standard errors of their difference (bootstrap over runs, seeded): a
real bias of a few per cent between the paths fails it at these N. The README ("Fleet
mode") states the differences measured on larger campaigns.

The fleet flies FLEET_RUNS_PER_SINGLE times the per-vehicle runs: its runs cost about 1/60 of a
per-vehicle run's CPU, and a difference's standard error falls with 1/n_fleet + 1/n_single, so
n_single = 17 against 170 fleet runs (1.1/17 = 0.065) resolves a difference as finely as the 30
against 30 this test flew before (2/30 = 0.067), and 22 against 220 as finely as 40 against 40
(0.050), for about 40 % of the CPU. Fisher's test and the bootstrap take unequal groups as they
are. The per-vehicle campaigns fly on the session's process pool (conftest). Measured at SEED
(2026-12-05): the standard errors came out as before (10: 7.1 m, 0.0021 rad, 24 against 7.2,
0.0023, 33 at 30/30; 11: 0.016 m, 0.00061 rad, 0.52 against 0.015, 0.00069, 0.72), and a fleet
magnetometer noise 1.6x too large fails 10 (Fisher p = 4e-6 on its sigma criterion; 30/30: 2e-8);
1.3x passes (yaw median +26 %, 2.8 standard errors).
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
@pytest.mark.parametrize(
    "name, runs",
    [("06_sensor_noise", 22), ("10_mag_update", 17), ("11_gps_update", 17), ("19_windy_hover", 17)],
)
def test_fleet_and_per_vehicle_campaigns_agree(name, runs, process_pool):
    scenario = catalog.load(name, None, [])
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
