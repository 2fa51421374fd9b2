"""The package as a user gets it: import direction, version, ``python -m``, and a wheel installed
outside the repository."""

import ast
import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

import pytest

import quad_drake
from quad_drake import catalog

REPO = Path(__file__).resolve().parent.parent
PACKAGE = Path(quad_drake.__file__).resolve().parent


def _imported_modules(path):
    """Absolute names of the modules `path` imports (relative imports resolved)."""
    module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                stem = f"{base}.{node.module}" if node.module else base
            else:
                stem = node.module
            names.add(stem)
            names.update(f"{stem}.{alias.name}" for alias in node.names)
    return names


def test_the_import_scan_sees_relative_imports_of_the_cli():
    # The scan below must be able to fail: __main__ imports the CLI with a relative import.
    assert "quad_drake.cli" in _imported_modules(PACKAGE / "__main__.py")


PURE = (
    "quad_drake.conventions",
    "quad_drake.fidelity",
    "quad_drake.rotations",
    "quad_drake.dynamics",
    "quad_drake.sensor_models",
    "quad_drake.faults",
    "quad_drake.noise_streams",
    "quad_drake.error_sampling",
    "quad_drake.control",
    "quad_drake.estimation",
    "quad_drake.config_fields",
    "quad_drake.flightlogs.reader",
    "quad_drake.flightlogs.playback",
    "quad_drake.flightlogs.comparison",
)
"""The pure modules (maths and models: numpy, no Drake); a package name covers its modules."""
KERNELS = ("quad_drake.kernels", "quad_drake.fleet.bounds")
"""The compiled kernels, below the systems."""

FORBIDDEN = (
    ("nothing imports the CLI", ("quad_drake",), ("quad_drake.cli",)),
    (
        "systems import no campaign, simulation, tuning or fleet module",
        ("quad_drake.systems",),
        ("quad_drake.campaigns", "quad_drake.simulation", "quad_drake.tuning", "quad_drake.fleet"),
    ),
    ("kernels import no pydrake and no systems", KERNELS, ("pydrake", "quad_drake.systems")),
    (
        "pure modules import no kernels, systems or pydrake",
        PURE,
        ("pydrake", "quad_drake.systems", "quad_drake.simulation", *KERNELS),
    ),
)
"""(rule, importers, imported): no module under an importer prefix imports one under an imported
prefix (issue 28). ``__main__`` is the CLI's own entry point."""


def _under(name, prefixes):
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def forbidden_edges(imports):
    """[(rule, importer, imported)] of the edges of `imports` ({module: imported names}) that
    FORBIDDEN forbids."""
    return [
        (rule, module, name)
        for rule, importers, imported in FORBIDDEN
        for module, names in sorted(imports.items())
        if _under(module, importers) and module not in ("quad_drake.cli", "quad_drake.__main__")
        for name in sorted(names)
        if _under(name, imported)
    ]


def _package_imports():
    return {
        ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts): _imported_modules(path)
        for path in sorted(PACKAGE.rglob("*.py"))
    }


def test_no_module_imports_across_a_forbidden_edge():
    assert forbidden_edges(_package_imports()) == []


@pytest.mark.parametrize("rule, importers, imported", FORBIDDEN, ids=[rule for rule, _, _ in FORBIDDEN])
def test_each_forbidden_edge_is_seen(rule, importers, imported):
    # Each rule can fail: one planted edge from a module it covers to each name it forbids.
    importer = importers[0] + (".planted" if importers[0] != "quad_drake" else ".anything")
    for name in imported:
        imports = _package_imports() | {importer: {name + ".x"}}
        assert forbidden_edges(imports) == [(rule, importer, name + ".x")]


def test_catalog_lists_the_bundled_scenarios_from_the_top_level_folder():
    scenarios = catalog.bundled_scenarios()
    # 01-11, 11_gps_update_eskf, the faults 12-18, the air 19-22 (+ 22's eskf), baro and 3-axis mag 23-25
    assert list(scenarios)[:2] == ["01_intro", "02_attitude_control"] and len(scenarios) == 27
    assert all(path.parent == REPO / "scenarios" for path in scenarios.values())
    assert not (PACKAGE / "scenarios").exists()  # one source: the wheel's copy is built from it


def test_the_wheel_lists_every_package_and_ships_the_scenarios_as_package_data():
    """pyproject lists its packages (the top-level scenarios/ is mapped into the package), so a new
    subpackage must be listed too."""
    setuptools = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    packages = {".".join(p.parent.relative_to(REPO).parts) for p in PACKAGE.rglob("__init__.py")}
    assert set(setuptools["packages"]) == packages | {"quad_drake.scenarios"}
    assert setuptools["package-dir"] == {"quad_drake.scenarios": "scenarios"}
    assert setuptools["package-data"]["quad_drake.scenarios"] == ["*.yaml"]


def _run(*args, **kwargs):
    return subprocess.run(args, capture_output=True, text=True, timeout=600, **kwargs)


def test_version_comes_from_one_place():
    for command in (["-m", "quad_drake", "--version"], ["-m", "quad_drake.cli", "--version"]):
        result = _run(sys.executable, *command)
        assert result.returncode == 0, result.stderr
        assert result.stdout.strip() == f"quad-drake {quad_drake.__version__}"


