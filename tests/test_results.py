"""The run folder contract: save, load without re-simulating, strict JSON, refusals, index."""

import json
import shutil

import numpy as np
import pytest

from quad_drake.config.errors import ConfigError
from quad_drake.estimation.vocabulary import DIAG
from quad_drake.output.export import export_csv
from quad_drake.output.jsonio import dump_json, to_json_ready
from quad_drake.output.report import find_summaries, write_index
from quad_drake.output.results import FORMAT_VERSION, RUNNER, load_run, save_run
from quad_drake.running import catalog
from quad_drake.running.simulation import run


def strict_loads(text):
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def fleet_run(tmp_path_factory):
    """09 (ten vehicles, fleet_sigma criteria) run and saved once."""
    result = run(catalog.load("09_predict_covariance"))
    return result, save_run(result, tmp_path_factory.mktemp("runs") / "09_predict_covariance")


@pytest.fixture(scope="module")
def sensor_run(tmp_path_factory):
    """11 (window and sigma criteria on GPS and estimate signals), shortened, saved once."""
    result = run(catalog.load("11_gps_update", 4, ["end_time=2"]))
    return result, save_run(result, tmp_path_factory.mktemp("runs") / "11_gps_update")


@pytest.mark.parametrize("which", ["fleet_run", "sensor_run"])
def test_load_run_gives_back_the_same_signals_and_verdicts(which, request):
    result, run_dir = request.getfixturevalue(which)
    loaded = load_run(run_dir)
    assert loaded.scenario == result.scenario
    np.testing.assert_array_equal(loaded.times, result.times)
    assert set(loaded.signals) == set(result.signals)
    for name, signal in result.signals.items():
        np.testing.assert_array_equal(loaded.signals[name].values, signal.values, err_msg=name)
        np.testing.assert_array_equal(loaded.signals[name].fresh, signal.fresh, err_msg=name)
    assert loaded.criteria == result.criteria and loaded.criteria  # text fields included
    for a, b in zip(loaded.criteria, result.criteria, strict=True):
        for key in (a.series or {}).keys() | (b.series or {}).keys():
            np.testing.assert_array_equal(a.series[key], b.series[key])
    assert loaded.wall_time == round(result.wall_time, 3) and loaded.runner == RUNNER


def test_summary_is_strict_json_with_format_and_verdict_texts(fleet_run):
    result, run_dir = fleet_run
    summary = strict_loads((run_dir / "summary.json").read_text())
    assert summary["format_version"] == FORMAT_VERSION and summary["kind"] == "run"
    assert (summary["runner"], summary["scenario"], summary["seed"]) == (RUNNER, "09_predict_covariance", 0)
    assert len(summary["criteria"]) == 4 + 10 * 5  # 4 fleet criteria, then 5 safety ones per vehicle
    for saved, verdict in zip(summary["criteria"], result.criteria, strict=True):
        assert saved["description"] == verdict.description and saved["trailing"] is None
    for saved, verdict in zip(summary["criteria"][:4], result.criteria[:4], strict=True):
        assert saved["kind"] == "fleet_sigma"
        assert saved["description"] == verdict.description and saved["measured_text"] == verdict.measured_text
        assert saved["samples"] == 10 * result.times.size  # every vehicle's every (fresh) sample
        assert "series" not in saved


def test_an_unknown_format_version_is_refused(sensor_run, tmp_path):
    run_dir = shutil.copytree(sensor_run[1], tmp_path / "copy")
    summary = json.loads((run_dir / "summary.json").read_text())
    summary["format_version"] = 99
    dump_json(run_dir / "summary.json", summary)
    with pytest.raises(ConfigError, match=r"format_version 99 is not supported \(this quad_drake reads 1\)"):
        load_run(run_dir)
    del summary["format_version"]
    dump_json(run_dir / "summary.json", summary)
    with pytest.raises(ConfigError, match="format_version None is not supported"):
        load_run(run_dir)


