"""Monte Carlo campaigns: same statistics whatever the runner, seeds, statistics, saved files,
the campaign page, progress output, Ctrl-C keeping the finished runs, the CLI's last line."""

import csv
import dataclasses
import io
import json
import math
import multiprocessing
import multiprocessing.connection
import os
import re
import signal
import subprocess
import sys

import numpy as np
import pytest
from pool_tasks import pid_after, worker_pid

from quad_drake import cli
from quad_drake.campaigns import (
    CampaignInterrupted,
    CampaignResult,
    InProcessRunner,
    ProcessPoolRunner,
    Runner,
    RunRecord,
    campaign,
    run_campaign,
    save,
    table,
)
from quad_drake.campaigns.output import rows
from quad_drake.campaigns.plots import errors_figure
from quad_drake.campaigns.records import slim
from quad_drake.campaigns.tally import ConsistencyTally
from quad_drake.config.errors import ConfigError
from quad_drake.config.schema import (
    CriterionConfig,
    ImuParams,
    MagParams,
    ScenarioConfig,
    SensorsConfig,
    VehicleConfig,
)
from quad_drake.estimation.vocabulary import EKF7
from quad_drake.judging import consistency as cons
from quad_drake.judging.evaluation import rms
from quad_drake.models.accuracy_bound import accuracy_bound
from quad_drake.output.report import write_index
from quad_drake.output.results import variant_name
from quad_drake.running import catalog


def strict_loads(text):
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def scenario():
    return catalog.load("10_mag_update", None, ["end_time=1.5"])


class Recording(InProcessRunner):
    """In this process, keeping each record as the worker sent it (with its series)."""

    def __init__(self):
        self.sent = {}

    def map(self, fn, tasks):
        for index, record in super().map(fn, tasks):
            self.sent[record.index] = record
            yield index, record


@pytest.fixture(scope="module")
def flown(scenario):
    """(campaign of 3 runs from seed 5, the records its workers sent, by index)."""
    runner = Recording()
    campaign_result = run_campaign(scenario, 3, runner=runner, seed=5, progress=False)
    return campaign_result, [runner.sent[i] for i in range(3)]


@pytest.fixture(scope="module")
def serial(flown):
    return flown[0]


@pytest.fixture(scope="module")
def sent(flown):
    return flown[1]


@pytest.mark.slow
def test_same_table_and_rows_whatever_the_runner(scenario, serial, process_pool):
    parallel = run_campaign(scenario, 3, runner=process_pool, seed=5, progress=False)
    assert (serial.runner, parallel.runner) == ("in-process", "process-pool x2")
    assert table(parallel) == table(serial)
    assert rows(parallel) == rows(serial)
    for a, b in zip(serial.consistency, parallel.consistency, strict=True):
        np.testing.assert_array_equal(a["times"], b["times"])
        np.testing.assert_array_equal(a["mean"], b["mean"])  # added in run order on every runner


def test_run_i_is_the_single_run_with_seed_s_plus_i(scenario, serial, sent):
    from quad_drake.running.simulation import run

    single = run(dataclasses.replace(scenario, seed=7))
    record = serial.records[2]
    assert (record.index, record.seed) == (2, 7)
    yaw_error = single.signals["Quad.Est.E.Yaw"].values
    assert record.metrics["Quad.Est.E.Yaw"]["rms"] == rms(yaw_error)
    assert record.metrics["Quad.Est.E.Yaw"]["rms_settled"] == rms(yaw_error[single.times >= 0.75 - 1e-9])
    logs = single.logs["Quad"]
    expected = cons.nees(EKF7.errors(logs), cons.covariance_matrices(logs["covariance"]))
    np.testing.assert_array_equal(sent[2].nees["Quad"], expected)
    assert record.nees_mean == {"Quad": float(np.mean(expected))}
    assert [c["description"] for c in record.criteria] == [c.description for c in single.criteria]
    assert serial.records[0].metrics["Quad.Est.E.Yaw"]["rms"] != record.metrics["Quad.Est.E.Yaw"]["rms"]


def test_records_hold_the_consistency_series_of_a_run(sent):
    record = sent[0]
    assert record.nees["Quad"].shape == (300,)  # 1.5 s of 5 ms samples
    assert np.isfinite(record.nees["Quad"]).all()
    stamps, nis = record.nis[("Quad", "mag")]
    assert stamps.size == nis.size == 150  # 0.008 + 0.01 k <= 1.5 s
    np.testing.assert_allclose(np.diff(stamps), 0.01, atol=1e-12)
    assert set(record.nis) == {("Quad", "mag")}  # no GPS on this vehicle
    assert record.nse["Quad"].shape == (7,)
    assert len(record.criteria) == 2 + 5 and not record.passed  # 2 own, 5 safety; 10 s window in 1.5 s


