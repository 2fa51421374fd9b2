"""Shared fixtures: scenario loading, output folders, the command line in-process, and flights
that several tests look at, simulated once per session."""

import subprocess

import pytest

from quad_drake import catalog


@pytest.fixture
def load_scenario():
    """load_scenario(name_or_path, *overrides, seed=None) -> validated ScenarioConfig."""

    def load(name_or_path, *overrides, seed=None):
        return catalog.load(name_or_path, seed, overrides)

    return load


@pytest.fixture
def out_dir(tmp_path):
    """A not-yet-existing output folder (``--out``) inside the test's tmp_path."""
    return tmp_path / "out"


@pytest.fixture
def quad_drake_cli(capsys):
    """quad_drake_cli(*args) -> CompletedProcess of ``quad-drake ARGS`` run in this process
    (what the console script runs, without the seconds a new interpreter takes to import drake)."""
    from quad_drake.cli import main

    def run(*args):
        code = main([str(a) for a in args])
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(["quad-drake", *args], code, out, err)

    return run


@pytest.fixture(scope="session")
def gps_flight():
    """A 3 s closed-loop flight on the EKF estimate: 11_gps_update with end_time=3
    (SimulationResult; treat as read-only)."""
    from quad_drake.simulation import run

    return run(catalog.load("11_gps_update", None, ["end_time=3"]))


@pytest.fixture(scope="session")
def gps_run_dir(gps_flight, tmp_path_factory):
    """The run folder (logs.npz, config.yaml, summary.json) of :func:`gps_flight`."""
    from quad_drake.results import save_run

    return save_run(gps_flight, tmp_path_factory.mktemp("gps_run") / "11_gps_update")
