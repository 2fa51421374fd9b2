"""A fleet batch's RunRecords folded chunk by chunk of log samples, without its full logs. Pure.

:class:`BatchSummary` takes N runs' exported signals a chunk of samples at a time (with the
sample before the chunk) and keeps what each run's
:class:`~quad_drake.campaigns.records.RunRecord` needs, with the per-vehicle path's own rules:

- the named signals (``results.signals_from_logs`` on the chunk and its previous sample, so
  a sensor's freshness is judged against the sample before, as on a whole log);
- the verdicts (``verdicts.CriteriaStream``: the analyzers' folds);
- the RMS / max errors (sums of squares and maxima per run), the NEES per sample and the
  time means of e^2/P (``consistency``), the fresh NIS values, the estimator's counters (its
  last sample) and the posterior CRB (``kernels.bounds.PcrbStream``, its covariance carried).

What it holds grows with the runs' length only by a few numbers per sample and run (the NEES,
the fresh NIS): :func:`summary_bytes`. ``campaigns.fleet.streaming.BatchSummarizer`` feeds it while a
batch flies; ``tests/test_fleet_summaries.py`` checks its records against the per-run
functions on each run's full logs to 1e-12, for any chunk size.
"""

import numpy as np

from quad_drake import conventions as c
from quad_drake.campaigns.records import (
    RunRecord,
    criteria_rows,
    metric_keys,
    settled_mask,
    vehicle_errors,
)
from quad_drake.estimation.registry import nis_sensors, vehicle_vocabulary
from quad_drake.estimation.vocabulary import NIS_COLUMNS, health_counts
from quad_drake.judging import consistency as cons
from quad_drake.judging.signals import vehicle_log_widths
from quad_drake.judging.verdicts import CriteriaStream
from quad_drake.kernels.bounds import PcrbStream
from quad_drake.models.fidelity import fidelity_from_mode
from quad_drake.output.results import signals_from_logs
from quad_drake.running.simulation import log_samples, sensor_schedule

CHUNK_SAMPLES = 200
"""Log samples per chunk (1 s of flight)."""


def summary_bytes(scenario, runs, chunk=CHUNK_SAMPLES) -> int:
    """Bytes a batch of `runs` runs of `scenario` holds while it is summarised, to within the
    small per-run sums: the chunk of every exported signal (chunk + 1 samples), and per run
    its NEES at each sample and the stamp and NIS of each fresh GPS or magnetometer update."""
    samples = log_samples(scenario)
    per_run = 0
    fidelity = fidelity_from_mode(scenario.fidelity)
    for vehicle in scenario.vehicles:
        per_run += 8 * (chunk + 1) * sum(vehicle_log_widths(vehicle, fidelity).values())
        if vehicle_vocabulary(vehicle) is not None:
            per_run += 8 * samples
            for sensor in ("gps", "mag", "baro"):
                if getattr(vehicle.sensors, sensor) is not None:
                    period = sensor_schedule(vehicle, sensor)[0]
                    per_run += 16 * min(samples, int(scenario.end_time / period) + 1)
    return runs * per_run


def _run_major(values):
    """A (k, N, ...) array of k samples as a contiguous (N, ..., k) copy: a run's samples are
    one contiguous row, which numpy sums pairwise. So a sum over them has the same rounding
    whatever N (numpy reduces a (k, 1) column pairwise but a (k, N) array row by row), and run
    i's record does not depend on its batch."""
    return np.ascontiguousarray(np.moveaxis(values, 0, -1))


def _sum_over_samples(values):
    """Sum over the samples (axis 0) of a (k, N, ...) array, run by run (:func:`_run_major`)."""
    return _run_major(values).sum(axis=-1)


