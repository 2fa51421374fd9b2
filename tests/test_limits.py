"""Sanity before work on every entry point: the library checks a config changed in Python as the
command line checks a file; absurd memory is refused with the estimate; duplicate YAML keys are
refused; criteria and faults that cannot matter are flagged; long flights show progress; the
numba compile time is kept apart from the flight's wall time."""

import dataclasses
import io
import math

import pytest

from quad_drake.campaigns import run_campaign
from quad_drake.campaigns.fleet.diagram import run_fleet
from quad_drake.config.errors import ConfigError
from quad_drake.config.loader import load_scenario
from quad_drake.config.schema import CriterionConfig, FaultConfig
from quad_drake.config.validation import ineffective_settings
from quad_drake.kernels import jit
from quad_drake.running import catalog, limits
from quad_drake.running.progress import FlightProgress
from quad_drake.running.simulation import run


def broken(name, what):
    """11_gps_update (0.1 s) broken in Python, after loading, as a user of the library might."""
    scenario = catalog.load(name, None, ["end_time=0.1"])
    vehicle = scenario.vehicles[0]
    if what == "negative mass":
        vehicle.physics.mass = -0.5
    elif what == "NaN start":
        vehicle.initial_position = [0.0, math.nan, -1.0]
    elif what == "off-tick period":
        vehicle.sensors.gps.period = 0.0031
    elif what == "reversed fault window":
        vehicle.faults = [FaultConfig(kind="gps_outage", start=0.08, end=0.02)]
    elif what == "a string for a number":
        vehicle.physics.mass = "heavy"
    return scenario


WHATS = ["negative mass", "NaN start", "off-tick period", "reversed fault window", "a string for a number"]
MESSAGES = {
    "negative mass": "physics.mass: must be > 0",
    "NaN start": "initial_position: must be finite",
    "off-tick period": "gps.period: must be a whole multiple",
    "reversed fault window": "faults.0.end: must be > start",
    "a string for a number": "wrong type",
}


@pytest.mark.parametrize("what", WHATS)
@pytest.mark.parametrize("entry", ["run", "run_fleet", "run_campaign"])
def test_the_library_refuses_a_config_broken_in_python(entry, what):
    scenario = broken("11_gps_update", what)
    call = {
        "run": lambda: run(scenario),
        "run_fleet": lambda: run_fleet(scenario, [1, 2]),
        "run_campaign": lambda: run_campaign(scenario, 2, progress=False),
    }[entry]
    with pytest.raises(ConfigError, match=MESSAGES[what]) as info:
        call()
    assert "\n" not in str(info.value)


def test_absurd_memory_is_refused_with_the_estimate(quad_drake_cli):
    scenario = catalog.load("11_gps_update", None, ["end_time=1e9"])
    with pytest.raises(ConfigError, match=r"would take about [\d.]+ TiB of memory"):
        run(scenario)
    for args in (
        ["run", "01_intro", "--set", "end_time=1e9"],
        ["montecarlo", "01_intro", "--fleet", "--set", "end_time=1e308"],  # was an OverflowError
        ["montecarlo", "11_gps_update", "--fleet", "--batch", "100000", "--runs", "100000"],
    ):
        result = quad_drake_cli(*args, "--no-plots")
        assert result.returncode == 2 and result.stdout == "", result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and "of memory, more than half of this machine's" in lines[0], lines
    # the estimate is the logged values' bytes (x LOG_COPIES) per sample over the samples
    scenario = catalog.load("11_gps_update")
    expected = scenario.end_time / 0.005 * limits.logged_values(scenario) * 8 * limits.LOG_COPIES
    assert limits.run_bytes(scenario) == pytest.approx(expected)
    assert limits.cost_warnings(scenario) == []  # 25 s: nothing to say
    long = dataclasses.replace(scenario, end_time=7200.0)
    (line,) = limits.cost_warnings(long)
    assert "simulates 7200 s: about 18 min of wall time" in line


