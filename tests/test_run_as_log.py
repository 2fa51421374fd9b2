"""Issue 38 item 5: a simulated run is a flight log too. ``flightlogs.recording`` writes the
samples a run's estimator received (and the true state as ``truth`` rows) as a replay CSV, and
replaying that CSV through the run's own estimator (``flightlogs.replay.replay_as_flown``)
reproduces the run's estimate; measured bit-identical on all three, the bound is 1e-9.

Shortened flights (the round trip is per tick, its length adds nothing): 11 and
11_gps_update_eskf to 6 s; 23 to 14 s, 4 s into its GPS outage (10-20 s: the barometer alone then).
"""

import numpy as np
import pytest

from quad_drake.flightlogs.reader import read_flight_log
from quad_drake.flightlogs.recording import record_run, write_run_csv
from quad_drake.flightlogs.replay import replay_as_flown
from quad_drake.running import catalog

FLIGHTS = {"11_gps_update": 6.0, "11_gps_update_eskf": 6.0, "23_gps_outage_baro": 14.0}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(FLIGHTS))
def test_a_run_written_as_a_log_replays_to_its_own_estimate(name, tmp_path):
    recorded = record_run(catalog.load(name, overrides=[f"end_time={FLIGHTS[name]}"]))
    log = read_flight_log(write_run_csv(recorded, tmp_path / f"{name}.csv"))
    assert len(log.imu) == len(recorded.tick_times) and log.gps is not None and log.heading is not None
    assert (log.baro is not None) == ("baro" in recorded.inputs)
    np.testing.assert_array_equal(log.truth_position.values[:, 0:3], recorded.truth[:, 0:3])
    times, logs = replay_as_flown(log, recorded.vehicle)
    n = len(times)
    assert n >= len(recorded.times) - 1  # the replay ends at the last tick, the run at end_time
    np.testing.assert_array_equal(times, recorded.times[:n])
    for name_ in ("estimated_state", "covariance"):
        np.testing.assert_allclose(logs[name_], recorded.logs[name_][:n], rtol=0, atol=1e-9)
