"""The package as a user gets it: import direction, version, ``python -m``, and a wheel installed
outside the repository."""

import ast
import functools
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import quad_drake
from quad_drake.running import catalog

REPO = Path(__file__).resolve().parent.parent
PACKAGE = Path(quad_drake.__file__).resolve().parent


def _module_name(path, package=PACKAGE):
    """Dotted name of the module at `path` (a package's ``__init__.py`` is the package)."""
    return ".".join(path.relative_to(package.parent).with_suffix("").parts).removesuffix(".__init__")


def _imported_modules(path, package=PACKAGE):
    """Absolute names `path` imports, anywhere in the file (inside functions too; relative imports
    resolved): ``from a import b`` gives ``a`` and ``a.b`` (b may be a module or a name)."""
    module = _module_name(path, package)
    parent = module if path.name == "__init__.py" else module.rpartition(".")[0]
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = parent.rsplit(".", node.level - 1)[0] if node.level > 1 else parent
                stem = f"{base}.{node.module}" if node.module else base
            else:
                stem = node.module
            names.add(stem)
            names.update(f"{stem}.{alias.name}" for alias in node.names)
    return names


@functools.cache
def _scanned_imports(package):
    """{module: frozenset of the names it imports} of the package at `package`, parsed once per
    process (0.4 s a scan; the package does not change during a session, and each test of the
    FORBIDDEN rules scans it once per forbidden name)."""
    return {
        _module_name(path, package): frozenset(_imported_modules(path, package))
        for path in sorted(package.rglob("*.py"))
    }


def package_imports(package=PACKAGE):
    """{module: the names it imports} of every module of the package at `package` (new sets, for
    the caller to change)."""
    return {module: set(names) for module, names in _scanned_imports(Path(package)).items()}


def test_the_import_scan_sees_relative_imports_and_imports_inside_functions():
    # The scan must be able to fail: __main__ imports the CLI relatively, and the CLI imports the
    # campaigns inside a function (a lazy import is an edge all the same).
    imports = package_imports()
    assert "quad_drake.cli" in imports["quad_drake.__main__"]
    assert "quad_drake.campaigns" in imports["quad_drake.cli"]


def file_edges(imports):
    """{module: the package modules it imports}: each imported name resolved to the deepest module
    of the package it names (``from quad_drake.config.errors import ConfigError`` is an arrow to
    ``quad_drake.config.errors``); names outside the package are left out."""
    modules = set(imports)

    def deepest(name):
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name

    return {m: {d for name in names if (d := deepest(name)) and d != m} for m, names in imports.items()}


def _packages_of(module):
    """The packages Python runs before `module` (``a.b.c``: ``a``, ``a.b``)."""
    parts = module.split(".")
    return {".".join(parts[:i]) for i in range(1, len(parts))}


def closure(module, imports, edges=None):
    """Every name importing `module` reaches, transitively: the package modules (with the
    packages Python runs before each) and the outside names (``pydrake.systems.framework``) they
    import. edges: ``file_edges(imports)`` where the caller has them already."""
    edges = file_edges(imports) if edges is None else edges
    seen, todo = set(), [module]
    while todo:
        current = todo.pop()
        for reached in edges.get(current, set()) | _packages_of(current):
            if reached not in seen:
                seen.add(reached)
                todo.append(reached)
    outside = {
        name for m in seen | {module} for name in imports.get(m, ()) if name.partition(".")[0] != "quad_drake"
    }
    return seen | outside


PURE = (
    "quad_drake.conventions",
    "quad_drake.config.errors",
    "quad_drake.config.fields",
    "quad_drake.config.schema",
    "quad_drake.config.validation",
    "quad_drake.models",
    "quad_drake.control",
    "quad_drake.estimation",
    "quad_drake.flightlogs.reader",
    "quad_drake.flightlogs.mag_calibration",
    "quad_drake.flightlogs.schedule",
    "quad_drake.flightlogs.px4_parameters",
    "quad_drake.grading.course",
    "quad_drake.grading.course_math",
    "quad_drake.grading.criteria",
    "quad_drake.grading.statistics",
)
"""The pure modules (maths, models and configuration: numpy, no Drake); a package name covers its
modules."""
KERNELS = ("quad_drake.kernels",)
"""The compiled kernels, below the systems."""
CAMPAIGN_ORCHESTRATION = tuple(
    f"quad_drake.campaigns.{m}" for m in ("campaign", "runners", "statistics", "output", "plots", "page")
)
"""What runs, sums up and writes out a campaign (the fleet is one way it flies its runs)."""

