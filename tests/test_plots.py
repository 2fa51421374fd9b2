"""Plots, report.html and index.html on hand-made runs, plus one real run."""

import math
import re

import numpy as np
import pytest

from quad_drake.config.schema import (
    CriterionConfig,
    GpsParams,
    ImuParams,
    MagParams,
    ScenarioConfig,
    VehicleConfig,
)
from quad_drake.estimation.vocabulary import DIAGNOSTICS_SIZE
from quad_drake.models.rotations import quat_from_euler
from quad_drake.output import plots
from quad_drake.output.report import criterion_row, ekf_consistency, key_metrics
from quad_drake.output.results import result_from_logs

LOG_PERIOD = 0.005


def _vehicle_logs(times, rng, estimator, offset=0.0):
    """Logs of a vehicle circling at 1 m altitude; estimate = truth + noise with a known sigma."""
    n = times.size
    omega = 0.5
    p = np.column_stack([np.cos(omega * times), np.sin(omega * times) + offset, np.full(n, -1.0)])
    v = np.column_stack([-omega * np.sin(omega * times), omega * np.cos(omega * times), np.zeros(n)])
    yaw = 0.2 * np.sin(times)
    q = np.array([quat_from_euler(0.05, -0.02, y) for y in yaw])
    state = np.column_stack([p, q, v, np.zeros((n, 3))])
    reference = np.column_stack([p + 0.05, v, np.zeros((n, 3)), np.zeros(n)])
    logs = {
        "state": state,
        "reference": reference,
        "motor_forces": np.full((n, 4), 1.23),
        "contacts": np.zeros((n, 3)),  # airborne: no floor or wall contact
    }
    if not estimator:
        return logs
    sigma = np.array([0.1, 0.1, 0.3, 0.1, 0.1, 0.3, 0.05])
    truth = np.column_stack([p, v, yaw])
    logs["ekf_state"] = truth + rng.normal(size=(n, 7)) * sigma
    covariance = np.zeros((n, 49))
    covariance[:, ::8] = sigma**2
    logs["covariance"] = covariance
    logs["attitude"] = np.column_stack([np.full(n, 0.05), np.full(n, -0.02), yaw]) + 0.01
    logs["diagnostics"] = np.zeros((n, DIAGNOSTICS_SIZE))
    ekf_state = logs["ekf_state"]
    estimated = np.column_stack([ekf_state[:, 0:3], np.zeros((n, 4)), ekf_state[:, 3:6], np.zeros((n, 3))])
    euler = np.column_stack([logs["attitude"][:, 0:2], ekf_state[:, 6]])
    estimated[:, 3:7] = [quat_from_euler(*a) for a in euler]
    logs["estimated_state"] = estimated
    logs["imu"] = np.column_stack([rng.normal(0, 0.5, n), np.zeros((n, 4)), np.zeros(n)])
    stamps = np.floor(times / 0.1 + 1e-9) * 0.1
    stamps[stamps == 0] = -1.0  # the first GPS sample arrives at 0.1 s
    logs["gps"] = np.column_stack([p + rng.normal(0, 0.7, (n, 3)), v, stamps])
    logs["mag"] = np.column_stack([yaw, np.floor(times / 0.01 + 1e-9) * 0.01])
    return logs


def make_result(names=("Quad",), estimator=True, end_time=4.0, criteria=None, seed=3):
    """A SimulationResult of hand-made logs, with the criteria evaluated as a run would."""
    rng = np.random.default_rng(seed)
    times = LOG_PERIOD * np.arange(1, int(round(end_time / LOG_PERIOD)) + 1)
    sensors = {"imu": ImuParams(), "gps": GpsParams(), "mag": MagParams()} if estimator else {}
    vehicles = []
    for name in names:
        vehicle = VehicleConfig(name=name)
        for kind, params in sensors.items():
            setattr(vehicle.sensors, kind, params)
        vehicles.append(vehicle)
    if criteria is None:
        criteria = [
            CriterionConfig(kind="window", signal=f"{names[0]}.PosFollowErr", threshold=0.1, window=1.0)
        ]
        if estimator:
            criteria.append(
                CriterionConfig(
                    kind="sigma",
                    signal=f"{names[0]}.GPS.X",
                    ref_signal=f"{names[0]}.Pos.X",
                    sigma=0.7,
                    min_percent=60,
                    max_percent=76,
                    window=1.0,
                )
            )
    scenario = ScenarioConfig(
        name="synthetic",
        description="hand-made logs",
        end_time=end_time,
        seed=seed,
        vehicles=vehicles,
        criteria=criteria,
    )
    logs = {name: _vehicle_logs(times, rng, estimator, offset=i) for i, name in enumerate(names)}
    return result_from_logs(scenario, times, logs, wall_time=0.5)


