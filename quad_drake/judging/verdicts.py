"""A scenario's criteria checked against its signals and judged on a run's signals.

The glue between the configuration, the named signals and the pure analyzers of
:mod:`quad_drake.judging.evaluation`: which criteria (``evaluation.judged_criteria``), which signals
they read, and one :class:`~quad_drake.judging.evaluation.CriterionResult` per criterion.
"""

from ..config.errors import ConfigError, did_you_mean
from .evaluation import CriterionResult, CriterionStream, evaluate_criterion, judged_criteria


def _signal_names(criterion, key, vehicle_names):
    """Full signal names a criterion's field refers to (a fleet criterion: one per vehicle)."""
    name = getattr(criterion, key)
    if criterion.kind == "fleet_sigma":
        return [f"{v}.{name}" for v in vehicle_names]
    return [name]


def check_criteria(scenario, available) -> None:
    """Raise ConfigError when a judged criterion names a signal not in `available` (the names
    the scenario produces, e.g. ``simulation.available_signals(scenario)``)."""
    vehicles = [v.name for v in scenario.vehicles]
    for i, criterion in enumerate(judged_criteria(scenario)):
        for key in ("signal", "ref_signal", "sigma_signal"):
            name = getattr(criterion, key)
            if name and any(n not in available for n in _signal_names(criterion, key, vehicles)):
                missing = next(n for n in _signal_names(criterion, key, vehicles) if n not in available)
                raise ConfigError(
                    f"criteria.{i}.{key}: unknown signal {name!r}{did_you_mean(missing, available)} "
                    f"(e.g. {', '.join(sorted(available)[:6])}, ...)"
                )


def evaluate_criteria(scenario, times, signals) -> list[CriterionResult]:
    """CriterionResult per judged criterion of `scenario`, on the logged 5 ms samples.

    times: (n,) s; signals: {name: Signal} over those samples.
    """
    vehicles = [v.name for v in scenario.vehicles]

    def lookup(name):
        return signals[name].values, signals[name].fresh

    return [evaluate_criterion(criterion, times, lookup, vehicles) for criterion in judged_criteria(scenario)]


class CriteriaStream:
    """The judged criteria of `scenario` for N runs, folded chunk by chunk of log samples
    (``evaluation.CriterionStream``): what a fleet batch judges while it flies."""

    def __init__(self, scenario, runs):
        vehicles = [v.name for v in scenario.vehicles]
        self._streams = [CriterionStream(c, runs, vehicles) for c in judged_criteria(scenario)]

    def update(self, times, signals) -> None:
        """Fold times (k,) s and {name: Signal} of (k, N) values and fresh masks."""

        def lookup(name):
            return signals[name].values, signals[name].fresh

        for stream in self._streams:
            stream.update(times, lookup)

    def results(self, j) -> list[CriterionResult]:
        """Run j's CriterionResult per judged criterion (as ``evaluate_criteria``'s)."""
        return [stream.result(j) for stream in self._streams]
