"""What one run of a campaign sends back: a small :class:`RunRecord`, never the logs."""

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .. import consistency as cons
from ..evaluation import max_abs, rms
from ..simulation import run

SETTLE_TIME = 5.0
"""s; ``rms_settled`` (and so the efficiency against the steady-state bound) uses the samples
from min(SETTLE_TIME, end_time / 2) on: the truth starts at the EKF's initial state, so the
error of the first seconds is smaller than in steady state."""

METRIC_STATS = ("rms", "max", "rms_settled")
ERROR_SIGNALS = tuple(f"Est.E.{name}" for name in cons.STATE_NAMES) + ("Est.E.Pos", "Est.E.Vel")
"""Per-vehicle error signals summarised for a vehicle with an estimator (PosFollowErr without)."""


def settle_time(end_time):
    """s; the start of the samples ``rms_settled`` uses."""
    return min(SETTLE_TIME, end_time / 2)


@dataclass
class RunRecord:
    """What one run sends back: verdicts, metrics and the per-sample consistency series."""

    index: int
    seed: int
    passed: bool
    criteria: list  # per judged criterion: {"kind", "description", "passed", "measured", "percent"}
    metrics: dict  # "<vehicle>.<signal>" -> {"rms", "max", "rms_settled"} (METRIC_STATS)
    nees: dict  # vehicle -> (n,) NEES at the log samples
    nse: dict  # vehicle -> (7,) time mean of e_i^2 / P_ii per EKF state
    nis: dict  # (vehicle, "gps" | "mag") -> (stamps, NIS) of the fresh updates
    wall_time: float  # s, simulation only
    times: np.ndarray = field(repr=False, default=None)  # (n,) s, log sample times


@dataclass(frozen=True)
class RunTask:
    """Run `index` of a campaign: `scenario` flown with `seed`."""

    scenario: object
    index: int
    seed: int


def summarize_run(result, index):
    """RunRecord of a SimulationResult (pure: reads its logs, signals and verdicts)."""
    metrics, nees, nse, nis = {}, {}, {}, {}
    settled = result.times >= settle_time(result.scenario.end_time) - 1e-9
    for vehicle, logs in result.logs.items():
        if "ekf_state" in logs:
            keys = ERROR_SIGNALS
            errors = cons.state_errors(logs["ekf_state"], logs["state"])
            covariances = cons.covariance_matrices(logs["covariance"])
            nees[vehicle] = cons.nees(errors, covariances)
            nse[vehicle] = np.mean(cons.normalized_squared_errors(errors, covariances), axis=0)
            for sensor in cons.NIS_DOF:
                if sensor in logs:
                    nis[(vehicle, sensor)] = cons.fresh_nis(logs["diagnostics"], sensor)
        else:
            keys = ["PosFollowErr"] if "reference" in logs else []
        for key in keys:
            values = result.signals[f"{vehicle}.{key}"].values
            metrics[f"{vehicle}.{key}"] = {
                "rms": rms(values),
                "max": max_abs(values),
                "rms_settled": rms(values[settled]),
            }
    criteria = [
        {
            "kind": c.kind,
            "description": c.description,
            "passed": bool(c.passed),
            "measured": float(c.measured),
            "percent": None if c.percent is None else float(c.percent),
        }
        for c in result.criteria
    ]
    return RunRecord(
        index,
        int(result.scenario.seed),
        bool(result.passed),
        criteria,
        metrics,
        nees,
        nse,
        nis,
        float(result.wall_time),
        np.asarray(result.times),
    )


def simulate_run(task):
    """Worker entry point: fly ``task.scenario`` with ``task.seed``; its RunRecord."""
    return summarize_run(run(dataclasses.replace(task.scenario, seed=task.seed)), task.index)
