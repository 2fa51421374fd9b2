"""What one run of a campaign sends back: a small :class:`RunRecord`, never the logs."""

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from ..estimation.registry import nis_sensors, vehicle_vocabulary
from ..estimation.vocabulary import EstimatorVocabulary, health_counts
from ..judging import consistency as cons
from ..judging.evaluation import max_abs, rms
from ..judging.signals import stamp_fresh
from ..models.accuracy_bound import posterior_crb
from ..running.simulation import run

SETTLE_TIME = 5.0
"""s; ``rms_settled`` (and so the efficiency against the steady-state bound) uses the samples
from min(SETTLE_TIME, end_time / 2) on: the truth starts at the EKF's initial state, so the
error of the first seconds is smaller than in steady state."""

METRIC_STATS = ("rms", "max", "rms_settled")
COMMON_ERRORS = ("X", "Y", "Z", "VX", "VY", "VZ", "Roll", "Pitch", "Yaw", "Pos", "Vel")
"""Error signals every estimator has (``Est.E.<key>``), besides its vocabulary's."""


def error_keys(vocabulary) -> list[str]:
    """The keys of the ``Est.E.<key>`` signals a campaign summarises for this estimator, in order:
    COMMON_ERRORS, then its vocabulary's other states (their units: ``signals.key_unit``)."""
    return list(dict.fromkeys((*COMMON_ERRORS, *vocabulary.state_names)))


def campaign_vocabulary(scenario) -> EstimatorVocabulary | None:
    """The estimator vocabulary of the scenario's first vehicle with an estimator, or None."""
    return next((v for v in map(vehicle_vocabulary, scenario.vehicles) if v is not None), None)


def settle_time(end_time) -> float:
    """s; the start of the samples ``rms_settled`` uses."""
    return min(SETTLE_TIME, end_time / 2)


def settled_mask(times, end_time) -> np.ndarray:
    """True at the log samples (times, s) ``rms_settled`` and the PCRB average use."""
    return np.asarray(times) >= settle_time(end_time) - 1e-9


@dataclass
class RunRecord:
    """What one run sends back: verdicts, metrics and the per-sample consistency series.

    A campaign keeps the :func:`slim` record: the series (nees, nis, times) folded into its
    ``tally.ConsistencyTally`` and replaced by their time means (nees_mean, nis_mean).
    """

    index: int
    seed: int
    passed: bool
    criteria: list  # per judged criterion: {"kind", "description", "passed", "measured", "unit", "percent"}
    metrics: dict  # "<vehicle>.<signal>" -> {"rms", "max", "rms_settled"} (METRIC_STATS)
    nees: dict  # vehicle -> (n,) NEES at the log samples; {} in a slim record
    nse: dict  # vehicle -> (k,) time mean of e_i^2 / P_ii per error state of its vocabulary
    nis: dict  # (vehicle, "gps" | "mag") -> (stamps, NIS) of the fresh updates; {} in a slim record
    wall_time: float  # s, simulation only
    times: np.ndarray = field(repr=False, default=None)  # (n,) s, log sample times; None in a slim record
    counters: dict = field(default_factory=dict)  # vehicle -> {diagnostics counter: final count}
    pcrb: dict = field(default_factory=dict)  # vehicle -> {state: PCRB variance averaged after settling}
    nees_mean: dict = field(default_factory=dict)  # vehicle -> time mean of its NEES (slim record)
    nis_mean: dict = field(default_factory=dict)  # (vehicle, sensor) -> mean of its NIS (slim record)


def _time_mean(values) -> float:
    """The mean of a statistic's samples; NaN where a NaN sample is among them or there are none
    (a flight too short for any fresh update of that sensor: not a warning, no samples to judge)."""
    return float(np.mean(values)) if len(values) else math.nan


def slim(record) -> RunRecord:
    """The RunRecord a campaign keeps: no per-sample series, their time means instead (a NaN
    sample makes its mean NaN, and so does a series without samples)."""
    return dataclasses.replace(
        record,
        nees={},
        nis={},
        times=None,
        nees_mean={vehicle: _time_mean(values) for vehicle, values in record.nees.items()},
        nis_mean={key: _time_mean(values) for key, (_, values) in record.nis.items()},
    )


@dataclass(frozen=True)
class RunTask:
    """Run `index` of a campaign: `scenario` flown with `seed`."""

    scenario: object
    index: int
    seed: int


