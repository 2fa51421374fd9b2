"""A run's results in memory (:class:`SimulationResult`) and on disk (the run folder).

The run folder is a versioned on-disk contract (``FORMAT_VERSION``):

- ``logs.npz``: ``times`` ((n,) s, the 5 ms log samples) and ``<vehicle>/<log name>``
  ((n, width) arrays, as :func:`quad_drake.running.simulation.read_logs` returns them);
- ``config.yaml``: the resolved scenario (seed included), so the folder reproduces itself;
- ``summary.json``: strict JSON with ``format_version``, ``kind: "run"``, the runner,
  scenario, seed, verdicts (with their text fields) and timing.

:func:`load_run` re-derives the signals from the logs and re-evaluates the verdicts from
the saved configuration, without simulating again.
"""

import hashlib
import io
import itertools
import json
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config.errors import ConfigError
from ..config.loader import dump_scenario, load_scenario
from ..estimation.registry import vehicle_vocabulary
from ..estimation.vocabulary import completed_diagnostics
from ..judging.signals import Signals, vehicle_signals
from ..judging.verdicts import evaluate_criteria
from .jsonio import dump_json
from .outdir import locked, remove_stale, write_binary_atomic, write_text_atomic

FORMAT_VERSION = 1
"""Version of the run folder layout and of summary.json; readers refuse other versions."""
RUNNER = "drake-diagram"
"""What produced a run: the Drake Diagram of :mod:`quad_drake.running.simulation`."""


@dataclass
class SimulationResult:
    """Logs, derived signals and criterion verdicts of one scenario run."""

    scenario: object  # ScenarioConfig
    times: np.ndarray  # (n,) s, log sample times 0.005 k, k >= 1
    logs: dict  # vehicle -> log name -> (n, width)
    signals: dict  # signal name -> Signal
    criteria: list  # CriterionResult per judged criterion (evaluation.judged_criteria)
    wall_time: float  # s, simulation only (without numba compiling its kernels: compile_time)
    runner: str = RUNNER
    extra: dict = field(default_factory=dict)
    compile_time: float = 0.0  # s, numba compiling kernels during this flight (first run after an install)

    @property
    def passed(self) -> bool:
        return all(r.passed for r in self.criteria)

    def summary(self) -> dict:
        """The summary.json dict: format, scenario, seed, verdicts with their text, timing."""
        return {
            "format_version": FORMAT_VERSION,
            "kind": "run",
            "runner": self.runner,
            "scenario": self.scenario.name,
            "description": self.scenario.description,
            "seed": self.scenario.seed,
            "end_time": self.scenario.end_time,
            "passed": self.passed,
            "wall_time_s": round(self.wall_time, 3),
            "real_time_factor": round(self.scenario.end_time / self.wall_time, 2)
            if self.wall_time > 0
            else None,
            "compile_time_s": round(self.compile_time, 3),
            "criteria": [r.to_dict() for r in self.criteria],
        }


def signals_from_logs(logs, scenario=None) -> Signals:
    """All vehicles' named signals from {vehicle: {log name: array}}.

    Estimator signals need the scenario (its vehicles' estimator vocabularies).
    """
    vocabularies = {} if scenario is None else {v.name: vehicle_vocabulary(v) for v in scenario.vehicles}
    return Signals().merged(
        *(
            vehicle_signals(vehicle, vehicle_logs, vocabularies.get(vehicle))
            for vehicle, vehicle_logs in logs.items()
        )
    )


def result_from_logs(scenario, times, logs, wall_time, runner=RUNNER) -> SimulationResult:
    """SimulationResult of logged arrays: the signals derived, every judged criterion evaluated."""
    signals = signals_from_logs(logs, scenario)
    return SimulationResult(
        scenario, times, logs, signals, evaluate_criteria(scenario, times, signals), wall_time, runner
    )


RUN_ARTIFACTS = ("report.html", "replay.html", "*.png", "csv/*.csv")
"""What a run folder holds besides its logs, config and summary (``plots.write_run_artifacts``,
``export.export_csv``): derived from the logs, so a new run in the folder removes the old ones."""


NPZ_TRIAL_BYTES = 1 << 16
"""Bytes of an array's .npy that :func:`savez_deflating` deflates on trial."""
NPZ_DEFLATE_GAIN = 0.9
"""An array is compressed in a run's logs.npz when deflate shrinks its trial below this fraction."""


def savez_deflating(file, arrays) -> None:
    """Write `arrays` ({name: array}) as an .npz into the binary file object `file`, read by
    ``np.load`` as ``np.savez_compressed``'s is: an array whose first NPZ_TRIAL_BYTES deflate
    (zlib level 1) shrinks below NPZ_DEFLATE_GAIN of their size is compressed, the others are
    stored. A flight's noisy float logs (state, IMU, estimates) shrink by 4 % yet took most of
    ``np.savez_compressed``'s 0.1 s CPU for 25 s of logs; the covariance, the reference, the
    counters and the held samples shrink 1.5 to 100 times (``docs/measurements/speed.md``)."""
    with zipfile.ZipFile(file, "w", allowZip64=True) as archive:
        for name, array in arrays.items():
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, np.asanyarray(array), allow_pickle=False)
            data = buffer.getbuffer()
            trial = data[:NPZ_TRIAL_BYTES]
            if len(zlib.compress(trial, 1)) < NPZ_DEFLATE_GAIN * len(trial):
                archive.writestr(f"{name}.npy", data, zipfile.ZIP_DEFLATED, 1)
            else:
                archive.writestr(f"{name}.npy", data, zipfile.ZIP_STORED)


