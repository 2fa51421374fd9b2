"""Fleet batches as campaign tasks: B runs flown at once, sent back as B RunRecords.

A :class:`BatchTask` is a task like ``campaigns.records.RunTask``, for any campaign
Runner (in-process, process pool, Dask): its worker flies the batch's runs as one fleet
whose sink, a ``fleet.streaming.BatchSummarizer``, folds the exported signals into each
run's record while it flies, with the per-vehicle path's rules (signals, verdicts, errors,
NEES/NIS, counters, PCRB). No full log is ever kept: a batch holds a chunk of its logs and a
few numbers per sample and run (``fleet.summaries.summary_bytes``), and only slim records and
the tally of their series leave the worker.
"""

import math
from dataclasses import dataclass

import numpy as np

from quad_drake.campaigns.fleet.diagram import build_fleet_diagram, fly, release_memory
from quad_drake.campaigns.fleet.streaming import BatchSummarizer
from quad_drake.campaigns.fleet.summaries import summary_bytes
from quad_drake.campaigns.records import RunRecord
from quad_drake.campaigns.tally import FoldedRecords, fold_records
from quad_drake.running.simulation import flight_end

MAX_BATCH = 1000
"""Runs of a default batch at most (beyond it a tick's cost no longer falls per vehicle)."""
BATCH_MEMORY = 1 << 29
"""Bytes a default batch's summaries may hold (512 MiB, ``fleet.summaries.summary_bytes``): 1000
runs of 11 hold 0.27 GiB; a batch of 11 flown for 600 s is cut to 241 runs."""


@dataclass(frozen=True)
class BatchTask:
    """Runs first_index .. first_index + len(seeds) - 1 of a campaign, run first_index + j with seeds[j]."""

    scenario: object
    first_index: int
    seeds: tuple


def default_batch_size(scenario, runs, jobs=1) -> int:
    """Runs per batch: at most what MAX_BATCH and BATCH_MEMORY allow, and the runs split evenly
    over the fewest rounds of `jobs` batches that hold them, so that no worker idles through a
    last round the others fly (3000 runs on 2 workers: 4 batches of 750, not 3 of 1000)."""
    size = max(1, min(MAX_BATCH, BATCH_MEMORY // max(1, summary_bytes(scenario, 1))))
    rounds = math.ceil(math.ceil(runs / size) / jobs)
    return max(1, math.ceil(runs / (rounds * jobs)))


def batches(scenario, runs, first_seed, batch_size) -> list[BatchTask]:
    """The BatchTask tasks of `runs` runs, run i with seed first_seed + i, `batch_size` per batch."""
    return [
        BatchTask(
            scenario, start, tuple(range(first_seed + start, first_seed + min(runs, start + batch_size)))
        )
        for start in range(0, runs, batch_size)
    ]


def batch_logs(logs, j) -> dict[str, dict[str, np.ndarray]]:
    """{vehicle: {log name: (samples, width)}} of run j of a batch's logs (samples, N, width)."""
    return {
        vehicle: {name: data[:, j, :] for name, data in vehicle_logs.items()}
        for vehicle, vehicle_logs in logs.items()
    }


def fly_batch(task) -> list[RunRecord]:
    """Fly a BatchTask, summarised while it flies; the full RunRecord of each of its runs
    (with its NEES and NIS series), by index."""
    diagram, summarizer = build_fleet_diagram(
        task.scenario,
        [int(seed) for seed in task.seeds],
        lambda signals, samples: BatchSummarizer(task.scenario, task.seeds, signals, samples),
    )
    wall_time = fly(diagram, flight_end(task.scenario))
    release_memory(diagram, keep=summarizer)
    records = summarizer.records(task.first_index, wall_time)
    summarizer.release_memory()
    return records


def simulate_batch(task) -> FoldedRecords:
    """Worker entry point: :func:`fly_batch`, sent back as slim records and the tally of their
    series (``campaigns.tally.FoldedRecords``): a batch of 1000 runs of 11 sends about 2 MB,
    not the 120 MB of its series."""
    return fold_records(fly_batch(task))
