"""Shared fixtures: scenario loading, output folders, the command line in-process, and flights
that several tests look at, simulated once per session."""

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path
from types import SimpleNamespace

import pytest

from quad_drake.running import catalog

ROOT = Path(__file__).resolve().parents[1]
REPOSITORY_OUT = ROOT / "out"


def folder_snapshot(folder):
    """{relative path: (size, mtime_ns)} of every file under `folder` ({} when it is missing)."""
    folder = Path(folder)
    if not folder.is_dir():
        return {}
    return {
        str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def as_flight_input(values):
    """`values` as a flight hands a sensor sample or a state to a compiled kernel: a read-only
    float64 copy (a Drake input port's value). Kernels called so run with the argument types
    ``quad-drake warmup`` compiled into numba's cache; a writable array is another signature,
    compiled again in a fresh clone (about 6 s of CPU for the aiding kernels' three)."""
    import numpy as np

    values = np.array(values, dtype=float)
    values.setflags(write=False)
    return values


def assert_each_context_flies_its_own(system):
    """An estimator `system` of n = 2 vehicles (``imu``, ``gps`` and ``mag`` inputs held at fixed
    samples) keeps its filter's state in each context: two contexts fly alike without touching
    each other, and a clone made mid-flight goes on from where it was cloned while its original
    goes on unchanged (``estimated_state`` and ``covariance`` compared bit for bit)."""
    import numpy as np
    from pydrake.systems.analysis import Simulator

    def context_with_inputs():
        context = system.CreateDefaultContext()
        system.GetInputPort("imu").FixValue(context, np.tile([0.1, -0.2, -9.7, 0.05, 0.0, 0.2], 2))
        system.GetInputPort("gps").FixValue(context, np.tile([0.5, 0.0, -1.0, 0.1, 0.0, 0.0, 0.05], 2))
        system.GetInputPort("mag").FixValue(context, np.tile([0.35, 0.05], 2))
        return context

    def outputs(context):
        return [system.GetOutputPort(name).Eval(context).copy() for name in ("estimated_state", "covariance")]

    def flown(context, until):
        Simulator(system, context).AdvanceTo(until)
        return outputs(context)

    def same(found, expected):
        for a, b in zip(found, expected, strict=True):
            np.testing.assert_array_equal(a, b)

    first = context_with_inputs()
    start = outputs(first)
    at_end = flown(first, 0.1)
    assert not np.array_equal(at_end[0], start[0])
    second = context_with_inputs()
    same(outputs(second), start)
    same(flown(second, 0.1), at_end)
    halfway = context_with_inputs()
    at_half = flown(halfway, 0.05)
    clone = halfway.Clone()
    same(flown(clone, 0.1), at_end)
    same(outputs(halfway), at_half)
    same(flown(halfway, 0.1), at_end)


@pytest.fixture(autouse=True)
def _work_in_a_temporary_folder(tmp_path, monkeypatch):
    """Every test runs in its own temporary working folder, so a command that writes to its
    default ``out/`` (``quad-drake run`` without ``--out``, in this process or a subprocess, which
    inherits the folder) writes there, never into the user's ``out/`` of the checkout."""
    monkeypatch.chdir(tmp_path)


@pytest.fixture(autouse=True, scope="session")
def _repository_out_untouched():
    """Fails the session's last test when any test added, changed or removed a file under the
    checkout's ``out/`` (a user's results, e.g. of ``make run``)."""
    before = folder_snapshot(REPOSITORY_OUT)
    yield
    after = folder_snapshot(REPOSITORY_OUT)
    assert after == before, f"the tests changed {REPOSITORY_OUT}: " + ", ".join(
        sorted(set(before) ^ set(after) | {k for k in before if k in after and before[k] != after[k]})[:5]
    )


@pytest.fixture
def load_scenario():
    """load_scenario(name_or_path, *overrides, seed=None) -> validated ScenarioConfig."""

    def load(name_or_path, *overrides, seed=None):
        return catalog.load(name_or_path, seed, overrides)

    return load


@pytest.fixture
def constant_q_ekf7():
    """--set overrides that give 11's EKF7 its tuning before the tilt-aware Q (README "Estimators"):
    a constant velocity and yaw Q wide enough for the whole flight, tilt term off, a small P0."""
    return [
        "vehicles.0.estimator.tilt_gyro_std=0",
        "vehicles.0.estimator.q_vel_xy_std=0.35",
        "vehicles.0.estimator.q_vel_z_std=0.25",
        "vehicles.0.estimator.q_yaw_std=0.06",
        "vehicles.0.estimator.init_std=[0.02, 0.02, 0.05, 0.02, 0.02, 0.05, 0.01]",
    ]


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
    from quad_drake.running.simulation import run

    return run(catalog.load("11_gps_update", None, ["end_time=3"]))


@pytest.fixture(scope="session")
def gps_run_dir(gps_flight, tmp_path_factory):
    """The run folder (logs.npz, config.yaml, summary.json) of :func:`gps_flight`."""
    from quad_drake.output.results import save_run

    return save_run(gps_flight, tmp_path_factory.mktemp("gps_run") / "11_gps_update")


@pytest.fixture(scope="session")
def process_pool():
    """A ``ProcessPoolRunner(2)`` whose two workers live for the session, for the tests that
    compare a campaign on the process pool with another runner: each worker imports Drake and
    loads the kernels once, not once per campaign. Tests of the pool's own start-up, abandonment
    or worker state make their own."""
    from quad_drake.campaigns import ProcessPoolRunner

    with ProcessPoolRunner(2) as pool:
        yield pool


def run_process(*args, timeout=600, **kwargs):
    """subprocess.run(args) with its output captured as text (`timeout` s at most)."""
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout, **kwargs)


