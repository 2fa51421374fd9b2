"""``quad-drake tune LOG``: the innovation statistics, the PX4 parameter mapping both ways, a short
delay recovery on a simulated run written as a log with a delayed GPS, and bad input."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from quad_drake.config.errors import ConfigError
from quad_drake.flightlogs import px4_parameters as px4
from quad_drake.flightlogs.settings import LOG_DIR, default_replay, load_replay
from quad_drake.judging import innovations


def test_white_consistent_innovations_are_judged_so_and_a_correlated_sequence_is_not():
    rng = np.random.default_rng(5)
    white = innovations.statistics_of("gps_vel_xy", rng.standard_normal((400, 2)), 2)
    assert white.in_band and white.white and white.ljung_box_p > 0.01
    assert innovations.channel_loss(white) < 0.05
    ar = np.zeros((400, 2))
    for k in range(1, 400):  # an AR(1) sequence: what a delay left out adds
        ar[k] = 0.8 * ar[k - 1] + 0.6 * rng.standard_normal(2)
    correlated = innovations.statistics_of("gps_vel_xy", ar, 2)
    assert not correlated.white and correlated.autocorrelation[0] == pytest.approx(0.8, abs=0.1)
    large = innovations.statistics_of("gps_vel_xy", 3.0 * rng.standard_normal((400, 2)), 2)
    assert not large.in_band and innovations.channel_loss(large) > 4.0


def test_the_likelihood_prefers_the_smaller_of_two_consistent_innovation_variances():
    """A noise inflated to hide a wrong delay makes the NIS consistent again (the consistency loss
    cannot tell) but costs its ln s² in the likelihood the tuner minimises."""
    z = np.random.default_rng(6).standard_normal((400, 2))
    small = innovations.statistics_of("gps_vel_xy", z, 2, np.full((400, 2), 0.1))
    inflated = innovations.statistics_of("gps_vel_xy", z, 2, np.full((400, 2), 0.2))
    assert innovations.loss({"a": small}) == innovations.loss({"a": inflated})
    difference = innovations.likelihood({"a": inflated}) - innovations.likelihood({"a": small})
    assert difference == pytest.approx(2 * 2 * np.log(2.0), rel=1e-12)
    nis_only = innovations.statistics_of("baro", z[:, 0] ** 2, 1)  # no innovation std: its loss
    assert innovations.likelihood({"baro": nis_only}) == innovations.channel_loss(nis_only)


def test_px4_parameters_round_trip_through_a_replay_config_and_a_parameter_file():
    rng = np.random.default_rng(3)
    start = default_replay("eskf")
    values = {p.name: float(p.default * rng.uniform(0.2, 5.0)) for p in px4.MAPPING}
    config = px4.from_parameters(start, values)
    back = px4.to_parameters(config)
    assert back.keys() == values.keys()
    for name, value in values.items():
        assert back[name] == pytest.approx(value, rel=1e-12), name
    assert config.gps_delay == pytest.approx(values["EKF2_GPS_DELAY"] * 1e-3, rel=1e-12)
    assert config.estimator.accel_std[2] == pytest.approx(values["EKF2_ACC_NOISE"] * np.sqrt(5.0), rel=1e-12)
    # PX4's one GPS noise sets the horizontal and, 1.5 times it, the vertical (as PX4 fuses them)
    position, velocity = values["EKF2_GPS_P_NOISE"], values["EKF2_GPS_V_NOISE"]
    assert config.estimator.gps_pos_std == pytest.approx([position, position, 1.5 * position], rel=1e-12)
    assert config.estimator.gps_vel_std == pytest.approx([velocity, velocity, 1.5 * velocity], rel=1e-12)
    assert start.estimator.gps_pos_std == [0.5, 0.5, 0.75] and start.estimator.gps_vel_std == [0.3, 0.3, 0.45]
    text = px4.parameter_file(config, start)
    assert px4.read_parameter_file(text) == pytest.approx(back, rel=1e-12)
    assert "PX4 default 0.5" in text and "ms -> s" in text
    missing = px4.from_parameters(start, {})  # a log without them: PX4's defaults
    assert px4.to_parameters(missing) == pytest.approx({p.name: p.default for p in px4.MAPPING}, rel=1e-12)


def test_px4_s_gravity_fusion_parameters_map_onto_the_eskf_s_gravity_std():
    """EKF2_GRAV_NOISE is the std of the unit vector f/|f| (g0): our gravity_std 1:1, not x 9.81;
    EKF2_IMU_CTRL bit 2 clear turns the fusion off (gravity_std 0), which writes no
    EKF2_GRAV_NOISE but a comment to clear the bit; a log without either: PX4's defaults (on, 1.0)."""
    start = default_replay("eskf")
    grav = px4.BY_NAME["EKF2_GRAV_NOISE"]
    assert (grav.default, grav.unit, grav.switch.name, grav.switch.bit, grav.switch.default) == (
        1.0,
        "g0",
        "EKF2_IMU_CTRL",
        2,
        7,
    )
    assert px4.from_parameters(start, {"EKF2_GRAV_NOISE": 0.5}).estimator.gravity_std == 0.5
    assert (
        px4.from_parameters(start, {"EKF2_GRAV_NOISE": 0.5, "EKF2_IMU_CTRL": 7}).estimator.gravity_std == 0.5
    )
    assert px4.from_parameters(start, {}).estimator.gravity_std == 1.0
    for bits in (0, 1, 3, 8 + 3):  # bit 2 clear, whatever the others
        off = px4.from_parameters(start, {"EKF2_GRAV_NOISE": 0.5, "EKF2_IMU_CTRL": bits})
        assert off.estimator.gravity_std == 0.0
    assert px4.from_parameters(start, {"EKF2_IMU_CTRL": 4}).estimator.gravity_std == 1.0
    assert "EKF2_GRAV_NOISE" not in px4.to_parameters(off) and "EKF2_IMU_CTRL" not in px4.to_parameters(off)
    text = px4.parameter_file(off, start)
    assert "EKF2_GRAV_NOISE" not in px4.read_parameter_file(text)
    assert "clear bit 2 of EKF2_IMU_CTRL" in text
    on = px4.from_parameters(start, {"EKF2_GRAV_NOISE": 0.25})
    assert px4.read_parameter_file(px4.parameter_file(on, start))["EKF2_GRAV_NOISE"] == 0.25
    # a bundled PX4 v1.14+ log holds both (PX4's defaults): its px4_parameters replay keeps the fusion
    replay_config = load_replay("sitl_takeoff_land_gps", "{kind: eskf}", ["px4_parameters=true"])
    assert replay_config.px4_parameters
    from quad_drake.flightlogs.reader import read_flight_log
    from quad_drake.flightlogs.settings import resolve_log

    parameters = read_flight_log(resolve_log("sitl_takeoff_land_gps")).parameters
    assert (parameters["EKF2_GRAV_NOISE"], parameters["EKF2_IMU_CTRL"]) == (1.0, 7)
    assert px4.from_parameters(replay_config, parameters).estimator.gravity_std == 1.0
    assert px4.from_parameters(replay_config, parameters | {"EKF2_IMU_CTRL": 3}).estimator.gravity_std == 0.0


