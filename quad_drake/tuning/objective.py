"""Pure: the loss ``quad-drake tune`` minimises, from a campaign's statistics.

Every number comes from :class:`~quad_drake.campaigns.statistics.CampaignResult` (its
``consistency`` series, ``efficiency`` rows and ``criteria`` pass rates) and the chi^2 band of
:func:`quad_drake.judging.consistency.chi2_band`: one place for each rule.

- **consistency**: per statistic (NEES, NIS gps, NIS mag) the share of samples whose
  run-averaged value lies *outside* the 95 % band that a campaign of ``target_runs`` runs is
  judged by (the held-out campaign's), plus the mean log-distance to that band (0 inside it:
  a smooth term that still ranks candidates whose averages all sit outside); averaged over
  the statistics. A consistent filter scores about 0.05-0.15.
- **accuracy**: the mean over bounded states of RMSE / bound - 1 (the posterior CRB where a run
  has it, else the hover Riccati bound): 0 for an efficient filter.
- **both**: their sum.

A candidate with any run failing any criterion is infeasible: INFEASIBLE + (share of failed
runs) is added, more than any feasible loss, so the search ranks every feasible candidate
first and, among infeasible ones, those that fail fewer runs.
"""

import math
from dataclasses import dataclass

import numpy as np

from ..judging import consistency as cons
from .settings import OBJECTIVES

INFEASIBLE = 100.0
"""Added to the loss of a candidate with a failed run (larger than any feasible loss)."""
NONFINITE_DISTANCE = 10.0
"""Log-distance to the band counted for a non-finite run-averaged statistic (a broken filter)."""
NONFINITE_RATIO = 100.0
"""RMSE / bound counted for a non-finite RMSE (a diverged run)."""


@dataclass(frozen=True)
class Score:
    """A candidate's loss and its parts, from one campaign."""

    loss: float
    consistency: float  # see the module docstring (computed whatever the objective)
    accuracy: float
    pass_rate: float  # share of runs passing every criterion
    in_band: dict  # statistic -> share of samples inside the target band

    @property
    def feasible(self) -> bool:
        return self.pass_rate == 1.0


def breakdown_score() -> Score:
    """Score of a candidate whose campaign broke down numerically (worse than any failing run)."""
    return Score(2 * INFEASIBLE + 1.0, math.nan, math.nan, 0.0, {})


def band_distance(values, band) -> float:
    """Mean over samples of max(0, ln(low / v), ln(v / high)): 0 inside the band."""
    values = np.asarray(values, dtype=float)
    low, high = band
    usable = np.isfinite(values) & (values > 0)
    safe = np.where(usable, values, 1.0)
    distance = np.maximum(0.0, np.maximum(np.log(low / safe), np.log(safe / high)))
    return float(np.mean(np.where(usable, distance, NONFINITE_DISTANCE)))


def consistency_loss(statistics, runs, target_runs) -> tuple[float, dict[str, float]]:
    """(loss, {statistic: in-band share}) of a campaign's ``consistency`` rows of `runs` runs
    against the bands of a campaign of `target_runs` runs (the same realisations per run)."""
    if not statistics:
        return 0.0, {}
    losses, in_band = [], {}
    for s in statistics:
        realisations = max(1, round(s["realisations"] * target_runs / runs))
        band = cons.chi2_band(s["dof"], realisations)
        in_band[s["statistic"]] = cons.in_band_fraction(s["mean"], band)
        losses.append(1.0 - in_band[s["statistic"]] + band_distance(s["mean"], band))
    return float(np.mean(losses)), in_band


def efficiency_ratio(row) -> float:
    """The RMSE / bound of an ``efficiency`` row the objective uses: PCRB where present, else hover."""
    return row["pcrb_efficiency"] if row["pcrb_efficiency"] is not None else row["efficiency"]


def accuracy_loss(efficiency) -> float:
    """Mean over the bounded states of RMSE / bound - 1 (NaN when no state is bounded)."""
    ratios = [efficiency_ratio(r) for r in efficiency if efficiency_ratio(r) is not None]
    if not ratios:
        return math.nan
    ratios = [r if math.isfinite(r) else NONFINITE_RATIO for r in ratios]
    return float(np.mean(ratios)) - 1.0


def pass_rate(criteria) -> float:
    """Share of runs passing every criterion, from a campaign's ``criteria`` rows (1 without any)."""
    rows = [r for r in criteria if r["criterion"] == "all criteria"]
    return rows[0]["rate"] if rows else 1.0


def score(campaign, objective, target_runs) -> Score:
    """Score of a CampaignResult under `objective` (OBJECTIVES); bands of `target_runs` runs."""
    if objective not in OBJECTIVES:
        raise ValueError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
    consistency, in_band = consistency_loss(campaign.consistency, campaign.runs, target_runs)
    accuracy = accuracy_loss(campaign.efficiency)
    rate = pass_rate(campaign.criteria)
    loss = {"consistency": consistency, "accuracy": accuracy, "both": consistency + accuracy}[objective]
    if rate < 1.0:
        loss += INFEASIBLE + (1.0 - rate)
    return Score(float(loss), consistency, accuracy, rate, in_band)