def _close(a, b, tol=1e-12):
    return abs(a - b) <= tol


ONE_ESTIMATING_VEHICLE = [
    "criterion_1",
    "criterion_2",
    "estimate_errors_Quad",
    "attitude_estimate_Quad",
    "state_estimate_Quad",
    "position",
    "top_view",
    "attitude",
    "thrust",
]
"""The figures of :func:`make_result`'s run (one estimating vehicle, a window and a sigma criterion)."""


def test_figure_set_of_one_estimating_vehicle():
    result = make_result()
    assert list(plots.make_figures(result)) == ONE_ESTIMATING_VEHICLE


def test_figure_set_without_estimator_and_of_a_fleet():
    assert list(plots.make_figures(make_result(("A", "B"), estimator=False))) == [
        "criterion_1",
        "position",
        "top_view",
        "attitude",
        "thrust",
    ]
    fleet = plots.make_figures(make_result(("Q1", "Q2", "Q3"), criteria=[]))
    assert list(fleet) == ["fleet_errors", "position", "top_view", "attitude", "thrust"]


def test_window_figure_draws_threshold_and_credited_stretch():
    result = make_result(estimator=False)
    verdict = result.criteria[0]
    assert verdict.passed  # |p_ref - p| = 0.087 m < 0.1 m
    fig = plots.make_figures(result)["criterion_1"][1]
    ax = fig.axes[0]
    threshold_lines = [line for line in ax.lines if np.allclose(line.get_ydata(), 0.1)]
    assert len(threshold_lines) == 1
    span = ax.patches[0]  # axvspan: Rectangle or Polygon by version
    x = span.get_patch_transform().transform(span.get_path().vertices)[:, 0]
    assert math.isclose(x.max() - x.min(), verdict.measured, abs_tol=1e-9)
    assert "PASS" in fig._suptitle.get_text()
    assert ax.get_ylabel() == "PosFollowErr [m]"


def test_sigma_figure_band_and_cumulative_share():
    result = make_result()
    verdict = result.criteria[1]
    fig = plots.make_figures(result)["criterion_2"][1]
    top, bottom = fig.axes
    pos_x = result.signals["Quad.Pos.X"].values
    edges = [line.get_ydata() for line in top.lines if line.get_color() == "tab:green"]
    assert len(edges) == 2
    assert np.allclose(edges[0], pos_x - 0.7) and np.allclose(edges[1], pos_x + 0.7)
    samples = top.lines[1].get_xdata()  # fresh GPS samples only: 10 Hz
    assert samples.size == result.signals["Quad.GPS.X"].fresh.sum() == 40
    share = bottom.lines[0].get_ydata()
    assert math.isclose(share[-1], verdict.percent, abs_tol=1e-9)
    assert f"{verdict.percent:.0f} %" in fig._suptitle.get_text()
    assert bottom.get_ylim() == (0.0, 100.0)


def test_every_axis_is_labelled_with_a_unit():
    for result in (make_result(), make_result(("Q1", "Q2", "Q3"), criteria=[])):
        for stem, (caption, fig) in plots.make_figures(result).items():
            assert caption and (fig._suptitle or fig.axes[0].get_title()), stem
            for ax in fig.axes:
                assert re.search(r"\[.+\]$", ax.get_ylabel()), (stem, ax.get_ylabel())
            assert re.search(r"\[.+\]$", fig.axes[-1].get_xlabel()), stem


