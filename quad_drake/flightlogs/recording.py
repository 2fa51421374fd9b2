"""A simulated run as a flight log: the samples its estimator received, written as a replay CSV.

:func:`record_run` flies one vehicle of a scenario (``simulation.build_vehicle``, seeded as
``simulation.run`` seeds it) with a ZeroOrderHold on each sensor output the estimator reads,
sampling every ONBOARD_PERIOD at EKF_OFFSET: simultaneous with the estimator's own update, so it
holds exactly what the estimator read at that tick (the IMU sample of the tick, the latest GPS,
magnetometer and barometer samples, faults applied). Each hold is logged every ONBOARD_PERIOD;
the log sample at t_(k+1) holds tick k's input (a log publishes before the updates of its time).

:func:`run_csv_rows` writes them in the CSV format of ``flightlogs.reader``: ``imu`` every tick
at its tick time; each stamped sample once, at its stamp (the time it was measured), as
``gps_ned`` (the run's NED metres: no geodetic round trip), ``heading`` (a yaw magnetometer) or
``mag`` (a 3-axis one) and ``baro``; the true state every tick as ``truth`` rows. The playback
emits a sample at the first tick at or after its time with its time as its stamp, so a replay of
the CSV feeds the estimator what it read in the run, tick for tick (a delayed sample, written
later at its measurement time, is the format's open end; ``arrival_delays`` writes a sensor's
samples at their arrival instead, as a flight controller logs a delayed sensor).
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, ZeroOrderHold

from quad_drake.conventions import EKF_OFFSET, LOG_PERIOD, NO_SAMPLE_STAMP, ONBOARD_PERIOD
from quad_drake.estimation import smoother
from quad_drake.estimation.registry import KINDS, vocabulary_for
from quad_drake.estimation.vocabulary import nominal_errors
from quad_drake.flightlogs import smoothing
from quad_drake.flightlogs.reader import read_flight_log
from quad_drake.flightlogs.replay import replay_as_flown
from quad_drake.models.fidelity import fidelity_from_mode
from quad_drake.running.simulation import build_vehicle

SENSOR_ROWS = {"gps": "gps_ned", "baro": "baro"}
"""CSV kind of each stamped sensor's samples (the magnetometer's depends on its width)."""


@dataclass
class RecordedRun:
    """One vehicle's simulated run: its estimator's logs every LOG_PERIOD (times (n,) s, k >= 1)
    and, per tick k (tick_times (m,) s), the samples the estimator read (inputs: sensor -> (m,
    width)) and the true state (truth (m, 13): p, q_NB, v, w)."""

    vehicle: object  # the VehicleConfig flown
    times: np.ndarray
    logs: dict
    tick_times: np.ndarray
    inputs: dict
    truth: np.ndarray


def record_run(scenario, vehicle_index=0) -> RecordedRun:
    """RecordedRun of vehicle `vehicle_index` of a ScenarioConfig flown for its end_time with its
    seed (module docstring)."""
    vehicle = scenario.vehicles[vehicle_index]
    fidelity = fidelity_from_mode(scenario.fidelity)
    builder = DiagramBuilder()
    sub = builder.AddSystem(build_vehicle(vehicle, fidelity))
    sensors = [s for s in ("imu", "gps", "mag", "baro") if sub.HasOutputPort(s)]
    tick_sinks = {}
    for name in [*sensors, "state"]:
        port = sub.GetOutputPort(name)
        hold = builder.AddSystem(ZeroOrderHold(ONBOARD_PERIOD, port.size(), EKF_OFFSET))
        builder.Connect(port, hold.get_input_port())
        tick_sinks[name] = LogVectorOutput(hold.get_output_port(), builder, publish_period=ONBOARD_PERIOD)
    names = vocabulary_for(vehicle.estimator).log_widths()
    sinks = {
        name: LogVectorOutput(sub.GetOutputPort(name), builder, publish_period=LOG_PERIOD) for name in names
    }
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.SetRandomContext(context, RandomGenerator(scenario.seed))
    simulator.Initialize()
    simulator.AdvanceTo(scenario.end_time)
    logs = {name: sink.FindLog(context).data()[:, 1:].T.copy() for name, sink in sinks.items()}
    times = sinks[next(iter(sinks))].FindLog(context).sample_times()[1:].copy()
    ticks = {name: sink.FindLog(context).data()[:, 1:].T.copy() for name, sink in tick_sinks.items()}
    tick_times = tick_sinks["state"].FindLog(context).sample_times()[:-1].copy()  # t_k of sample k+1
    truth = ticks.pop("state")
    return RecordedRun(vehicle, times, logs, tick_times, ticks, truth)


def run_csv_rows(recorded, arrival_delays=None) -> list[str]:
    """The replay CSV rows of a RecordedRun (module docstring): header, then rows by kind.

    arrival_delays ({sensor: s}, e.g. ``{"gps": 0.1, "mag": 0.04}``): those sensors' samples are
    written at the time they reached the flight controller, their stamp plus the delay, as a
    flight controller logs a delayed sensor (the delay a replay's ``gps_delay`` etc. undoes)."""
    arrival_delays = arrival_delays or {}
    rows = ["# a simulated run: the samples its estimator received", "time,sensor,v0,v1,v2,v3,v4,v5"]
    t = recorded.tick_times
    rows += _rows("imu", t, recorded.inputs["imu"])
    for sensor in ("gps", "mag", "baro"):
        if sensor not in recorded.inputs:
            continue
        samples = recorded.inputs[sensor]
        stamps = samples[:, -1]
        fresh = (stamps != NO_SAMPLE_STAMP) & (np.diff(stamps, prepend=NO_SAMPLE_STAMP) != 0)
        kind = SENSOR_ROWS.get(sensor) or ("heading" if samples.shape[1] == 2 else "mag")
        rows += _rows(kind, stamps[fresh] + arrival_delays.get(sensor, 0.0), samples[fresh, :-1])
    state = recorded.truth
    rows += _rows("truth", t, np.column_stack([state[:, 0:3], state[:, 7:10], state[:, 3:7]]))
    return rows


def _rows(kind, times, values):
    return [
        f"{float(time)!r},{kind}," + ",".join(repr(float(v)) for v in row)
        for time, row in zip(times, values, strict=True)
    ]


def write_run_csv(recorded, path, arrival_delays=None) -> Path:
    """Write a RecordedRun as a replay CSV at `path` (arrival_delays: :func:`run_csv_rows`'s);
    the path."""
    from quad_drake.output.outdir import write_text_atomic

    write_text_atomic(path, "\n".join(run_csv_rows(recorded, arrival_delays)) + "\n")
    return path


@dataclass(frozen=True)
class SmoothedRun:
    """A simulated run smoothed: the :class:`RecordedRun`, the filter's smoothing.TickLogs replayed from
    its CSV, the stored FilterPass and the Smoothed pass; truth (T, 13) the true state at each tick
    (p, q_NB, v, w, the ``state`` layout)."""

    recorded: object
    ticks: smoothing.TickLogs
    filtered: object  # smoother.FilterPass
    smoothed: object  # smoother.Smoothed

    @property
    def truth(self) -> np.ndarray:
        return self.recorded.truth[: self.filtered.x_updated.shape[0]]


def smooth_run(scenario, directory, vehicle_index=0) -> SmoothedRun:
    """Fly vehicle `vehicle_index` of a ScenarioConfig with an ESKF (:func:`record_run`), write
    it as a replay CSV into `directory`, replay it through the same estimator tick by tick and
    smooth that pass. Raises AssertionError if the replay's estimate is not the run's (to 1e-9)."""
    recorded = record_run(scenario, vehicle_index)
    log = read_flight_log(write_run_csv(recorded, Path(directory) / f"{scenario.name or 'run'}.csv"))
    times, logs, ticks = replay_as_flown(log, recorded.vehicle, ticks=True)
    m = len(times)
    for name in ("estimated_state", "covariance"):
        np.testing.assert_allclose(logs[name], recorded.logs[name][:m], rtol=0, atol=1e-9)
    filtered = smoothing.eskf_pass(ticks, recorded.vehicle.estimator)
    return SmoothedRun(recorded, ticks, filtered, smoother.smooth_eskf(filtered))


def smooth_vehicles(result, directory) -> list[str]:
    """Smooth each ESKF vehicle of a ``SimulationResult`` IN PLACE (``quad-drake run --smooth``):
    its run flown again as a log into `directory` (:func:`smooth_run`; the estimate checked equal to
    the run's to 1e-9), ``smoothed_state`` (16) and ``smoothed_sigma`` (n) added to its logs at the
    log times; one printed line per vehicle (position RMSE and NEES per dof against the truth)."""
    lines = []
    scenario = result.scenario
    for index, vehicle in enumerate(scenario.vehicles):
        if vehicle.estimator is None or not KINDS[vehicle.estimator.kind].smoothable:
            lines.append(f"{vehicle.name}: not smoothed (the smoother runs over the ESKF only)")
            continue
        run = smooth_run(scenario, directory, index)
        logs = result.logs[vehicle.name]
        m = min(len(run.recorded.times), len(result.times))
        np.testing.assert_allclose(
            run.recorded.logs["estimated_state"][:m], logs["estimated_state"][:m], rtol=0, atol=1e-9
        )
        logs.update(smoothing.smoothed_logs(run.ticks, run.smoothed, result.times))
        n = run.filtered.P_updated.shape[1]
        stats = []
        for x, P in ((run.filtered.x_updated, run.filtered.P_updated), (run.smoothed.x, run.smoothed.P)):
            e = nominal_errors(x, run.truth, n)
            nees = np.einsum("ti,ti->t", e, np.linalg.solve(P, e[:, :, None])[:, :, 0])
            stats.append((float(np.sqrt(np.mean(np.sum(e[:, 0:3] ** 2, axis=1)))), float(np.mean(nees)) / n))
        (rmse_f, nees_f), (rmse_s, nees_s) = stats
        lines.append(
            f"{vehicle.name}: RTS smoother position RMSE {rmse_s:.3f} m against the filter's {rmse_f:.3f} m "
            f"(ratio {rmse_s / rmse_f:.2f}); NEES per dof {nees_s:.2f} (filter {nees_f:.2f}), every 2 ms tick"
        )
    return lines