@pytest.mark.slow
def test_wheel_installed_outside_the_repo_lists_and_runs_the_bundled_scenarios(tmp_path):
    # Build from a copy of what the sdist holds: no stale build/ or egg-info of the checkout leaks in.
    source = tmp_path / "source"
    for folder in ("quad_drake", "scenarios"):
        shutil.copytree(REPO / folder, source / folder, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(REPO / name, source)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | {"MPLBACKEND": "Agg"}
    wheels = tmp_path / "wheels"
    built = _run(
        sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "-q", "-w", str(wheels), env=env
    )
    assert built.returncode == 0, built.stderr
    (wheel,) = wheels.glob("quad_drake-*.whl")

    # A fresh venv that sees this interpreter's site-packages (drake, numpy...) through a .pth
    # line, after its own: the wheel's copy of quad_drake wins, the editable install never loads.
    venv = tmp_path / "venv"
    assert _run(sys.executable, "-m", "venv", str(venv), env=env).returncode == 0
    python = venv / "bin" / "python"
    purelib = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    site = _run(str(python), "-c", purelib, env=env).stdout.strip()
    Path(site, "parent_site.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    installed = _run(str(python), "-m", "pip", "install", "--no-deps", "-q", str(wheel), env=env)
    assert installed.returncode == 0, installed.stderr

    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    quad_drake_exe = str(venv / "bin" / "quad-drake")

    where = _run(str(python), "-c", "import quad_drake; print(quad_drake.__file__)", cwd=cwd, env=env)
    assert Path(where.stdout.strip()).is_relative_to(venv), where.stdout + where.stderr

    folder = _run(
        str(python), "-c", "from quad_drake import catalog; print(catalog.SCENARIO_DIR)", cwd=cwd, env=env
    )
    assert Path(folder.stdout.strip()) == Path(where.stdout.strip()).parent / "scenarios", folder.stderr
    listed = _run(quad_drake_exe, "list", cwd=cwd, env=env)
    assert listed.returncode == 0, listed.stderr
    assert len(listed.stdout.strip().splitlines()) == 27

    out = tmp_path / "out"
    ran = _run(quad_drake_exe, "run", "01_intro", "--no-plots", "--out", str(out), cwd=cwd, env=env)
    assert ran.returncode == 0, ran.stderr
    assert "PASS: ABS(Quad.PosFollowErr)" in ran.stdout
    assert (out / "01_intro" / "logs.npz").is_file()

    # A scenario flying a packaged trajectory file (data/traj) resolves it from the wheel too.
    traj = _run(
        quad_drake_exe, "run", "05_trajectory_follow", "--set", "end_time=0.2", "--no-plots",
        "--out", str(out), cwd=cwd, env=env,
    )  # fmt: skip
    assert traj.returncode in (0, 1) and "Traceback" not in traj.stderr, traj.stderr

    # The README's own estimator, copied into a new file outside the repository, flies 11.
    from test_custom_estimator import custom_override, readme_estimator

    readme_estimator(cwd)
    own = _run(
        quad_drake_exe, "run", "11_gps_update", "--no-plots", "--out", str(out),
        "--set", custom_override("my_ekf.py:MyEkf"), cwd=cwd, env=env,
    )  # fmt: skip
    assert own.returncode == 0 and "PASS: ABS(Quad.Est.E.Pos)" in own.stdout, own.stdout + own.stderr

    # The bundled flight logs are package data: both replay from the wheel (issue 33).
    for log in ("real_auav_x21_attitude_flight", "sitl_takeoff_land_gps"):
        replayed = _run(quad_drake_exe, "replay", log, "--no-plots", "--out", str(out), cwd=cwd, env=env)
        assert replayed.returncode == 0 and "NIS mag (1 dof)" in replayed.stdout, replayed.stderr
        assert (out / f"{log}-ekf7" / "summary.json").is_file()

    for command in ([quad_drake_exe], [str(python), "-m", "quad_drake"]):
        version = _run(*command, "--version", cwd=cwd, env=env)
        assert version.stdout.strip() == f"quad-drake {quad_drake.__version__}", version.stderr


def test_make_run_installs_only_what_running_needs_and_make_test_runs_in_parallel(tmp_path):
    venv = tmp_path / "venv"  # not there: make prints every step it would take
    run = subprocess.run(["make", "-n", "run", f"VENV={venv}"], cwd=REPO, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "pip install -q -e .\n" in run.stdout and "[test]" not in run.stdout
    test = subprocess.run(["make", "-n", "test", f"VENV={venv}"], cwd=REPO, capture_output=True, text=True)
    workers = "auto" if len(os.sched_getaffinity(0)) >= 4 else "0"  # as nproc: serial below 4 cores
    assert "pip install -q -e '.[test]'" in test.stdout and f"pytest -n {workers}" in test.stdout
    forced = ["make", "-n", "test", f"VENV={venv}", "TEST_JOBS=3"]
    assert "pytest -n 3" in subprocess.run(forced, cwd=REPO, capture_output=True, text=True).stdout
    assert "pytest-xdist" in (REPO / "pyproject.toml").read_text()