def test_fleet_sigma_criteria_are_drawn_once_in_the_fleet_figure():
    from quad_drake.config.schema import CriterionConfig

    criteria = [CriterionConfig(kind="fleet_sigma", signal="Est.E.X", sigma_signal="Est.S.X")]
    result = make_result(("Q1", "Q2", "Q3"), criteria=criteria)
    figures = plots.make_figures(result)
    assert "fleet_errors" in figures and not any(stem.startswith("criterion_") for stem in figures)
    title = figures["fleet_errors"][1].axes[0].get_title()
    share = float(re.match(r"X error: (\d+) % within", title).group(1))
    assert 60.0 < share < 76.0  # Gaussian errors: ~68 % within one sigma


def test_metrics_and_consistency_tables():
    result = make_result()
    metrics = {(v, what): (rms, peak) for v, what, _, rms, peak in key_metrics(result)}
    follow = metrics[("Quad", "position tracking error |p_ref - p|")]
    assert math.isclose(follow[0], 0.05 * math.sqrt(3), rel_tol=1e-9)
    assert math.isclose(follow[1], 0.05 * math.sqrt(3), rel_tol=1e-9)
    rows = {row[1]: row for row in ekf_consistency(result)}
    assert list(rows) == ["X", "Y", "Z", "VX", "VY", "VZ", "Yaw"]
    _, _, unit, rms, _, one, two = rows["Z"]
    assert unit == "m" and math.isclose(rms, 0.3, rel_tol=0.05)
    assert 64 < one < 72 and 93 < two < 97


def test_criterion_rows_of_window_and_sigma_criteria():
    result = make_result()
    window, sigma = (criterion_row(v) for v in result.criteria[:2])  # then the safety ones
    assert window[:3] == ["|Quad.PosFollowErr| &lt; 0.1 m for &gt; 1 s", "window", ("PASS", "PASS")]
    assert window[3] == f"longest stretch within: {result.criteria[0].measured:.4g} s"
    assert window[4] == "&gt; 1 s"
    assert sigma[0] == "|Quad.GPS.X - Quad.Pos.X| &lt;= 0.7: 60-76 % (last 1 s)" and sigma[1] == "sigma"
    assert sigma[3].startswith(f"{result.criteria[1].percent:.3g} % of 40 samples within")
    assert sigma[4] == "share in (60 %, 76 %) for the last &gt;= 1 s"


def test_run_artifacts_are_self_contained(tmp_path):
    result = make_result(end_time=25.0)
    artifacts = plots.write_run_artifacts(result, tmp_path)  # the plots' CPU: benchmarks/bench_plots.py
    assert [p.name for p in artifacts["plots"]] == [f"{stem}.png" for stem in ONE_ESTIMATING_VEHICLE]
    assert sorted(artifacts["plots"]) == sorted(tmp_path.glob("*.png"))
    assert all(p.stat().st_size > 10_000 for p in artifacts["plots"])
    report = artifacts["report"].read_text()
    assert report.count("data:image/png;base64,") == len(artifacts["plots"])
    assert not re.search(r"(src|href)=\"(https?:)?//", report)  # nothing fetched from the network
    assert 'href="replay.html"' in report
    for verdict in result.criteria:
        assert verdict.line in report
    assert "vehicles:" in report and "Quad.GPS.X" in report  # the resolved config
    assert artifacts["replay"].name == "replay.html" and artifacts["replay"].stat().st_size > 100_000


def test_diverged_run_still_gets_plots_and_report(tmp_path):
    result = make_result()
    for name in ("Quad.PosFollowErr", "Quad.Est.E.Pos"):
        result.signals[name].values[100:] = np.nan
    result.signals["Quad.Pos.X"].values[200:] = 1e9
    written = plots.write_plots(result, tmp_path)
    assert len(written) == 9
    report = plots.write_report(result, tmp_path / "report.html", written).read_text()
    assert ">nan<" in report


