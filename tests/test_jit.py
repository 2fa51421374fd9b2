"""jit: numba's cache where it can be written, a private temporary directory where numba has
none, no cache (one warning) where nothing can be written; the first compile announced on a
terminal."""

import io
import json
import os
import shutil
import stat
import subprocess
import sys
import warnings
from pathlib import Path

import numba
import pytest

import quad_drake
from quad_drake.kernels import jit


def _sourceless_function(module="quad_drake.test_kernels"):
    """A function of `module` that numba cannot cache anywhere: its code has no source file."""
    namespace = {"__name__": module}
    exec("def twice(x):\n    return 2.0 * x\n", namespace)
    return namespace["twice"]


@pytest.fixture
def temporary_directory(monkeypatch, tmp_path):
    """tempfile.gettempdir() is tmp_path / "tmp" for the test."""
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setenv("TMPDIR", str(folder))
    monkeypatch.setattr("tempfile.tempdir", None)  # gettempdir reads TMPDIR again
    return folder


@pytest.fixture
def blocked_function(monkeypatch, tmp_path, temporary_directory):
    """A function in a module file for which numba can write none of its own caches (a file
    stands in place of its __pycache__, HOME is a file) and NUMBA_CACHE_DIR is unset; the
    warning of njit_cached not yet given."""
    module = tmp_path / "module"
    module.mkdir()
    (module / "kernel.py").write_text("def triple(x):\n    return 3.0 * x\n")
    (module / "__pycache__").write_text("")
    home = tmp_path / "home"
    home.write_text("")
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    monkeypatch.setattr(jit, "_warned", False)
    namespace = {"__name__": "kernel"}
    path = module / "kernel.py"
    exec(compile(path.read_text(), str(path), "exec"), namespace)
    return namespace["triple"]


def test_numba_itself_cannot_cache_the_blocked_function(blocked_function):
    with pytest.raises(RuntimeError, match="cannot cache"):
        numba.njit(cache=True)(blocked_function)


def test_where_numba_has_no_cache_the_kernel_caches_in_the_temporary_directory(
    blocked_function, temporary_directory
):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning: it is cached
        triple = jit.njit_cached(blocked_function)
    assert triple(2.0) == 6.0
    assert numba.config.CACHE_DIR == jit.fallback_cache_dir()
    assert list(Path(jit.fallback_cache_dir()).glob("**/kernel.triple-*.nbi"))


def test_a_kernel_with_no_cache_anywhere_compiles_uncached_and_warns_once(blocked_function):
    with pytest.warns(RuntimeWarning, match="NUMBA_CACHE_DIR"):
        twice = jit.njit_cached(_sourceless_function())
    assert numba.config.CACHE_DIR == jit.fallback_cache_dir()  # the temporary directory was tried
    assert twice(1.5) == 3.0
    assert twice.__class__.__name__ == "CPUDispatcher"  # compiled, not the Python function
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a second kernel does not warn again
        assert jit.njit_cached(_sourceless_function())(2.0) == 4.0


def test_an_unusable_numba_cache_dir_of_the_user_is_named_in_the_warning(
    monkeypatch, tmp_path, blocked_function
):
    not_a_folder = tmp_path / "file"
    not_a_folder.write_text("")
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(not_a_folder))
    with pytest.warns(RuntimeWarning, match=f"NUMBA_CACHE_DIR={not_a_folder} is not usable"):
        assert jit.njit_cached(blocked_function)(1.0) == 3.0
    assert numba.config.CACHE_DIR == str(not_a_folder)  # the user's choice is kept


def test_the_fallback_directory_is_per_user_under_tmpdir(temporary_directory):
    path = Path(jit.fallback_cache_dir())
    assert path.parent == temporary_directory
    assert path.name == f"quad_drake-numba-{os.getuid()}"


def test_a_fallback_directory_others_can_write_is_not_used(blocked_function):
    """numba's cache files are pickles: a directory another user could have planted them in
    (group- or world-writable, a link, someone else's) is never given to numba."""
    planted = Path(jit.fallback_cache_dir())
    planted.mkdir(mode=0o777)
    planted.chmod(0o777)
    with pytest.warns(RuntimeWarning, match="a directory of this user's that no one else can write"):
        triple = jit.njit_cached(blocked_function)
    assert numba.config.CACHE_DIR == ""
    assert triple(1.0) == 3.0
    assert not any(planted.iterdir())