@pytest.fixture(scope="session")
def installed_wheel(tmp_path_factory):
    """The package as a user installs it: a wheel built from a copy of what the sdist holds (no
    stale build/ or egg-info of the checkout leaks in), installed into a new venv that sees this
    interpreter's site-packages (drake, numpy, ...) after its own, so the wheel's copy of
    quad_drake wins (and numba caches its kernels beside it, starting from the checkout's
    cache). A namespace: ``wheel``, ``venv``, ``python``, ``exe`` (its quad-drake) and ``env``
    (no PYTHONPATH, Agg plots)."""
    folder = tmp_path_factory.mktemp("installed_wheel")
    source = folder / "source"
    for name in ("quad_drake", "scenarios"):
        shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, source)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | {"MPLBACKEND": "Agg"}
    wheels = folder / "wheels"
    pip = [sys.executable, "-m", "pip"]
    built = run_process(*pip, "wheel", source, "--no-deps", "-q", "-w", wheels, env=env)
    assert built.returncode == 0, built.stderr
    (wheel,) = wheels.glob("quad_drake-*.whl")
    venv = folder / "venv"  # without a pip of its own: this interpreter's pip installs into it
    assert run_process(sys.executable, "-m", "venv", "--without-pip", str(venv), env=env).returncode == 0
    python = venv / "bin" / "python"
    purelib = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    site = run_process(str(python), "-c", purelib, env=env).stdout.strip()
    Path(site, "parent_site.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    installed = run_process(*pip, "--python", python, "install", "--no-deps", "-q", wheel, env=env)
    assert installed.returncode == 0, installed.stderr
    # numba's on-disk cache of the checkout's kernels (what `quad-drake warmup` compiled; `make test`
    # runs it first), copied beside the wheel's modules: numba 0.68 loads a kernel from it only
    # where the module's source has the content hash it was compiled from, so the wheel compiles
    # only what the checkout has not (compiling them again cost the wheel test about 27 s of its
    # 45 s of CPU; what a first run compiles is tests/test_jit.py's concern).
    for cached in (ROOT / "quad_drake").rglob("__pycache__/*.nb[ic]"):
        beside = Path(site, "quad_drake", cached.relative_to(ROOT / "quad_drake"))
        beside.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(cached, beside)
    exe = venv / "bin" / "quad-drake"
    return SimpleNamespace(wheel=wheel, venv=venv, python=python, exe=exe, env=env)
