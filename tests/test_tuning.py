"""quad-drake tune: the search space, the objective, the CMA-ES search, and the command line
(bad input before any work, outputs, determinism, both estimators, a fault scenario, Ctrl-C)."""

import copy
import csv
import dataclasses
import json
import math
import signal
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from quad_drake.config.errors import ConfigError
from quad_drake.config.loader import load_scenario
from quad_drake.estimation.registry import KINDS, EskfEstimatorConfig
from quad_drake.judging import consistency as cons
from quad_drake.tuning import objective, search, session, space
from quad_drake.tuning.objective import INFEASIBLE, Score

EKF7_KEYS = KINDS["ekf7"].tuning_keys(None)
ESKF_KEYS = KINDS["eskf"].tuning_keys(EskfEstimatorConfig())
SHORT_11 = ["end_time=2", "criteria.0.window=1"]
"""11's flight cut to 2 s, its position criterion to a 1 s window (a 20 s window cannot pass)."""
TINY = ["--budget", "3", "--seeds", "2", "--holdout", "2", "--jobs", "1", "--quiet"]


def strict_loads(text):
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


def test_the_package_exports_every_public_name_from_its_module():
    import quad_drake.tuning as tuning

    modules = {"objective": objective, "session": session, "space": space}
    for name in tuning.__all__:
        value = getattr(tuning, name)
        home = tuning._LAZY.get(name)
        assert home is None or value is getattr(modules[home], name), name
        assert name in dir(tuning)
    assert tuning.TuneSettings is session.TuneSettings and tuning.OBJECTIVES == objective.OBJECTIVES
    with pytest.raises(AttributeError, match="no attribute 'tunes'"):
        tuning.tunes  # noqa: B018 (the attribute access is the test)


# ----- search space ---------------------------------------------------------------------------


def test_default_space_is_the_estimators_noise_fields_that_are_switched_on(load_scenario):
    reference = load_scenario(
        "11_gps_update", "vehicles.0.estimator={kind: ekf7}"
    )  # the reference's EKF values
    assert [p.key for p in space.search_space(reference)] == [
        k
        for k in EKF7_KEYS
        if k != "estimator.tilt_gyro_std"  # off (0) in the reference
    ]
    tuned_11 = space.search_space(load_scenario("11_gps_update"))  # q_pos_*_std = 0 there, tilt on
    assert [p.key for p in tuned_11] == [k for k in EKF7_KEYS if "q_pos" not in k]
    with_biases = load_scenario("11_gps_update_eskf", "vehicles.0.estimator.estimate_biases=true")
    assert [p.key for p in space.search_space(with_biases)] == list(ESKF_KEYS)
    no_bias = load_scenario("11_gps_update_eskf")  # estimate_biases: false there (its IMU has none)
    assert [p.key for p in space.search_space(no_bias)] == [k for k in ESKF_KEYS if "_bias_" not in k]
    no_gps = load_scenario("10_mag_update", "vehicles.0.estimator={kind: ekf7}")  # a magnetometer but no GPS
    assert [p.key for p in space.search_space(no_gps)] == [
        k for k in EKF7_KEYS if ".gps_" not in k and k != "estimator.tilt_gyro_std"
    ]


def test_a_multiplier_scales_scalars_and_whole_vectors_in_log_space(load_scenario):
    eskf = load_scenario("11_gps_update_eskf")
    params = space.search_space(eskf, ["estimator.gps_pos_std", "estimator.mag_yaw_std"])
    before = copy.deepcopy(eskf)
    tuned = space.apply(eskf, params, [math.log10(2.0), -1.0])
    np.testing.assert_allclose(tuned.vehicles[0].estimator.gps_pos_std, [1.4, 1.4, 4.0], rtol=1e-12)
    assert tuned.vehicles[0].estimator.mag_yaw_std == pytest.approx(0.01, rel=1e-12)
    assert eskf == before  # the start is not touched
    assert space.apply(eskf, params, [0.0, 0.0]) == eskf  # x = 0 is the scenario as given


def test_a_relative_key_tunes_every_vehicle_a_full_key_one(load_scenario):
    one = load_scenario("11_gps_update")
    second = dataclasses.replace(copy.deepcopy(one.vehicles[0]), name="Quad2")
    second.estimator.q_yaw_std = 0.5
    two = dataclasses.replace(one, vehicles=[one.vehicles[0], second])
    (both,) = space.search_space(two, ["estimator.q_yaw_std"])
    start = one.vehicles[0].estimator.q_yaw_std
    tuned = space.apply(two, [both], [1.0])
    assert [v.estimator.q_yaw_std for v in tuned.vehicles] == pytest.approx([10 * start, 5.0], rel=1e-12)
    (first,) = space.search_space(two, ["vehicles.0.estimator.q_yaw_std"])
    one_tuned = space.apply(two, [first], [1.0]).vehicles
    assert [v.estimator.q_yaw_std for v in one_tuned] == pytest.approx([10 * start, 0.5], rel=1e-12)


