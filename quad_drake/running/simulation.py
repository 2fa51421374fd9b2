"""Wire scenarios into Drake Diagrams and run them.

A vehicle (plant, sensors, estimator, controller, trajectory) is a sub-Diagram with its
signals exported; its estimator is itself a sub-Diagram, chosen by the vehicle's
``estimator.kind`` (``systems/estimators.build_estimator``), so a scenario instantiates it N times.
The top-level Diagram logs every exported signal of every vehicle every 5 ms through
one Multiplexer and one ``LogVectorOutput``: every leaf system costs ~0.3-0.6 us in
every Simulator step, so one logger instead of one per signal saves ~10 % (DESIGN §9).
The scenario seed reaches every noise source through ``SetRandomContext``. The same
``build_vehicle`` given run seeds builds N copies of a vehicle flown at once (fleet mode,
``campaigns.fleet.diagram``): every system sized by N, the noise from counter-based streams.
"""

import time

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder, EventStatus, InputPort
from pydrake.systems.primitives import (
    ConstantVectorSource,
    LogVectorOutput,
    Multiplexer,
    RandomSource,
    ZeroOrderHold,
)

from .. import conventions as c
from ..config.validation import check_scenario
from ..estimation.registry import flies_on_estimate, vehicle_vocabulary
from ..judging.signals import (
    empty_logs,
    vehicle_log_names,
    vehicle_log_widths,
    vehicle_signals,
)
from ..judging.verdicts import check_criteria
from ..kernels import jit
from ..models.error_sampling import TICK_LOG_WIDTHS, TICK_REFERENCE, TICK_STATE
from ..models.faults import sensor_of
from ..models.fidelity import PHYSICAL, fidelity_from_mode
from ..models.rotations import quat_from_euler
from ..models.trajectories import float32_clock, trajectory_from_config
from ..output.results import SimulationResult, result_from_logs
from ..systems.controller import CascadeController
from ..systems.estimators import build_estimator
from ..systems.failsafe import FailsafeSupervisor
from ..systems.faults import GpsDelayCompensator, SensorFaults
from ..systems.noise import NoiseStreamSource
from ..systems.plant import QuadrotorPlant
from ..systems.sensors import Barometer, Gps, Imu, Magnetometer
from ..systems.trajectory import TrajectorySource
from ..systems.wind import Wind
from .limits import check_run


def initial_state(vehicle) -> np.ndarray:
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


def add_tick_holds(builder, outputs, n=1) -> None:
    """Add the holds of ``error_sampling``'s tick logs (``errors_at_onboard_tick``) to `builder`
    and put their output ports in `outputs` (log name: port), which must hold ``state`` (n*13)
    and ``reference`` (n*10) of one vehicle (n = 1) or of a fleet's N copies (n = N).

    Each is a ZeroOrderHold that samples every ONBOARD_PERIOD at CONTROLLER_OFFSET, with the
    controller (no extra event time): after the sensors and estimators of tick t_k, before the
    plant steps, so it holds the truth at t_k and the reference the controller used, as the
    binary's ``UpdateTrueError`` and ``PosFollowErr`` see them, until the next tick. A 5 ms log
    sample at t reads what the last tick before t left (the loggers publish before the updates
    at t).
    """
    for name, source in ((TICK_STATE, "state"), (TICK_REFERENCE, "reference")):
        hold = builder.AddNamedSystem(
            f"{name}_hold",
            ZeroOrderHold(c.ONBOARD_PERIOD, n * TICK_LOG_WIDTHS[name], c.CONTROLLER_OFFSET),
        )
        builder.Connect(outputs[source], hold.get_input_port())
        outputs[name] = hold.get_output_port()


def _add_noise(builder, system, port, seeds, stream):
    """Feed the random input `port` of `system` (n times system.noise_size values drawn from
    system.noise_distribution every system.noise_period): with `seeds` None a Drake RandomSource (seeded by
    ``SetRandomContext``), else a NoiseStreamSource of the streams named `stream` of the run seeds
    (``models.random_streams``), named ``<system>_<port>``."""
    input_port = system.GetInputPort(port)
    distribution = system.noise_distribution
    if seeds is None:
        source = RandomSource(distribution, input_port.size(), system.noise_period)
    else:
        source = NoiseStreamSource(distribution, system.noise_size, system.noise_period, seeds, stream)
    builder.Connect(
        builder.AddNamedSystem(f"{system.get_name()}_{port}", source).get_output_port(0), input_port
    )


def _never_sampled(builder, size, n):
    """n sensor outputs that never carry a sample (stamp = NO_SAMPLE_STAMP)."""
    value = np.zeros((n, size))
    value[:, -1] = c.NO_SAMPLE_STAMP
    return builder.AddSystem(ConstantVectorSource(value.ravel())).get_output_port(0)


