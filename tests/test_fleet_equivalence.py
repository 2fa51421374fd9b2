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
"""

import numpy as np
import pytest
from scipy.stats import fisher_exact

from quad_drake.campaigns import ProcessPoolRunner, run_campaign
from quad_drake.running import catalog

SEED = 7000
BOOTSTRAP = 2000
MAX_STANDARD_ERRORS = 3.5
MIN_P_VALUE = 0.01


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
    [("06_sensor_noise", 40), ("10_mag_update", 30), ("11_gps_update", 30), ("19_windy_hover", 30)],
)
def test_fleet_and_per_vehicle_campaigns_agree(name, runs):
    scenario = catalog.load(name, None, [])
    fleet = run_campaign(scenario, runs, seed=SEED, progress=False, fleet_batch=runs)
    single = run_campaign(scenario, runs, runner=ProcessPoolRunner(2), seed=SEED, progress=False)
    assert [row["criterion"] for row in fleet.criteria] == [row["criterion"] for row in single.criteria]
    for a, b in zip(fleet.criteria, single.criteria, strict=True):
        print(f"{name} {a['criterion']}: fleet {a['passes']}/{runs}, per-vehicle {b['passes']}/{runs}")
        table = [[a["passes"], runs - a["passes"]], [b["passes"], runs - b["passes"]]]
        assert fisher_exact(table)[1] >= MIN_P_VALUE, (a, b)
    rng = np.random.default_rng(SEED)
    for key, statistic in (("Est.E.Pos", np.median), ("Est.E.Yaw", np.median), ("NEES", np.mean)):
        f, s = per_run(fleet, key), per_run(single, key)
        assert len(f) == len(s) == runs
        difference = statistic(np.asarray(f)) - statistic(np.asarray(s))
        se = bootstrap_se(f, s, statistic, rng)
        print(f"{name} {key}: fleet {statistic(f):.4g}, per-vehicle {statistic(s):.4g}, SE {se:.2g}")
        assert abs(difference) <= MAX_STANDARD_ERRORS * se, (key, difference, se)