@pytest.mark.parametrize(
    "keys, message",
    [
        (["estimator.q_velo_std"], "unknown field 'q_velo_std' in vehicles.0.estimator"),
        (["estimator.accel_std"], "unknown field 'accel_std' in vehicles.0.estimator"),
        (["estimator.q_pos_xy_std"], "starts at 0"),  # 0 in 11: a multiplier cannot move it
        (["flies_on"], "not a number"),
        (["vehicles.3.estimator.q_yaw_std"], "vehicles.N.<field> with N in 0..0"),
        (["estimator.q_yaw_std", "estimator.q_yaw_std"], "given twice"),
        (
            ["estimator.q_yaw_std", "vehicles.0.estimator.q_yaw_std"],
            "sets the same field as estimator.q_yaw_std",
        ),
        (["ekf..q_yaw_std"], "expected a dotted config key"),
    ],
)
def test_a_key_that_cannot_be_searched_is_one_config_error(load_scenario, keys, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")) as error:
        space.search_space(load_scenario("11_gps_update"), keys)
    assert "\n" not in str(error.value)


# ----- objective --------------------------------------------------------------------------------


def _statistic(name, dof, mean, realisations):
    return {"statistic": name, "dof": dof, "realisations": realisations, "mean": np.asarray(mean, float)}


def test_consistency_loss_uses_the_band_of_the_held_out_campaign():
    band_100 = cons.chi2_band(7, 100)
    inside = _statistic("NEES", 7, np.full(50, 7.0), 10)  # the expected value: inside every band
    loss, in_band = objective.consistency_loss([inside], runs=10, target_runs=100)
    assert loss == 0.0 and in_band == {"NEES": 1.0}
    # 8.5 is inside the 10-run band but outside the 100-run one: the training average is judged
    # by the band the held-out campaign will use
    high = _statistic("NEES", 7, np.full(50, 8.5), 10)
    assert cons.in_band_fraction(high["mean"], cons.chi2_band(7, 10)) == 1.0
    loss, in_band = objective.consistency_loss([high], runs=10, target_runs=100)
    assert in_band == {"NEES": 0.0}
    assert loss == pytest.approx(1.0 + math.log(8.5 / band_100[1]), rel=1e-12)
    # the smooth part ranks two averages that are both outside: farther is worse
    higher = _statistic("NEES", 7, np.full(50, 12.0), 10)
    assert objective.consistency_loss([higher], 10, 100)[0] > loss
    broken = _statistic("NEES", 7, np.full(50, np.nan), 10)
    assert objective.consistency_loss([broken], 10, 100)[0] == 1.0 + objective.NONFINITE_DISTANCE


def test_consistency_loss_averages_the_statistics():
    good = _statistic("NEES", 7, np.full(20, 7.0), 10)
    half = _statistic("NIS mag", 1, np.r_[np.ones(10), np.full(10, 10.0)], 10)
    loss, in_band = objective.consistency_loss([good, half], runs=10, target_runs=10)
    high = cons.chi2_band(1, 10)[1]
    assert in_band == {"NEES": 1.0, "NIS mag": 0.5}
    assert loss == pytest.approx((0.0 + 0.5 + 0.5 * math.log(10.0 / high)) / 2, rel=1e-12)


def _row(state, hover, pcrb):
    return {"vehicle": "Quad", "state": state, "rmse": 0.1, "efficiency": hover, "pcrb_efficiency": pcrb}


def test_accuracy_loss_is_the_mean_efficiency_over_the_bounds_minus_one():
    rows = [_row("X", 1.2, 1.1), _row("Yaw", 2.0, None), _row("AttN", None, 1.5)]
    assert objective.accuracy_loss(rows) == pytest.approx((1.1 + 2.0 + 1.5) / 3 - 1.0, rel=1e-12)
    assert math.isnan(objective.accuracy_loss([]))


def _campaign(rate, nees_mean=7.0, efficiency=1.5):
    return SimpleNamespace(
        runs=10,
        consistency=[_statistic("NEES", 7, np.full(20, nees_mean), 10)],
        efficiency=[_row("X", efficiency, efficiency)],
        criteria=[{"criterion": "all criteria", "rate": rate}],
    )


def test_objectives_and_the_penalty_for_a_failed_run():
    passing = objective.score(_campaign(1.0, nees_mean=9.0), "both", 10)
    assert passing.feasible and passing.loss == pytest.approx(passing.consistency + passing.accuracy)
    assert objective.score(_campaign(1.0), "accuracy", 10).loss == pytest.approx(0.5)
    assert objective.score(_campaign(1.0), "consistency", 10).loss == 0.0
    failing = objective.score(_campaign(0.9), "consistency", 10)  # perfectly consistent, one run failed
    assert not failing.feasible and failing.loss == pytest.approx(INFEASIBLE + 0.1)
    worse = objective.score(_campaign(0.5), "consistency", 10)
    assert worse.loss > failing.loss > passing.loss
    with pytest.raises(ValueError, match="objective"):
        objective.score(_campaign(1.0), "speed", 10)


def test_the_verdict_asks_every_held_out_run_to_pass_and_the_loss_not_to_rise():
    def result(after_rate, after_nees):
        settings = SimpleNamespace(objective="consistency")
        return SimpleNamespace(
            problem=SimpleNamespace(settings=settings),
            before=_campaign(1.0, nees_mean=12.0),
            after=_campaign(after_rate, nees_mean=after_nees),
        )

    start = objective.score(_campaign(1.0, nees_mean=12.0), "consistency", 10).loss
    assert start > 1.0  # 12 is outside the 10-run band of a 7-dof NEES
    assert session.verdict(result(1.0, 7.0)) == (
        True,
        f"PASS: tuned: every criterion passed in 10 of 10 held-out runs; held-out loss 0 (start {start:.4g})",
    )
    passed, line = session.verdict(result(0.9, 7.0))
    assert not passed and line.startswith("FAIL: tuned: every criterion passed in 9 of 10")
    passed, line = session.verdict(result(1.0, 20.0))  # every run passes, but less consistent
    assert not passed and line.startswith("FAIL: held-out loss")


# ----- search -----------------------------------------------------------------------------------


def _quadratic(target):
    return search.one_at_a_time(_quadratic_of_one(target))


def _quadratic_of_one(target):
    def evaluate(x):
        return Score(float(np.sum((np.asarray(x) - target) ** 2)), 0.0, 0.0, 1.0, {})

    return evaluate


def test_search_spends_the_budget_starts_at_the_start_and_is_deterministic():
    target = np.array([0.4, -0.3, 0.2])
    first = search.search(_quadratic(target), 3, 17, 1.0, seed=5)
    second = search.search(_quadratic(target), 3, 17, 1.0, seed=5)
    assert len(first.history) == 17 and not first.interrupted
    assert first.history[0].x == (0.0, 0.0, 0.0) and first.history[0].generation == 0
    assert [(e.x, e.score.loss) for e in first.history] == [(e.x, e.score.loss) for e in second.history]
    other = search.search(_quadratic(target), 3, 17, 1.0, seed=6)
    assert [e.x for e in other.history] != [e.x for e in first.history]
    assert all(abs(v) <= 1.0 for e in first.history for v in e.x)


def test_search_finds_the_minimum_inside_the_bounds():
    target = np.array([0.4, -0.3, 0.2, 0.7])
    result = search.search(_quadratic(target), 4, 300, 1.0, seed=0)
    np.testing.assert_allclose(result.best.x, target, atol=0.02)
    clipped = search.search(_quadratic(np.array([3.0, 0.0])), 2, 200, 1.0, seed=0)  # outside the box
    np.testing.assert_allclose(clipped.best.x, [1.0, 0.0], atol=0.02)


def test_ctrl_c_ends_the_search_with_the_best_so_far():
    calls = []

    def evaluate(x):
        if len(calls) == 5:
            raise KeyboardInterrupt
        calls.append(x)
        return _quadratic_of_one(np.array([0.5, 0.5]))(x)

    result = search.search(search.one_at_a_time(evaluate), 2, 50, 1.0)
    assert result.interrupted and len(result.history) == 5
    assert result.best.score.loss == min(e.score.loss for e in result.history)


def _last_first(evaluate, stop_after=None):
    """A generation evaluator that scores a generation's candidates at once and gives them back
    in reverse order (as a pool may), with Ctrl-C after `stop_after` scores."""
    given = []

    def generation(xs):
        for i in reversed(range(len(xs))):
            if len(given) == stop_after:
                raise KeyboardInterrupt
            given.append(i)
            yield i, evaluate(xs[i])

    return generation


def test_a_generation_scored_at_once_in_any_order_gives_the_same_search():
    target = np.array([0.4, -0.3, 0.2])
    in_order = search.search(_quadratic(target), 3, 17, 1.0, seed=5)
    shuffled = search.search(_last_first(_quadratic_of_one(target)), 3, 17, 1.0, seed=5)
    assert [(e.index, e.generation, e.x, e.score.loss) for e in shuffled.history] == [
        (e.index, e.generation, e.x, e.score.loss) for e in in_order.history
    ]
    stopped = search.search(_last_first(_quadratic_of_one(target), stop_after=3), 3, 17, 1.0, seed=5)
    population = search.population_size(3, 17)
    assert stopped.interrupted  # the start, then the last two candidates of generation 1, kept in order
    assert [e.index for e in stopped.history] == [0, population - 1, population]
    assert [e.x for e in stopped.history] == [in_order.history[i].x for i in (0, population - 1, population)]


def test_population_fits_three_generations_into_a_small_budget():
    assert search.population_size(10, 1000) == 4 + int(3 * math.log(10))
    assert search.population_size(10, 20) == 6
    assert search.population_size(10, 4) == 3  # never more than the budget after the start


# ----- command line: bad input before any work ----------------------------------------------


@pytest.fixture
def nothing_flies(monkeypatch):
    def fly(*args, **kwargs):
        raise AssertionError("a campaign flew before the input was checked")

    monkeypatch.setattr(session, "fly_campaign", fly)
    monkeypatch.setattr(session, "score_candidates", fly)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--params", "estimator.q_velo_std"], "--params estimator.q_velo_std: unknown field 'q_velo_std'"),
        (["--budget", "0"], "--budget must be >= 1, got 0"),
        (["--seeds", "0"], "--seeds must be >= 1"),
        (["--jobs", "0"], "--jobs must be >= 1"),
        (["--seed", "0", "--seeds", "5", "--holdout-seed", "3"], "overlap the training seeds 0..4"),
        (["--set", "end_time=-1"], "end_time: must be > 0"),
    ],
)
def test_bad_input_is_one_line_and_exit_2_before_any_run(
    quad_drake_cli, nothing_flies, out_dir, args, message
):
    result = quad_drake_cli("tune", "11_gps_update", "--out", out_dir, *args)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and message in result.stderr, result.stderr
    assert not out_dir.exists()