def test_a_private_directory_is_made_0o700_and_a_link_or_shared_one_is_refused(tmp_path):
    made = tmp_path / "made"
    assert jit.private_directory(made)
    assert stat.S_IMODE(made.stat().st_mode) == 0o700
    assert jit.private_directory(made)  # an existing private one
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o770)
    assert not jit.private_directory(shared)
    link = tmp_path / "link"
    link.symlink_to(made)
    assert not jit.private_directory(link)
    a_file = tmp_path / "file"
    a_file.write_text("")
    assert not jit.private_directory(a_file)


def test_a_read_only_install_with_a_read_only_home_caches_its_kernels_in_the_temporary_directory(tmp_path):
    """A copy of the package whose __pycache__ cannot be created (a file stands in its place)
    and a HOME under which no cache directory can be made: without the fallback, importing a
    module with a cached kernel raises numba's "cannot cache function" RuntimeError."""
    package = tmp_path / "site" / "quad_drake"
    shutil.copytree(Path(quad_drake.__file__).parent, package, ignore=shutil.ignore_patterns("__pycache__"))
    for folder in [package, *(p for p in package.rglob("*") if p.is_dir())]:
        (folder / "__pycache__").write_text("")
    home = tmp_path / "home"
    home.write_text("")  # a file: ~/.cache cannot be created under it
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    env = {
        key: value for key, value in os.environ.items() if key not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")
    }
    env.update(
        HOME=str(home), TMPDIR=str(temporary), PYTHONPATH=str(package.parent), PYTHONDONTWRITEBYTECODE="1"
    )
    code = (
        "import quad_drake.kernels.rotations as k; "
        f"assert k.__file__.startswith({str(package)!r}); print(k.wrap_to_pi(7.0))"
    )
    result = subprocess.run(
        [sys.executable, "-W", "error::RuntimeWarning", "-c", code],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    assert abs(float(result.stdout) - (7.0 - 2 * 3.141592653589793)) < 1e-12
    cached = list(temporary.glob("quad_drake-numba-*/**/*.nbi"))
    assert any("wrap_to_pi" in p.name for p in cached), cached


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_the_first_compile_of_a_process_is_announced_once_on_a_terminal(monkeypatch):
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    monkeypatch.setattr(jit.compile_notice, "shown", False)
    numba.njit(_sourceless_function())(1.0)  # compiled: nothing cached for it
    numba.njit(_sourceless_function())(1.0)
    assert terminal.getvalue() == jit.COMPILE_NOTICE + "\n"


def test_another_library_s_compile_is_not_announced(monkeypatch):
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    monkeypatch.setattr(jit.compile_notice, "shown", False)
    numba.njit(_sourceless_function("users_notebook"))(1.0)
    assert terminal.getvalue() == ""
    numba.njit(_sourceless_function())(1.0)
    assert terminal.getvalue() == jit.COMPILE_NOTICE + "\n"


def test_a_compile_is_not_announced_on_a_log(monkeypatch):
    log = io.StringIO()
    monkeypatch.setattr(sys, "stderr", log)
    monkeypatch.setattr(jit.compile_notice, "shown", False)
    numba.njit(_sourceless_function())(1.0)
    assert log.getvalue() == ""


KERNEL_SIGNATURES = """
import gc, json, sys
from pathlib import Path
from numba.core.dispatcher import Dispatcher

def kernel_signatures():
    \"\"\"{module.qualname: [argument types]} of every quad_drake kernel this process called (compiled
    or loaded from the cache): numba caches per function and argument types.\"\"\"
    calls = {}
    for d in gc.get_objects():
        if isinstance(d, Dispatcher) and d.py_func.__module__.startswith("quad_drake"):
            name = f"{d.py_func.__module__}.{d.py_func.__qualname__}"
            calls.setdefault(name, set()).update(str(signature) for signature in d.signatures)
    return {name: sorted(types) for name, types in calls.items() if types}
"""

WARMUP = (
    KERNEL_SIGNATURES
    + """
from quad_drake.campaigns.warmup import warm_up_command
assert warm_up_command(force=True) == 0  # flies even where an earlier warm-up left its stamp
from quad_drake.campaigns.warmup import STAMP_NAME, stamp_is_current
from quad_drake.kernels import jit
stamp = json.loads((Path(jit.cache_stamp_dir()) / STAMP_NAME).read_text())
print("stamp", stamp_is_current(Path(jit.cache_stamp_dir()) / STAMP_NAME), len(stamp["sources"]))
print(json.dumps(kernel_signatures()))
"""
)

AFTER_WARMUP = (
    KERNEL_SIGNATURES
    + """
from quad_drake.running import catalog
from quad_drake.kernels import jit
from quad_drake.campaigns import run_campaign
from quad_drake.running.simulation import run

run(catalog.load("11_gps_update", 7, ["end_time=1"]))  # longer than the warm-up, another seed
run(catalog.load("25_baro_step", 3, ["end_time=0.5", "vehicles.0.estimator={kind: eskf}"]))  # the ESKF
run_campaign(catalog.load("19_windy_hover", 5, ["end_time=0.5"]), 3, progress=False, fleet_batch=3)  # a fleet
run_campaign(catalog.load("24_mag3_disturbance", 1, ["end_time=0.5"]), 2, progress=False)
print(f"compiled {jit.compile_seconds():.3f} s")
print(json.dumps(kernel_signatures()))
"""
)


@pytest.mark.slow
def test_after_quad_drake_warmup_no_flight_compiles(tmp_path):
    """`quad-drake warmup` calls every kernel a flight uses with the argument types the flight
    passes, so that on an empty cache it compiles them all: a later process flies other scenario
    lengths, seeds, estimators, fleet sizes and campaigns calling no kernel with types the
    warm-up did not call, and compiles nothing (every kernel it calls loads from the cache).

    Both processes use the package's own cache (a kernel missing there is compiled by the warm-up,
    once for the whole test session): that the warm-up called a kernel with the types proves it
    compiles it on an empty cache (numba compiles on the first call per types, and caches what it
    compiles: test_a_read_only_install... above), without compiling every kernel again here."""
    env = {**os.environ, "PYTHONPATH": str(Path(quad_drake.__file__).parent.parent)}  # the tree under test
    processes = []
    for script in (WARMUP, AFTER_WARMUP):
        done = subprocess.run(
            [sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=900, cwd=tmp_path
        )
        assert done.returncode == 0, done.stderr
        processes.append(done.stdout.strip().splitlines())
    warm, later = processes
    assert "every kernel a flight uses is in the cache" in "\n".join(warm)
    stamp_line = warm[-2].split()  # the warm-up's stamp: current, naming the kernels' source files
    assert stamp_line[:2] == ["stamp", "True"] and int(stamp_line[2]) > 10, warm[-2]
    assert later[-2] == "compiled 0.000 s", later
    warmed, flown = json.loads(warm[-1]), json.loads(later[-1])
    assert len(flown) > 20, flown  # every flight calls kernels: the census sees them
    missing = {name: sorted(set(types) - set(warmed.get(name, ()))) for name, types in flown.items()}
    assert not {name: types for name, types in missing.items() if types}, missing


def test_a_current_warm_up_stamp_flies_nothing_and_a_changed_kernel_source_flies_again(
    tmp_path, monkeypatch, capsys
):
    from quad_drake.campaigns import warmup

    kernel = tmp_path / "kernel.py"
    kernel.write_text("def f(x):\n    return x\n")
    monkeypatch.setattr(jit, "cache_stamp_dir", lambda: str(tmp_path))
    stamp = tmp_path / warmup.STAMP_NAME
    stamp.write_text(json.dumps(warmup.cache_stamp([str(kernel)])))
    assert warmup.stamp_is_current(stamp)

    def no_flight(*args, **kwargs):
        raise AssertionError("a current stamp flies nothing")

    monkeypatch.setattr(warmup.catalog, "load", no_flight)
    assert warmup.warm_up_command() == 0
    assert "nothing to fly" in capsys.readouterr().out
    with pytest.raises(AssertionError, match="flies nothing"):  # --force flies
        warmup.warm_up_command(force=True)

    for other in ({"numba": "0.1"}, {"python": "2.7"}, {"package": "/elsewhere"}, {"sources": {}}):
        stamp.write_text(json.dumps({**warmup.cache_stamp([str(kernel)]), **other}))
        assert not warmup.stamp_is_current(stamp)
    stamp.write_text(json.dumps(warmup.cache_stamp([str(kernel)])))
    kernel.write_text("def f(x):\n    return 2 * x\n")  # numba compiles it again: the warm-up flies again
    assert not warmup.stamp_is_current(stamp)
    kernel.unlink()
    assert not warmup.stamp_is_current(stamp)
    for saved in ({"numba": numba.__version__}, "not a stamp", [1]):
        stamp.write_text(json.dumps(saved))
        assert not warmup.stamp_is_current(stamp)
    stamp.write_text("{")
    assert not warmup.stamp_is_current(stamp)
