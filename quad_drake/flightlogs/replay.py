"""Replay a recorded flight through an estimator sub-Diagram: wiring, run, results.

The Diagram: a ``systems.playback.LogPlayback`` emits the log's samples on the onboard tick; its
``imu``, ``gps`` and ``mag`` outputs feed the estimator of ``systems.estimators.build_estimator``
(the same sub-Diagram a simulated vehicle flies on, unchanged); every estimator output and every
playback output is logged by its own ``VectorLogSink`` every LOG_PERIOD. A log without GPS
feeds the estimator PX4's fake position instead (``flightlogs.schedule.fake_position``), so the
attitude part runs and the position part stays bounded; its position is not compared (there is
no reference) and its GPS NIS is not judged.

:func:`replay` is the library call behind ``quad-drake replay``; :func:`save_replay` writes the
run folder (``logs.npz``, ``config.yaml``, ``summary.json`` of kind ``"replay"``; the report and
plots: ``flightlogs.page``).
"""

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from quad_drake.conventions import LOG_PERIOD
from quad_drake.estimation.registry import vocabulary_for
from quad_drake.estimation.vocabulary import health_counts, health_line
from quad_drake.flightlogs import comparison
from quad_drake.flightlogs.reader import read_flight_log
from quad_drake.flightlogs.schedule import (
    fake_position,
    initial_attitude,
    playback_streams,
    superseded_samples,
)
from quad_drake.flightlogs.settings import ReplayConfig, dump_replay, resolve_log, vehicle_for
from quad_drake.kernels import jit
from quad_drake.models.fidelity import PHYSICAL
from quad_drake.output.jsonio import dump_json
from quad_drake.output.outdir import write_binary_atomic, write_text_atomic
from quad_drake.output.results import FORMAT_VERSION
from quad_drake.running.limits import LOG_COPIES, check_memory
from quad_drake.systems.estimators import build_estimator
from quad_drake.systems.playback import LogPlayback

COMPARE_AFTER = 5.0
"""s from the log's start before anything is compared or judged: the estimators start from the
first samples (the EKF7's complementary filter from level, at τ = 0.5 s; both filters' yaw and
biases from their initial σ), and a comparison should see them running, not starting."""
RUNNER = "drake-replay"
"""What produced a replay: the Drake Diagram of this module."""


@dataclass
class ReplayResult:
    """A replayed flight: its logs, the comparison with the log's own estimate, timing."""

    config: ReplayConfig
    log: object  # reader.FlightLog (declination as replayed)
    times: np.ndarray  # (n,) s, log samples LOG_PERIOD k, k >= 1
    logs: dict  # log name -> (n, width): the estimator's outputs and the playback's
    wall_time: float  # s
    fake_position: bool  # a log without GPS, given PX4's fake position
    attitude: list = field(default_factory=list)  # [comparison.StateDifference] roll, pitch, yaw
    position: list = field(default_factory=list)  # [StateDifference] x ... vz; [] without GPS
    nis: list = field(default_factory=list)  # [comparison.NisSummary] per judged sensor
    innovations: dict = field(default_factory=dict)  # sensor -> comparison.innovations (stamps, values)
    superseded: dict = field(default_factory=dict)  # stream -> samples never emitted (> 500 Hz)
    compile_time: float = 0.0  # s, numba compiling kernels during this replay

    @property
    def vocabulary(self):
        return vocabulary_for(self.config.estimator)

    def notes(self):
        """Lines that say what this replay could and could not judge."""
        lines = [
            "The reference is the flight controller's own estimate (PX4), another estimator and not "
            "the truth: a difference is the two estimators' disagreement."
        ]
        if self.fake_position:
            lines.append(
                "The log has no GPS: the attitude part is judged; the estimator was given PX4's fake "
                f"position (0 m with σ = {self.config.fake_position_std:g} m every "
                f"{self.config.fake_position_period:g} s), its position is not compared and its GPS "
                "NIS not judged."
            )
        if self.log.mag_field is None:
            lines.append("The log has no magnetometer: the yaw is the gyro's alone.")
        if self.log.reference_attitude is None:
            lines.append("The log has no vehicle_attitude: nothing to compare the attitude with.")
        for stream, count in self.superseded.items():
            if count:
                lines.append(f"{count} {stream} samples came faster than the 2 ms tick and were superseded.")
        return lines

    def health_line(self):
        return health_line("replay", self.config.estimator.kind, health_counts(self.logs["diagnostics"]))

    def summary(self):
        """The summary.json dict (kind ``"replay"``)."""
        return {
            "format_version": FORMAT_VERSION,
            "kind": "replay",
            "runner": RUNNER,
            "scenario": self.config.name,
            "log": self.log.source,
            "estimator": self.config.estimator.kind,
            "duration_s": round(self.log.duration, 3),
            "sensors": ["imu", *self.log.sensors()],
            "fake_position": self.fake_position,
            "compare_after_s": COMPARE_AFTER,
            "wall_time_s": round(self.wall_time, 3),
            "real_time_factor": round(self.log.duration / self.wall_time, 2) if self.wall_time > 0 else None,
            "compile_time_s": round(self.compile_time, 3),
            "differences": [_difference_dict(d) for d in self.attitude + self.position],
            "nis": [_nis_dict(s) for s in self.nis],
            "notes": self.notes(),
        }


