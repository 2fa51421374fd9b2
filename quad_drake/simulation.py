"""Wire scenarios into Drake Diagrams and run them.

A vehicle (plant, sensors, attitude filter, EKF, controller, trajectory) is a
sub-Diagram with its signals exported, so a scenario instantiates it N times.
The top-level Diagram logs every exported signal of every vehicle every 5 ms through
one Multiplexer and one ``LogVectorOutput``: every leaf system costs ~0.3-0.6 us in
every Simulator step, so one logger instead of one per signal saves ~10 % (DESIGN §9).
The scenario seed reaches every noise source through ``SetRandomContext``.
"""

import dataclasses
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.common import RandomDistribution, RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput, Multiplexer, RandomSource

from . import conventions as c
from .config import ConfigError, dump_scenario
from .consistency import fleet_sigma_fraction
from .evaluation import evaluate_criterion, fleet_sigma_threshold
from .rotations import quat_from_euler
from .signals import empty_logs, vehicle_signals
from .systems.controller import CascadeController
from .systems.estimators import ComplementaryFilter, Ekf, EstimatedStateAssembler
from .systems.plant import QuadrotorPlant
from .systems.sensors import Gps, Imu, Magnetometer
from .systems.trajectory import TrajectorySource
from .trajectories import trajectory_from_config


def initial_state(vehicle):
    """13-vector (p, q wxyz, v, w) of a VehicleConfig's initial conditions."""
    yaw, pitch, roll = vehicle.initial_ypr
    return np.concatenate(
        [
            vehicle.initial_position,
            quat_from_euler(roll, pitch, yaw),
            vehicle.initial_velocity,
            vehicle.initial_omega,
        ]
    )


def vehicle_log_names(vehicle):
    """Names of the signals a vehicle exports (and the top level logs)."""
    names = ["state", "reference", "motor_forces"]
    sensors = vehicle.sensors
    names += [s for s in ("imu", "gps", "mag") if getattr(sensors, s) is not None]
    if sensors.imu is not None:
        names += ["attitude", "ekf_state", "covariance", "diagnostics"]
    return names


def _add_noisy(builder, system, name, port="noise", distribution=RandomDistribution.kGaussian):
    """Add `system` and a RandomSource (system.noise_size, system.noise_period) feeding `port`."""
    builder.AddNamedSystem(name, system)
    noise = builder.AddNamedSystem(
        f"{name}_noise" if port == "noise" else port,
        RandomSource(distribution, system.noise_size, system.noise_period),
    )
    builder.Connect(noise.get_output_port(0), system.GetInputPort(port))
    return system


def _never_sampled(builder, size):
    """A sensor output that never carries a sample (stamp = NO_SAMPLE_STAMP)."""
    value = np.zeros(size)
    value[-1] = c.NO_SAMPLE_STAMP
    return builder.AddSystem(ConstantVectorSource(value)).get_output_port(0)


def build_vehicle(vehicle):
    """The sub-Diagram of one VehicleConfig; its outputs are named as `vehicle_log_names`."""
    builder = DiagramBuilder()
    plant = _add_noisy(
        builder,
        QuadrotorPlant(vehicle.physics, initial_state(vehicle)),
        "plant",
        "motor_noise",
        RandomDistribution.kUniform,
    )
    controller = builder.AddNamedSystem("controller", CascadeController(vehicle.controller))
    trajectory = builder.AddNamedSystem(
        "trajectory", TrajectorySource(trajectory_from_config(vehicle.trajectory))
    )
    builder.Connect(controller.GetOutputPort("motor_thrusts"), plant.GetInputPort("motor_thrusts"))
    builder.Connect(trajectory.GetOutputPort("reference"), controller.GetInputPort("reference"))
    outputs = {
        "state": plant.GetOutputPort("state"),
        "reference": trajectory.GetOutputPort("reference"),
        "motor_forces": plant.GetOutputPort("motor_forces"),
    }
    state_for_control = plant.GetOutputPort("state")

    sensors = vehicle.sensors
    if sensors.imu is not None:
        imu = _add_noisy(builder, Imu(sensors.imu), "imu")
        builder.Connect(plant.GetOutputPort("state"), imu.GetInputPort("state"))
        builder.Connect(plant.GetOutputPort("acceleration"), imu.GetInputPort("acceleration"))
        outputs["imu"] = imu.GetOutputPort("imu")
    for kind, sensor_class in (("gps", Gps), ("mag", Magnetometer)):
        params = getattr(sensors, kind)
        if params is not None:
            sensor = _add_noisy(builder, sensor_class(params), kind)
            builder.Connect(plant.GetOutputPort("state"), sensor.GetInputPort("state"))
            outputs[kind] = sensor.GetOutputPort(kind)

    if sensors.imu is not None:
        ekf = builder.AddNamedSystem("ekf", Ekf(vehicle.ekf))
        attitude_filter = builder.AddNamedSystem(
            "attitude_filter",
            ComplementaryFilter(
                vehicle.attitude_filter, initial_attitude=(0.0, 0.0, vehicle.ekf.init_state[6])
            ),
        )
        builder.Connect(outputs["imu"], attitude_filter.GetInputPort("imu"))
        builder.Connect(ekf.GetOutputPort("ekf_state"), attitude_filter.GetInputPort("ekf_state"))
        builder.Connect(outputs["imu"], ekf.GetInputPort("imu"))
        builder.Connect(attitude_filter.GetOutputPort("attitude"), ekf.GetInputPort("attitude"))
        builder.Connect(outputs.get("gps") or _never_sampled(builder, c.GPS_SIZE), ekf.GetInputPort("gps"))
        builder.Connect(outputs.get("mag") or _never_sampled(builder, c.MAG_SIZE), ekf.GetInputPort("mag"))
        outputs["attitude"] = attitude_filter.GetOutputPort("attitude")
        for name in ("ekf_state", "covariance", "diagnostics"):
            outputs[name] = ekf.GetOutputPort(name)
        if not vehicle.use_ideal_estimator:
            assembler = builder.AddNamedSystem("estimated_state", EstimatedStateAssembler())
            for name in ("attitude", "ekf_state", "imu"):
                builder.Connect(outputs[name], assembler.GetInputPort(name))
            state_for_control = assembler.GetOutputPort("estimated_state")
    builder.Connect(state_for_control, controller.GetInputPort("state"))

    for name in vehicle_log_names(vehicle):
        builder.ExportOutput(outputs[name], name)
    diagram = builder.Build()
    diagram.set_name(vehicle.name)
    return diagram


