"""Output folders keep every result: a folder per run variant, whole files or none, one line and
exit 3 on a write error, concurrent invocations into one --out, reproductions beside the run."""

import errno
import io
import json
import os
import subprocess
import sys
import threading
import zipfile

import numpy as np
import pytest

from quad_drake.output import results
from quad_drake.output.outdir import atomic_path, is_result_folder, write_text_atomic
from quad_drake.output.results import claim_run_folder, load_run, save_run, savez_deflating, variant_name
from quad_drake.running import catalog


def test_an_error_while_writing_leaves_the_earlier_file_and_no_temporary(tmp_path):
    path = tmp_path / "summary.json"
    path.write_text("the earlier result")
    with pytest.raises(OSError), atomic_path(path) as temporary:
        temporary.write_text("half of the new")
        raise OSError(errno.ENOSPC, "No space left on device")
    assert path.read_text() == "the earlier result"
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]
    write_text_atomic(path, "the new result")
    assert path.read_text() == "the new result" and len(list(tmp_path.iterdir())) == 1
    assert (path.stat().st_mode & 0o777) == 0o666 & ~_umask()  # not mkstemp's 0600


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _full_disk(*args, **kwargs):
    f = args[0]
    f.write(b"PK\x03\x04 a torn zip")
    raise OSError(errno.ENOSPC, "No space left on device")


def test_a_full_disk_keeps_the_earlier_run_whole(gps_flight, tmp_path, monkeypatch):
    run_dir = save_run(gps_flight, tmp_path / "11_gps_update")
    before = {p.name: p.read_bytes() for p in run_dir.iterdir()}
    monkeypatch.setattr(results, "savez_deflating", _full_disk)
    with pytest.raises(OSError):
        save_run(gps_flight, run_dir)
    assert {p.name: p.read_bytes() for p in run_dir.iterdir()} == before
    assert load_run(run_dir).passed == gps_flight.passed


def test_a_write_error_is_one_line_and_exit_3(quad_drake_cli, tmp_path, monkeypatch):
    monkeypatch.setattr(results, "savez_deflating", _full_disk)
    result = quad_drake_cli("run", "01_intro", "--no-plots", "--out", tmp_path / "out")
    assert result.returncode == 3
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "No space left on device" in lines[0] and "Traceback" not in result.stderr
    assert not list((tmp_path / "out" / "01_intro").glob(".*tmp*"))  # no torn temporary left


def test_logs_npz_compresses_what_deflate_shrinks_and_stores_the_rest():
    rng = np.random.default_rng(3)
    arrays = {
        "times": np.arange(1, 5001) * 0.005,
        "Quad/state": rng.standard_normal((5000, 13)),  # noise: deflate cannot shrink it
        "Quad/diagnostics": np.where(np.arange(5000)[:, None] % 7 == 0, np.nan, np.zeros((5000, 17))),
        "Quad/gps": np.repeat(rng.standard_normal((50, 7)), 100, axis=0).astype(np.float32),
        "empty": np.zeros((0, 3)),
    }
    buffer = io.BytesIO()
    savez_deflating(buffer, arrays)
    kinds = {i.filename: i.compress_type for i in zipfile.ZipFile(io.BytesIO(buffer.getvalue())).infolist()}
    assert kinds["Quad/state.npy"] == zipfile.ZIP_STORED
    assert kinds["Quad/diagnostics.npy"] == kinds["Quad/gps.npy"] == zipfile.ZIP_DEFLATED
    loaded = np.load(io.BytesIO(buffer.getvalue()))
    assert sorted(loaded.files) == sorted(arrays)
    for name, array in arrays.items():
        assert loaded[name].dtype == array.dtype and loaded[name].shape == array.shape
        np.testing.assert_array_equal(loaded[name], array)  # NaN where NaN, bit for bit elsewhere


def test_folder_names_carry_the_seed_and_a_hash_of_the_overrides():
    assert variant_name("11_gps_update") == "11_gps_update"
    assert variant_name("11_gps_update", 7) == "11_gps_update-seed7"
    a = variant_name("11_gps_update", None, ["end_time=5"])
    assert a.startswith("11_gps_update-set") and len(a) == len("11_gps_update-set") + 6
    assert a == variant_name("11_gps_update", None, ["end_time=5"])  # the same command, the same folder
    assert a != variant_name("11_gps_update", None, ["end_time=6"])
    assert variant_name("x", 0, ["a=1"]).startswith("x-seed0-set")