class _VehicleSums:
    """One vehicle's running sums over N runs (see :class:`BatchSummary`)."""

    def __init__(self, vehicle, log_names, runs, samples, settle):
        self.name, self.settle = vehicle.name, settle
        self.vocabulary = vehicle_vocabulary(vehicle)
        self.metric_keys = metric_keys(self.vocabulary, log_names)
        self.square_sums = {key: np.zeros(runs) for key in self.metric_keys}
        self.settled_square_sums = {key: np.zeros(runs) for key in self.metric_keys}
        self.maxima = {key: np.full(runs, -np.inf) for key in self.metric_keys}
        self.nees = self.nse_sums = self.pcrb = self.pcrb_sums = None
        self.nis, self.last_diagnostics = {}, None
        self._bound_rows = 0  # samples whose PCRB has been added
        if self.vocabulary is not None:
            self.nees = np.empty((runs, samples))  # run-major: a run's series is a contiguous row
            self.nse_sums = np.zeros((runs, self.vocabulary.size))
            self.nis = {s: [[] for _ in range(runs)] for s in nis_sensors(vehicle)}
            if "gps" in log_names:
                self.pcrb = PcrbStream(vehicle.sensors, runs)

    def update(self, first, times, logs, signals, unsettled):
        """Fold samples first .. first + k - 1 at times (k,) s: logs {name: (k, N, w)}, the
        vehicle's signals {name: Signal (k, N)}; the first `unsettled` samples come before
        the settling time, the others after it."""
        for key in self.metric_keys:
            values = _run_major(signals[f"{self.name}.{key}"].values)
            squares = values * values
            self.square_sums[key] += squares.sum(axis=-1)
            self.settled_square_sums[key] += squares[:, unsettled:].sum(axis=-1)
            self.maxima[key] = np.maximum(self.maxima[key], np.abs(values).max(axis=-1))
        if self.vocabulary is None:
            return
        errors = vehicle_errors(signals, self.name, self.vocabulary)
        covariances = cons.covariance_matrices(logs["covariance"])
        self.nees[:, first : first + times.size] = cons.nees_of(self.vocabulary, logs, errors).T
        self.nse_sums += _sum_over_samples(cons.normalized_squared_errors(errors, covariances))
        self.last_diagnostics = logs["diagnostics"][-1].copy()  # the chunk's buffer is reused
        diagnostics = logs["diagnostics"]
        for sensor, per_run in self.nis.items():
            nis_column, stamp_column = NIS_COLUMNS[sensor]
            fresh = signals[f"{self.name}.Est.{sensor.capitalize()}NIS"].fresh
            for j, run in enumerate(per_run):
                rows = fresh[:, j]
                if rows.any():
                    run.append((diagnostics[rows, j, stamp_column], diagnostics[rows, j, nis_column]))
        if self.pcrb is not None:
            mag = signals[f"{self.name}.MagYaw"].fresh if f"{self.name}.MagYaw" in signals else None
            gps = signals[f"{self.name}.GPS.X"].fresh
            self._add_bound(self.pcrb.update(logs["state"], gps, np.zeros_like(gps) if mag is None else mag))

    def _add_bound(self, variances):
        """Add the settled samples of a PcrbStream output (its rows follow the last ones added)."""
        done, rows = self._bound_rows, next(iter(variances.values())).shape[0]
        settled = self.settle[done : done + rows]
        if self.pcrb_sums is None:
            self.pcrb_sums = {name: np.zeros(v.shape[1]) for name, v in variances.items()}
        for name, v in variances.items():
            self.pcrb_sums[name] += _sum_over_samples(v[settled])
        self._bound_rows = done + rows

    def finish(self):
        if self.pcrb is not None:
            self._add_bound(self.pcrb.finish())

    def record_fields(self, j, samples):
        """Run j's share of the record: (metrics, nees, nse, nis, counters, pcrb) dicts."""
        count, settled = samples, int(np.count_nonzero(self.settle[:samples]))
        with np.errstate(invalid="ignore", divide="ignore"):
            metrics = {
                f"{self.name}.{key}": {
                    "rms": float(np.sqrt(self.square_sums[key][j] / count)),
                    "max": float(self.maxima[key][j]),
                    "rms_settled": float(np.sqrt(self.settled_square_sums[key][j] / settled)),
                }
                for key in self.metric_keys
            }
        if self.vocabulary is None:
            return metrics, {}, {}, {}, {}, {}
        nis = {}
        for sensor, per_run in self.nis.items():
            parts = per_run[j]
            nis[(self.name, sensor)] = (
                (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))
                if parts
                else (np.zeros(0), np.zeros(0))
            )
        pcrb = {}
        if self.pcrb is not None and settled:
            pcrb[self.name] = {name: float(s[j] / settled) for name, s in self.pcrb_sums.items()}
        return (
            metrics,
            {self.name: self.nees[j, :samples]},
            {self.name: self.nse_sums[j] / count},
            nis,
            {self.name: health_counts(self.last_diagnostics[j][None] if samples else np.zeros((0, 1)))},
            pcrb,
        )