def save_run(result, out_dir) -> Path:
    """Write logs.npz (:func:`savez_deflating`), config.yaml (resolved) and summary.json into
    out_dir, after removing an earlier run's RUN_ARTIFACTS there (a run without plots must not
    sit beside the old run's report); returns out_dir. Each file is written whole or not at all
    (``outdir.atomic_path``), summary.json last, so a folder with a summary has its logs."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    remove_stale(out_dir, RUN_ARTIFACTS)
    arrays = {"times": result.times}
    for vehicle, logs in result.logs.items():
        for name, data in logs.items():
            arrays[f"{vehicle}/{name}"] = data
    write_binary_atomic(out_dir / "logs.npz", lambda f: savez_deflating(f, arrays))
    write_text_atomic(out_dir / "config.yaml", dump_scenario(result.scenario))
    dump_json(out_dir / "summary.json", result.summary())
    return out_dir


def variant_name(name, seed=None, overrides=()) -> str:
    """The folder name of a scenario flown with ``--seed`` `seed` and ``--set`` `overrides`:
    `name` as it is, then ``-seed<seed>`` when a seed is given, then ``-set<6 hex digits>`` (a
    SHA-256 of the overrides in order) when there are any, e.g. ``11_gps_update-seed7-set3fa2c1``.
    A run of the same command so lands in the same folder (replacing its own earlier result)
    and a run of another seed or overrides in its own."""
    parts = [name]
    if seed is not None:
        parts.append(f"seed{seed}")
    if overrides:
        digest = hashlib.sha256("\n".join(overrides).encode("utf-8")).hexdigest()[:6]
        parts.append(f"set{digest}")
    return "-".join(parts)


def claim_run_folder(out, name, scenario, replace=True) -> Path:
    """The folder under `out` a run of `scenario` is written to, claimed for it by its config.yaml.

    ``out/name`` when it is free, or (``replace``) holds a run of the same resolved config (the
    same command again: its own earlier result); otherwise the first free ``out/name-2``,
    ``out/name-3``, ... (a run of an edited file keeps the earlier one). Chosen and claimed
    under the out folder's lock (``outdir.locked``), so concurrent invocations into one
    ``--out`` never share a folder unless they fly the same config.
    """
    out = Path(out)
    config = dump_scenario(scenario)
    with locked(out):
        for k in itertools.count(1):
            folder = out / (name if k == 1 else f"{name}-{k}")
            if folder.exists() and not _claimable(folder, config, replace):
                continue
            folder.mkdir(exist_ok=True)
            write_text_atomic(folder / "config.yaml", config)
            return folder


def _claimable(folder, config, replace):
    """True for an empty folder, or (replace) a run folder of the same resolved `config`."""
    if not folder.is_dir():
        return False
    if not any(folder.iterdir()):
        return True
    try:
        return replace and (folder / "config.yaml").read_text(encoding="utf-8") == config
    except (OSError, UnicodeDecodeError):
        return False


def load_logs(run_dir) -> tuple[np.ndarray, dict[str, dict[str, np.ndarray]]]:
    """(times, {vehicle: {log name: array}}) from a run folder's logs.npz.

    Raises ConfigError (one line) for a folder without logs, one whose summary.json is not a
    run's of a supported format_version (:func:`read_summary`), and logs that cannot be read.
    """
    path = Path(run_dir) / "logs.npz"
    if not path.is_file():
        raise ConfigError(f"{run_dir}: no logs.npz (is this a run folder?)")
    read_summary(Path(run_dir) / "summary.json", kind="run")
    try:
        with np.load(path) as data:
            logs = {}
            for key in data.files:
                if key != "times":
                    vehicle, name = key.split("/", 1)
                    logged = data[key]  # an earlier version's diagnostics completed to today's layout
                    logs.setdefault(vehicle, {})[name] = (
                        completed_diagnostics(logged) if name == "diagnostics" else logged
                    )
            return data["times"], logs
    except (OSError, EOFError, KeyError, ValueError, zipfile.BadZipFile) as e:
        reason = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ConfigError(f"{path}: not a readable quad_drake log ({reason})") from None


def read_summary(path, kind=None) -> dict:
    """The dict of a summary.json of a supported format_version (and `kind`, when given).

    Raises ConfigError (one line) for a missing or unreadable file, an unknown format
    version or another kind of summary.
    """
    path = Path(path)
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path.parent}: no summary.json (is this a run folder?)") from None
    except (OSError, UnicodeDecodeError, ValueError) as e:
        raise ConfigError(f"{path}: not readable JSON ({e})") from None
    version = summary.get("format_version") if isinstance(summary, dict) else None
    if version != FORMAT_VERSION:
        raise ConfigError(
            f"{path}: format_version {version!r} is not supported (this quad_drake reads {FORMAT_VERSION})"
        )
    if kind is not None and summary.get("kind") != kind:
        raise ConfigError(f"{path}: a {summary.get('kind')!r} summary, not a {kind!r} one")
    return summary


def load_run(run_dir) -> SimulationResult:
    """SimulationResult of a run folder: logs loaded, signals re-derived and verdicts
    re-evaluated from its config.yaml (nothing is simulated); wall time from summary.json.

    Raises ConfigError for a folder without logs, config or a supported summary.
    """
    run_dir = Path(run_dir)
    summary = read_summary(run_dir / "summary.json", kind="run")
    times, logs = load_logs(run_dir)
    scenario = load_scenario(run_dir / "config.yaml")
    return result_from_logs(
        scenario, times, logs, float(summary["wall_time_s"]), summary.get("runner", RUNNER)
    )
