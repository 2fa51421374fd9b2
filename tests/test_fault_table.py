"""benchmarks/fault_table.py: the table it writes into docs/measurements/faults.md (pure parts, no flight)."""

import importlib.util
from pathlib import Path

import pytest

SPEC = importlib.util.spec_from_file_location(
    "fault_table", Path(__file__).resolve().parent.parent / "benchmarks" / "fault_table.py"
)
fault_table = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(fault_table)

FIGURES = {
    "runs": 50,
    "seeds": [100, 149],
    "passes": 48,
    "floor_strikes": 2,
    "max_est_pos": 44.913,
    "max_follow": 48.68,
    "failed_seeds": [110, 131],
    "runner": "process pool (2 workers)",
}


def test_wilson_interval_matches_the_closed_form():
    low, high = fault_table.wilson(48, 50)
    p, n, z = 48 / 50, 50, 1.959963984540054
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * (p * (1 - p) / n + z * z / (4 * n * n)) ** 0.5
    assert low == pytest.approx(100 * (centre - half), abs=1e-9)
    assert high == pytest.approx(100 * (centre + half), abs=1e-9)
    assert fault_table.wilson(50, 50)[1] == pytest.approx(100.0)


def test_row_line_shows_the_figures_and_the_set_to_reproduce_it():
    row = fault_table.Row("13_gps_outlier", "EKF7, gate off", ("vehicles.0.estimator.gps_gate_sigma=0",))
    line = fault_table.row_line(row, FIGURES)
    assert line.startswith("| 13_gps_outlier | EKF7, gate off | 50 (100–149) | 48/50 = 96 % [87, 99] | 2 |")
    assert (
        "| 44.91 | 48.68 | process pool (2 workers) | `--set vehicles.0.estimator.gps_gate_sigma=0` |" in line
    )
    quoted = fault_table.Row("12_gps_outage", "EKF7", (fault_table.EKF7,))
    assert f"`--set '{fault_table.EKF7}'`" in fault_table.row_line(quoted, FIGURES)
    assert fault_table.EKF7.startswith("vehicles.0.estimator={kind: ekf7, q_pos_xy_std: 0.05,")


def test_replace_table_rewrites_only_between_the_markers():
    text = f"before\n{fault_table.BEGIN}\nold | table\n{fault_table.END}\nafter\n"
    new = fault_table.replace_table(text, "NEW")
    assert new == f"before\n{fault_table.BEGIN}\nNEW\n{fault_table.END}\nafter\n"
    with pytest.raises(ValueError):
        fault_table.replace_table("no markers", "NEW")


def test_every_row_names_a_bundled_scenario_and_each_has_an_off_row():
    """The bundled configuration first (no --set), then at least one row without its mitigation."""
    from quad_drake.running import catalog

    bundled = catalog.bundled_scenarios()
    assert all(row.scenario in bundled for row in fault_table.ROWS)
    for name in {row.scenario for row in fault_table.ROWS}:
        rows = [row for row in fault_table.ROWS if row.scenario == name]
        assert [bool(row.overrides) for row in rows][:2] == [False, True], name
        assert all(row.overrides for row in rows[1:]), name


def test_the_cache_is_keyed_by_the_runner_and_ignores_rows_another_runner_measured(tmp_path):
    import json

    row = fault_table.Row("14_gps_delay", "ESKF, no compensation", ("vehicles.0.gps_delay_compensation=0",))
    fleet = fault_table.cache_path(tmp_path, row, 50, 100, 25)
    pool = fault_table.cache_path(tmp_path, row, 50, 100, None)
    assert fleet.name == "14_gps_delay_vehicles_0_gps_delay_compensation_0_n50_s100_fleet25.json"
    assert pool.name == "14_gps_delay_vehicles_0_gps_delay_compensation_0_n50_s100.json"
    assert fault_table.cached(fleet, 25) is None  # nothing cached yet
    fleet.write_text(json.dumps(FIGURES))  # a pool row under a fleet key, as the script used to write 14
    assert fault_table.cached(fleet, 25) is None
    measured = dict(FIGURES, runner="fleet (batch 25) on process-pool x2")
    fleet.write_text(json.dumps(measured))
    assert fault_table.cached(fleet, 25) == measured
    assert fault_table.cached(fleet, 250) is None
    pool.write_text(json.dumps(measured))
    assert fault_table.cached(pool, None) is None
    pool.write_text(json.dumps(FIGURES))
    assert fault_table.cached(pool, None) == FIGURES
