"""Many flight logs replayed in one Diagram (``replay.replay_many``): a LogPlayback of n flights and
an estimator of n vehicles, each with its own log's settings, give each log the estimates of its
replay alone; ``quad-drake replay A B`` takes that path unless ``--separately``."""

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from quad_drake.config import MagParams, SensorsConfig, VehicleConfig
from quad_drake.config.errors import ConfigError
from quad_drake.estimation.registry import Ekf7EstimatorConfig, EskfEstimatorConfig, sharing_problem
from quad_drake.flightlogs.reader import Samples, read_flight_log
from quad_drake.flightlogs.replay import replay, replay_many
from quad_drake.flightlogs.settings import default_replay, resolve_log

BUNDLED = ("real_auav_x21_attitude_flight", "sitl_takeoff_land_gps")
TRUTH_LOG = Path(__file__).parent / "data" / "flight_logs" / "sitl_ground_truth.ulg"


def first_seconds(log, seconds):
    """The FlightLog `log` cut to its samples at t <= `seconds` (every timestamped signal; one with
    none left is None, as in a log without it)."""
    cut = {}
    for name, value in vars(log).items():
        if isinstance(value, Samples):
            kept = value.times <= seconds
            cut[name] = Samples(value.times[kept], value.values[kept]) if kept.any() else None
    return dataclasses.replace(log, **cut)


CUT = (20.0, 14.0)
"""s of each bundled log replayed by the bit-for-bit test (of 69 s and 31 s; the SITL log's first
fix at 9.2 s and its barometer inside): the replays of the whole logs took 16 s of CPU for the two kinds."""


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["eskf", "ekf7"])
def test_the_bundled_logs_in_one_diagram_equal_each_alone_bit_for_bit(kind):
    configs = [dataclasses.replace(default_replay(kind), log=name) for name in BUNDLED]
    logs = [first_seconds(read_flight_log(resolve_log(n)), t) for n, t in zip(BUNDLED, CUT, strict=True)]
    together = replay_many(configs, logs)
    for config, log, shared in zip(configs, logs, together, strict=True):
        alone = replay(config, log)
        assert shared.logs_in_diagram == 2 and alone.logs_in_diagram == 1
        np.testing.assert_array_equal(shared.times, alone.times)  # each cut at its own log's end
        assert set(shared.logs) == set(alone.logs)
        for name, data in alone.logs.items():
            np.testing.assert_array_equal(shared.logs[name], data, err_msg=f"{config.log} {name}")
            for own in (data, shared.logs[name]):  # arrays of their own, not views of a sink's memory
                assert own.flags.owndata and own.flags.writeable and own.flags.c_contiguous, name
        assert [d.rms for d in shared.attitude] == [d.rms for d in alone.attitude]
    # the two logs differ in every per-vehicle setting: start, GPS noise (one fake), field, barometer
    sitl = together[1]
    assert sitl.aiding.baro_fused and not together[0].aiding.baro_fused and sitl.aiding.late_fix > 9
    assert together[0].fake_position and not sitl.fake_position


def test_only_logs_whose_settings_allow_it_share_a_diagram():
    eskf, ekf7 = (VehicleConfig(estimator=e) for e in (EskfEstimatorConfig(), Ekf7EstimatorConfig()))
    started = dataclasses.replace(
        eskf, estimator=dataclasses.replace(eskf.estimator, init_ypr=[1.0, 0.1, 0.0])
    )
    field = dataclasses.replace(eskf.estimator.mag_field, declination=0.2, hard_iron=[0.1, 0.0, 0.0])
    fielded = dataclasses.replace(eskf, estimator=dataclasses.replace(eskf.estimator, mag_field=field))
    assert sharing_problem([eskf, started, fielded]) is None
    assert sharing_problem([eskf, ekf7]) == "estimator kinds ekf7, eskf differ"
    tuned = dataclasses.replace(eskf, estimator=dataclasses.replace(eskf.estimator, mag_yaw_std=0.2))
    assert (
        sharing_problem([eskf, tuned])
        == "estimator.mag_yaw_std differs (kind eskf takes it for all vehicles)"
    )
    field = dataclasses.replace(field, field_std=[0.1, 0.1, 0.1])
    noisier = dataclasses.replace(eskf, estimator=dataclasses.replace(eskf.estimator, mag_field=field))
    assert "estimator.mag_field.field_std differs" in sharing_problem([eskf, noisier])
    three_axis = dataclasses.replace(eskf, sensors=SensorsConfig(mag=MagParams(three_axis=True)))
    assert sharing_problem([eskf, three_axis]) == "the sensors differ in more than the barometer"


@pytest.mark.slow
def test_many_logs_replay_in_one_diagram_unless_separately(quad_drake_cli, tmp_path):
    """Two short logs (the SITL log with ground truth, and a folder holding a copy of it): one
    Diagram by default, each its own with --separately; the tables and the estimates the same."""
    folder = tmp_path / "logs"
    folder.mkdir()
    shutil.copy(TRUTH_LOG, folder / "copy.ulg")
    names = ("sitl_ground_truth-eskf", "copy-eskf")
    tables, estimates = {}, {}
    for flag in ((), ("--separately",)):
        out = tmp_path / ("separately" if flag else "together")
        result = quad_drake_cli(
            "replay", TRUTH_LOG, folder, "--estimator", "{kind: eskf}", "--no-plots", "--out", out, *flag
        )
        assert result.returncode == 0, result.stdout + result.stderr
        assert ("(one Diagram of 2 logs)" in result.stdout) == (not flag)
        summaries = [json.loads((out / name / "summary.json").read_text(encoding="utf-8")) for name in names]
        assert [s["logs_in_diagram"] for s in summaries] == [1 if flag else 2] * 2
        tables[flag] = (out / "replay_table.csv").read_text(encoding="utf-8")
        estimates[flag] = [np.load(out / name / "logs.npz")["replay/estimated_state"] for name in names]
    assert tables[()] == tables[("--separately",)] and len(tables[()].splitlines()) == 3
    for together, separately in zip(estimates[()], estimates[("--separately",)], strict=True):
        np.testing.assert_array_equal(together, separately)


def test_logs_that_fit_alone_but_not_together_replay_each_alone(monkeypatch):
    """The memory rule (``limits.check_memory``) before anything is built: each log alone in
    ``_prepare``, the logs of one Diagram together; too many for one Diagram replay each alone."""
    from quad_drake.flightlogs import replay as replay_module
    from quad_drake.running import limits

    configs = [dataclasses.replace(default_replay("ekf7"), log=name) for name in BUNDLED]
    logs = [first_seconds(read_flight_log(resolve_log(n)), 12.0) for n in BUNDLED]
    estimates = []
    monkeypatch.setattr(replay_module, "check_memory", lambda nbytes, *args: estimates.append(nbytes))
    replay_many(configs, logs)  # each log alone, then the two together
    alone = max(estimates[0:2])
    assert len(estimates) == 3 and estimates[2] == pytest.approx(2 * alone, rel=1e-3)
    monkeypatch.undo()
    monkeypatch.setattr(limits, "physical_memory", lambda: int(2 * 1.5 * alone))  # half of it: 1.5 logs
    assert [r.logs_in_diagram for r in replay_many(configs, logs)] == [1, 1]
    monkeypatch.setattr(limits, "physical_memory", lambda: int(2 * 0.5 * alone))
    refused = replay_many(configs, logs)
    assert all(isinstance(e, ConfigError) and "would take about" in str(e) for e in refused), refused