def test_saved_files_and_the_campaign_page(serial, tmp_path):
    out = save(serial, tmp_path / "mc")
    with open(out / "runs.csv") as f:
        csv_rows = list(csv.DictReader(f))
    assert [r["seed"] for r in csv_rows] == ["5", "6", "7"]
    assert float(csv_rows[1]["Quad.Est.E.Yaw.rms"]) == serial.records[1].metrics["Quad.Est.E.Yaw"]["rms"]
    assert "Quad.Est.E.Yaw.rms_settled" in csv_rows[0]
    assert {"c1.passed", "c2.percent", "Quad.NEES.mean", "Quad.NIS.mag.mean"} <= set(csv_rows[0])
    summary = strict_loads((out / "summary.json").read_text())
    assert (summary["format_version"], summary["kind"], summary["partial"]) == (1, "campaign", False)
    assert summary["runs"] == 3 and summary["first_seed"] == 5 and summary["completed"] == [0, 1, 2]
    assert [c["statistic"] for c in summary["consistency"]] == ["NEES", "NIS mag"]
    assert summary["consistency"][0]["band"] == pytest.approx(cons.chi2_band(7, 3))
    assert [e["state"] for e in summary["efficiency"]] == ["Yaw"]
    assert summary["verdict"] == serial.verdict()
    assert (out / "table.txt").read_text() == table(serial)
    assert np.load(out / "consistency.npz")["NEES_mean"].shape == (300,)
    for name in ("consistency.png", "errors.png"):
        assert (out / name).stat().st_size > 10_000
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 2
    low, high = serial.criteria[0]["ci95"]
    assert f"[{100 * low:.3g}, {100 * high:.3g}]" in page  # pass rates with their interval
    assert "|Quad.Est.E.Yaw| &lt; 0.12 rad for &gt; 10 s" in page
    assert ">NIS mag<" in page and ">Quad.Yaw<" in page  # consistency and efficiency tables
    index = write_index(tmp_path).read_text()
    assert 'href="mc/report.html"' in index and "Monte Carlo campaigns" in index
    assert "graded runs" not in index and "<code>quad-drake run NAME</code> writes one" in index


def test_summary_names_the_unit_of_every_column_and_the_column_of_every_criterion(serial, tmp_path):
    out = save(serial, tmp_path / "mc")
    with open(out / "runs.csv") as f:
        header = next(csv.reader(f))
    summary = strict_loads((out / "summary.json").read_text())
    columns = summary["columns"]
    assert list(columns) == header
    kinds = ["window", "sigma", "floor", "room", "finite", "tracking", "attitude", None]
    assert [c["kind"] for c in summary["criteria"]] == kinds
    assert [c["column"] for c in summary["criteria"]] == ["c1", "c2", "c3", "c4", "c5", "c6", "c7", "passed"]
    units = ["s", "s", "count", "s", "count", "m", "rad", None]
    assert [c["measured_unit"] for c in summary["criteria"]] == units
    for criterion in summary["criteria"][:-1]:
        assert columns[f"{criterion['column']}.measured"] == criterion["measured_unit"]
        assert columns[f"{criterion['column']}.passed"] == ""
    assert columns["c2.percent"] == "%" and "c1.percent" not in columns
    assert columns["Quad.Est.E.Yaw.rms"] == columns["Quad.Est.E.Yaw.rms_settled"] == "rad"
    assert columns["Quad.PosFollowErr.max"] == "m"
    assert columns["Quad.NEES.mean"] == columns["seed"] == ""
    assert summary["metrics"]["Est.E.Vel"]["unit"] == "m/s"
    assert [(e["state"], e["unit"]) for e in summary["efficiency"]] == [("Yaw", "rad")]