def test_the_sensor_delays_default_to_the_logs_own():
    start = default_replay("eskf")
    assert (start.gps_delay, start.mag_delay, start.baro_delay) == (None, None, None)
    ulog = px4.log_delays(start, {"EKF2_GPS_DELAY": 110.0, "EKF2_MAG_DELAY": 20.0})
    assert (ulog.gps_delay, ulog.mag_delay, ulog.baro_delay) == (0.11, 0.02, 0.0)
    csv = px4.log_delays(start, {})  # a CSV, another estimator's log: as logged
    assert (csv.gps_delay, csv.mag_delay, csv.baro_delay) == (0.0, 0.0, 0.0)
    chosen = load_replay("sitl_takeoff_land_gps", "{kind: eskf}", ["gps_delay=0"])  # the log as logged
    assert px4.log_delays(chosen, {"EKF2_GPS_DELAY": 110.0}).gps_delay == 0.0
    assert "EKF2_GPS_DELAY" not in px4.to_parameters(start)  # left to the log: not written
    with pytest.raises(ConfigError, match=r"gps_delay: must be within \[0, 0.5\] s"):
        load_replay("sitl_takeoff_land_gps", "{kind: eskf}", ["gps_delay=0.6"])


def test_px4_parameters_are_an_eskf_option():
    with pytest.raises(ConfigError, match="px4_parameters: maps EKF2_"):
        load_replay("sitl_takeoff_land_gps", "{kind: ekf7}", ["px4_parameters=true"])