FORBIDDEN = (
    ("nothing imports the CLI", ("quad_drake",), ("quad_drake.cli",)),
    (
        "systems import no campaign, simulation or tuning module",
        ("quad_drake.systems",),
        ("quad_drake.campaigns", "quad_drake.running", "quad_drake.tuning"),
    ),
    ("kernels import no pydrake and no systems", KERNELS, ("pydrake", "quad_drake.systems")),
    (
        "pure modules import no kernels, systems or pydrake",
        PURE,
        ("pydrake", "quad_drake.systems", "quad_drake.running", *KERNELS),
    ),
    (
        "judging imports no pydrake and no systems",
        ("quad_drake.judging", "quad_drake.flightlogs.comparison"),
        ("pydrake", "quad_drake.systems", "quad_drake.running"),
    ),
    (
        "the configuration's only pydrake is the loader's",
        ("quad_drake.config",),
        ("pydrake.systems", "pydrake.multibody", "pydrake.geometry", "quad_drake.systems"),
    ),
    (
        "campaigns fly on the fleet, the fleet never reaches back",
        ("quad_drake.campaigns.fleet",),
        CAMPAIGN_ORCHESTRATION,
    ),
)
"""(rule, importers, imported): no module under an importer prefix reaches a name under an imported
prefix through its import closure (issues 28, 37: transitive, imports inside functions and the
packages Python runs on the way included). ``__main__`` is the CLI's own entry point."""


def _under(name, prefixes):
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def forbidden_reaches(imports):
    """[(rule, importer, reached)] of the names the FORBIDDEN rules forbid that a module of
    `imports` ({module: imported names}) reaches."""
    found, edges, closures = [], file_edges(imports), {}
    for rule, importers, imported in FORBIDDEN:
        for module in sorted(imports):
            if _under(module, importers) and module not in ("quad_drake.cli", "quad_drake.__main__"):
                if module not in closures:
                    closures[module] = closure(module, imports, edges)
                reached = closures[module]
                found += [(rule, module, name) for name in sorted(reached) if _under(name, imported)]
    return found


def test_no_module_reaches_across_a_forbidden_edge():
    assert forbidden_reaches(package_imports()) == []


def test_no_pure_module_loads_pydrake_when_imported():
    # The closure is what Python loads: check it against the interpreter on the modules issue 37
    # named (each in a fresh process; the lazy config package must not load its loader).
    names = (
        "quad_drake.config.errors",
        "quad_drake.config",
        "quad_drake.kernels.ekf7",
        "quad_drake.flightlogs.reader",
    )
    code = "import importlib, sys; importlib.import_module(sys.argv[1]); print('pydrake' in sys.modules)"
    for name in names:
        assert _run(sys.executable, "-c", code, name).stdout.strip() == "False", name


@pytest.mark.parametrize("rule, importers, imported", FORBIDDEN, ids=[r[0] for r in FORBIDDEN])
def test_each_forbidden_reach_is_seen_two_arrows_away(rule, importers, imported):
    # Each rule can fail, transitively: a planted module it covers imports an innocent planted
    # module, which imports the forbidden name.
    importer = importers[0] + ".planted"
    middle = "quad_drake.planted_middle"
    for name in imported:
        planted = name if name.startswith("quad_drake.") else name + ".x"  # a module of ours, or outside
        imports = package_imports() | {importer: {middle}, middle: {planted}}
        found = forbidden_reaches(imports)
        assert (rule, importer, planted) in found
        assert {m for _, m, _ in found} <= {importer, middle}  # the package itself stays clean


