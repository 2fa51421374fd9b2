"""A campaign's statistics from its run records: pass rates with Clopper-Pearson intervals,
error distributions, NEES/NIS consistency against chi^2 bands, efficiency against the
tilt-aware hover Riccati bound and the posterior CRB (:mod:`quad_drake.models.accuracy_bound`)."""

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Optional

import numpy as np

from ..judging import consistency as cons
from ..judging.signals import key_unit
from ..models.accuracy_bound import accuracy_bound
from .records import campaign_vocabulary, criterion_column
from .tally import NEES, nis_statistic


def _ratio(rmse, bound):
    if bound is None:
        return None
    return rmse / bound if bound > 0 else math.inf


def per_dof_text(row) -> str:
    """``NEES/dof 1.06 [1.04, 1.08]``: a consistency row's average per dof with its 95 % interval
    (``not finite`` when a realisation diverged)."""
    low, high = row["per_dof_ci95"]
    if not math.isfinite(row["per_dof"]):
        return f"{row['statistic']}/dof not finite (a run diverged)"
    return f"{row['statistic']}/dof {row['per_dof']:.3g} [{low:.3g}, {high:.3g}]"


def tolerance_text(row) -> str:
    """``[0.667, 1.5]``: the tolerance a consistency row is judged against."""
    low, high = row["tolerance"]
    return f"[{low:.3g}, {high:.3g}]"


def distribution(values) -> dict[str, float]:
    """median, 95th percentile, max; a NaN (diverged run) counts as +inf."""
    values = np.asarray(values, dtype=float)
    values = np.where(np.isnan(values), np.inf, values)
    return {
        "median": float(np.median(values)),
        "p95": float(np.percentile(values, 95)),
        "max": float(np.max(values)),
    }


