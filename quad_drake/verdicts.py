"""A scenario's criteria checked against its signals and judged on a run's signals.

The glue between the configuration, the named signals and the pure analyzers of
:mod:`quad_drake.evaluation`: which criteria (``evaluation.judged_criteria``), which signals
they read, and one :class:`~quad_drake.evaluation.CriterionResult` per criterion.
"""

from .config import ConfigError
from .evaluation import evaluate_criterion, fleet_sigma_threshold, judged_criteria


def _signal_names(criterion, key, vehicle_names):
    """Full signal names a criterion's field refers to (a fleet criterion: one per vehicle)."""
    name = getattr(criterion, key)
    if criterion.kind == "fleet_sigma":
        return [f"{v}.{name}" for v in vehicle_names]
    return [name]


def check_criteria(scenario, available):
    """Raise ConfigError when a judged criterion names a signal not in `available` (the names
    the scenario produces, e.g. ``simulation.available_signals(scenario)``)."""
    vehicles = [v.name for v in scenario.vehicles]
    for i, criterion in enumerate(judged_criteria(scenario)):
        for key in ("signal", "ref_signal", "sigma_signal"):
            name = getattr(criterion, key)
            if name and any(n not in available for n in _signal_names(criterion, key, vehicles)):
                raise ConfigError(
                    f"criteria.{i}.{key}: unknown signal {name!r} "
                    f"(e.g. {', '.join(sorted(available)[:6])}, ...)"
                )


def evaluate_criteria(scenario, times, signals):
    """CriterionResult per judged criterion of `scenario`, on the logged 5 ms samples.

    times: (n,) s; signals: {name: Signal} over those samples.
    """

    def lookup(name):
        return signals[name].values, signals[name].fresh

    results = []
    for criterion in judged_criteria(scenario):
        if criterion.kind == "fleet_sigma":
            from .consistency import fleet_samples  # lazily: it imports scipy.stats (~1 s)

            errors, sigmas = fleet_samples(signals, criterion.signal, criterion.sigma_signal)
            results.append(
                fleet_sigma_threshold(
                    errors,
                    sigmas,
                    criterion.signal,
                    criterion.sigma_signal,
                    criterion.sigma_multiple,
                    criterion.min_percent,
                    criterion.max_percent,
                )
            )
        else:
            results.append(evaluate_criterion(criterion, times, lookup))
    return results