def file_circles(imports):
    """The circles among the package's modules (strongly connected components of more than one
    module of :func:`file_edges`, imports inside functions counted; the packages Python runs on
    the way are not arrows), each sorted."""
    edges = file_edges(imports)
    order, low, stack, on_stack, circles = {}, {}, [], set(), []

    def visit(v):  # Tarjan's algorithm
        order[v] = low[v] = len(order)
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in order:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], order[w])
        if low[v] == order[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in sorted(edges):
        if v not in order:
            visit(v)
    return sorted(circles)


def test_no_file_circle():
    assert file_circles(package_imports()) == []


def test_a_planted_circle_is_seen():
    # conventions is imported (through a chain) by the CLI: one arrow back closes a circle.
    imports = package_imports()
    imports["quad_drake.conventions"] = imports["quad_drake.conventions"] | {"quad_drake.cli"}
    (circle,) = file_circles(imports)
    assert {"quad_drake.conventions", "quad_drake.cli"} <= set(circle)


FLOORS = (
    ("shared constants", ("quad_drake.conventions",)),
    (
        "pure: configuration, models, estimators, control, recorded-log reading",
        ("quad_drake.config", "quad_drake.models", "quad_drake.estimation", "quad_drake.control")
        + ("quad_drake.flightlogs.reader", "quad_drake.flightlogs.schedule")
        + ("quad_drake.flightlogs.settings", "quad_drake.flightlogs.mag_calibration")
        + ("quad_drake.flightlogs.px4_parameters",)
        + ("quad_drake.grading.course", "quad_drake.grading.course_math", "quad_drake.grading.criteria")
        + ("quad_drake.grading.student_template",),
    ),
    ("compiled kernels", ("quad_drake.kernels",)),
    (
        "judging a flight from its logs",
        ("quad_drake.judging", "quad_drake.flightlogs.comparison", "quad_drake.grading.statistics"),
    ),
    ("Drake systems", ("quad_drake.systems",)),
    ("output", ("quad_drake.output",)),
    ("running a scenario", ("quad_drake.running",)),
    (
        "campaigns, tuning, flight-log replay",
        ("quad_drake.campaigns", "quad_drake.tuning", "quad_drake.flightlogs", "quad_drake.grading"),
    ),
    ("command line", ("quad_drake.cli", "quad_drake.__main__")),
)
"""The floors of the house, bottom up: a module imports its own floor or lower ones (the longest
prefix names a module's floor; the package ``quad_drake`` itself is no floor)."""


def floor_of(module):
    best = max(
        ((len(p), i) for i, (_, prefixes) in enumerate(FLOORS) for p in prefixes if _under(module, (p,))),
        default=None,
    )
    return None if best is None else best[1]


def arrows_up(imports):
    """[(importer, imported)] of the file arrows that run from a floor to a higher one."""
    return sorted(
        (m, d)
        for m, targets in file_edges(imports).items()
        for d in targets
        if floor_of(m) is not None and floor_of(d) is not None and floor_of(d) > floor_of(m)
    )


def test_every_module_has_a_floor_and_no_arrow_runs_up():
    imports = package_imports()
    assert [m for m in imports if m != "quad_drake" and floor_of(m) is None] == []
    assert arrows_up(imports) == []


def test_an_arrow_up_is_seen():
    imports = package_imports()
    imports["quad_drake.models.dynamics"] = imports["quad_drake.models.dynamics"] | {
        "quad_drake.running.simulation"
    }
    assert arrows_up(imports) == [("quad_drake.models.dynamics", "quad_drake.running.simulation")]


def test_catalog_lists_the_bundled_scenarios_from_the_top_level_folder():
    scenarios = catalog.bundled_scenarios()
    # 01-11, 11_gps_update_eskf, the faults 12-18, the air 19-22 (+ 22's eskf), baro and 3-axis mag 23-25,
    # the EKF-GSF 26-28, the no-aiding failsafe 29
    assert list(scenarios)[:2] == ["01_intro", "02_attitude_control"] and len(scenarios) == 31
    assert all(path.parent == REPO / "scenarios" for path in scenarios.values())
    assert not (PACKAGE / "scenarios").exists()  # one source: the wheel's copy is built from it


def test_the_wheel_lists_every_package_and_ships_the_scenarios_as_package_data():
    """pyproject lists its packages (the top-level scenarios/ is mapped into the package; each
    folder of data files under quad_drake/data/ is a package of data alone), so a new subpackage
    or data folder must be listed too."""
    setuptools = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    packages = {".".join(p.parent.relative_to(REPO).parts) for p in PACKAGE.rglob("__init__.py")}
    data = {".".join(p.relative_to(REPO).parts) for p in (PACKAGE / "data").iterdir() if p.is_dir()}
    assert set(setuptools["packages"]) == packages | data | {"quad_drake.scenarios"}
    assert set(setuptools["package-data"]) == data | {"quad_drake.scenarios"}  # every data folder ships
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
def test_wheel_installed_outside_the_repo_lists_and_runs_the_bundled_scenarios(installed_wheel, tmp_path):
    # The session's wheel, installed into a venv of its own (conftest).
    python, env, venv = str(installed_wheel.python), installed_wheel.env, installed_wheel.venv
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    quad_drake_exe = str(installed_wheel.exe)

    where = _run(str(python), "-c", "import quad_drake; print(quad_drake.__file__)", cwd=cwd, env=env)
    assert Path(where.stdout.strip()).is_relative_to(venv), where.stdout + where.stderr

    folder = _run(
        str(python),
        "-c",
        "from quad_drake.running import catalog; print(catalog.SCENARIO_DIR)",
        cwd=cwd,
        env=env,
    )
    assert Path(folder.stdout.strip()) == Path(where.stdout.strip()).parent / "scenarios", folder.stderr
    listed = _run(quad_drake_exe, "list", cwd=cwd, env=env)
    assert listed.returncode == 0, listed.stderr
    assert len(listed.stdout.strip().splitlines()) == 31

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

    # The manual's own estimator, copied into a new file outside the repository, flies 11: 6 s of
    # it, the window 4 s, as the manual's campaign of it (the whole 25 s passes in-process,
    # tests/test_custom_estimator.py::test_the_manual_example_flies_11; here 2.4 s of CPU against 5.5).
    from test_custom_estimator import custom_override, manual_estimator

    manual_estimator(cwd)
    own = _run(
        quad_drake_exe, "run", "11_gps_update", "--no-plots", "--out", str(out), "--set", "end_time=6",
        "--set", "criteria.0.window=4", "--set", custom_override("my_ekf.py:MyEkf"), cwd=cwd, env=env,
    )  # fmt: skip
    assert own.returncode == 0 and "PASS: ABS(Quad.Est.E.Pos)" in own.stdout, own.stdout + own.stderr

    # The bundled flight logs are package data: both are found by name and read from the wheel,
    # and `replay` flies one of them there (both logs' replays are checked in-process in
    # tests/test_flight_log_replay.py; the second replay from the wheel cost 22 s CPU).
    logs = ("real_auav_x21_attitude_flight", "sitl_takeoff_land_gps")
    read = (
        "import sys; from quad_drake.flightlogs.settings import resolve_log; "
        "from quad_drake.flightlogs.reader import read_flight_log\n"
        "for name in sys.argv[1:]:\n"
        "    path = resolve_log(name); log = read_flight_log(path)\n"
        "    print(path, log.duration, ' '.join(log.sensors()))"
    )
    found = _run(str(python), "-c", read, *logs, cwd=cwd, env=env)
    assert found.returncode == 0, found.stderr
    for line in found.stdout.strip().splitlines():
        path, duration, *sensors = line.split()
        assert Path(path).is_relative_to(venv) and float(duration) > 30 and "mag" in sensors, line
    replayed = _run(quad_drake_exe, "replay", logs[1], "--no-plots", "--out", str(out), cwd=cwd, env=env)
    assert replayed.returncode == 0 and "NIS mag (1 dof)" in replayed.stdout, replayed.stderr
    assert (out / f"{logs[1]}-ekf7" / "summary.json").is_file()

    for command in ([quad_drake_exe], [str(python), "-m", "quad_drake"]):
        version = _run(*command, "--version", cwd=cwd, env=env)
        assert version.stdout.strip() == f"quad-drake {quad_drake.__version__}", version.stderr


def test_make_run_installs_only_what_running_needs_and_make_test_runs_in_parallel(tmp_path):
    venv = tmp_path / "venv"  # not there: make prints every step it would take
    run = subprocess.run(["make", "-n", "run", f"VENV={venv}"], cwd=REPO, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "pip install -q -e .\n" in run.stdout and "[test]" not in run.stdout
    test = subprocess.run(["make", "-n", "test", f"VENV={venv}"], cwd=REPO, capture_output=True, text=True)
    cores = len(os.sched_getaffinity(0))  # as nproc: a worker per core from 4, two on 2 or 3, serial on 1
    workers = "auto" if cores >= 4 else "2" if cores >= 2 else "0"
    assert "pip install -q -e '.[test]'" in test.stdout and f"pytest -n {workers}" in test.stdout
    assert ("quad-drake warmup" in test.stdout) == (workers != "0")  # kernels compiled once, not per worker
    assert f"PYTHONDONTWRITEBYTECODE= {venv}/bin/python -m pytest" in test.stdout  # asserts rewritten once
    forced = ["make", "-n", "test", f"VENV={venv}", "TEST_JOBS=3"]
    forced = subprocess.run(forced, cwd=REPO, capture_output=True, text=True).stdout
    assert "quad-drake warmup >/dev/null && " in forced and "pytest -n 3" in forced
    serial = ["make", "-n", "test", f"VENV={venv}", "TEST_JOBS=0"]
    serial = subprocess.run(serial, cwd=REPO, capture_output=True, text=True).stdout
    assert "pytest -n 0" in serial and "warmup" not in serial
    assert "pytest-xdist" in (REPO / "pyproject.toml").read_text()