def test_an_eskf_campaign_gives_every_error_signal_its_unit(tmp_path):
    scenario = catalog.load("17_imu_bias", None, ["end_time=1"])
    result = run_campaign(scenario, 2, runner=InProcessRunner(), progress=False)
    units = {key: m["unit"] for key, m in result.metrics.items()}
    assert (units["Est.E.AttN"], units["Est.E.BAX"], units["Est.E.BGZ"]) == ("rad", "m/s^2", "rad/s")
    assert "" not in units.values()
    figure = errors_figure(result)  # one box-plot panel per unit, every error signal in one
    ticks = [t.get_text() for ax in figure.axes for t in ax.get_xticklabels()]
    assert sorted(ticks) == sorted(key.rsplit(".", 1)[-1] for key in units)
    assert len(figure.axes) == len(set(units.values()))
    table_text = table(result)
    assert "Est.E.AttN [rad]" in table_text and "Est.E.BGZ [rad/s]" in table_text


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
        verdict = {"kind": "window", "description": "d", "passed": i < 15, "measured": 0.6, "unit": "s"}
        verdict["percent"] = None
        records.append(
            RunRecord(
                i,
                100 + i,
                i < 15,
                [verdict],
                metrics,
                {"Quad": np.full(50, nees_level)},
                {"Quad": np.ones(7)},
                nis,
                0.1,
                0.005 * np.arange(1, 51),
            )
        )
    tally = ConsistencyTally()
    for record in records:
        tally += ConsistencyTally.of(record)
    return CampaignResult(scenario, [slim(r) for r in records], tally, wall_time=2.0, runner="in-process")


def test_pass_rates_come_with_clopper_pearson_intervals():
    campaign_result = hand_made_campaign(7.0)
    criteria = campaign_result.criteria
    assert [r["passes"] for r in criteria] == [15, 15]
    assert criteria[0]["rate"] == 0.75
    assert criteria[0]["ci95"] == pytest.approx(cons.binomial_interval(15, 20))
    assert "75.0%" in table(campaign_result)


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
    assert not bad.passed and "FAIL" in table(bad)
    assert nees["per_dof"] == 1.0 and nees["per_dof_ci95"] == [1.0, 1.0]  # every run the same
    assert bad.consistency[0]["per_dof"] == pytest.approx(12 / 7) and nees["tolerance"] == [1 / 1.5, 1.5]


def test_failure_reasons_explain_the_verdict():
    good, bad = hand_made_campaign(7.0), hand_made_campaign(12.0)
    assert good.failure_reasons() == []
    assert good.verdict() == "PASS: every consistency criterion passed (all criteria passed in 15 of 20 runs)"
    assert bad.failure_reasons() == ["NEES/dof 1.71 [1.71, 1.71] outside [0.667, 1.5]"]
    assert bad.verdict() == "FAIL: NEES/dof 1.71 [1.71, 1.71] outside [0.667, 1.5]"


def test_efficiency_is_pooled_rmse_over_the_bound():
    campaign_result = hand_made_campaign(7.0)
    (row,) = campaign_result.efficiency  # uses rms_settled, not rms
    bound = accuracy_bound(campaign_result.scenario.vehicles[0])["Yaw"].mean_std
    rmse = math.sqrt(np.mean(np.square(0.02 * np.arange(1, 21))))
    assert row["rmse"] == pytest.approx(rmse)
    assert row["efficiency"] == pytest.approx(rmse / bound)


def test_progress_is_a_tqdm_bar_on_a_terminal_and_plain_lines_elsewhere():
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    record = hand_made_campaign(7.0).records[0]
    for stream, carriage_return in ((Terminal(), True), (io.StringIO(), False)):
        progress = campaign.Progress("t", 20, stream=stream)
        for _ in range(20):
            progress.update([record])
        progress.close()
        text = stream.getvalue()
        assert ("\r" in text) is carriage_return and "20/20" in text
    lines = io.StringIO()
    progress = campaign.Progress("t", 20, stream=lines)
    for _ in range(20):
        progress.update([record])
    assert len(lines.getvalue().splitlines()) == 10  # about every tenth of the runs
    batches = io.StringIO()  # fleet batches: their runs arrive together, one line per batch
    progress = campaign.Progress("t", 20, stream=batches)
    progress.update([record] * 7)
    progress.update([record] * 13)
    counts = [line.split(",")[0] for line in batches.getvalue().splitlines()]
    assert counts == ["t: 7/20 runs", "t: 20/20 runs"]
    slow = io.StringIO()  # runs that take long: a line at least every LINE_INTERVAL_S
    progress = campaign.Progress("t", 1000, stream=slow)
    progress.start_line("fleet (batch 1) on in-process")
    progress.update([record])
    progress.last_line -= campaign.LINE_INTERVAL_S
    progress.update([record])
    assert slow.getvalue().splitlines()[0] == "t: 0/1000 runs, started (fleet (batch 1) on in-process)"
    assert [line.split(",")[0] for line in slow.getvalue().splitlines()[1:]] == ["t: 2/1000 runs"]