def test_real_run_artifacts(tmp_path):
    from quad_drake.running import catalog
    from quad_drake.running.simulation import run

    result = run(catalog.load("01_intro"))
    artifacts = plots.write_run_artifacts(result, tmp_path)
    assert [p.name for p in artifacts["plots"]] == [
        "criterion_1.png",
        "position.png",
        "top_view.png",
        "attitude.png",
        "thrust.png",
    ]
    report = artifacts["report"].read_text()
    assert result.criteria[0].line in report
    assert ('class="PASS"' in report) == result.passed


def test_fleet_sigma_criterion_row_reports_the_share_over_the_fleet():
    criteria = [
        CriterionConfig(
            kind="fleet_sigma",
            signal="Est.E.X",
            sigma_signal="Est.S.X",
            sigma_multiple=2,
            min_percent=90,
            max_percent=100,
        )
    ]
    result = make_result(("Q1", "Q2", "Q3"), criteria=criteria)
    verdict = result.criteria[0]
    row = criterion_row(verdict)
    assert row[0] == "fleet |V.Est.E.X| &lt;= 2 V.Est.S.X: 90-100 % (3 vehicles V)"
    assert row[1] == "fleet_sigma" and row[2] == (("PASS", "PASS") if verdict.passed else ("FAIL", "FAIL"))
    assert row[3] == f"{verdict.percent:.3g} % of {3 * result.times.size} samples within"
    assert row[4] == "share in [90 %, 100 %]"
    text = " ".join((row[0], row[3], row[4]))
    assert "stretch" not in text and "≤ 0" not in text
    assert 93 < verdict.percent < 97  # Gaussian errors: ~95 % within two sigma


def test_fleet_sigma_counts_only_fresh_samples():
    criteria = [CriterionConfig(kind="fleet_sigma", signal="GPS.X", sigma_signal="Est.S.X", sigma_multiple=1)]
    result = make_result(("Q1", "Q2", "Q3"), criteria=criteria)
    fresh = sum(int(result.signals[f"{v}.GPS.X"].fresh.sum()) for v in ("Q1", "Q2", "Q3"))
    assert fresh == 3 * 40 and result.criteria[0].samples == fresh


@pytest.mark.parametrize(
    "criteria, expected",
    [
        (None, ["|Quad.PosFollowErr| &lt; 0.1 m for &gt; 1 s", "longest stretch within: "]),
        (
            [CriterionConfig(kind="fleet_sigma", signal="Est.E.VX", sigma_signal="Est.S.VX", min_percent=60)],
            ["fleet |V.Est.E.VX| &lt;= 1 V.Est.S.VX: 60-100 % (3 vehicles V)", "share in [60 %, 100 %]"],
        ),
        (
            [CriterionConfig(kind="bound", signal="Quad.Est.E.Pos", threshold=2.0, start=1.0, end=3.0)],
            ["|Quad.Est.E.Pos| &lt; 2 m in [1, 3) s", "&lt; 2 m on every sample", "max "],
        ),
        (
            [CriterionConfig(kind="recovery", signal="Quad.Est.E.Pos", threshold=2.0, start=1.0, window=1.0)],
            ["|Quad.Est.E.Pos| &lt; 2 m within 1 s after 1 s", "back under within 1 s, and staying"],
        ),
    ],
)
def test_report_html_renders_each_criterion_from_its_text(tmp_path, criteria, expected):
    fleet = criteria is not None and criteria[0].kind == "fleet_sigma"
    names = ("Q1", "Q2", "Q3") if fleet else ("Quad",)
    result = make_result(names, criteria=criteria)
    report = plots.write_report(result, tmp_path / "report.html").read_text()
    for text in expected:
        assert text in report
    for verdict in result.criteria:
        assert f"<td>{verdict.kind}</td>" in report and verdict.measured_text.split(";")[0] in report
    if fleet:
        assert "stretch" not in report and "≤ 0" not in report


