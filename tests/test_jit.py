"""jit.njit_cached: numba's cache where it can be written, the temporary directory where numba
has none, no cache (one warning) where nothing can be written."""

import io
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
from quad_drake import jit


def _sourceless_function():
    """A function numba cannot cache anywhere: its code has no source file."""
    namespace = {}
    exec("def twice(x):\n    return 2.0 * x\n", namespace)
    return namespace["twice"]


@pytest.fixture
def temporary_directory(monkeypatch, tmp_path):
    """tempfile.gettempdir() is tmp_path for the test."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr("tempfile.tempdir", None)  # gettempdir reads TMPDIR again
    return tmp_path


def test_a_kernel_with_no_cache_anywhere_compiles_uncached_and_warns_once(monkeypatch, temporary_directory):
    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    monkeypatch.setattr(jit, "_warned", False)
    with pytest.warns(RuntimeWarning, match="NUMBA_CACHE_DIR"):
        twice = jit.njit_cached(_sourceless_function())
    assert numba.config.CACHE_DIR == jit.fallback_cache_dir()  # the temporary directory was tried
    assert twice(1.5) == 3.0
    assert twice.__class__.__name__ == "CPUDispatcher"  # compiled, not the Python function
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a second kernel does not warn again
        assert jit.njit_cached(_sourceless_function())(2.0) == 4.0


def test_the_fallback_directory_is_per_user_under_tmpdir(temporary_directory):
    path = Path(jit.fallback_cache_dir())
    assert path.parent == temporary_directory
    assert path.name == f"quad_drake-numba-{os.getuid()}"


def test_a_fallback_directory_others_can_write_is_not_used(monkeypatch, temporary_directory):
    """numba's cache files are pickles: a directory another user could have planted them in
    (group- or world-writable, a link, someone else's) is never given to numba."""
    planted = Path(jit.fallback_cache_dir())
    planted.mkdir(mode=0o777)
    planted.chmod(0o777)
    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    monkeypatch.setattr(jit, "_warned", False)
    with pytest.warns(RuntimeWarning, match="writable by this user only"):
        twice = jit.njit_cached(_sourceless_function())
    assert numba.config.CACHE_DIR == ""
    assert twice(1.0) == 2.0


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
        "import quad_drake.fleet.estimation_kernels as k; "
        f"assert k.__file__.startswith({str(package)!r}); print(k._wrap(7.0))"
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
    assert any("_wrap" in p.name for p in cached), cached


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


def test_a_compile_is_not_announced_on_a_log(monkeypatch):
    log = io.StringIO()
    monkeypatch.setattr(sys, "stderr", log)
    monkeypatch.setattr(jit.compile_notice, "shown", False)
    numba.njit(_sourceless_function())(1.0)
    assert log.getvalue() == ""