@pytest.mark.parametrize(
    "content, message",
    [(None, "no such flight log file"), (b"not a ulog", "not a readable ULog file")],
)
def test_a_missing_or_unreadable_log_is_one_line_and_exit_2(quad_drake_cli, tmp_path, content, message):
    # In this process (a new one cost about 2 s of CPU to import drake; `python -m quad_drake`'s exit
    # code on a bad log is checked in tests/test_flight_log_replay.py): a traceback fails the test.
    path = tmp_path / "flight.ulg"
    if content is not None:
        path.write_bytes(content)
    done = quad_drake_cli("tune", path, "--out", tmp_path / "out")
    assert done.returncode == 2 and done.stdout == ""
    assert message in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert "Traceback" not in done.stderr


def test_a_folder_stands_for_its_logs_as_the_replay_takes_it(quad_drake_cli, tmp_path):
    from quad_drake.tuning.logs import is_log_name

    assert is_log_name(tmp_path) and is_log_name("a.ULG") and is_log_name("sitl_takeoff_land_gps")
    assert not is_log_name("11_gps_update")
    done = quad_drake_cli("tune", tmp_path, "--out", tmp_path / "out")  # a folder without logs
    assert done.returncode == 2 and done.stdout == "" and "Traceback" not in done.stderr
    assert "a folder without .ulg or .csv flight logs" in done.stderr


def test_a_log_named_twice_is_tuned_on_once_and_said(quad_drake_cli, tmp_path, monkeypatch):
    # the logs the search is given, caught before any replay: the bundled name and its path, and
    # a folder holding a copy of the ground-truth log beside that copy named again, each once
    from quad_drake.tuning import logs as log_tuning

    given = {}

    def caught(log_names, holdout_names, overrides, settings):
        given.update(tuned=log_names, held=holdout_names)
        raise ConfigError("caught before any replay")

    monkeypatch.setattr(log_tuning, "prepare", caught)
    folder = tmp_path / "held"
    folder.mkdir()
    copy = folder / "truth.ulg"
    copy.write_bytes((Path(__file__).parent / "data" / "flight_logs" / "sitl_ground_truth.ulg").read_bytes())
    bundled = str(LOG_DIR / "sitl_takeoff_land_gps.ulg")
    done = quad_drake_cli("tune", "sitl_takeoff_land_gps", bundled, "--holdout-logs", folder, copy)
    assert done.returncode == 2 and "caught before any replay" in done.stderr
    assert given == {"tuned": ["sitl_takeoff_land_gps"], "held": [str(copy)]}
    assert f"note: {bundled}, {copy}: given more than once (the same file); taken once" in done.stdout


def test_a_log_both_tuned_on_and_held_out_is_one_line_and_exit_2(quad_drake_cli, tmp_path):
    # a held-out log the search replays judges nothing held out: refused before any replay, by
    # the file it names (a bundled name and its path alike)
    bundled = str(LOG_DIR / "sitl_takeoff_land_gps.ulg")
    done = quad_drake_cli(
        "tune", "sitl_takeoff_land_gps", "--holdout-logs", bundled, "--out", tmp_path / "out"
    )
    assert done.returncode == 2 and done.stdout == "" and "Traceback" not in done.stderr
    assert "is both tuned on and held out" in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_delayed_gps_is_recovered_from_the_log_alone(tmp_path, seed=3001):
    """An 8 s run of 11_gps_update_eskf written with its GPS samples 120 ms late (between the
    profile's grid points): the tuner, starting from zero delay and PX4's noise, finds the delay
    within 20 ms (a seed not tuned on; with a budget of 36 on 16 s, 3001 and 3002 gave 116 and 119
    ms). A budget of 24 replays holds the GPS delay's grid and bounded search (the 12 more of 36
    profiled the magnetometer's delay, not asserted here). On 8 s (16 s, then 10 s until
    2026-12-06, the same figures): 118 ms at 3001, and within 8.2 ms of 120 ms at each of the seeds
    3002-3022 too (as on 10 and 16 s; on 7 s 3012 gave 100 ms and 3016 138 ms, at the bound)."""
    from quad_drake.flightlogs.recording import record_run, write_run_csv
    from quad_drake.running import catalog
    from quad_drake.tuning.logs import prepare, tune_logs
    from quad_drake.tuning.settings import LogTuneSettings

    record = record_run(catalog.load("11_gps_update_eskf", seed, ["end_time=8"]))
    path = write_run_csv(record, tmp_path / "run.csv", {"gps": 0.12})
    imu = ["estimator.accel_std=[0.5, 0.5, 1.5]", "estimator.gyro_std=[0.5, 0.5, 0.5]"]
    settings = LogTuneSettings(budget=24, train_fraction=0.9, curve_points=0, imu_noise=False)
    problem = prepare([str(path)], [], [*imu, "estimator.estimate_biases=false"], settings)
    assert [d.name for d in problem.space if d.is_delay] == ["gps_delay", "mag_delay"]
    result = tune_logs(problem, progress=False)
    tuned = dataclasses.asdict(result.tuned)
    assert abs(tuned["gps_delay"] - 0.12) <= 0.02
    assert result.search.best.score.loss < result.search.history[0].score.loss


