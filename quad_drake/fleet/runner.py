"""Fleet batches as campaign tasks: B runs flown at once, sent back as B RunRecords.

A :class:`FleetBatch` is a task like ``campaigns.records.RunTask``, for any campaign
Runner (in-process, process pool, Dask): its worker flies the batch's runs as one fleet
whose sink, a ``fleet.streaming.FleetSummarizer``, folds the exported signals into each
run's record while it flies, with the per-vehicle path's rules (signals, verdicts, errors,
NEES/NIS, counters, PCRB). Only the records leave the worker; no full log is ever kept, so
a batch's memory is bounded by its size times a chunk of samples, not by its length.
"""

import math
from dataclasses import dataclass

from quad_drake.campaigns.tally import fold_records
from quad_drake.fleet.simulation import build_fleet_diagram, fly, release_memory
from quad_drake.fleet.streaming import FleetSummarizer

RUNNER = "drake-fleet"
"""What produced a fleet run (a run summary's ``runner``), as ``results.RUNNER`` for the per-vehicle path."""
MAX_BATCH = 1000
"""Runs of a default batch at most (beyond it a tick's cost no longer falls per vehicle)."""


@dataclass(frozen=True)
class FleetBatch:
    """Runs first_index .. first_index + len(seeds) - 1 of a campaign, run first_index + j with seeds[j]."""

    scenario: object
    first_index: int
    seeds: tuple


def default_batch_size(runs, jobs=1):
    """Runs per batch: MAX_BATCH, split evenly over `jobs` workers when the campaign is
    smaller than jobs full batches."""
    return max(1, min(MAX_BATCH, math.ceil(runs / jobs)))


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


def fly_batch(task):
    """Fly a FleetBatch, summarised while it flies; the full RunRecord of each of its runs
    (with its NEES and NIS series), by index."""
    diagram, summarizer = build_fleet_diagram(
        task.scenario,
        list(task.seeds),
        lambda signals, samples: FleetSummarizer(task.scenario, task.seeds, signals, samples),
    )
    wall_time = fly(diagram, task.scenario.end_time)
    release_memory(diagram, keep=summarizer)
    records = summarizer.records(task.first_index, wall_time)
    summarizer.release_memory()
    return records


def simulate_batch(task):
    """Worker entry point: :func:`fly_batch`, sent back as slim records and the tally of their
    series (``campaigns.tally.FoldedRecords``): a batch of 1000 runs of 11 sends about 2 MB,
    not the 120 MB of its series."""
    return fold_records(fly_batch(task))