def test_a_fleet_label_names_the_batch_flown(scenario):
    assert campaign._fleet_tasks(scenario, 3, 0, 50)[2] == "fleet (batch 3)"  # not the 50 asked for
    assert campaign._fleet_tasks(scenario, 120, 0, 50)[2] == "fleet (batch 50)"


# ----- errors, Ctrl-C and the command line ---------------------------------------------------------


def test_a_failing_run_names_its_seed(monkeypatch, scenario):
    def diverge(task):
        raise FloatingPointError("diverged")

    monkeypatch.setattr(campaign, "simulate_run", diverge)
    with pytest.raises(RuntimeError, match=r"\(seed 10\).*quad-drake run 10_mag_update --seed 10"):
        run_campaign(scenario, 3, seed=10, progress=False)


def test_bad_counts_are_config_errors(scenario):
    with pytest.raises(ConfigError, match="--runs must be >= 1"):
        run_campaign(scenario, 0, progress=False)
    with pytest.raises(ConfigError, match=r"--seed: seeds must lie in .*, got -1 to 0"):
        run_campaign(scenario, 2, seed=-1, progress=False)
    with pytest.raises(ConfigError, match=r"--seed: seeds must lie in .*, got 4294967295 to 4294967296"):
        run_campaign(scenario, 2, seed=2**32 - 1, progress=False)
    with pytest.raises(ConfigError, match="--jobs must be >= 1"):
        ProcessPoolRunner(0)


@pytest.mark.slow
def test_a_process_pool_used_as_a_context_keeps_its_workers_from_one_map_to_the_next():
    # Three maps on two workers: kept workers give at most two pids over all three; workers
    # started anew for each map would give at least one new pid per map, three or more. (Which
    # of the two kept workers takes a map's tasks is up to the pool: the first map may run on
    # one of them alone while the other starts.)
    with ProcessPoolRunner(2) as runner:
        maps = [{pid for _, pid in runner.map(worker_pid, range(6))} for _ in range(3)]
    kept = set().union(*maps)
    assert 1 <= len(kept) <= 2 and os.getpid() not in kept, maps
    fresh = {pid for _, pid in ProcessPoolRunner(2).map(worker_pid, range(2))}
    assert not fresh & kept  # outside ``with`` every map starts its own workers
    with ProcessPoolRunner(2) as runner:
        abandoned = runner.map(worker_pid, range(6))
        first = {next(abandoned)[1]}
        abandoned.close()  # as on Ctrl-C or a failed task: the kept workers are let go, unwaited
        after = {pid for _, pid in runner.map(worker_pid, range(4))}
    assert after and not after & first


@pytest.mark.slow
@pytest.mark.parametrize("kept", [False, True])
def test_an_interrupted_process_pool_abandons_the_runs_its_workers_hold(kept):
    """Ctrl-C used to take 9 s on 11: the interpreter's exit waited for the workers to fly the
    runs they held. Now they are stopped: workers asleep for a minute are gone in seconds."""
    before = set(multiprocessing.active_children())
    with ProcessPoolRunner(2) as runner:
        mapped = (runner if kept else ProcessPoolRunner(2)).map(pid_after, [0.0, 60.0, 60.0, 60.0])
        next(mapped)
        workers = [p for p in multiprocessing.active_children() if p not in before]
        mapped.close()  # as on Ctrl-C or a failed task
    assert len(workers) == 2
    for worker in workers:  # its sentinel is ready once it has exited (is_alive can miss that on 3.11:
        # the executor's thread may reap it first, and then poll() never learns its exit code)
        assert multiprocessing.connection.wait([worker.sentinel], timeout=20) == [worker.sentinel]


class InterruptedRunner(Runner):
    """Gives back `k` finished records (out of order, as a pool would), then Ctrl-C."""

    name = "interrupted"

    def __init__(self, records, k):
        self.records, self.k = records, k

    def map(self, fn, tasks):
        for record in reversed(self.records[: self.k]):
            yield record.index, record
        raise KeyboardInterrupt