class SignalLog:
    """The samples of one signal: its rows of the scenario log (a VectorLog look-alike)."""

    def __init__(self, log, rows):
        self._log, self._rows = log, rows

    def sample_times(self):
        """(n,) sample times, s."""
        return self._log.sample_times()

    def data(self):
        """(width, n): one column per sample, as VectorLog.data()."""
        return self._log.data()[self._rows]


class SignalLogger:
    """One logged signal: an input of the scenario's log Multiplexer and its rows in the one
    5 ms VectorLogSink; ``FindLog(context)`` and ``get_input_port()`` work as on a VectorLogSink
    of that signal alone."""

    def __init__(self, sink, rows, input_port):
        self.sink, self.rows = sink, rows
        self._input_port = input_port

    def FindLog(self, context):  # noqa: N802 (VectorLogSink's name)
        return SignalLog(self.sink.FindLog(context), self.rows)

    def get_input_port(self):
        return self._input_port


def build_diagram(scenario):
    """(Diagram, {vehicle name: {log name: SignalLogger}}) for a ScenarioConfig.

    Vehicles are sub-Diagrams named as in the config; all their exported signals go through
    one Multiplexer (``log_signals``) into one ``LogVectorOutput`` (``logger``, LOG_PERIOD).
    """
    builder = DiagramBuilder()
    ports, rows, start = [], [], 0
    for vehicle in scenario.vehicles:
        sub = builder.AddSystem(build_vehicle(vehicle))
        for name in vehicle_log_names(vehicle):
            port = sub.GetOutputPort(name)
            ports.append(port)
            rows.append((vehicle.name, name, slice(start, start + port.size())))
            start += port.size()
    mux = builder.AddNamedSystem("log_signals", Multiplexer([port.size() for port in ports]))
    for i, port in enumerate(ports):
        builder.Connect(port, mux.get_input_port(i))
    sink = LogVectorOutput(mux.get_output_port(0), builder, publish_period=c.LOG_PERIOD)
    sink.set_name("logger")
    loggers = {vehicle.name: {} for vehicle in scenario.vehicles}
    for i, (vehicle, name, block) in enumerate(rows):
        loggers[vehicle][name] = SignalLogger(sink, block, mux.get_input_port(i))
    diagram = builder.Build()
    diagram.set_name(scenario.name)
    return diagram, loggers


def read_logs(loggers, context, n_samples):
    """(times (n,), {vehicle: {log name: (n, width)}}) of the samples at LOG_PERIOD k, k = 1..n,
    from the loggers of :func:`build_diagram` (they share one VectorLogSink)."""
    keep = slice(1, n_samples + 1)  # the reference's analyzer frames: t = 0 is not one
    sink = next(iter(next(iter(loggers.values())).values())).sink
    log = sink.FindLog(context)
    data = log.data()[:, keep].T
    logs = {
        vehicle: {name: data[:, logger.rows].copy() for name, logger in vehicle_loggers.items()}
        for vehicle, vehicle_loggers in loggers.items()
    }
    return log.sample_times()[keep].copy(), logs


