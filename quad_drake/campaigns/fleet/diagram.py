"""Wire a scenario's fleet (N runs at once) into one Drake Diagram and fly it.

A fleet of N runs of a scenario is one Diagram: per VehicleConfig one sub-Diagram
(``simulation.build_vehicle(vehicle, fidelity, seeds=seeds)``) whose systems advance the N
copies of that vehicle, vehicle j of every group flying run seed ``seeds[j]``. Every exported
signal goes to one sink: a :class:`BatchRecorder`, which keeps the full logs at the 5 ms samples
((samples, N, width) per signal: :func:`run_fleet`, for tests and analysis), or a campaign's
``campaigns.fleet.streaming.BatchSummarizer``, which folds them into the runs' records as they are flown
(``campaigns.fleet.runner``).
"""

import time

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem

from quad_drake import conventions as c
from quad_drake.config.validation import check_scenario
from quad_drake.judging.signals import vehicle_log_widths
from quad_drake.models.fidelity import fidelity_from_mode
from quad_drake.running.limits import check_run
from quad_drake.running.simulation import build_vehicle, flight_end, log_samples


class BatchRecorder(LeafSystem):
    """Keeps its inputs at the log samples t = k LOG_PERIOD, k = 1..samples, in preallocated
    arrays: ``logs[(vehicle, name)]`` (samples, N, width). A periodic publish, as the
    per-vehicle path's ``LogVectorOutput`` (it sees the values held before the updates at t);
    the sample at t = 0 is not kept (``simulation.read_logs`` drops it too)."""

    def __init__(self, signals, n, samples):
        super().__init__()
        self.logs, self._inputs = {}, []
        for key, width in signals:
            port = self.DeclareVectorInputPort(f"{key[0]}.{key[1]}", n * width)
            self.logs[key] = np.full((samples, n, width), np.nan)
            self._inputs.append((port.Eval, self.logs[key], n, width))
        self._samples = samples
        self.recorded = 0  # samples kept so far (the last one falls past end_time when rounding says so)
        self.DeclarePeriodicPublishEvent(c.LOG_PERIOD, 0.0, self._record)

    def release_memory(self) -> dict[str, dict[str, np.ndarray]]:
        """Hand over the logs and drop every reference to them (see
        ``systems.noise.NoiseStreamSource.release_memory``)."""
        logs, self.logs, self._inputs = self.logs, None, []
        return logs

    def _record(self, context):
        k = int(round(context.get_time() / c.LOG_PERIOD))
        if 1 <= k <= self._samples:
            self.recorded = max(self.recorded, k)
            for evaluate, log, n, width in self._inputs:
                log[k - 1] = evaluate(context).reshape(n, width)


def build_fleet_diagram(scenario, seeds, make_sink=None) -> tuple[Diagram, LeafSystem]:
    """(Diagram, sink) of `scenario` flown by N = len(seeds) runs; the sink, a LeafSystem made
    by ``make_sink(signals, samples)`` (signals: ((vehicle, log name), width) per input port,
    samples: log samples of a run), takes every exported signal; default a BatchRecorder."""
    fidelity = fidelity_from_mode(scenario.fidelity)
    samples = log_samples(scenario)
    builder = DiagramBuilder()
    ports, signals = [], []
    for vehicle in scenario.vehicles:
        sub = builder.AddSystem(build_vehicle(vehicle, fidelity, seeds=seeds))
        for name, width in vehicle_log_widths(vehicle, fidelity).items():
            ports.append(sub.GetOutputPort(name))
            signals.append(((vehicle.name, name), width))
    if make_sink is None:
        sink = BatchRecorder(signals, len(seeds), samples)
    else:
        sink = make_sink(signals, samples)
    builder.AddNamedSystem("sink", sink)
    for i, port in enumerate(ports):
        builder.Connect(port, sink.get_input_port(i))
    diagram = builder.Build()
    diagram.set_name(f"{scenario.name}_fleet")
    return diagram, sink


def release_memory(diagram, keep=None) -> None:
    """Call ``release_memory()`` of every fleet system in `diagram` but `keep`: pydrake never
    frees a Diagram of Python systems, so a batch's large arrays must be dropped by hand
    (without it a campaign's workers grow by a batch's arrays per batch)."""
    for system in diagram.GetSystems():
        if isinstance(system, Diagram):
            release_memory(system, keep)
        elif hasattr(system, "release_memory") and system is not keep:
            system.release_memory()


def fly(diagram, end_time) -> float:
    """Fly a fleet Diagram from t = 0 to end_time s; the wall time it took, s."""
    simulator = Simulator(diagram)
    start = time.perf_counter()
    simulator.Initialize()
    simulator.AdvanceTo(end_time)
    return time.perf_counter() - start


def run_fleet(scenario, seeds) -> tuple[np.ndarray, dict[str, dict[str, np.ndarray]], float]:
    """(times (samples,), {vehicle: {log name: (samples, N, width)}}, wall time s) of `scenario`
    flown by the runs with seeds `seeds` (N,) for end_time s, every exported signal kept (a
    campaign never needs these logs: it summarises its batches while they fly,
    ``campaigns.fleet.streaming``). The scenario is checked as a loaded file is (``config.check_scenario``)
    and the N runs' logs must fit (``limits.check_run``): ConfigError, nothing flown."""
    check_scenario(scenario)
    check_run(scenario, at_once=len(seeds))
    diagram, recorder = build_fleet_diagram(scenario, [int(s) for s in seeds])
    wall_time = fly(diagram, flight_end(scenario))
    release_memory(diagram, keep=recorder)
    recorded = recorder.release_memory()
    samples = recorder.recorded
    logs = {vehicle.name: {} for vehicle in scenario.vehicles}
    for (vehicle, name), data in recorded.items():
        logs[vehicle][name] = data[:samples]
    return c.LOG_PERIOD * np.arange(1, samples + 1), logs, wall_time