@pytest.mark.parametrize("k", [0, 2])
def test_ctrl_c_keeps_the_finished_runs(scenario, serial, sent, tmp_path, k):
    with pytest.raises(CampaignInterrupted) as caught:
        run_campaign(scenario, 3, runner=InterruptedRunner(sent, k), seed=5, progress=False)
    partial = caught.value.campaign
    assert isinstance(caught.value, KeyboardInterrupt)
    assert (partial.partial, partial.runs, partial.planned, partial.completed) == (True, k, 3, list(range(k)))
    tally = sum((ConsistencyTally.of(r) for r in sent[:k]), ConsistencyTally())
    finished = CampaignResult(serial.scenario, serial.records[:k], tally, 1.0, "in-process")
    assert partial.criteria == finished.criteria and partial.metrics == finished.metrics
    assert [c["realisations"] for c in partial.consistency] == ([k, k] if k else [])  # NEES, NIS mag
    for a, b in zip(partial.consistency, finished.consistency, strict=True):
        np.testing.assert_array_equal(a["mean"], b["mean"])  # arrived in reverse order, added in run order
    out = save(partial, tmp_path / "mc", plots=False)
    summary = strict_loads((out / "summary.json").read_text())
    assert (summary["partial"], summary["runs"], summary["runs_planned"]) == (True, k, 3)
    assert summary["completed"] == list(range(k))
    with open(out / "runs.csv") as f:
        assert [r["seed"] for r in csv.DictReader(f)] == [str(5 + i) for i in range(k)]
    assert table(partial).startswith(f"Monte Carlo 10_mag_update: {k} of 3 runs (interrupted) of 1.5 s")
    assert summary["verdict"].startswith(f"PARTIAL ({k} of 3 runs, interrupted): ")  # never a bare PASS


def test_ctrl_c_in_the_cli_saves_a_partial_campaign_and_exits_130(monkeypatch, tmp_path, capsys):
    real_map = InProcessRunner.map

    def interrupted_after_two(self, fn, tasks):
        for n, item in enumerate(real_map(self, fn, tasks)):
            if n == 2:
                raise KeyboardInterrupt
            yield item

    monkeypatch.setattr(InProcessRunner, "map", interrupted_after_two)
    argv = ["montecarlo", "10_mag_update", "--runs", "4", "--jobs", "1", "--set", "end_time=0.3"]
    code = cli.main([*argv, "--seed", "3", "--out", str(tmp_path), "--quiet"])
    out, err = capsys.readouterr()
    folder = tmp_path / variant_name("10_mag_update_montecarlo", 3, ["end_time=0.3"])
    assert code == 130 and out == ""
    warnings = [line for line in err.splitlines() if line.startswith("quad-drake: warning: ")]
    assert len(warnings) == 2  # its 10 s and 2 s windows cannot matter in 0.3 s (config.ineffective_settings)
    assert err.strip().splitlines()[len(warnings) :] == [
        f"quad-drake: interrupted after 2 of 4 runs; the finished ones are in "
        f"{folder}/ (runs.csv, summary.json marked partial)"
    ]
    summary = strict_loads((folder / "summary.json").read_text())
    assert (summary["partial"], summary["completed"], summary["first_seed"]) == (True, [0, 1], 3)
    with open(folder / "runs.csv") as f:
        assert [r["seed"] for r in csv.DictReader(f)] == ["3", "4"]
    assert f"{folder.name}/report.html" in (tmp_path / "index.html").read_text()


def test_montecarlo_cli_prints_table_and_explains_its_exit_code(tmp_path, capsys):
    argv = ["montecarlo", "10_mag_update", "--runs", "2", "--jobs", "1", "--seed", "3"]
    code = cli.main([*argv, "--set", "end_time=0.5", "--out", str(tmp_path), "--no-plots"])
    out, err = capsys.readouterr()
    assert "Monte Carlo 10_mag_update: 2 runs of 0.5 s, seeds 3..4" in out
    assert "runs/min" in out and "2/2 runs" in err
    folder = tmp_path / variant_name("10_mag_update_montecarlo", 3, ["end_time=0.5"])
    summary = strict_loads((folder / "summary.json").read_text())
    assert code == (0 if summary["consistency_passed"] else 1)
    last = out.strip().splitlines()[-1]
    assert last == summary["verdict"]
    assert last.startswith("PASS: every consistency" if code == 0 else "FAIL: ")
    assert not (folder / "errors.png").exists() and (folder / "report.html").is_file()