def available_signals(scenario):
    """Names of every signal the scenario's criteria may refer to."""
    names = set()
    for vehicle in scenario.vehicles:
        names |= set(vehicle_signals(vehicle.name, empty_logs(vehicle_log_names(vehicle))))
    return names


def check_criteria(scenario):
    """Raise ConfigError when a criterion names a signal the scenario does not produce."""
    known = available_signals(scenario)
    for i, criterion in enumerate(scenario.criteria):
        for key in ("signal", "ref_signal", "sigma_signal"):
            name = getattr(criterion, key)
            names = (
                [f"{v.name}.{name}" for v in scenario.vehicles] if criterion.kind == "fleet_sigma" else [name]
            )
            if name and any(n not in known for n in names):
                raise ConfigError(
                    f"criteria.{i}.{key}: unknown signal {name!r} (e.g. {', '.join(sorted(known)[:6])}, ...)"
                )


def evaluate_criteria(scenario, times, signals):
    """CriterionResult per scenario criterion, on the logged 5 ms samples."""

    def lookup(name):
        return signals[name].values, signals[name].fresh

    results = []
    for criterion in scenario.criteria:
        if criterion.kind == "fleet_sigma":
            fraction = fleet_sigma_fraction(
                signals, criterion.signal, criterion.sigma_signal, criterion.sigma_multiple
            )
            results.append(
                fleet_sigma_threshold(
                    fraction,
                    len(scenario.vehicles) * times.size,
                    criterion.signal,
                    criterion.sigma_signal,
                    criterion.sigma_multiple,
                    criterion.min_percent,
                    criterion.max_percent,
                )
            )
        else:
            results.append(evaluate_criterion(criterion, times, lookup))
    return results


@dataclass
class SimulationResult:
    """Logs, derived signals and criterion verdicts of one scenario run."""

    scenario: object
    times: np.ndarray  # (n,) s, log sample times 0.005 k, k >= 1
    logs: dict  # vehicle -> log name -> (n, width)
    signals: dict  # signal name -> Signal
    criteria: list  # CriterionResult per scenario criterion
    wall_time: float  # s, simulation only
    extra: dict = field(default_factory=dict)

    @property
    def passed(self):
        return all(r.passed for r in self.criteria)

    def summary(self):
        """JSON-ready summary: scenario, seed, verdicts, wall time."""
        return {
            "scenario": self.scenario.name,
            "seed": self.scenario.seed,
            "end_time": self.scenario.end_time,
            "passed": self.passed,
            "wall_time_s": round(self.wall_time, 3),
            "real_time_factor": round(self.scenario.end_time / self.wall_time, 2),
            "criteria": [dataclasses.asdict(r) for r in self.criteria],
        }

    def save(self, out_dir):
        """Write logs.npz, config.yaml (resolved) and summary.json into out_dir."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        arrays = {"times": self.times}
        for vehicle, logs in self.logs.items():
            for name, data in logs.items():
                arrays[f"{vehicle}/{name}"] = data
        np.savez_compressed(out_dir / "logs.npz", **arrays)
        (out_dir / "config.yaml").write_text(dump_scenario(self.scenario))
        (out_dir / "summary.json").write_text(json.dumps(self.summary(), indent=2) + "\n")
        return out_dir


def load_logs(run_dir):
    """(times, {vehicle: {log name: array}}) from a run folder's logs.npz."""
    path = Path(run_dir) / "logs.npz"
    if not path.is_file():
        raise ConfigError(f"{run_dir}: no logs.npz (is this a run folder?)")
    data = np.load(path)
    logs = {}
    for key in data.files:
        if key != "times":
            vehicle, name = key.split("/", 1)
            logs.setdefault(vehicle, {})[name] = data[key]
    return data["times"], logs


def signals_from_logs(logs):
    """All vehicles' named signals from {vehicle: {log name: array}}."""
    signals = {}
    for vehicle, vehicle_logs in logs.items():
        signals.update(vehicle_signals(vehicle, vehicle_logs))
    return signals


def run(scenario):
    """Simulate a ScenarioConfig for end_time s with its seed; evaluate its criteria."""
    check_criteria(scenario)
    diagram, loggers = build_diagram(scenario)
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.SetRandomContext(context, RandomGenerator(scenario.seed))
    start = time.perf_counter()
    simulator.Initialize()
    simulator.AdvanceTo(scenario.end_time)
    wall_time = time.perf_counter() - start

    times, logs = read_logs(loggers, context, int(round(scenario.end_time / c.LOG_PERIOD)))
    signals = signals_from_logs(logs)
    return SimulationResult(
        scenario, times, logs, signals, evaluate_criteria(scenario, times, signals), wall_time
    )