def test_a_run_saved_before_a_diagnostics_entry_was_appended_loads_and_exports(sensor_run, tmp_path):
    # An earlier quad_drake wrote the diagnostics without the entries appended since (the GPS height
    # restarts): the run loads, exports and reports with them at their value before any update.
    result, saved = sensor_run
    run_dir = shutil.copytree(saved, tmp_path / "older")
    with np.load(run_dir / "logs.npz") as data:
        logs = {key: data[key] for key in data.files}
    restarts = DIAG["gps_height_restarts"]
    logs["Quad/diagnostics"] = logs["Quad/diagnostics"][:, :restarts]  # the width before it
    np.savez(run_dir / "logs.npz", **logs)
    loaded = load_run(run_dir)
    assert (loaded.signals["Quad.Est.GpsHeightRestarts"].values == 0.0).all()
    for name, signal in result.signals.items():
        np.testing.assert_array_equal(loaded.signals[name].values, signal.values, err_msg=name)
    assert [p.name for p in export_csv(run_dir, tmp_path / "csv")][0] == "Quad.csv"


def test_a_folder_without_logs_or_summary_is_refused(sensor_run, tmp_path):
    run_dir = shutil.copytree(sensor_run[1], tmp_path / "copy")
    (run_dir / "logs.npz").unlink()
    with pytest.raises(ConfigError, match="no logs.npz"):
        load_run(run_dir)
    with pytest.raises(ConfigError, match="no summary.json"):
        load_run(tmp_path / "empty")


def test_json_ready_turns_numpy_and_non_finite_values_into_plain_json():
    value = {"a": np.float64("nan"), "b": [np.int64(3), np.inf, -np.inf], 4: np.array([1.5, np.nan])}
    assert to_json_ready(value) == {"a": None, "b": [3, None, None], "4": [1.5, None]}
    assert isinstance(to_json_ready(np.bool_(True)), bool)


def test_index_links_every_run_folder_under_out(sensor_run, fleet_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(sensor_run[1], out / "11_gps_update")  # an earlier invocation
    shutil.copytree(fleet_run[1], out / "sweep" / "09_predict_covariance")  # nested
    (out / "sweep" / "09_predict_covariance" / "report.html").write_text("x")
    old = out / "old_format"
    shutil.copytree(sensor_run[1], old)
    (old / "summary.json").write_text('{"scenario": "x", "passed": true}')
    dump_json(out / "summary.json", [sensor_run[0].summary()])  # a batch list: not a folder
    assert [f.name for f, _ in find_summaries(out)] == ["11_gps_update", "09_predict_covariance"]
    index = write_index(out).read_text()
    assert ">11_gps_update<" in index and "sweep/09_predict_covariance" in index
    assert 'href="sweep/09_predict_covariance/report.html"' in index
    assert "old_format" not in index
    graded = sum(1 for r in (sensor_run[0], fleet_run[0]) if r.passed)
    assert f"{graded} of 2 graded runs passed" in index


def test_a_new_run_in_a_folder_removes_the_old_runs_derived_files(gps_flight, tmp_path):
    stale = [tmp_path / "report.html", tmp_path / "replay.html", tmp_path / "Quad_position.png"]
    (tmp_path / "csv").mkdir()
    stale.append(tmp_path / "csv" / "Quad.csv")
    for path in stale:
        path.write_text("an earlier run's")
    (tmp_path / "notes.txt").write_text("the user's")
    save_run(gps_flight, tmp_path)
    assert not any(path.exists() for path in stale)
    assert (tmp_path / "notes.txt").read_text() == "the user's" and (tmp_path / "logs.npz").is_file()


def test_the_index_is_one_line_per_run_and_lists_tune_sessions(sensor_run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(sensor_run[1], out / "11_gps_update")
    tune = out / "11_gps_update_tune"
    tune.mkdir()
    (tune / "report.html").write_text("the session's page")
    session = {"scenario": "11_gps_update", "settings": {"objective": "both"}, "candidates": 12}
    session |= {"start_loss": 0.5, "best_loss": 0.25, "interrupted": False}
    session["holdout"] = {"before": {"passes": 9, "runs": 10}, "after": {"passes": 10, "runs": 10}}
    dump_json(tune / "tune.json", session)
    index = write_index(out).read_text()
    assert "<h2>Tuning sessions</h2>" in index and 'href="11_gps_update_tune/report.html">tune page' in index
    assert "0.5 → 0.25" in index and "9/10 → 10/10" in index
    # a run's row carries its failed lines only: the PASS lines are on its page
    result = sensor_run[0]
    for verdict in result.criteria:
        assert (verdict.line in index) is (not verdict.passed)