def test_report_html_renders_the_safety_criteria_from_their_text(tmp_path):
    # A vehicle that touched the floor twice (from 1.5 s) and hit a wall for 0.25 s (from 2 s).
    result = make_result(estimator=False)
    logs = result.logs["Quad"]
    logs["contacts"][:, 1] = np.where(result.times >= 1.5, 1.0, 0.0) + np.where(result.times >= 3.0, 1.0, 0.0)
    logs["contacts"][:, 2] = np.where(result.times >= 2.0, 250.0, 0.0)
    result = result_from_logs(result.scenario, result.times, result.logs, wall_time=0.5)
    verdicts = {v.kind: v for v in result.criteria}
    assert set(verdicts) == {"window", "floor", "room", "finite", "tracking", "attitude"}
    assert not verdicts["floor"].passed and not verdicts["room"].passed and not result.passed
    report = plots.write_report(result, tmp_path / "report.html").read_text()
    for line in (
        "FAIL: Quad touched the floor 2 times (first at 1.500 s)",
        "FAIL: Quad was stopped by a wall or the ceiling for 0.250 s (first at 2.000 s)",
        "PASS: the true state of Quad stayed finite",
    ):
        assert line in report
    for verdict in result.criteria:
        assert f"<td>{verdict.kind}</td>" in report
        for text in (verdict.description, verdict.measured_text, verdict.required_text):
            assert text and text.replace("<", "&lt;").replace(">", "&gt;") in report


def test_bound_and_recovery_criteria_get_a_figure_and_faults_are_shaded_on_every_time_plot():
    from quad_drake.config.schema import FaultConfig

    criteria = [
        CriterionConfig(kind="bound", signal="Quad.Est.E.Pos", threshold=2.0, start=1.0, end=3.0),
        CriterionConfig(kind="recovery", signal="Quad.Est.E.Pos", threshold=2.0, start=3.0, window=0.5),
    ]
    result = make_result(criteria=criteria)
    result.scenario.vehicles[0].faults = [
        FaultConfig(kind="gps_outage", start=1.0, end=3.0),
        FaultConfig(kind="gps_outlier", time=2.5, offset=[50.0, 0.0, 0.0]),
    ]
    figures = plots.make_figures(result)
    assert figures["criterion_1"][0].startswith("Criterion 1: |Quad.Est.E.Pos| < 2 m in [1, 3) s")
    assert figures["criterion_2"][0].startswith("Criterion 2: |Quad.Est.E.Pos| < 2 m within 0.5 s after 3 s")
    title = figures["criterion_2"][1]._suptitle.get_text()
    assert ("PASS" if result.criteria[1].passed else "FAIL") in title and result.criteria[
        1
    ].measured_text in title
    for stem, (_, fig) in figures.items():
        if stem == "top_view":
            continue
        first = fig.time_axes[0]
        spans = [p for p in first.patches if p.get_label() == "fault: gps_outage"]
        lines = [line for line in first.lines if line.get_label() == "fault: gps_outlier"]
        assert len(spans) == 1 and len(lines) == 1, stem
        assert spans[0].get_x() == 1.0 and spans[0].get_width() == 2.0  # the window [1, 3) s
        for ax in fig.time_axes[1:]:
            assert any(p.get_x() == 1.0 for p in ax.patches), stem
    assert plots.fault_spans(result.scenario) == [(1.0, 3.0, "gps_outage"), (2.5, 2.5, "gps_outlier")]


def test_run_and_campaign_pages_name_the_fault_window(tmp_path):
    from quad_drake.config.schema import FaultConfig
    from quad_drake.output.report import faults_html

    result = make_result()
    assert faults_html(result.scenario) == []
    result.scenario.vehicles[0].faults = [FaultConfig(kind="mag_bias", start=1.0, end=2.5, offset=[1.0])]
    report = plots.write_report(result, tmp_path / "report.html").read_text()
    assert "Injected fault (hatched red on the time plots): mag_bias in [1, 2.5) s." in report


def _first_panel_labels(fig):
    return [artist.get_label() for artist in fig.time_axes[0].patches + fig.time_axes[0].lines]