class BatchSummary:
    """The RunRecords of a fleet batch's N runs, folded chunk by chunk of log samples. Pure.

    scenario: the batch's ScenarioConfig; seeds: (N,) run seeds; samples: log samples a run
    has at most; log_names: {vehicle: the names of its exported logs}.
    """

    def __init__(self, scenario, seeds, samples, log_names):
        self.scenario, self.seeds = scenario, tuple(int(s) for s in seeds)
        runs = len(self.seeds)
        self.times = c.LOG_PERIOD * np.arange(1, samples + 1)
        settle = settled_mask(self.times, scenario.end_time)
        self._vehicles = [
            _VehicleSums(v, log_names[v.name], runs, samples, settle) for v in scenario.vehicles
        ]
        self._settle = settle
        self._criteria = CriteriaStream(scenario, runs)
        self.samples = 0  # samples folded so far

    def update(self, logs, has_previous) -> None:
        """Fold the next k samples: logs {vehicle: {name: (k (+1), N, w)}}; with has_previous,
        row 0 of every log is the sample before them (only used to judge freshness)."""
        skip = 1 if has_previous else 0
        k = next(iter(next(iter(logs.values())).values())).shape[0] - skip
        if k <= 0:
            return
        signals = signals_from_logs(logs, self.scenario).from_sample(skip)
        first = self.samples
        times = self.times[first : first + k]
        unsettled = int(np.count_nonzero(~self._settle[first : first + k]))  # the times increase
        self._criteria.update(times, signals)
        for vehicle in self._vehicles:
            vehicle_logs = {name: log[skip:] for name, log in logs[vehicle.name].items()}
            vehicle.update(first, times, vehicle_logs, signals, unsettled)
        self.samples += k

    def records(self, first_index, wall_time) -> list[RunRecord]:
        """The RunRecord of each run, index first_index + j (wall_time: the batch's, s, shared evenly)."""
        for vehicle in self._vehicles:
            vehicle.finish()
        records = []
        for j, seed in enumerate(self.seeds):
            fields = [{} for _ in range(6)]
            for vehicle in self._vehicles:
                for merged, part in zip(fields, vehicle.record_fields(j, self.samples), strict=True):
                    merged.update(part)
            metrics, nees, nse, nis, counters, pcrb = fields
            verdicts = self._criteria.results(j)
            records.append(
                RunRecord(
                    first_index + j,
                    seed,
                    all(v.passed for v in verdicts),
                    criteria_rows(verdicts),
                    metrics,
                    nees,
                    nse,
                    nis,
                    wall_time / len(self.seeds),
                    times=self.times[: self.samples],  # one array for all the runs
                    counters=counters,
                    pcrb=pcrb,
                )
            )
        return records


def summarize_logs(scenario, seeds, logs, chunk=CHUNK_SAMPLES) -> BatchSummary:
    """A BatchSummary of full logs {vehicle: {name: (n, N, w)}} fed `chunk` samples at a time
    (what a BatchSummarizer does while the batch flies); for tests and benchmarks."""
    n = next(iter(next(iter(logs.values())).values())).shape[0]
    summary = BatchSummary(scenario, seeds, n, {vehicle: list(x) for vehicle, x in logs.items()})
    for start in range(0, n, chunk):
        first = max(start - 1, 0)
        part = {v: {name: x[first : start + chunk] for name, x in vl.items()} for v, vl in logs.items()}
        summary.update(part, start > 0)
    return summary