def sensor_schedule(vehicle, sensor) -> tuple[float, float]:
    """(period, event time of the first sample) of a vehicle's sensor, s (see systems/sensors)."""
    if sensor == "imu":
        return c.ONBOARD_PERIOD, c.SENSOR_OFFSET
    params = getattr(vehicle.sensors, sensor)
    first = params.period if sensor in ("gps", "baro") else params.first_sample_time
    return params.period, first + c.SLOW_SENSOR_OFFSET


def _add_faults(builder, vehicle, outputs, n):
    """Put a SensorFaults between each faulted sensor and its consumers: ``outputs[sensor]``
    (the sensor's output port) is replaced by the fault system's, which is what gets logged."""
    for sensor in sorted({sensor_of(f.kind) for f in vehicle.faults}):
        period, first_sample = sensor_schedule(vehicle, sensor)
        size = outputs[sensor].size() // n
        system = builder.AddNamedSystem(
            f"{sensor}_faults", SensorFaults(sensor, size, vehicle.faults, period, first_sample, n)
        )
        builder.Connect(outputs[sensor], system.GetInputPort(sensor))
        outputs[sensor] = system.GetOutputPort(sensor)


def _add_estimator(builder, vehicle, fidelity, outputs, seeds):
    """Add the estimator of the vehicle's n copies (``build_estimator``; n = 1 without run seeds)
    fed by the sensors in `outputs` that it has inputs for (a missing GPS or magnetometer never
    samples; a barometer feeds an estimator that fuses it, ``systems/updates.py``), with the GPS
    delay compensation when configured; its log signals go into `outputs`."""
    n = 1 if seeds is None else len(seeds)
    estimator = builder.AddSystem(build_estimator(vehicle, fidelity, n=n))
    for name in vehicle_vocabulary(vehicle).log_widths():
        outputs[name] = estimator.GetOutputPort(name)
    kinds = [kind for kind in ("imu", "gps", "mag", "baro") if estimator.HasInputPort(kind)]
    inputs = {
        kind: outputs.get(kind) or _never_sampled(builder, estimator.GetInputPort(kind).size() // n, n)
        for kind in kinds
    }
    if vehicle.gps_delay_compensation > 0:
        max_lag = vehicle.gps_delay_compensation
        compensator = builder.AddNamedSystem(
            "gps_delay_compensation",
            GpsDelayCompensator(max_lag, n),
        )
        builder.Connect(inputs["gps"], compensator.GetInputPort("gps"))
        builder.Connect(outputs["estimated_state"], compensator.GetInputPort("estimated_state"))
        inputs["gps"] = compensator.GetOutputPort("gps")
    for kind, port in inputs.items():
        builder.Connect(port, estimator.GetInputPort(kind))


def _add_wind(builder, vehicle, plant, outputs, n, add):
    """Add the vehicle's Wind (n vehicles; its turbulence noise the stream ``<vehicle>/wind``) and
    feed the plant's ``wind`` input, which exists only with drag (still air when the vehicle has no
    ``wind``); the wind goes into `outputs`."""
    if vehicle.wind is not None:
        wind = Wind(vehicle.wind, n)
        add("wind", wind, *([("noise", "wind")] if wind.HasInputPort("noise") else []))
        outputs["wind"] = wind.GetOutputPort("wind")
    if plant.HasInputPort("wind"):
        source = outputs.get("wind") or builder.AddSystem(
            ConstantVectorSource(np.zeros(3 * n))
        ).get_output_port(0)
        builder.Connect(source, plant.GetInputPort("wind"))


def _add_failsafe(builder, vehicle, trajectory, controller, plant, outputs, n):
    """Put the vehicle's FailsafeSupervisor (n vehicles) between its trajectory and its controller
    and between its controller and its plant, fed by the estimate and the estimator's diagnostics;
    its status goes into `outputs` (``failsafe``). The logged ``reference`` stays the trajectory's."""
    supervisor = builder.AddNamedSystem("failsafe", FailsafeSupervisor(vehicle.failsafe, n))
    for name in ("estimated_state", "diagnostics"):
        builder.Connect(outputs[name], supervisor.GetInputPort(name))
    builder.Connect(trajectory.GetOutputPort("reference"), supervisor.GetInputPort("reference"))
    builder.Connect(supervisor.GetOutputPort("reference"), controller.GetInputPort("reference"))
    builder.Connect(controller.GetOutputPort("motor_thrusts"), supervisor.GetInputPort("motor_thrusts"))
    builder.Connect(supervisor.GetOutputPort("motor_thrusts"), plant.GetInputPort("motor_thrusts"))
    outputs["failsafe"] = supervisor.GetOutputPort("failsafe")


def build_vehicle(vehicle, fidelity=PHYSICAL, *, seeds=None) -> Diagram:
    """The sub-Diagram of one VehicleConfig; its outputs are named as `vehicle_log_names`.

    fidelity: the scenario's :class:`~quad_drake.models.fidelity.Fidelity`, given to every system.
    seeds: None for one vehicle whose noise comes from Drake's RandomSource (seeded by the
    Diagram's ``SetRandomContext``); else N = len(seeds) copies of the vehicle flown at once,
    copy j drawing the counter-based noise streams of run seed ``seeds[j]`` (``models.random_streams``,
    named ``<vehicle name>/<noise input>``), every output N x width, vehicle-major.
    """
    n = 1 if seeds is None else len(seeds)
    builder = DiagramBuilder()

    def add(name, system, *noise_inputs):
        """Add `system` as `name`, each of its noise inputs ((port, stream name)) fed."""
        builder.AddNamedSystem(name, system)
        for port, stream in noise_inputs:
            _add_noise(builder, system, port, seeds, f"{vehicle.name}/{stream}")
        return system

    plant = add(
        "plant",
        QuadrotorPlant(vehicle.physics, initial_state(vehicle), fidelity, n),
        ("motor_noise", "motor_noise"),
    )
    controller = add("controller", CascadeController(vehicle.controller, fidelity, n))
    trajectory = add("trajectory", TrajectorySource(trajectory_from_config(vehicle.trajectory), fidelity, n))
    outputs = {name: plant.GetOutputPort(name) for name in ("state", "motor_forces", "contacts")}
    outputs["reference"] = trajectory.GetOutputPort("reference")
    _add_wind(builder, vehicle, plant, outputs, n, add)
    if fidelity.errors_at_onboard_tick:
        add_tick_holds(builder, outputs, n)

    sensors = vehicle.sensors
    if sensors.imu is not None:
        imu = Imu(sensors.imu, fidelity, n)
        bias_walk = [("bias_noise", "imu_bias")] if imu.HasInputPort("bias_noise") else []
        add("imu", imu, ("noise", "imu"), *bias_walk)
        builder.Connect(plant.GetOutputPort("state"), imu.GetInputPort("state"))
        motion = "delta_velocity" if sensors.imu.delta_velocity else "acceleration"
        builder.Connect(plant.GetOutputPort(motion), imu.GetInputPort(motion))
        outputs["imu"] = imu.GetOutputPort("imu")
        outputs["imu_saturation"] = imu.GetOutputPort("imu_saturation")
    for kind, sensor_class in (("gps", Gps), ("mag", Magnetometer)):
        params = getattr(sensors, kind)
        if params is not None:
            sensor = add(kind, sensor_class(params, fidelity, n), ("noise", kind))
            builder.Connect(plant.GetOutputPort("state"), sensor.GetInputPort("state"))
            outputs[kind] = sensor.GetOutputPort(kind)
    if sensors.baro is not None:
        baro = add("baro", Barometer(sensors.baro, vehicle.physics.z_bounds[1], n), ("noise", "baro"))
        builder.Connect(plant.GetOutputPort("state"), baro.GetInputPort("state"))
        outputs["baro"] = baro.GetOutputPort("baro")
    _add_faults(builder, vehicle, outputs, n)

    state_for_control = plant.GetOutputPort("state")
    if vehicle_vocabulary(vehicle) is not None:
        _add_estimator(builder, vehicle, fidelity, outputs, seeds)
        if flies_on_estimate(vehicle):
            state_for_control = outputs["estimated_state"]
    builder.Connect(state_for_control, controller.GetInputPort("state"))
    if vehicle.failsafe is None:
        builder.Connect(trajectory.GetOutputPort("reference"), controller.GetInputPort("reference"))
        builder.Connect(controller.GetOutputPort("motor_thrusts"), plant.GetInputPort("motor_thrusts"))
    else:
        _add_failsafe(builder, vehicle, trajectory, controller, plant, outputs, n)

    for name in vehicle_log_names(vehicle, fidelity):
        builder.ExportOutput(outputs[name], name)
    diagram = builder.Build()
    diagram.set_name(vehicle.name)
    return diagram


class SignalLog:
    """The samples of one signal: its rows of the scenario log (a VectorLog look-alike)."""

    def __init__(self, log, rows):
        self._log, self._rows = log, rows

    def sample_times(self) -> np.ndarray:
        """(n,) sample times, s."""
        return self._log.sample_times()

    def data(self) -> np.ndarray:
        """(width, n): one column per sample, as VectorLog.data()."""
        return self._log.data()[self._rows]


class SignalLogger:
    """One logged signal: an input of the scenario's log Multiplexer and its rows in the one
    5 ms VectorLogSink; ``FindLog(context)`` and ``get_input_port()`` work as on a VectorLogSink
    of that signal alone."""

    def __init__(self, sink, rows, input_port):
        self.sink, self.rows = sink, rows
        self._input_port = input_port

    def FindLog(self, context) -> SignalLog:  # noqa: N802 (VectorLogSink's name)
        return SignalLog(self.sink.FindLog(context), self.rows)

    def get_input_port(self) -> InputPort:
        return self._input_port


def build_diagram(scenario) -> tuple[Diagram, dict[str, dict[str, SignalLogger]]]:
    """(Diagram, {vehicle name: {log name: SignalLogger}}) for a ScenarioConfig.

    Vehicles are sub-Diagrams named as in the config; all their exported signals go through
    one Multiplexer (``log_signals``) into one ``LogVectorOutput`` (``logger``, LOG_PERIOD).
    """
    builder = DiagramBuilder()
    ports, rows, start = [], [], 0
    fidelity = fidelity_from_mode(scenario.fidelity)
    for vehicle in scenario.vehicles:
        sub = builder.AddSystem(build_vehicle(vehicle, fidelity))
        for name in vehicle_log_names(vehicle, fidelity):
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


def read_logs(loggers, context, n_samples) -> tuple[np.ndarray, dict[str, dict[str, np.ndarray]]]:
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


def log_samples(scenario) -> int:
    """Log samples of a run of `scenario` (at t = LOG_PERIOD k, k = 1..samples): end_time /
    LOG_PERIOD, or with ``reference_log_samples`` the binary's count, the first k whose 5 ms
    frame ends with its float32 clock at or past end_time (SPEC §0.2: 5,001 in 25 s, 8,003 in
    40 s, 201 in 1 s). A run flies until its last sample, :func:`flight_end`."""
    samples = int(round(scenario.end_time / c.LOG_PERIOD))
    if not fidelity_from_mode(scenario.fidelity).reference_log_samples:
        return samples
    steps_per_sample = int(round(c.LOG_PERIOD / c.PHYSICS_PERIOD))
    k = max(samples - 1, 0)
    while float32_clock(steps_per_sample * k) < scenario.end_time:
        k += 1
    return k


def flight_end(scenario) -> float:
    """s, the time a run of `scenario` flies to: end_time, or the time of its last log sample
    when that is later (``reference_log_samples``)."""
    return max(scenario.end_time, log_samples(scenario) * c.LOG_PERIOD)


def available_signals(scenario) -> set[str]:
    """Names of every signal the scenario's criteria may refer to."""
    names = set()
    fidelity = fidelity_from_mode(scenario.fidelity)
    for vehicle in scenario.vehicles:
        logs = empty_logs(vehicle_log_widths(vehicle, fidelity))
        names |= set(vehicle_signals(vehicle.name, logs, vehicle_vocabulary(vehicle)))
    return names


def run(scenario, progress=None) -> SimulationResult:
    """SimulationResult of a ScenarioConfig simulated for end_time s with its seed, its criteria
    evaluated (:mod:`quad_drake.output.results`). The scenario is checked first as a loaded file is
    (``config.check_scenario``, ``limits.check_run``): ConfigError, nothing flown."""
    check_scenario(scenario)
    check_run(scenario)
    check_criteria(scenario, available_signals(scenario))
    diagram, loggers = build_diagram(scenario)
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.SetRandomContext(context, RandomGenerator(scenario.seed))
    if progress is not None:
        simulator.set_monitor(_progress_monitor(progress, scenario.end_time))
    compiled = jit.compile_seconds()
    start = time.perf_counter()
    simulator.Initialize()
    simulator.AdvanceTo(flight_end(scenario))
    compile_time = jit.compile_seconds() - compiled
    wall_time = time.perf_counter() - start - compile_time

    times, logs = read_logs(loggers, context, log_samples(scenario))
    result = result_from_logs(scenario, times, logs, wall_time)
    result.compile_time = compile_time
    return result


PROGRESS_STEPS = 100
"""How often a flight calls its progress callback: every 1/PROGRESS_STEPS of end_time."""


def _progress_monitor(progress, end_time):
    """A Simulator monitor calling progress(t) (t: simulated s) about every end_time /
    PROGRESS_STEPS; it reads the time only, so the flight is the same with or without it."""
    step = end_time / PROGRESS_STEPS
    due = [step]

    def monitor(context):
        t = context.get_time()
        if t >= due[0]:
            progress(t)
            due[0] = t + step
        return EventStatus.Succeeded()

    return monitor
