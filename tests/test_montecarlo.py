"""Monte Carlo campaigns: determinism across job counts, seeds, statistics, saved files, CLI."""

import csv
import dataclasses
import json
import math

import numpy as np
import pytest

from quad_drake import catalog, montecarlo
from quad_drake import consistency as cons
from quad_drake.accuracy_bound import accuracy_bound
from quad_drake.config import (
    ConfigError,
    CriterionConfig,
    ImuParams,
    MagParams,
    ScenarioConfig,
    SensorsConfig,
    VehicleConfig,
)
from quad_drake.evaluation import rms
from quad_drake.montecarlo import CampaignResult, RunRecord, run_campaign


@pytest.fixture(scope="module")
def scenario():
    return catalog.load("10_mag_update", None, ["end_time=1.5"])


@pytest.fixture(scope="module")
def serial(scenario):
    return run_campaign(scenario, 3, jobs=1, seed=5, progress=False)


@pytest.mark.slow
def test_same_table_and_rows_whatever_the_number_of_jobs(scenario, serial):
    parallel = run_campaign(scenario, 3, jobs=2, seed=5, progress=False)
    assert parallel.jobs == 2
    assert parallel.table() == serial.table()
    assert parallel.rows() == serial.rows()
    for a, b in zip(serial.records, parallel.records, strict=True):
        np.testing.assert_array_equal(a.nees["Quad"], b.nees["Quad"])


def test_run_i_is_the_single_run_with_seed_s_plus_i(scenario, serial):
    from quad_drake.simulation import run

    single = run(dataclasses.replace(scenario, seed=7))
    record = serial.records[2]
    assert (record.index, record.seed) == (2, 7)
    yaw_error = single.signals["Quad.Est.E.Yaw"].values
    assert record.metrics["Quad.Est.E.Yaw"]["rms"] == rms(yaw_error)
    assert record.metrics["Quad.Est.E.Yaw"]["rms_settled"] == rms(yaw_error[single.times >= 0.75 - 1e-9])
    logs = single.logs["Quad"]
    expected = cons.nees(
        cons.state_errors(logs["ekf_state"], logs["state"]), cons.covariance_matrices(logs["covariance"])
    )
    np.testing.assert_array_equal(record.nees["Quad"], expected)
    assert serial.records[0].metrics["Quad.Est.E.Yaw"]["rms"] != record.metrics["Quad.Est.E.Yaw"]["rms"]


def test_records_hold_the_consistency_series_of_a_run(serial):
    record = serial.records[0]
    assert record.nees["Quad"].shape == (300,)  # 1.5 s of 5 ms samples
    assert np.isfinite(record.nees["Quad"]).all()
    stamps, nis = record.nis[("Quad", "mag")]
    assert stamps.size == nis.size == 150  # 0.008 + 0.01 k <= 1.5 s
    np.testing.assert_allclose(np.diff(stamps), 0.01, atol=1e-12)
    assert set(record.nis) == {("Quad", "mag")}  # no GPS on this vehicle
    assert record.nse["Quad"].shape == (7,)
    assert len(record.criteria) == 2 and not record.passed  # a 10 s window cannot pass in 1.5 s