def test_windy_runs_get_the_wind_its_steady_part_and_its_turbulence_and_the_gust_window_is_marked(tmp_path):
    from quad_drake.config import GustConfig, WindConfig
    from quad_drake.models.wind import steady_wind
    from quad_drake.output.report import gust_spans
    from quad_drake.output.results import result_from_logs

    base = make_result()
    gust = GustConfig(start=1.0, duration=1.5, amplitude=6.0, direction=[0.0, 2.0, 0.0])
    base.scenario.vehicles[0].wind = WindConfig(mean=[3.0, 1.0, 0.0], gusts=[gust], turbulence="moderate")
    times = base.times
    steady = np.array([steady_wind(t, base.scenario.vehicles[0].wind) for t in times])
    turbulence = np.random.default_rng(5).normal(0.0, 1.0, (times.size, 3))
    logs = {"Quad": {**base.logs["Quad"], "wind": steady + turbulence}}
    result = result_from_logs(base.scenario, times, logs, wall_time=0.5)
    figures = plots.make_figures(result)
    fig = figures["wind_Quad"][1]
    axes = fig.axes
    for i in range(3):  # left: the wind and its steady part; right: the turbulence
        lines = {line.get_label(): line.get_ydata() for line in axes[2 * i].lines}
        assert np.array_equal(lines["wind"], steady[:, i] + turbulence[:, i])
        assert np.array_equal(lines["steady: mean + gusts"], steady[:, i])
        (turbulent,) = [
            line.get_ydata() for line in axes[2 * i + 1].lines if line.get_label() == "turbulence"
        ]
        assert np.allclose(turbulent, turbulence[:, i], atol=1e-12)
    assert steady[np.searchsorted(times, 1.75), 1] == pytest.approx(1.0 + 6.0)  # the gust's peak, east
    label = "gust 6 m/s along (0, 2, 0)"
    assert gust_spans(result.scenario) == [(1.0, 2.5, label)]
    for stem, (_, fig) in figures.items():
        if stem == "top_view":
            continue
        (span,) = [p for p in fig.time_axes[0].patches if p.get_label() == label]
        assert span.get_x() == 1.0 and span.get_width() == 1.5, stem
        assert all(any(p.get_x() == 1.0 for p in ax.patches) for ax in fig.time_axes), stem
    report = plots.write_report(result, tmp_path / "report.html").read_text()
    assert f"Events (marked on the time plots): {label} in [1, 2.5] s." in report
    assert "wind_Quad" not in plots.make_figures(make_result())  # still air: no wind figure


def test_touchdowns_are_marked_with_their_time_and_speed():
    from quad_drake.output.report import touchdown_marks
    from quad_drake.output.results import result_from_logs

    base = make_result()
    logs = {"Quad": dict(base.logs["Quad"])}
    contacts = np.zeros((base.times.size, 3))
    state = logs["Quad"]["state"].copy()
    landing, resting = (np.searchsorted(base.times, t) for t in (2.0, 3.0))
    contacts[landing:, 1] = 1  # the landing at 2 s ...
    contacts[resting:, 1] = 2  # ... and a touch at rest
    state[landing - 1, 9], state[resting - 1, 9] = 0.4, 0.001  # vz down before each, m/s
    logs["Quad"].update(contacts=contacts, state=state)
    result = result_from_logs(base.scenario, base.times, logs, wall_time=0.5)
    label = "touchdown 2.00 s, 0.40 m/s (1 more, each ≤ 0.001 m/s)"
    assert touchdown_marks(result) == [(pytest.approx(2.0), label)]
    for stem, (_, fig) in plots.make_figures(result).items():
        if stem != "top_view":
            assert label in _first_panel_labels(fig), stem
            assert all(
                any(line.get_xdata()[0] == base.times[landing] for line in ax.lines) for ax in fig.time_axes
            )