def vehicle_errors(signals, vehicle, vocabulary) -> np.ndarray:
    """(n, k) ``vocabulary.errors`` of a vehicle's logs, as its ``Est.E.<state>`` signals hold them
    ((n, N, k) of a fleet batch's (n, N) signals)."""
    return np.stack([signals[f"{vehicle}.Est.E.{key}"].values for key in vocabulary.state_names], axis=-1)


def consistency_series(vocabulary, logs, errors) -> tuple[np.ndarray, np.ndarray]:
    """(NEES (n,), time mean (k,) of e_i^2 / P_ii) of a vehicle's logs (n, width) and errors (n, k)."""
    covariances = cons.covariance_matrices(logs["covariance"])
    nse = np.mean(cons.normalized_squared_errors(errors, covariances), axis=0)
    return cons.nees_of(vocabulary, logs, errors), nse


def _posterior_crb(logs, sensors):
    """``accuracy_bound.posterior_crb`` along a vehicle's logged truth, fusing its logged GPS and
    magnetometer samples."""
    no_mag = np.zeros(logs["state"].shape[0], dtype=bool)
    mag_fresh = stamp_fresh(logs["mag"][:, -1]) if "mag" in logs else no_mag
    return posterior_crb(logs["state"], stamp_fresh(logs["gps"][:, -1]), mag_fresh, sensors)


def metric_keys(vocabulary, log_names) -> list[str]:
    """The signals (``V.<key>``) a run's record summarises for a vehicle with estimator
    `vocabulary` (None: none) and logs `log_names`: its ``Est.E.*`` errors, and PosFollowErr
    (the true flight) when it has a reference."""
    keys = [] if vocabulary is None else [f"Est.E.{key}" for key in error_keys(vocabulary)]
    return keys + (["PosFollowErr"] if "reference" in log_names else [])


def criterion_column(number) -> str:
    """The runs.csv column prefix of a campaign's judged criterion `number` (1, 2, ...): ``c1``
    for ``c1.passed``, ``c1.measured`` and ``c1.percent``."""
    return f"c{number}"


def criteria_rows(verdicts) -> list[dict]:
    """A record's ``criteria``: per CriterionResult its kind, description, verdict, measured
    value (and its unit) and percentage, as plain values."""
    return [
        {
            "kind": c.kind,
            "description": c.description,
            "passed": bool(c.passed),
            "measured": float(c.measured),
            "unit": c.measured_unit,
            "percent": None if c.percent is None else float(c.percent),
        }
        for c in verdicts
    ]


def summarize_run(result, index) -> RunRecord:
    """RunRecord of a SimulationResult (pure: reads its logs, signals and verdicts). A fleet
    batch makes the same records while it flies (``fleet.streaming``)."""
    metrics, nees, nse, nis, counters, pcrb = {}, {}, {}, {}, {}, {}
    settled = settled_mask(result.times, result.scenario.end_time)
    configs = {v.name: v for v in result.scenario.vehicles}
    for vehicle, logs in result.logs.items():
        vocabulary = vehicle_vocabulary(configs[vehicle])
        if vocabulary is not None:
            nees[vehicle], nse[vehicle] = consistency_series(
                vocabulary, logs, vehicle_errors(result.signals, vehicle, vocabulary)
            )
            for sensor in nis_sensors(configs[vehicle]):
                nis[(vehicle, sensor)] = cons.fresh_nis(logs["diagnostics"], sensor)
            counters[vehicle] = health_counts(logs["diagnostics"])
            if "gps" in logs and settled.any():
                bound = _posterior_crb(logs, configs[vehicle].sensors)
                pcrb[vehicle] = {name: float(np.mean(v[settled])) for name, v in bound.items()}
        for key in metric_keys(vocabulary, logs):
            values = result.signals[f"{vehicle}.{key}"].values
            metrics[f"{vehicle}.{key}"] = {
                "rms": rms(values),
                "max": max_abs(values),
                "rms_settled": rms(values[settled]),
            }
    return RunRecord(
        index,
        int(result.scenario.seed),
        bool(result.passed),
        criteria_rows(result.criteria),
        metrics,
        nees,
        nse,
        nis,
        float(result.wall_time),
        times=np.asarray(result.times),
        counters=counters,
        pcrb=pcrb,
    )


def simulate_run(task) -> RunRecord:
    """Worker entry point: fly ``task.scenario`` with ``task.seed``; its RunRecord."""
    return summarize_run(run(dataclasses.replace(task.scenario, seed=task.seed)), task.index)