def test_saved_files(serial, tmp_path):
    out = serial.save(tmp_path / "mc")
    with open(out / "runs.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["seed"] for r in rows] == ["5", "6", "7"]
    assert float(rows[1]["Quad.Est.E.Yaw.rms"]) == serial.records[1].metrics["Quad.Est.E.Yaw"]["rms"]
    assert "Quad.Est.E.Yaw.rms_settled" in rows[0]
    assert {"c1.passed", "c2.percent", "Quad.NEES.mean", "Quad.NIS.mag.mean"} <= set(rows[0])
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"] == 3 and summary["first_seed"] == 5
    assert [c["statistic"] for c in summary["consistency"]] == ["NEES", "NIS mag"]
    assert summary["consistency"][0]["band"] == pytest.approx(cons.chi2_band(7, 3))
    assert [e["state"] for e in summary["efficiency"]] == ["Yaw"]
    assert (out / "table.txt").read_text() == serial.table()
    assert np.load(out / "consistency.npz")["NEES_mean"].shape == (300,)
    for name in ("consistency.png", "errors.png"):
        assert (out / name).stat().st_size > 10_000


# ----- statistics on hand-made records (no simulation) ------------------------------------------


def hand_made_campaign(nees_level):
    vehicle = VehicleConfig(name="Quad", sensors=SensorsConfig(imu=ImuParams(), mag=MagParams()))
    scenario = ScenarioConfig(
        name="t",
        end_time=1.0,
        seed=100,
        vehicles=[vehicle],
        criteria=[CriterionConfig(kind="window", signal="Quad.Est.E.Yaw", threshold=0.1, window=0.5)],
    )
    records = []
    for i in range(20):
        yaw_rms = math.nan if i == 19 else 0.01 * (i + 1)
        metrics = {"Quad.Est.E.Yaw": {"rms": yaw_rms, "max": 3 * (i + 1), "rms_settled": 0.02 * (i + 1)}}
        stamps = 0.008 + 0.01 * np.arange(10)
        nis = {("Quad", "mag"): (stamps, np.full(10, 1.0))}
        records.append(
            RunRecord(
                i,
                100 + i,
                i < 15,
                [{"passed": i < 15, "measured": 0.6, "percent": None}],
                metrics,
                {"Quad": np.full(50, nees_level)},
                {"Quad": np.ones(7)},
                nis,
                0.1,
                0.005 * np.arange(1, 51),
            )
        )
    return CampaignResult(scenario, records, wall_time=2.0, jobs=1)


def test_pass_rates_come_with_clopper_pearson_intervals():
    campaign = hand_made_campaign(7.0)
    rows = campaign.criteria
    assert [r["passes"] for r in rows] == [15, 15]
    assert rows[0]["rate"] == 0.75
    assert rows[0]["ci95"] == pytest.approx(cons.binomial_interval(15, 20))
    assert "75.0%" in campaign.table()


def test_metric_distributions_count_a_diverged_run_as_infinite():
    metrics = hand_made_campaign(7.0).metrics["Est.E.Yaw"]
    assert metrics["rms"]["median"] == pytest.approx(0.105)
    assert metrics["rms"]["max"] == math.inf
    assert metrics["max"] == {"median": 31.5, "p95": pytest.approx(57.15), "max": 60.0}


def test_consistency_criterion_passes_inside_the_band_and_fails_outside():
    good, bad = hand_made_campaign(7.0), hand_made_campaign(12.0)
    nees = good.consistency[0]
    assert (nees["statistic"], nees["realisations"], nees["in_band"]) == ("NEES", 20, 1.0)
    assert good.consistency[1]["statistic"] == "NIS mag" and good.passed
    assert bad.consistency[0]["in_band"] == 0.0 and bad.consistency[0]["above"] == 1.0
    assert not bad.passed and "FAIL" in bad.table()


def test_efficiency_is_pooled_rmse_over_the_bound():
    campaign = hand_made_campaign(7.0)
    (row,) = campaign.efficiency  # uses rms_settled, not rms
    bound = accuracy_bound(campaign.scenario.vehicles[0])["Yaw"].mean_std
    rmse = math.sqrt(np.mean(np.square(0.02 * np.arange(1, 21))))
    assert row["rmse"] == pytest.approx(rmse)
    assert row["efficiency"] == pytest.approx(rmse / bound)


# ----- errors and the command line ---------------------------------------------------------------


def test_a_failing_run_names_its_seed(monkeypatch, scenario):
    def diverge(scenario, index, seed):
        raise FloatingPointError("diverged")

    monkeypatch.setattr(montecarlo, "simulate_run", diverge)
    with pytest.raises(RuntimeError, match=r"\(seed 10\).*quad-drake run 10_mag_update --seed 10"):
        run_campaign(scenario, 3, jobs=1, seed=10, progress=False)


@pytest.mark.parametrize("runs, jobs, seed", [(0, 1, None), (2, 0, None), (2, 1, -1)])
def test_bad_counts_are_config_errors(scenario, runs, jobs, seed):
    with pytest.raises(ConfigError):
        run_campaign(scenario, runs, jobs, seed=seed, progress=False)


def test_montecarlo_command_prints_the_table_saves_and_explains_its_exit_code(tmp_path, capsys):
    from quad_drake.cli import main

    args = ["10_mag_update", "--runs", "2", "--jobs", "1", "--seed", "3", "--set", "end_time=0.5"]
    code = main(["montecarlo", *args, "--out", str(tmp_path), "--no-plots"])
    out, err = capsys.readouterr()
    assert "Monte Carlo 10_mag_update: 2 runs of 0.5 s, seeds 3..4" in out
    assert "runs/min" in out and "2/2 runs" in err
    summary = json.loads((tmp_path / "10_mag_update_montecarlo" / "summary.json").read_text())
    assert code == (0 if summary["consistency_passed"] else 1)
    last = out.strip().splitlines()[-1]
    assert last.startswith("PASS (exit 0): " if code == 0 else "FAIL (exit 1): "), last
    assert not (tmp_path / "10_mag_update_montecarlo" / "errors.png").exists()


def test_a_failing_campaign_names_the_consistency_test_that_failed(tmp_path, capsys):
    from quad_drake.cli import main

    # The EKF believes the magnetometer 10x better than it is: its NIS is ~100x its dof.
    overconfident = ["--set", "end_time=1", "--set", "vehicles.0.ekf.mag_yaw_std=0.01"]
    code = main(
        ["montecarlo", "10_mag_update", "--runs", "2", *overconfident, "--out", str(tmp_path), "--no-plots"]
    )
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert code == 1
    assert last.startswith("FAIL (exit 1): NEES mean inside its chi2 95% band"), last
    assert "; NIS mag mean inside its chi2 95% band" in last and last.endswith("needs >= 80%")


def test_criterion_labels():
    assert (
        montecarlo.criterion_label(
            CriterionConfig(kind="window", signal="Quad.Est.E.Pos", threshold=1, window=20)
        )
        == "|Quad.Est.E.Pos| < 1 for > 20 s"
    )
    assert (
        montecarlo.criterion_label(
            CriterionConfig(
                kind="sigma",
                signal="Quad.GPS.X",
                ref_signal="Quad.Pos.X",
                sigma=0.7,
                min_percent=64,
                max_percent=73,
                window=2,
            )
        )
        == "|Quad.GPS.X - Quad.Pos.X| <= 0.7: 64-73 % (last 2 s)"
    )
    assert (
        montecarlo.criterion_label(
            CriterionConfig(
                kind="fleet_sigma",
                signal="Est.E.X",
                sigma_signal="Est.S.X",
                sigma_multiple=2,
                min_percent=90,
                max_percent=100,
            )
        )
        == "fleet |Est.E.X| <= 2 Est.S.X: 90-100 %"
    )