def test_the_faulted_barometer_and_field_are_drawn_beside_the_truth_and_the_estimate():
    from quad_drake.config import BaroParams, FaultConfig
    from quad_drake.models.rotations import rotation_from_quat
    from quad_drake.models.sensor_models import world_field
    from quad_drake.output.results import result_from_logs

    base = make_result()
    vehicle = base.scenario.vehicles[0]
    vehicle.sensors.baro = BaroParams()
    vehicle.sensors.mag = MagParams(three_axis=True, hard_iron=[0.08, -0.05, 0.03])
    vehicle.faults = [FaultConfig(kind="baro_step", start=1.0, end=4.0, offset=[3.0])]
    logs = {"Quad": dict(base.logs["Quad"])}
    state, times = logs["Quad"]["state"], base.times
    stamps = np.floor(times / 0.05 + 1e-9) * 0.05
    height = -state[:, 2] + 3.0 * (times >= 1.0)
    logs["Quad"]["baro"] = np.column_stack([height, stamps])
    m_N = np.array(world_field(0.5, 0.0, 1.1))
    field = np.array([rotation_from_quat(q).T @ m_N for q in state[:, 3:7]]) + [0.08, -0.05, 0.03]
    logs["Quad"]["mag"] = np.column_stack([field + 0.1 * (times >= 1.0)[:, None], stamps])
    result = result_from_logs(base.scenario, times, logs, wall_time=0.5)
    fig = plots.make_figures(result)["measurements_Quad"][1]
    fresh = result.signals["Quad.Baro.Height"].fresh
    for ax, measured, truth in zip(
        fig.axes, [height, *(field + 0.1 * (times >= 1.0)[:, None]).T], [-state[:, 2], *field.T], strict=True
    ):
        lines = {line.get_label(): line for line in ax.lines}
        assert np.array_equal(lines["measured"].get_ydata(), measured[fresh])
        assert np.allclose(lines["true"].get_ydata(), truth, atol=1e-12)
        assert "estimated" in lines
    assert np.array_equal(fig.axes[0].lines[2].get_ydata(), -result.signals["Quad.Est.Z"].values)
    assert "measurements_Quad" not in plots.make_figures(make_result())  # GPS and yaw: no such figure


def test_a_fault_over_the_judged_band_stays_red_and_green_not_brown():
    from matplotlib.colors import to_rgb

    from quad_drake.config import FaultConfig

    criteria = [CriterionConfig(kind="bound", signal="Quad.Est.E.Pos", threshold=5.0, start=1.0, end=3.0)]
    result = make_result(criteria=criteria)
    result.scenario.vehicles[0].faults = [FaultConfig(kind="gps_outage", start=1.0, end=3.0)]
    fig = plots.make_figures(result)["criterion_1"][1]
    fig.canvas.draw()
    pixels = np.asarray(fig.canvas.buffer_rgba())[..., :3] / 255.0
    ax = fig.axes[0]
    (x0, y0), (x1, y1) = ax.transData.transform([(1.3, 2.5), (2.7, 4.5)])  # inside both, above the signal
    height = pixels.shape[0]
    region = pixels[int(height - y1) : int(height - y0), int(x0) : int(x1)].reshape(-1, 3)
    white, green, red = np.ones(3), np.array(to_rgb("tab:green")), np.array(to_rgb(plots.FAULT_COLOR))
    band = 0.15 * green + 0.85 * white
    brown = 0.12 * red + 0.88 * band  # a red fill over the band: what the old shading gave everywhere
    near = np.linalg.norm(region - brown, axis=1) < 0.02  # (a hatch line's antialiased edge may pass it)
    assert near.mean() < 0.05, near.mean()
    assert np.mean(np.linalg.norm(region - band, axis=1) < 0.02) > 0.5  # the band still reads green
    assert np.mean(region[:, 0] - region[:, 1] > 0.25) > 0.03  # and the fault's hatching red