@pytest.mark.slow
def test_a_failing_campaign_names_the_consistency_test_that_failed(tmp_path, capsys):
    # The EKF believes the magnetometer 10x better than it is: its NIS is ~100x its dof. Four
    # runs: two give Student's t interval 1 degree of freedom (12.7 standard errors each way),
    # too wide to show anything; four show it (NIS mag/dof 72.7 [44.6, 101]).
    overconfident = ["--set", "end_time=1", "--set", "vehicles.0.estimator.mag_yaw_std=0.01"]
    argv = ["montecarlo", "10_mag_update", "--runs", "4", "--jobs", "1", *overconfident]
    code = cli.main([*argv, "--out", str(tmp_path), "--no-plots", "--quiet"])
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert code == 1
    outside = r"/dof [\d.]+ \[[\d.]+, [\d.]+\] outside \[0.667, 1.5\]"
    assert re.fullmatch(rf"FAIL: (NEES{outside}; )?NIS mag{outside}", last), last


def test_progress_writes_no_carriage_return_into_a_log_file(tmp_path, monkeypatch, capsys):
    """`quad-drake montecarlo ... 2> log`: stderr a file, as a redirected process has it (its
    progress goes to sys.stderr, a tqdm bar only where that is a terminal)."""
    log = tmp_path / "stderr.log"
    argv = ["montecarlo", "10_mag_update", "--runs", "2", "--jobs", "1", "--set", "end_time=0.3"]
    with open(log, "w") as stderr:
        monkeypatch.setattr(sys, "stderr", stderr)
        code = cli.main([*argv, "--out", str(tmp_path), "--no-plots"])
        monkeypatch.undo()
    text = log.read_bytes()
    assert b"\r" not in text and b"10_mag_update: 2/2 runs" in text, text
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert code == (0 if last.startswith("PASS") else 1) and last.startswith(("PASS", "FAIL"))


@pytest.mark.slow
def test_a_real_ctrl_c_keeps_the_finished_runs(tmp_path):
    """SIGINT to the CLI process while it flies (in-process runner): partial files, exit 130."""
    command = [sys.executable, "-m", "quad_drake.cli", "montecarlo", "10_mag_update", "--runs", "200"]
    command += ["--jobs", "1", "--set", "end_time=0.3", "--out", str(tmp_path), "--no-plots"]
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # not ignored if we are
    )
    started = process.stderr.readline()  # in a log, a campaign says at once that it started
    while started.startswith("quad-drake: warning: "):  # after what cannot matter in 0.3 s
        started = process.stderr.readline()
    assert started.startswith("10_mag_update: 0/200 runs, started (in-process)"), started
    first = process.stderr.readline()  # the first progress line: 20 runs finished
    assert "20/200 runs" in first, first
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 130 and "Traceback" not in err and out == ""
    assert err.strip().splitlines()[-1].startswith("quad-drake: interrupted after ")
    folder = tmp_path / variant_name("10_mag_update_montecarlo", None, ["end_time=0.3"])
    summary = strict_loads((folder / "summary.json").read_text())
    assert summary["partial"] and 20 <= summary["runs"] < 200
    assert summary["completed"] == list(range(summary["runs"]))  # one after the other in-process


def test_a_campaign_saved_over_another_leaves_none_of_its_plots(tmp_path):
    folder = tmp_path / "t_montecarlo"
    folder.mkdir()
    stale = [folder / "errors.png", folder / "consistency.png", folder / "consistency.npz"]
    for path in stale:
        path.write_bytes(b"an earlier campaign's")
    (folder / "notes.txt").write_text("the user's")
    save(hand_made_campaign(7.0), folder, plots=False)
    assert not (folder / "errors.png").exists() and not (folder / "consistency.png").exists()
    assert (folder / "consistency.npz").read_bytes() != b"an earlier campaign's"  # this campaign's own
    assert (folder / "notes.txt").read_text() == "the user's"


def test_a_fault_campaign_shades_the_fault_and_names_it_on_its_page(tmp_path):
    from quad_drake.campaigns.plots import consistency_figure
    from quad_drake.config.schema import FaultConfig

    result = hand_made_campaign(7.0)
    result.scenario.vehicles[0].faults = [FaultConfig(kind="mag_outage", start=0.2, end=0.4)]
    figure = consistency_figure(result)
    for ax in figure.time_axes:
        spans = [p for p in ax.patches if p.get_x() == 0.2 and p.get_width() == pytest.approx(0.2)]
        assert len(spans) == 1
    save(result, tmp_path, plots=True)
    page = (tmp_path / "report.html").read_text()
    assert "Injected fault (hatched red on the time plots): mag_outage in [0.2, 0.4) s." in page
    assert "mean / dof" in page and '<td class="num">[0.667, 1.5]</td>' in page