@dataclass
class CampaignResult:
    """Records of a campaign (ordered by run index), the tally of their consistency series and
    the statistics derived from them.

    A campaign stopped early (Ctrl-C) is ``partial``: its statistics are those of the
    finished runs, ``completed`` lists their indices.
    """

    scenario: object  # ScenarioConfig; its seed is the campaign's first seed S
    records: list  # slim RunRecord (``records.slim``) per finished run, by index; run i has seed S + i
    tally: object  # ConsistencyTally of the finished runs' NEES / NIS series
    wall_time: float  # s, whole campaign
    runner: str  # Runner.name
    planned: Optional[int] = None  # runs asked for (None: as many as records)
    tolerance: float = cons.COVARIANCE_TOLERANCE  # the consistency criterion's (consistency.py)
    run_command: Optional[str] = None  # flies one run alone, given its --seed

    @property
    def runs(self) -> int:
        """Number of finished runs."""
        return len(self.records)

    @property
    def partial(self) -> bool:
        return self.planned is not None and self.runs < self.planned

    @property
    def seeds(self) -> tuple[int, int]:
        """(first, last) seed of the runs asked for."""
        return self.scenario.seed, self.scenario.seed + (self.planned or self.runs) - 1

    @property
    def completed(self) -> list[int]:
        """Indices of the finished runs."""
        return [r.index for r in self.records]

    @cached_property
    def criteria(self) -> list[dict]:
        """Per judged criterion (then 'all criteria'): passes, runs, rate and 95 % interval, with
        the criterion's kind, its runs.csv column prefix (``c1``: ``c1.passed``, ``c1.measured``
        ...; ``passed`` for all criteria) and the unit of its ``measured`` column."""
        if not self.records or not self.records[0].criteria:
            return []
        shapes = [
            (c["description"], c["kind"], criterion_column(j), c["unit"])
            for j, c in enumerate(self.records[0].criteria, start=1)
        ]
        shapes.append(("all criteria", None, "passed", None))
        verdicts = [[r.criteria[j]["passed"] for r in self.records] for j in range(len(shapes) - 1)]
        verdicts.append([r.passed for r in self.records])
        rows = []
        for (label, kind, column, unit), passed in zip(shapes, verdicts, strict=True):
            k = int(sum(passed))
            rows.append(
                {
                    "criterion": label,
                    "kind": kind,
                    "column": column,
                    "measured_unit": unit,
                    "passes": k,
                    "runs": self.runs,
                    "rate": k / self.runs,
                    "ci95": list(cons.binomial_interval(k, self.runs)),
                }
            )
        return rows

    @cached_property
    def metrics(self) -> dict[str, dict]:
        """{signal without vehicle: {"unit", "rms": dist, "max": dist, "vehicles": n}}, pooled over
        vehicles (``signals.key_unit``)."""
        pooled = {}
        for name in self.records[0].metrics if self.records else ():
            vehicle, key = name.split(".", 1)
            entry = pooled.setdefault(key, {"rms": [], "max": [], "vehicles": []})
            entry["vehicles"].append(vehicle)
            for record in self.records:
                entry["rms"].append(record.metrics[name]["rms"])
                entry["max"].append(record.metrics[name]["max"])
        return {
            key: {
                "unit": key_unit(key),
                "rms": distribution(e["rms"]),
                "max": distribution(e["max"]),
                "vehicles": len(e["vehicles"]),
            }
            for key, e in pooled.items()
        }

    def settled_rms(self, key) -> list[float]:
        """Per (run, vehicle) settled RMS of the pooled metric `key` (e.g. ``Est.E.X``)."""
        return [
            r.metrics[name]["rms_settled"]
            for r in self.records
            for name in r.metrics
            if name.split(".", 1)[1] == key
        ]

    @cached_property
    def consistency(self) -> list[dict]:
        """Per statistic (NEES, then each sensor's NIS): the campaign criterion and, as
        information, the mean over all (run, vehicle) realisations against the chi^2 95 % band at
        the stamps every realisation had (``tally``).

        The criterion: the average of the statistic per degree of freedom over time and
        realisations, with its 95 % confidence interval over the realisations' own time means
        (``consistency.per_dof_interval``), must meet [1 / tolerance, tolerance]
        (``consistency.within_tolerance``). Its meaning does not change with the run count:
        more runs narrow the interval around the same average. The share of samples inside the
        band does change (the band narrows as 1/sqrt(M)), so it is shown but not judged.
        """
        sums, stats = self.tally.sums, []
        if NEES in sums:
            means = [m for r in self.records for m in r.nees_mean.values()]
            dof = campaign_vocabulary(self.scenario).nees_dof
            stats.append(self._statistic(NEES, dof, sums[NEES], means))
        for sensor, dof in cons.NIS_DOF.items():
            name = nis_statistic(sensor)
            if name in sums:
                means = [m for r in self.records for (_, s), m in r.nis_mean.items() if s == sensor]
                stats.append(self._statistic(name, dof, sums[name], means))
        return stats

    def _statistic(self, name, dof, stamp_sum, run_means):
        count = stamp_sum.count
        band = cons.chi2_band(dof, count)
        mean = stamp_sum.mean
        per_dof, low, high = cons.per_dof_interval(run_means, dof)
        return {
            "statistic": name,
            "dof": dof,
            "realisations": count,
            "per_dof": per_dof,
            "per_dof_ci95": [low, high],
            "tolerance": [1.0 / self.tolerance, self.tolerance],
            "band": list(band),
            "time_mean": float(np.mean(mean)),
            "in_band": cons.in_band_fraction(mean, band),
            "below": float(np.mean(mean < band[0])),
            "above": float(np.mean(mean > band[1])),
            "passed": cons.within_tolerance((low, high), self.tolerance),
            "times": stamp_sum.stamps,
            "mean": mean,
        }

    @cached_property
    def state_consistency(self) -> np.ndarray | None:
        """(k,) mean over runs, vehicles and time of e_i^2 / P_ii (1 = consistent), or None."""
        rows = [r.nse[v] for r in self.records for v in r.nse]
        return np.mean(rows, axis=0) if rows else None

    @cached_property
    def state_names(self) -> tuple[str, ...]:
        """Error-state names of the campaign's estimator (the order of ``state_consistency``)."""
        vocabulary = campaign_vocabulary(self.scenario)
        return () if vocabulary is None else vocabulary.state_names

    @cached_property
    def counters(self) -> dict[str, int]:
        """{diagnostics counter: total over runs and vehicles} (gated samples, resets, repairs)."""
        totals = {}
        for record in self.records:
            for vehicle_counters in record.counters.values():
                for name, count in vehicle_counters.items():
                    totals[name] = totals.get(name, 0) + count
        return totals

    @cached_property
    def efficiency(self) -> list[dict]:
        """Per vehicle and bounded state (with its unit): the hover Riccati bound sigma, the posterior
        CRB sigma (sqrt of its variance averaged over runs after the settling time), the RMSE pooled over
        runs after the settling time, and the efficiencies RMSE / bound (>= 1 up to sampling
        error and the bounds' simplifications; None where a bound does not cover the state)."""
        rows = []
        for vehicle in self.scenario.vehicles if self.records else ():
            try:
                bounds = accuracy_bound(vehicle)
            except ValueError:  # a noiseless GPS or magnetometer: no finite ratio
                bounds = {}
            pcrb = [r.pcrb[vehicle.name] for r in self.records if vehicle.name in r.pcrb]
            states = list(bounds) + [s for s in (pcrb[0] if pcrb else {}) if s not in bounds]
            for state in states:
                name = f"{vehicle.name}.Est.E.{state}"
                if name not in self.records[0].metrics:
                    continue
                rmse = math.sqrt(np.mean([r.metrics[name]["rms_settled"] ** 2 for r in self.records]))
                hover = bounds[state].mean_std if state in bounds else None
                crb = math.sqrt(np.mean([p[state] for p in pcrb])) if pcrb and state in pcrb[0] else None
                rows.append(
                    {
                        "vehicle": vehicle.name,
                        "state": state,
                        "unit": key_unit(f"Est.E.{state}"),
                        "bound_std": hover,
                        "posterior_std": bounds[state].posterior_std if state in bounds else None,
                        "pcrb_std": crb,
                        "rmse": rmse,
                        "efficiency": _ratio(rmse, hover),
                        "pcrb_efficiency": _ratio(rmse, crb),
                    }
                )
        return rows

    @property
    def passed(self) -> bool:
        """True when every campaign consistency criterion passed (or there is none)."""
        return all(s["passed"] for s in self.consistency)

    def failure_reasons(self) -> list[str]:
        """One line per failed consistency criterion, e.g.
        ``NEES/dof 1.62 [1.55, 1.70] outside [0.667, 1.5]``."""
        return [f"{per_dof_text(s)} outside {tolerance_text(s)}" for s in self.consistency if not s["passed"]]

    def verdict(self) -> str:
        """The one line that explains the exit code: which consistency criterion failed, or PASS;
        a partial campaign's says first that it judges only the runs that finished."""
        partial = f"PARTIAL ({self.runs} of {self.planned} runs, interrupted): " if self.partial else ""
        return partial + self._judgement()

    def _judgement(self):
        reasons = self.failure_reasons()
        if reasons:
            return "FAIL: " + "; ".join(reasons)
        every = [row for row in self.criteria if row["criterion"] == "all criteria"]
        rates = f" (all criteria passed in {every[0]['passes']} of {every[0]['runs']} runs)" if every else ""
        if not self.consistency:
            return f"PASS: no consistency criterion (no estimator){rates}"
        return f"PASS: every consistency criterion passed{rates}"

    def timing(self) -> dict[str, object]:
        """Wall time, runs per minute, runner and mean simulation time per run (not in the table)."""
        return {
            "wall_time_s": self.wall_time,
            "runs_per_minute": 60.0 * self.runs / self.wall_time if self.wall_time > 0 else math.nan,
            "runner": self.runner,
            "simulation_s_mean": float(np.mean([r.wall_time for r in self.records]))
            if self.records
            else math.nan,
        }