def smoothed_eskf_result(smoothed=True, seed=5):
    """A hand-made ESKF run (9 error states) whose estimate has a known σ, and with ``smoothed``
    the logs ``quad-drake run --smooth`` adds: a smoothed nominal (p, v, q_NB, biases) whose
    errors have half that σ, and that σ as ``smoothed_sigma``."""
    from quad_drake.estimation.registry import EskfEstimatorConfig

    base = make_result(seed=seed)
    rng = np.random.default_rng(seed)
    logs = dict(base.logs["Quad"])
    for name in ("ekf_state", "attitude"):
        del logs[name]
    truth = logs["state"]
    n = truth.shape[0]
    sigma = np.array([0.1, 0.1, 0.3, 0.1, 0.1, 0.3, 0.05, 0.05, 0.05])
    estimate = truth.copy()
    estimate[:, 0:3] += rng.normal(size=(n, 3)) * sigma[0:3]
    estimate[:, 7:10] += rng.normal(size=(n, 3)) * sigma[3:6]
    logs["estimated_state"] = estimate
    logs["covariance"] = np.tile(np.diag(sigma**2).ravel(), (n, 1))
    logs["imu_bias"] = np.zeros((n, 6))
    if smoothed:
        nominal = np.column_stack([truth[:, 0:3], truth[:, 7:10], truth[:, 3:7], np.zeros((n, 6))])
        nominal[:, 0:6] += rng.normal(size=(n, 6)) * sigma[0:6] / 2
        logs["smoothed_state"] = nominal
        logs["smoothed_sigma"] = np.tile(sigma / 2, (n, 1))
    vehicle = base.scenario.vehicles[0]
    vehicle.estimator = EskfEstimatorConfig(estimate_biases=False)
    return result_from_logs(base.scenario, base.times, {"Quad": logs}, wall_time=0.5)


def test_a_smoothed_run_draws_and_reports_the_smoother_beside_the_estimate(tmp_path):
    from quad_drake.output.report import smoother_consistency

    result = smoothed_eskf_result()
    figures = plots.make_figures(result)
    stems = list(figures)
    assert stems.index("smoothed_errors_Quad") == stems.index("state_estimate_Quad") + 1
    smoothed = result.logs["Quad"]["smoothed_state"]
    states = figures["state_estimate_Quad"][1].axes
    for i, ax in enumerate(states):  # x y z, then vx vy vz: the smoothed line beside the estimate
        lines = {line.get_label(): line for line in ax.lines}
        np.testing.assert_array_equal(lines["smoothed"].get_ydata(), smoothed[:, i])
    errors = figures["smoothed_errors_Quad"][1].axes
    assert [ax.get_title().split(":")[0] for ax in errors] == [
        "X", "Y", "Z", "VX", "VY", "VZ", "AttN", "AttE", "AttD"
    ]  # fmt: skip
    truth = result.logs["Quad"]["state"]
    z_lines = {line.get_label(): line for line in errors[2].lines}
    np.testing.assert_allclose(
        z_lines["smoother"].get_ydata(), smoothed[:, 2] - truth[:, 2], rtol=0, atol=1e-12
    )
    rows = {row[1]: row for row in smoother_consistency(result)}
    assert list(rows) == ["X", "Y", "Z", "VX", "VY", "VZ", "AttN", "AttE", "AttD"]
    _, _, unit, rms_filter, rms_smoother, one, two = rows["Z"]
    assert unit == "m" and math.isclose(rms_filter, 0.3, rel_tol=0.05)
    assert math.isclose(rms_smoother, 0.15, rel_tol=0.05) and 64 < one < 72 and 93 < two < 97
    artifacts = plots.write_run_artifacts(result, tmp_path)
    report = artifacts["report"].read_text()
    assert "RTS smoother against the filter" in report and "smoothed_errors_Quad.png" in [
        p.name for p in artifacts["plots"]
    ]
    plain = smoothed_eskf_result(smoothed=False)  # a run without --smooth: no smoother anywhere
    plain_figures = plots.make_figures(plain)
    assert "smoothed_errors_Quad" not in plain_figures and smoother_consistency(plain) == []
    plain_states = plain_figures["state_estimate_Quad"][1].axes
    assert "smoothed" not in {line.get_label() for ax in plain_states for line in ax.lines}