def _difference_dict(d):
    return {
        "state": d.state,
        "unit": d.unit,
        "count": d.count,
        "rms": d.rms,
        "max_abs": d.max_abs,
        "sigma_rms": d.sigma_rms,
        "within_2sigma": d.within_2sigma,
    }


def _nis_dict(s):
    return {
        "sensor": s.sensor,
        "dof": s.dof,
        "count": s.count,
        "mean": s.mean,
        "band": list(s.band),
        "in_band": s.in_band,
        "single_share": s.single_share,
    }


def build_replay_diagram(log, config):
    """(Diagram, {log name: VectorLogSink}, fake position used) replaying the FlightLog `log`
    through the estimator of the ReplayConfig `config` (module docstring)."""
    fake = log.gps is None and config.fake_position_std > 0
    gps = fake_position(log, config.fake_position_period) if fake else None
    streams = playback_streams(log, gps)
    vehicle = vehicle_for(config, initial_attitude(log), fake)
    builder = DiagramBuilder()
    playback = builder.AddNamedSystem("playback", LogPlayback(streams))
    estimator = builder.AddSystem(build_estimator(vehicle, PHYSICAL))
    for name in ("imu", "gps", "mag"):
        builder.Connect(playback.GetOutputPort(name), estimator.GetInputPort(name))
    sinks = {}
    outputs = [(name, estimator) for name in vocabulary_for(config.estimator).log_widths()]
    outputs += [(name, playback) for name in streams]
    for name, system in outputs:
        sinks[name] = LogVectorOutput(system.GetOutputPort(name), builder, publish_period=LOG_PERIOD)
        sinks[name].set_name(f"{name}_log")
    diagram = builder.Build()
    diagram.set_name(config.name or "replay")
    return diagram, sinks, fake


def replay(config, log=None):
    """ReplayResult of the ReplayConfig `config` (its ``log`` file read unless the FlightLog `log`
    is given): the flight replayed to its last IMU sample, compared with the log's own estimate.

    Raises reader.FlightLogError (a ConfigError, one line) for a log that cannot be replayed.
    """
    log = read_flight_log(resolve_log(config.log)) if log is None else log
    if config.mag_declination is not None:
        log = dataclasses.replace(log, mag_declination=config.mag_declination)
    if not config.name:
        config = dataclasses.replace(config, name=Path(log.source).stem)
    diagram, sinks, fake = build_replay_diagram(log, config)
    width = sum(sink.get_input_port().size() for sink in sinks.values())
    check_memory(
        log.duration / LOG_PERIOD * width * 8.0 * LOG_COPIES,
        f"{log.source}: a replay of {log.duration:g} s",
        "replay a shorter stretch of the flight (e.g. cut into a CSV log)",
    )
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    compiled = jit.compile_seconds()
    start = time.perf_counter()
    simulator.Initialize()
    simulator.AdvanceTo(log.duration)
    compile_time = jit.compile_seconds() - compiled
    wall_time = time.perf_counter() - start - compile_time
    times, logs = _read_sinks(sinks, context)
    result = ReplayResult(config, log, times, logs, wall_time, fake, compile_time=compile_time)
    _judge(result)
    return result


def _read_sinks(sinks, context):
    """(times (n,), {name: (n, width)}) of the LOG_PERIOD samples k >= 1 of every sink."""
    logs, times = {}, None
    for name, sink in sinks.items():
        found = sink.FindLog(context)
        logs[name] = found.data()[:, 1:].T.copy()
        times = found.sample_times()[1:].copy()
    return times, logs


def _judge(result):
    """Fill `result`'s comparison, NIS summaries and superseded-sample counts."""
    log, vocabulary = result.log, result.vocabulary
    if log.reference_attitude is not None:
        result.attitude = comparison.compare_attitude(
            vocabulary, result.times, result.logs, log.reference_attitude, COMPARE_AFTER
        )
    if log.reference_position is not None and not result.fake_position:
        result.position = comparison.compare_position(
            vocabulary, result.times, result.logs, log.reference_position, COMPARE_AFTER
        )
    judged = ["mag"] + ([] if result.fake_position else ["gps"])
    summaries = [comparison.nis_summary(result.logs["diagnostics"], s, COMPARE_AFTER) for s in judged]
    result.nis = [s for s in summaries if s is not None]
    result.innovations = {
        s.sensor: comparison.innovations(result.logs, s.sensor, COMPARE_AFTER) for s in result.nis
    }
    sources = {"imu": log.imu, "gps": log.gps, "mag": log.mag_field, "baro": log.baro}
    result.superseded = {name: superseded_samples(s.times) for name, s in sources.items() if s is not None}


def save_replay(result, out_dir):
    """Write logs.npz (``times`` and ``replay/<log name>``), config.yaml (the resolved
    ReplayConfig) and summary.json into out_dir; returns out_dir."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    arrays = {"times": result.times} | {f"replay/{name}": data for name, data in result.logs.items()}
    write_binary_atomic(out_dir / "logs.npz", lambda f: np.savez_compressed(f, **arrays))
    write_text_atomic(out_dir / "config.yaml", dump_replay(result.config))
    dump_json(out_dir / "summary.json", result.summary())
    return out_dir