def test_duplicate_yaml_keys_are_refused(tmp_path):
    path = tmp_path / "twice.yaml"
    path.write_text("end_time: 2\nseed: 1\nend_time: 3\n")
    with pytest.raises(ConfigError, match=r"duplicate key 'end_time' \(first at line 1\) at line 3"):
        load_scenario(path)
    nested = tmp_path / "nested.yaml"
    nested.write_text("vehicles:\n  - name: A\n    physics: {mass: 1, mass: 2}\n")
    with pytest.raises(ConfigError, match="duplicate key 'mass'"):
        load_scenario(nested)
    merged = tmp_path / "merged.yaml"  # a merge key may still be overridden
    merged.write_text("_base: &base {end_time: 2, seed: 4}\n<<: *base\nend_time: 1\n")
    scenario = load_scenario(merged)
    assert (scenario.end_time, scenario.seed) == (1.0, 4)


def test_criteria_and_faults_that_cannot_matter_are_flagged(quad_drake_cli, tmp_path):
    scenario = catalog.load("12_gps_outage", None, ["end_time=5"])
    scenario.criteria.append(CriterionConfig(kind="window", signal="Quad.Est.E.Pos", threshold=1, window=6))
    scenario.vehicles[0].faults.append(FaultConfig(kind="gps_outlier", time=7.0, offset=[1.0, 0.0, 0.0]))
    lines = ineffective_settings(scenario)
    assert any(
        line.startswith("criteria.0 (bound on Quad.Est.E.Pos): [10, 12) s starts after") for line in lines
    )
    assert any("criteria.1 (recovery on Quad.Est.E.Pos): judged from 15 s" in line for line in lines)
    assert any(
        "criteria.2 (window on Quad.Est.E.Pos): its 6 s window is not shorter" in line for line in lines
    )
    assert any("faults.0 (gps_outage): starts at 10 s, after the 5 s flight" in line for line in lines)
    assert any("faults.1 (gps_outlier): starts at 7 s" in line for line in lines)
    for name in catalog.bundled_scenarios():  # every bundled scenario flies without a warning
        bundled = catalog.load(name)
        assert ineffective_settings(bundled) == [] and limits.cost_warnings(bundled) == [], name
    result = quad_drake_cli("run", "12_gps_outage", "--set", "end_time=1", "--no-plots", "--out", tmp_path)
    assert (
        "quad-drake: warning: 12_gps_outage: vehicles.0.faults.0 (gps_outage): starts at 10 s"
        in result.stderr
    )


def test_a_long_flight_shows_progress_as_plain_lines_in_a_log():
    stream = io.StringIO()
    progress = FlightProgress("11_gps_update", 100.0, stream=stream)
    for t in range(1, 101):
        progress(float(t))
    progress.close()
    lines = stream.getvalue().splitlines()
    assert len(lines) == 10 and lines[0].startswith("11_gps_update: 10 of 100 s simulated, ")
    assert "\r" not in stream.getvalue()


def test_the_flight_calls_its_progress_and_flies_the_same():
    scenario = catalog.load("01_intro", None, ["end_time=0.5"])
    seen = []
    with_progress = run(scenario, progress=seen.append)
    plain = run(scenario)
    assert 90 <= len(seen) <= 101 and seen == sorted(seen) and seen[-1] <= 0.5
    for name, log in plain.logs["Quad"].items():
        assert (with_progress.logs["Quad"][name] == log).all(), name


def test_compile_time_is_counted_apart_from_the_flight():
    notice = jit.CompileNotice()
    notice.on_start(None)  # nested compilations count once (not a terminal here: no notice)
    notice.on_start(None)
    notice.on_end(None)
    notice.on_end(None)
    assert notice.seconds > 0.0 and notice._depth == 0
    result = run(catalog.load("01_intro", None, ["end_time=0.2"]))
    assert result.compile_time >= 0.0 and result.summary()["compile_time_s"] == round(result.compile_time, 3)