def test_an_unusable_out_folder_is_exit_2(quad_drake_cli, nothing_flies, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    result = quad_drake_cli("tune", "11_gps_update", "--out", blocker)
    assert result.returncode == 2 and "exists and is not a folder" in result.stderr
    result = quad_drake_cli("tune", "11_gps_update", "--out", tmp_path / "no" / "such")
    assert result.returncode == 2 and "does not exist" in result.stderr


def test_a_scenario_without_an_estimator_cannot_be_tuned(quad_drake_cli, nothing_flies, out_dir):
    result = quad_drake_cli("tune", "01_intro", "--out", out_dir)
    assert result.returncode == 2 and "has no estimator to tune" in result.stderr


# ----- command line: real (tiny) tuning runs ------------------------------------------------


def _history(folder):
    with open(folder / "history.csv") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_tune_writes_a_runnable_tuned_yaml_and_is_deterministic(quad_drake_cli, tmp_path):
    args = ["tune", "11_gps_update", *TINY, "--params", "estimator.q_vel_xy_std", "estimator.q_yaw_std"]
    args += [f"--set={s}" for s in SHORT_11]
    first = quad_drake_cli(*args, "--out", tmp_path / "a")
    assert first.returncode in (0, 1), first.stderr
    assert first.stdout.strip().splitlines()[-1].startswith(("PASS", "FAIL"))
    folder = tmp_path / "a"
    for name in ("tuned.yaml", "history.csv", "objective.png", "tune.json", "before_after.txt"):
        assert (folder / name).is_file(), name
    assert (folder / "holdout_before" / "summary.json").is_file()
    rows = _history(folder)
    assert [r["candidate"] for r in rows] == ["0", "1", "2"]
    summary = strict_loads((folder / "tune.json").read_text())
    best = min(rows, key=lambda r: float(r["loss"]))
    assert summary["best_loss"] == float(best["loss"]) and summary["holdout"]["seeds"] == [0, 1]
    tuned = load_scenario(folder / "tuned.yaml")
    assert tuned.name == "11_gps_update_tuned" and tuned.end_time == 2.0
    # history.csv, tune.json and tuned.yaml carry the same value, in full precision
    assert tuned.vehicles[0].estimator.q_vel_xy_std == float(best["value.estimator.q_vel_xy_std"])
    searched = {p["key"]: p["tuned"] for p in summary["parameters"]}
    assert searched["estimator.q_vel_xy_std"] == tuned.vehicles[0].estimator.q_vel_xy_std
    assert "before" in (folder / "before_after.txt").read_text()
    page = (folder / "report.html").read_text()  # the session's page, linked from the index
    assert "estimator.q_vel_xy_std" in page and 'href="holdout_after/report.html"' in page
    from quad_drake.output.report import write_index

    assert 'href="a/report.html">tune page</a>' in write_index(tmp_path).read_text()
    # the same seeds and budget: the same search, also with a generation's candidates on two workers
    second = quad_drake_cli(*args, "--out", tmp_path / "b", "--no-holdout", "--jobs", "2")
    assert second.returncode == 0, second.stderr
    assert (tmp_path / "b" / "history.csv").read_text() == (folder / "history.csv").read_text()
    assert (tmp_path / "b" / "tuned.yaml").read_text() == (folder / "tuned.yaml").read_text()
    run = quad_drake_cli("run", folder / "tuned.yaml", "--out", tmp_path / "run", "--no-plots")
    assert run.returncode in (0, 1) and "Traceback" not in run.stderr, run.stderr


@pytest.mark.slow
def test_tune_works_for_the_eskf_and_a_fault_scenario(quad_drake_cli, tmp_path):
    eskf = quad_drake_cli(
        "tune", "11_gps_update_eskf", *TINY, "--no-holdout", "--out", tmp_path / "eskf",
        *[f"--set={s}" for s in SHORT_11], "--params", "estimator.gps_pos_std", "estimator.accel_std",
    )  # fmt: skip
    assert eskf.returncode == 0, eskf.stderr
    assert load_scenario(tmp_path / "eskf" / "tuned.yaml").vehicles[0].estimator.kind == "eskf"
    # 13's outlier moved to 1 s of a 2 s flight, its criteria with it
    fault = ["end_time=2", "criteria.0.window=1", "vehicles.0.faults.0.time=1", "criteria.1.start=1"]
    fault += ["criteria.1.end=2"]
    outlier = quad_drake_cli(
        "tune", "13_gps_outlier", *TINY, "--objective", "consistency", "--out", tmp_path / "fault",
        *[f"--set={s}" for s in fault],
    )  # fmt: skip
    assert outlier.returncode in (0, 1), outlier.stderr
    rows = _history(tmp_path / "fault")
    searched = {f"value.{k}" for k in EKF7_KEYS if k != "estimator.tilt_gyro_std"}  # 13: off
    assert len(rows) == 3 and searched <= set(rows[0]) and "value.estimator.tilt_gyro_std" not in rows[0]


@pytest.mark.slow
def test_a_real_ctrl_c_keeps_the_best_so_far(tmp_path):
    command = [sys.executable, "-m", "quad_drake.cli", "tune", "11_gps_update", "--budget", "200"]
    command += ["--seeds", "1", "--jobs", "1", "--out", str(tmp_path / "t")]
    command += [f"--set={s}" for s in SHORT_11]
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # not ignored if we are
    )
    first = process.stderr.readline()  # the first progress line: the start is scored
    assert "candidate 0 (1/200; 0 is the start)" in first, first
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 130 and "Traceback" not in err and out == "", err
    assert err.strip().splitlines()[-1].startswith("quad-drake: interrupted; kept the best of ")
    rows = _history(tmp_path / "t")
    assert 1 <= len(rows) < 200
    assert load_scenario(tmp_path / "t" / "tuned.yaml").name == "11_gps_update_tuned"
    summary = strict_loads((tmp_path / "t" / "tune.json").read_text())
    assert summary["interrupted"] and summary["candidates"] == len(rows)


@pytest.mark.parametrize("name", ["11_gps_update", "19_windy_hover"])
def test_a_candidates_set_texts_give_the_scenario_its_values(name):
    """The "reproduce with" hint of a failing candidate's run carries its values as --set texts."""
    from quad_drake.config import dump_scenario
    from quad_drake.running import catalog
    from quad_drake.tuning.space import apply, overrides, search_space

    start = catalog.load(name)
    space = search_space(start, None)
    x = np.linspace(-0.5, 0.7, len(space))
    assert dump_scenario(catalog.load(name, None, overrides(space, x))) == dump_scenario(
        apply(start, space, x)
    )
    assert dump_scenario(apply(start, space, x)) != dump_scenario(start)