def test_a_folder_holding_another_config_is_never_replaced(tmp_path):
    first, second = catalog.load("01_intro", 1), catalog.load("01_intro", 2)
    assert claim_run_folder(tmp_path, "01_intro", first) == tmp_path / "01_intro"
    assert claim_run_folder(tmp_path, "01_intro", first) == tmp_path / "01_intro"  # its own: replaced
    assert claim_run_folder(tmp_path, "01_intro", second) == tmp_path / "01_intro-2"
    assert claim_run_folder(tmp_path, "01_intro", first, replace=False) == tmp_path / "01_intro-3"
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("the user's")
    assert claim_run_folder(tmp_path, "mine", first) == tmp_path / "mine-2"


def test_concurrent_claims_get_distinct_folders(tmp_path):
    scenarios = [catalog.load("01_intro", seed) for seed in range(8)]
    claimed, barrier = [None] * 8, threading.Barrier(8)

    def claim(i):
        barrier.wait()
        claimed[i] = claim_run_folder(tmp_path, "01_intro", scenarios[i])

    threads = [threading.Thread(target=claim, args=(i,)) for i in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(set(claimed)) == 8


def test_out_pointing_at_a_run_folder_is_refused(quad_drake_cli, gps_run_dir, tmp_path):
    before = {p.name: p.read_bytes() for p in gps_run_dir.iterdir()}
    for command in ("run", "montecarlo"):
        result = quad_drake_cli(command, "01_intro", "--no-plots", "--out", gps_run_dir)
        assert result.returncode == 2 and "is a run or campaign folder" in result.stderr
    assert {p.name: p.read_bytes() for p in gps_run_dir.iterdir()} == before
    assert is_result_folder(gps_run_dir) and not is_result_folder(tmp_path)


def test_reproducing_from_a_run_folder_writes_beside_it(quad_drake_cli, tmp_path, monkeypatch):
    out = tmp_path / "out"
    assert quad_drake_cli("run", "01_intro", "--seed", "3", "--no-plots", "--out", out).returncode == 0
    run_dir = out / "01_intro-seed3"
    original = (run_dir / "summary.json").read_bytes()
    monkeypatch.chdir(run_dir)  # as the report says: `quad-drake run config.yaml` in this folder
    assert quad_drake_cli("run", "config.yaml", "--no-plots").returncode == 0
    assert sorted(p.name for p in run_dir.iterdir()) == ["config.yaml", "logs.npz", "summary.json"]
    assert (run_dir / "summary.json").read_bytes() == original
    again = load_run(out / "01_intro-seed3-2")
    assert again.scenario.seed == 3 and again.passed


@pytest.mark.slow
def test_concurrent_invocations_into_one_out_keep_every_run(tmp_path):
    out = tmp_path / "out"
    # Four processes, each about 3 s of CPU (Drake's import and the plots): three folders of three
    # kinds (a seed, a --set, the plain name) and one command twice. A second seed (until
    # 2026-12-06) claimed a fourth name as the first did; many concurrent claims of one name's
    # seeds are test_concurrent_claims_get_distinct_folders above, in one process.
    commands = [
        ["run", "01_intro", "--seed", "1"],
        ["run", "01_intro", "--set", "end_time=1.5"],
        ["run", "01_intro"],
        ["run", "01_intro"],  # the same command twice: one folder, whole
    ]
    processes = [
        subprocess.Popen(
            [sys.executable, "-m", "quad_drake.cli", *c, "--out", str(out)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for c in commands
    ]
    for process in processes:
        _, err = process.communicate(timeout=600)
        assert process.returncode == 0, err
    folders = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert folders == [
        "01_intro",
        "01_intro-seed1",
        variant_name("01_intro", None, ["end_time=1.5"]),
    ]
    for folder in folders:
        result = load_run(out / folder)
        assert result.passed and (out / folder / "report.html").is_file()
    index = (out / "index.html").read_text()
    assert all(f">{folder}<" in index for folder in folders)
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]
    assert json.loads((out / "01_intro" / "summary.json").read_text())["seed"] == 0
