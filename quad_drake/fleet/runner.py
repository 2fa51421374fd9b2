"""Fleet batches as campaign tasks: B runs flown at once, sent back as B RunRecords.

A :class:`FleetBatch` is a task like ``campaigns.records.RunTask``, for any campaign
Runner (in-process, process pool, Dask): its worker flies the batch's runs as one fleet
(``fleet.simulation.run_fleet``) and summarises them with the per-vehicle path's functions,
so every verdict and statistic follows the one rule of its kind: the signals
(``results.signals_from_logs``), the NEES and normalised squared errors
(``campaigns.records.consistency_series``) and the PCRB (``fleet.bounds``) of the N runs at
once, since those functions take a batch's (samples, N, width) logs as well as one run's;
then per run its criteria (``verdicts.evaluate_criteria``) and its record
(``campaigns.records.summarize_run``: metrics, NIS, counters), from its rows of those.
``tests/test_fleet_summaries.py`` checks the records against the per-run functions on each
run's slice of the logs to 1e-12. Only the records leave the worker; the batch's logs, its
memory (``simulation.batch_bytes``), are freed with it.
"""

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from quad_drake.campaigns.records import consistency_series, summarize_run, vehicle_errors
from quad_drake.estimation.vocabulary import vehicle_vocabulary
from quad_drake.fleet.bounds import posterior_crbs
from quad_drake.fleet.simulation import batch_bytes, run_fleet
from quad_drake.results import SimulationResult, signals_from_logs
from quad_drake.signals import Signal, stamp_fresh
from quad_drake.verdicts import evaluate_criteria

RUNNER = "drake-fleet"
"""What produced a fleet run (a run summary's ``runner``), as ``results.RUNNER`` for the per-vehicle path."""
BATCH_MEMORY = 3 << 28
"""Bytes of logs a default batch may hold (768 MiB): the batch size is chosen to stay below it.
Summarising a batch holds about 1.6x its logs at the peak, so a worker stays near 1.5 GiB with
its code, and a campaign on two workers under 4 GB whatever its number of runs."""
MAX_BATCH = 1000
"""Runs of a default batch at most (beyond it a tick's cost no longer falls per vehicle)."""


@dataclass(frozen=True)
class FleetBatch:
    """Runs first_index .. first_index + len(seeds) - 1 of a campaign, run first_index + j with seeds[j]."""

    scenario: object
    first_index: int
    seeds: tuple


def default_batch_size(scenario, runs, jobs=1):
    """Runs per batch: as many as BATCH_MEMORY and MAX_BATCH allow, split evenly over `jobs`
    workers when the campaign is smaller than jobs full batches."""
    per_run = max(1, batch_bytes(scenario, 1))
    size = max(1, min(MAX_BATCH, BATCH_MEMORY // per_run))
    return max(1, min(size, math.ceil(runs / jobs)))


def batches(scenario, runs, first_seed, batch_size):
    """The FleetBatch tasks of `runs` runs, run i with seed first_seed + i, `batch_size` per batch."""
    return [
        FleetBatch(
            scenario, start, tuple(range(first_seed + start, first_seed + min(runs, start + batch_size)))
        )
        for start in range(0, runs, batch_size)
    ]


def batch_logs(logs, j):
    """{vehicle: {log name: (samples, width)}} of run j of a batch's logs (samples, N, width)."""
    return {
        vehicle: {name: data[:, j, :] for name, data in vehicle_logs.items()}
        for vehicle, vehicle_logs in logs.items()
    }


def batch_bounds(scenario, logs):
    """{vehicle: {state: (n, N) PCRB variance}} of the batch's vehicles whose runs
    ``summarize_run`` gives a PCRB (an estimator and a GPS), computed for the N runs at once."""
    bounds = {}
    for vehicle in scenario.vehicles:
        vehicle_logs = logs[vehicle.name]
        if vehicle_vocabulary(vehicle) is None or "gps" not in vehicle_logs:
            continue
        gps = stamp_fresh(vehicle_logs["gps"][:, :, -1])
        mag = stamp_fresh(vehicle_logs["mag"][:, :, -1]) if "mag" in vehicle_logs else np.zeros_like(gps)
        bounds[vehicle.name] = posterior_crbs(vehicle_logs["state"], gps, mag, vehicle.sensors)
    return bounds


def batch_consistency(scenario, logs, signals):
    """{vehicle: (NEES (n, N), NSE means (N, k))}: ``records.consistency_series`` of the batch's
    vehicles with an estimator, for the N runs at once; signals: the batch's (n, N) signals."""
    series = {}
    for vehicle in scenario.vehicles:
        vocabulary = vehicle_vocabulary(vehicle)
        if vocabulary is not None:
            errors = vehicle_errors(signals, vehicle.name, vocabulary)
            series[vehicle.name] = consistency_series(vocabulary, logs[vehicle.name], errors)
    return series


class _Rows:
    """Run j's slice of a batch's arrays (samples first, runs second), from one contiguous copy
    with the runs first, made on first use: a column of the batch would be read with a stride
    of N samples (a cache miss per sample), once per use and per run."""

    def __init__(self):
        self._copies = {}

    def __call__(self, array, j):
        key = id(array)
        if key not in self._copies:  # the array is kept with its copy, so that its id stays its own
            self._copies[key] = (array, np.ascontiguousarray(np.swapaxes(np.ascontiguousarray(array), 0, 1)))
        return self._copies[key][1][j]


class _RunView(Mapping):
    """{name: run j's value} of a batch's {name: batch value}, each made on first use by `make`."""

    def __init__(self, batch, make):
        self._batch, self._make, self._made = batch, make, {}

    def __getitem__(self, name):
        if name not in self._made:
            self._made[name] = self._make(self._batch[name])
        return self._made[name]

    def __contains__(self, name):
        return name in self._batch

    def __iter__(self):
        return iter(self._batch)

    def __len__(self):
        return len(self._batch)


def simulate_batch(task):
    """Worker entry point: fly a FleetBatch; the RunRecord of each of its runs, by index."""
    return summarize_batch(task, *run_fleet(task.scenario, task.seeds))


def summarize_batch(task, times, logs, wall_time):
    """The RunRecord of each run of a flown FleetBatch (``run_fleet``'s times, logs, wall time).

    The signals, NEES, normalised squared errors and PCRB of the batch are computed for its N
    runs at once by the per-run functions (which take (n, N, width) logs); each run's criteria
    and record are then made from its rows, by the per-vehicle path's functions.
    """
    signals = signals_from_logs(logs, task.scenario)
    consistency = batch_consistency(task.scenario, logs, signals)
    bounds = batch_bounds(task.scenario, logs)
    row = _Rows()
    records = []
    for j, seed in enumerate(task.seeds):
        scenario = dataclasses.replace(task.scenario, seed=seed)
        run_signals = _RunView(signals, lambda s, j=j: Signal(row(s.values, j), row(s.fresh, j)))
        run_logs = {v: _RunView(vehicle_logs, lambda x, j=j: row(x, j)) for v, vehicle_logs in logs.items()}
        result = SimulationResult(
            scenario,
            times,
            run_logs,
            run_signals,
            evaluate_criteria(scenario, times, run_signals),
            wall_time / len(task.seeds),
            RUNNER,
        )
        run_bounds = {v: {k: row(b, j) for k, b in states.items()} for v, states in bounds.items()}
        run_consistency = {v: (row(nees, j), nse[j]) for v, (nees, nse) in consistency.items()}
        records.append(summarize_run(result, task.first_index + j, run_bounds, run_consistency))
    return records