def test_a_sensor_delay_replays_its_samples_as_measured_that_much_earlier():
    from quad_drake.flightlogs.reader import Samples
    from quad_drake.flightlogs.schedule import measured_at

    samples = Samples(np.array([0.05, 0.1, 0.3]), np.array([[1.0], [2.0], [3.0]]))
    shifted = measured_at(samples, 0.1)
    np.testing.assert_allclose(shifted.times, [0.0, 0.2], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(shifted.values, [[2.0], [3.0]])
    assert measured_at(samples, 0.0) is samples and measured_at(None, 0.1) is None


def test_the_default_split_tunes_and_judges_on_the_bundled_sitl_flight_alike():
    """The bundled SITL log stands on the ground until 19 s and flies 19-26 s: the log's first 60 %
    (``--split tail``, the only split until 2026-12-06) tuned on the ground alone (5-18.7 s) and
    judged on the whole flight. The default's interleaved blocks put moving GPS samples in both
    parts, and its windows tile [5 s, end) with the training share of each block."""
    from quad_drake.flightlogs.reader import read_flight_log
    from quad_drake.flightlogs.settings import resolve_log
    from quad_drake.tuning.logs import SPLIT_BLOCK, split
    from quad_drake.tuning.settings import LogTuneSettings

    log = read_flight_log(resolve_log("sitl_takeoff_land_gps"))
    moving = log.gps.times[np.abs(log.gps.values[:, 5]) > 0.3]  # climbing or descending
    assert len(moving) > 60
    training, held = split(log, LogTuneSettings())
    assert innovations.inside(moving, training).sum() >= 20 and innovations.inside(moving, held).sum() >= 20
    tail_training, tail_held = split(log, LogTuneSettings(split="tail"))
    assert not innovations.inside(moving, tail_training).any()  # what the blocks mend
    edges = sorted([*training, *held])
    assert edges[0][0] == 5.0 and edges[-1][1] >= log.duration
    assert all(a[1] == pytest.approx(b[0], abs=1e-12) for a, b in zip(edges, edges[1:], strict=False))
    assert all(end - start == pytest.approx(0.6 * SPLIT_BLOCK, abs=1e-12) for start, end in training[:-1])
    stamps = np.arange(5.0, log.duration, 0.01)
    assert not np.any(innovations.inside(stamps, training) & innovations.inside(stamps, held))


@pytest.mark.parametrize(
    "how, trained_on, held_label",
    [
        ("tail", "the first 60 % of each log", "sitl_takeoff_land_gps after 16.3 s"),
        ("blocks", "the first 60 % of each 4 s block of each log", "sitl_takeoff_land_gps held-out blocks"),
    ],
)
def test_the_split_is_worded_in_one_place_for_the_header_and_the_held_out_labels(how, trained_on, held_label):
    """``tuning.logs`` words both texts of a split side by side (the header's training part, the
    held-out part's label), as the header and the before/after table printed them."""
    from types import SimpleNamespace

    from quad_drake.tuning.logs import held_out_label, trained_part_text
    from quad_drake.tuning.settings import LogTuneSettings

    settings = LogTuneSettings(split=how)
    log = SimpleNamespace(source="/logs/sitl_takeoff_land_gps.ulg", duration=27.2)
    held = ((16.32, math.inf),) if how == "tail" else ((7.4, 9.0), (11.4, 13.0))
    assert trained_part_text(settings) == trained_on
    assert held_out_label(settings, log, held) == held_label


def test_the_search_sets_the_accelerometer_s_axes_apart_and_reaches_a_simulator_s_noise():
    """On the bundled SITL log one multiplier for the accelerometer's three axes left the horizontal
    velocity's prior variance 16 times its innovations' variance (NIS per dof 0.05-0.08), the
    vertical needing the larger noise; and its GPS horizontal velocity innovations (RMS 0.0026 m/s)
    lie under the former floor, 1/100 of PX4's 0.3 m/s."""
    from quad_drake.tuning.logs import apply, prepare
    from quad_drake.tuning.settings import LogTuneSettings

    problem = prepare(["sitl_takeoff_land_gps"], [], [], LogTuneSettings(budget=10))
    names = [d.name for d in problem.space]
    assert {"accel_xy", "accel_z", "gyro"} <= set(names) and "accel" not in names
    x = np.zeros(len(names))
    x[names.index("accel_z")] = 1.0
    start = problem.config.estimator.accel_std
    tuned = apply(problem.config, problem.space, x).estimator.accel_std
    assert tuned == pytest.approx([start[0], start[1], 10.0 * start[2]], rel=1e-12)
    velocity = problem.space[names.index("gps_vel_xy")]
    assert velocity.value(velocity.bounds[0]) < 0.0026 / 2 and velocity.value(velocity.bounds[1]) >= 30.0
    # the GPS noise searched is the one fused: not raised to the receiver's accuracy (0.30 m at the
    # end of this log, above the tuned 0.009 m), as a replay fuses it by default
    assert default_replay("eskf").gps_receiver_accuracy and not problem.config.gps_receiver_accuracy


def test_a_gps_height_the_barometer_replaces_is_neither_searched_nor_judged():
    """With the barometer the height reference (a log's EKF2_HGT_REF, or --set
    height_reference=baro) the replay fuses no GPS height (its σ 1000 m, as PX4's): its noise is
    no search coordinate and no channel judged; the GPS height reference keeps both."""
    from quad_drake.tuning.logs import channel_statistics, prepare, split
    from quad_drake.tuning.settings import LogTuneSettings

    settings = LogTuneSettings(budget=10, imu_noise=False, delays=False)
    by_gps = prepare(["sitl_takeoff_land_gps"], [], ["height_reference=gps"], settings)
    by_baro = prepare(["sitl_takeoff_land_gps"], [], ["height_reference=baro"], settings)
    searched = ["gps_pos_xy", "gps_pos_z", "gps_vel_xy", "gps_vel_z", "field", "baro"]
    assert [d.name for d in by_gps.space] == searched
    assert [d.name for d in by_baro.space] == [c for c in searched if c != "gps_pos_z"]
    log = by_baro.logs[0]
    _, held = split(log, settings)
    assert "gps_pos_z" not in channel_statistics(by_baro.config, log, held)
    assert "gps_pos_z" in channel_statistics(by_gps.config, log, held)
    # a log whose own EKF2_HGT_MODE makes the barometer the reference (PX4 v1.8 SITL, GPS throughout)
    second = Path(__file__).parent / "data" / "flight_logs" / "sitl_v18_ground_truth.ulg"
    by_log = prepare([str(second)], [], [], settings)
    assert [d.name for d in by_log.space] == [c for c in searched if c != "gps_pos_z"]


def _synthetic_problem(monkeypatch, objective, budget):
    """A LogTuneProblem over the barometer's noise and the GPS and barometer delays whose loss is
    objective(config) (no replay: ``_score`` replaced), nothing held out."""
    from quad_drake.tuning import logs
    from quad_drake.tuning.settings import LogTuneSettings

    start = dataclasses.replace(default_replay("eskf"), gps_delay=0.0, baro_delay=0.0)
    monkeypatch.setattr(logs, "_score", lambda problem, config: logs.LogScore(objective(config), 0.0, ({},)))
    space = [logs.Dimension("baro", 3.5), logs.Dimension("gps_delay", 0.0), logs.Dimension("baro_delay", 0.0)]
    return logs.LogTuneProblem(start, [], [], space, LogTuneSettings(budget=budget, curve_points=0))


def test_a_delay_least_at_the_end_of_the_range_is_kept_at_the_start_and_said_so(monkeypatch):
    """On x500v2_v6xrt the barometer delay's objective fell all the way to 300 ms (PX4's largest
    EKF2_BARO_DELAY), through the GPS height alone: no minimum inside the range, no estimate. The
    search took the grid point where its budget ran out (200 ms) or would have taken 300 ms."""
    from quad_drake.tuning.logs import tune_logs

    problem = _synthetic_problem(monkeypatch, lambda c: 100.0 * (c.gps_delay - 0.12) ** 2 - c.baro_delay, 80)
    result = tune_logs(problem, progress=False)
    assert abs(result.tuned.gps_delay - 0.12) <= 0.004 and result.tuned.baro_delay == 0.0
    assert list(result.kept) == ["baro_delay"] and "least at 300 ms" in result.kept["baro_delay"]
    least = min(result.search.history, key=lambda e: e.score.loss)  # a grid point at 300 ms
    assert least.x[2] == pytest.approx(3.0) and result.best.x[2] == 0.0
    assert not any(e.generation == 4 and e.x[2] != 0.0 for e in result.search.history)  # Powell leaves it


def test_a_delay_whose_grid_the_budget_cannot_hold_is_not_profiled(monkeypatch):
    """A grid cut by the budget left the delay at the last grid point tried (x500v2_v6xrt at budget
    100: its barometer delay at 200 ms, the objective still falling): now a profile starts only
    with the replays for its whole grid left (17: 7 delays every 50 ms, each re-matched, then 3
    matchings; the GPS delay's profile leaves fewer of the 20)."""
    from quad_drake.tuning.logs import tune_logs

    problem = _synthetic_problem(monkeypatch, lambda c: 100.0 * (c.gps_delay - 0.12) ** 2 - c.baro_delay, 20)
    result = tune_logs(problem, progress=False)
    assert result.tuned.baro_delay == 0.0 and "not profiled" in result.kept["baro_delay"]
    assert all(e.x[2] == 0.0 for e in result.search.history)  # not one replay spent on its grid
    assert abs(result.tuned.gps_delay - 0.12) <= 0.02 and "gps_delay" not in result.kept


def test_a_noise_tuned_to_a_bound_of_its_range_is_said_to_be_one():
    """x500v2_v6xrt's horizontal accelerometer noise ended at the search's floor (1/1000 of PX4's):
    a bound, not an estimate, and the header says so; a noise inside its range and a delay at 0 ms
    (a delay's own limit) are printed plainly."""
    from quad_drake.tuning import logs
    from quad_drake.tuning.log_output import header
    from quad_drake.tuning.search import Evaluation, SearchResult
    from quad_drake.tuning.settings import LogTuneSettings

    space = [logs.Dimension("accel_xy", 0.78), logs.Dimension("baro", 3.5), logs.Dimension("gps_delay", 0.11)]
    problem = logs.LogTuneProblem(default_replay("eskf"), [], [], space, LogTuneSettings(budget=2))
    score = logs.LogScore(1.0, 0.0, ({},))
    tuned = Evaluation(1, 1, (-logs.DECADES_DOWN, -0.5, 0.0), logs.LogScore(0.5, 0.0, ({},)))
    result = logs.LogTuneResult(problem, SearchResult([Evaluation(0, 0, (0.0, 0.0, 1.1), score), tuned]))
    lines = header(result)
    assert "accel_xy: 0.78 -> 0.00078 (at the search's floor, 1/1000 of the start: it may lie lower)" in lines
    assert "baro: 3.5 -> 1.107" in lines and "gps_delay: 110 -> 0 ms" in lines
    ceiling = Evaluation(2, 1, (logs.DECADES_UP, 0.0, 1.1), logs.LogScore(0.1, 0.0, ({},)))
    result.search.history.append(ceiling)
    ceiling_line = "accel_xy: 0.78 -> 78 (at the search's ceiling, 100 times the start: it may lie higher)"
    assert ceiling_line in header(result)


def test_every_barometer_update_is_judged_whatever_its_delay():
    """The bundled SITL log's barometer samples come in pairs 4 ms apart; the replay's diagnostics,
    logged every 5 ms, show one NIS per log period, so at a barometer delay of 2 ms (and 292 ms)
    half of the samples were never judged. The tuner's replays log the diagnostics every 2 ms
    tick (``innovations.UPDATE_DIAGNOSTICS``)."""
    import math

    from quad_drake.flightlogs.reader import read_flight_log
    from quad_drake.flightlogs.settings import resolve_log
    from quad_drake.tuning.logs import channel_statistics, cut

    log = read_flight_log(resolve_log("sitl_takeoff_land_gps"))
    config = dataclasses.replace(load_replay("sitl_takeoff_land_gps", "{kind: eskf}", []), baro_delay=0.002)
    measured = log.baro.times - config.baro_delay
    statistics = channel_statistics(config, cut(log, 12.0), ((5.0, math.inf),))
    assert np.diff(log.baro.times)[:2] == pytest.approx([0.004, 0.096], abs=1e-9)
    assert statistics["baro"].count == np.count_nonzero((measured >= 5.0) & (measured <= 12.0 - 0.002)) == 140
