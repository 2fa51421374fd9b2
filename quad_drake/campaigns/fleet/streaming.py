"""A fleet batch summarised while it flies: the Drake sink of a campaign's fleet Diagram.

A :class:`BatchSummarizer` takes the place of the recorder (``campaigns.fleet.diagram``): it keeps
the exported signals of the last :data:`~quad_drake.campaigns.fleet.summaries.CHUNK_SAMPLES` log samples
(and the one before them) in reused buffers and, each time the chunk fills, hands it to a
:class:`~quad_drake.campaigns.fleet.summaries.BatchSummary`, which folds it into the runs' records.
"""

import numpy as np
from pydrake.systems.framework import LeafSystem

from quad_drake import conventions as c
from quad_drake.campaigns.fleet.summaries import CHUNK_SAMPLES, BatchSummary
from quad_drake.campaigns.records import RunRecord


class BatchSummarizer(LeafSystem):
    """Folds its inputs at the log samples t = k LOG_PERIOD, k = 1..samples, into a
    :class:`BatchSummary`, a chunk of CHUNK_SAMPLES at a time. A periodic publish, as the
    recorder's (it sees the values held before the updates at t); the sample at t = 0 is not
    judged (``simulation.read_logs`` drops it too). signals: ((vehicle, log name), width) per
    input, in port order."""

    def __init__(self, scenario, seeds, signals, samples, chunk=CHUNK_SAMPLES):
        super().__init__()
        n = len(seeds)
        log_names = {}
        self._inputs, self._buffers = [], {}
        for (vehicle, name), width in signals:
            port = self.DeclareVectorInputPort(f"{vehicle}.{name}", n * width)
            buffer = np.empty((chunk + 1, n, width))  # row 0: the sample before the chunk
            self._buffers.setdefault(vehicle, {})[name] = buffer
            self._inputs.append((port.EvalBasicVector, buffer, n, width))
            log_names.setdefault(vehicle, []).append(name)
        self.summary = BatchSummary(scenario, seeds, samples, log_names)
        self._samples, self._chunk = samples, chunk
        self._rows, self._last_k = 0, 0  # rows of the chunk filled; last sample taken
        self.DeclarePeriodicPublishEvent(c.LOG_PERIOD, 0.0, self._record)

    def _record(self, context):
        k = int(round(context.get_time() / c.LOG_PERIOD))
        if not 1 <= k <= self._samples or k <= self._last_k:
            return
        self._last_k = k
        self._rows += 1
        for evaluate, buffer, n, width in self._inputs:  # a view of the port's value, copied once
            buffer[self._rows] = evaluate(context).get_value().reshape(n, width)
        if self._rows == self._chunk:
            self._flush()

    def _flush(self):
        if self._rows == 0:
            return
        has_previous = self.summary.samples > 0
        start = 0 if has_previous else 1
        self.summary.update(
            {
                v: {name: b[start : self._rows + 1] for name, b in logs.items()}
                for v, logs in self._buffers.items()
            },
            has_previous,
        )
        for logs in self._buffers.values():
            for buffer in logs.values():
                buffer[0] = buffer[self._rows]
        self._rows = 0

    def records(self, first_index, wall_time) -> list[RunRecord]:
        """Fold what the chunk holds; the RunRecord of each run (``BatchSummary.records``)."""
        self._flush()
        return self.summary.records(first_index, wall_time)

    def release_memory(self) -> None:
        """Drop the chunk buffers and the summary (see ``systems.noise.NoiseStreamSource.release_memory``)."""
        self._buffers, self._inputs, self.summary = {}, [], None
