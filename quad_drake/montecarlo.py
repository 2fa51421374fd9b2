"""Monte Carlo campaigns: N seeded runs of a scenario, in parallel, with statistics.

Run i uses seed S + i, so any run reproduces alone with ``quad-drake run NAME --seed S+i``.
Runs execute in worker processes (``spawn``: one Drake simulation per process, since
Python systems cannot run in parallel in one process), in-process for one job, or on a
Dask cluster (``scheduler`` address; the ``cluster`` extra). Workers return a small
:class:`RunRecord` (verdicts, error metrics, per-sample NEES/NIS), never the logs; records
are ordered by run index, so the statistics do not depend on the number of jobs.

The campaign reports, per scenario criterion, the pass rate with a 95 % Clopper-Pearson
interval; median / 95th percentile / max over runs of the RMS and max of each error
signal; the mean NEES (7 dof) and NIS (GPS 6, magnetometer 1 dof) over runs against their
chi^2 95 % bands, with the share of time inside the band as a campaign criterion; and,
where the sensors allow, the RMS error over the steady-state Kalman bound per state
(:mod:`quad_drake.accuracy_bound`).
"""

import csv
import dataclasses
import json
import math
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from . import consistency as cons
from .accuracy_bound import accuracy_bound
from .config import ConfigError

MIN_IN_BAND = 0.8
"""Campaign criterion: share of samples whose run-averaged NEES/NIS lies inside its 95 %
chi^2 band. A consistent filter sits inside 95 % of the time on average; 0.8 leaves room
for the strong time correlation of the averaged statistic (see tests/test_consistency.py)."""

SETTLE_TIME = 5.0
"""s; ``rms_settled`` (and so the efficiency against the steady-state bound) uses the samples
from min(SETTLE_TIME, end_time / 2) on: the truth starts at the EKF's initial state, so the
error of the first seconds is smaller than in steady state."""

METRIC_STATS = ("rms", "max", "rms_settled")

ERROR_KEYS = ("X", "Y", "Z", "VX", "VY", "VZ", "Yaw", "Pos", "Vel")
UNITS = {
    "X": "m",
    "Y": "m",
    "Z": "m",
    "VX": "m/s",
    "VY": "m/s",
    "VZ": "m/s",
    "Yaw": "rad",
    "Pos": "m",
    "Vel": "m/s",
    "PosFollowErr": "m",
}


@dataclass
class RunRecord:
    """What one run sends back: verdicts, metrics and the per-sample consistency series."""

    index: int
    seed: int
    passed: bool
    criteria: list  # per scenario criterion: {"passed", "measured", "percent"}
    metrics: dict  # "<vehicle>.<signal>" -> {"rms", "max", "rms_settled"} (METRIC_STATS)
    nees: dict  # vehicle -> (n,) NEES at the log samples
    nse: dict  # vehicle -> (7,) time mean of e_i^2 / P_ii per EKF state
    nis: dict  # (vehicle, "gps" | "mag") -> (stamps, NIS) of the fresh updates
    wall_time: float  # s, simulation only
    times: np.ndarray = field(repr=False, default=None)  # (n,) s, log sample times


def summarize_run(result, index):
    """RunRecord of a SimulationResult (pure: reads its logs, signals and verdicts)."""
    from .evaluation import max_abs, rms

    metrics, nees, nse, nis = {}, {}, {}, {}
    settled = result.times >= min(SETTLE_TIME, result.scenario.end_time / 2) - 1e-9
    for vehicle, logs in result.logs.items():
        if "ekf_state" in logs:
            keys = [f"Est.E.{key}" for key in ERROR_KEYS]
            errors = cons.state_errors(logs["ekf_state"], logs["state"])
            covariances = cons.covariance_matrices(logs["covariance"])
            nees[vehicle] = cons.nees(errors, covariances)
            nse[vehicle] = np.mean(cons.normalized_squared_errors(errors, covariances), axis=0)
            for sensor in ("gps", "mag"):
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


def simulate_run(scenario, index, seed):
    """Worker entry point: run `scenario` with `seed`, return its RunRecord."""
    from .simulation import run

    return summarize_run(run(dataclasses.replace(scenario, seed=seed)), index)


# ----- running ----------------------------------------------------------------


class _Progress:
    """One stderr line, rewritten in place: done/total, a bar, elapsed time and ETA."""

    def __init__(self, label, total, enabled):
        self.label, self.total, self.enabled = label, total, enabled
        self.start = time.perf_counter()
        self.failed = 0

    def update(self, done, record):
        self.failed += not record.passed
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.start
        eta = elapsed / done * (self.total - done)
        filled = int(round(30 * done / self.total))
        sys.stderr.write(
            f"\r{self.label}: [{'#' * filled}{'.' * (30 - filled)}] {done}/{self.total} runs, "
            f"{self.failed} failed, {elapsed:.0f} s, ETA {eta:.0f} s "
        )
        if done == self.total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def _failure(scenario, index, seed, error):
    return RuntimeError(
        f"run {index} (seed {seed}) failed: {error!r}; reproduce with "
        f"quad-drake run {scenario.name} --seed {seed}"
    )


def _run_local(scenario, seeds, jobs, progress):
    records = [None] * len(seeds)
    if jobs == 1:
        for i, seed in enumerate(seeds):
            try:
                records[i] = simulate_run(scenario, i, seed)
            except Exception as e:
                raise _failure(scenario, i, seed, e) from e
            progress.update(i + 1, records[i])
        return records
    executor = ProcessPoolExecutor(
        max_workers=min(jobs, len(seeds)), mp_context=multiprocessing.get_context("spawn")
    )
    try:
        futures = {executor.submit(simulate_run, scenario, i, seed): i for i, seed in enumerate(seeds)}
        for done, future in enumerate(as_completed(futures), start=1):
            i = futures[future]
            try:
                records[i] = future.result()
            except BrokenProcessPool:  # a worker died (e.g. a script without a main guard)
                raise
            except Exception as e:
                raise _failure(scenario, i, seeds[i], e) from e
            progress.update(done, records[i])
    finally:
        executor.shutdown(wait=True, cancel_futures=True)
    return records


def _run_dask(scenario, seeds, scheduler, progress):
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:
        raise ConfigError("--scheduler needs dask: pip install 'quad_drake[cluster]'") from None
    records = [None] * len(seeds)
    try:
        client = Client(scheduler, set_as_default=False)
    except (OSError, ValueError, TypeError) as e:
        raise ConfigError(f"--scheduler {scheduler}: cannot connect ({e})") from None
    with client:
        futures = client.map(simulate_run, [scenario] * len(seeds), range(len(seeds)), seeds, pure=False)
        index = {future.key: i for i, future in enumerate(futures)}
        try:
            for done, future in enumerate(dask_completed(futures, loop=client.loop), start=1):
                i = index[future.key]
                try:
                    records[i] = future.result()
                except Exception as e:
                    raise _failure(scenario, i, seeds[i], e) from e
                progress.update(done, records[i])
        finally:
            client.cancel([f for f in futures if not f.done()])
    return records


def run_campaign(scenario, runs, jobs=1, seed=None, scheduler=None, progress=True):
    """CampaignResult of `runs` runs of a ScenarioConfig, run i with seed (seed or scenario.seed) + i.

    jobs: worker processes (1: in this process). scheduler: a Dask scheduler address
    (e.g. ``tcp://host:8786``); then `jobs` is ignored and the cluster's workers run the
    runs (start them with one thread each). progress: a progress line on stderr.
    A failing run raises RuntimeError naming its seed.
    """
    if runs < 1:
        raise ConfigError(f"montecarlo: --runs must be >= 1, got {runs}")
    if jobs < 1:
        raise ConfigError(f"montecarlo: --jobs must be >= 1, got {jobs}")
    first = scenario.seed if seed is None else seed
    if first < 0:
        raise ConfigError(f"montecarlo: --seed must be >= 0, got {first}")
    from .simulation import check_criteria

    check_criteria(scenario)
    seeds = [first + i for i in range(runs)]
    bar = _Progress(scenario.name, runs, progress)
    start = time.perf_counter()
    if scheduler:
        records = _run_dask(scenario, seeds, scheduler, bar)
    else:
        records = _run_local(scenario, seeds, jobs, bar)
    return CampaignResult(
        dataclasses.replace(scenario, seed=first),
        records,
        time.perf_counter() - start,
        "dask" if scheduler else jobs,
    )


# ----- statistics -------------------------------------------------------------


def criterion_label(criterion):
    """Short description of a CriterionConfig for tables."""
    kind, signal = criterion.kind, criterion.signal
    if kind == "window":
        return f"|{signal}| < {criterion.threshold:g} for > {criterion.window:g} s"
    if kind == "sigma":
        ref = criterion.ref_signal or f"{criterion.ref:g}"
        sigma = criterion.sigma_signal or f"{criterion.sigma:g}"
        return (
            f"|{signal} - {ref}| <= {sigma}: {criterion.min_percent:g}-{criterion.max_percent:g} % "
            f"(last {criterion.window:g} s)"
        )
    if kind == "fleet_sigma":
        return (
            f"fleet |{signal}| <= {criterion.sigma_multiple:g} {criterion.sigma_signal}: "
            f"{criterion.min_percent:g}-{criterion.max_percent:g} %"
        )
    return f"{kind} {signal}"


def _distribution(values):
    """median, 95th percentile, max; a NaN (diverged run) counts as +inf."""
    values = np.asarray(values, dtype=float)
    values = np.where(np.isnan(values), np.inf, values)
    return {
        "median": float(np.median(values)),
        "p95": float(np.percentile(values, 95)),
        "max": float(np.max(values)),
    }


def _json_ready(value):
    """Nested dicts/lists of plain Python values; non-finite floats become None."""
    if isinstance(value, dict):
        return {str(k): _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    return value


@dataclass
class CampaignResult:
    """Records of a campaign (ordered by run index) and the statistics derived from them."""

    scenario: object  # ScenarioConfig; its seed is the campaign's first seed S
    records: list  # RunRecord per run, run i has seed S + i
    wall_time: float  # s, whole campaign
    jobs: object  # worker processes, or "dask"
    min_in_band: float = MIN_IN_BAND

    @property
    def runs(self):
        return len(self.records)

    @cached_property
    def criteria(self):
        """Per scenario criterion (then 'all criteria'): passes, rate and 95 % interval."""
        labels = [criterion_label(c) for c in self.scenario.criteria]
        verdicts = [[r.criteria[j]["passed"] for r in self.records] for j in range(len(labels))]
        if labels:
            labels.append("all criteria")
            verdicts.append([r.passed for r in self.records])
        rows = []
        for label, passed in zip(labels, verdicts, strict=True):
            k = int(sum(passed))
            rows.append(
                {
                    "criterion": label,
                    "passes": k,
                    "runs": self.runs,
                    "rate": k / self.runs,
                    "ci95": list(cons.binomial_interval(k, self.runs)),
                }
            )
        return rows

    @cached_property
    def metrics(self):
        """{signal without vehicle: {"rms": dist, "max": dist, "vehicles": n}}, pooled over vehicles."""
        pooled = {}
        for name in self.records[0].metrics:
            vehicle, key = name.split(".", 1)
            entry = pooled.setdefault(key, {"rms": [], "max": [], "vehicles": []})
            entry["vehicles"].append(vehicle)
            for record in self.records:
                entry["rms"].append(record.metrics[name]["rms"])
                entry["max"].append(record.metrics[name]["max"])
        return {
            key: {
                "rms": _distribution(e["rms"]),
                "max": _distribution(e["max"]),
                "vehicles": len(e["vehicles"]),
            }
            for key, e in pooled.items()
        }

    @cached_property
    def consistency(self):
        """Mean NEES / NIS over all (run, vehicle) realisations against the chi^2 95 % band."""
        stats = []
        first = self.records[0]
        if first.nees:
            series = np.vstack([r.nees[v] for r in self.records for v in r.nees])
            stats.append(self._statistic("NEES", 7, first.times, series))
        for sensor in ("gps", "mag"):
            series = [r.nis[key] for r in self.records for key in r.nis if key[1] == sensor]
            if series:
                stamps, values = cons.stack_by_stamp(series)
                stats.append(self._statistic(f"NIS {sensor}", cons.NIS_DOF[sensor], stamps, values))
        return stats

    def _statistic(self, name, dof, times, values):
        count = values.shape[0]
        band = cons.chi2_band(dof, count)
        mean = values.mean(axis=0)
        fraction = cons.in_band_fraction(mean, band)
        return {
            "statistic": name,
            "dof": dof,
            "realisations": count,
            "band": list(band),
            "time_mean": float(np.mean(mean)),
            "in_band": fraction,
            "below": float(np.mean(mean < band[0])),
            "above": float(np.mean(mean > band[1])),
            "passed": bool(fraction >= self.min_in_band),
            "times": np.asarray(times),
            "mean": mean,
        }

    @cached_property
    def state_consistency(self):
        """(7,) mean over runs, vehicles and time of e_i^2 / P_ii (1 = consistent), or None."""
        rows = [r.nse[v] for r in self.records for v in r.nse]
        return np.mean(rows, axis=0) if rows else None

    @cached_property
    def efficiency(self):
        """Per vehicle and bounded state: bound sigma, RMSE pooled over runs after the settling
        time (SETTLE_TIME), and efficiency = RMSE / bound (>= 1 up to sampling error and the
        bound's simplifications)."""
        rows = []
        for vehicle in self.scenario.vehicles:
            try:
                bounds = accuracy_bound(vehicle)
            except ValueError:  # a noiseless GPS or magnetometer: no finite ratio
                continue
            for state, bound in bounds.items():
                name = f"{vehicle.name}.Est.E.{state}"
                if name not in self.records[0].metrics:
                    continue
                rmse = math.sqrt(np.mean([r.metrics[name]["rms_settled"] ** 2 for r in self.records]))
                rows.append(
                    {
                        "vehicle": vehicle.name,
                        "state": state,
                        "bound_std": bound.mean_std,
                        "posterior_std": bound.posterior_std,
                        "rmse": rmse,
                        "efficiency": rmse / bound.mean_std if bound.mean_std > 0 else math.inf,
                    }
                )
        return rows

    @property
    def passed(self):
        """True when every campaign consistency criterion passed (or there is none)."""
        return all(s["passed"] for s in self.consistency)

    def failure_reasons(self):
        """One phrase per failed campaign consistency test (empty when :attr:`passed`)."""
        return [
            f"{s['statistic']} mean inside its chi2 95% band {100 * s['in_band']:.1f}% of the time, "
            f"needs >= {100 * self.min_in_band:.0f}%"
            for s in self.consistency
            if not s["passed"]
        ]

    def table(self):
        """The campaign's statistics as text; identical for the same scenario, runs and seed."""
        s = self.scenario
        lines = [
            f"Monte Carlo {s.name}: {self.runs} runs of {s.end_time:g} s, "
            f"seeds {s.seed}..{s.seed + self.runs - 1}",
            "",
        ]
        if self.criteria:
            lines.append(f"{'criterion':58s} {'passes':>9s} {'rate':>7s}  95% CI")
            for row in self.criteria:
                low, high = row["ci95"]
                lines.append(
                    f"{row['criterion'][:58]:58s} {row['passes']:4d}/{row['runs']:<4d} "
                    f"{100 * row['rate']:6.1f}%  [{100 * low:5.1f}, {100 * high:5.1f}]"
                )
            lines.append("")
        if self.metrics:
            lines.append(
                f"{'error signal':24s} {'RMS: median':>12s} {'p95':>8s} {'max':>8s}   "
                f"{'MAX: median':>11s} {'p95':>8s} {'max':>8s}"
            )
            for key, m in self.metrics.items():
                label = f"{key} [{UNITS.get(key.rsplit('.', 1)[-1], '')}]"
                label += f" x{m['vehicles']}" if m["vehicles"] > 1 else ""
                r, x = m["rms"], m["max"]
                lines.append(
                    f"{label:24s} {r['median']:12.4f} {r['p95']:8.4f} {r['max']:8.4f}   "
                    f"{x['median']:11.4f} {x['p95']:8.4f} {x['max']:8.4f}"
                )
            lines.append("")
        if self.consistency:
            lines.append(
                "consistency: mean over M realisations (runs x vehicles) vs its chi2 95% band; "
                f"criterion: in band >= {100 * self.min_in_band:.0f}% of the samples"
            )
            lines.append(
                f"{'statistic':10s} {'dof':>3s} {'M':>5s} {'band':>17s} {'time mean':>10s} "
                f"{'in band':>8s} {'below':>6s} {'above':>6s}  result"
            )
            for c in self.consistency:
                band = f"[{c['band'][0]:.3g}, {c['band'][1]:.3g}]"
                lines.append(
                    f"{c['statistic']:10s} {c['dof']:3d} {c['realisations']:5d} {band:>17s} "
                    f"{c['time_mean']:10.3f} {100 * c['in_band']:7.1f}% {100 * c['below']:5.1f}% "
                    f"{100 * c['above']:5.1f}%  {'PASS' if c['passed'] else 'FAIL'}"
                )
            if self.state_consistency is not None:
                lines.append(
                    "per state, mean e^2/P (1 = consistent): "
                    + "  ".join(
                        f"{n} {v:.3g}" for n, v in zip(cons.STATE_NAMES, self.state_consistency, strict=True)
                    )
                )
            lines.append("")
        if self.efficiency:
            lines.append(
                "accuracy bound: steady-state Kalman sigma with the true sensor noise "
                f"(time-averaged); RMSE from t >= {min(SETTLE_TIME, s.end_time / 2):g} s; "
                "efficiency = RMSE / bound"
            )
            lines.append(f"{'state':18s} {'bound':>9s} {'RMSE':>9s} {'efficiency':>11s}")
            for e in self.efficiency:
                label = f"{e['vehicle']}.{e['state']} [{UNITS[e['state']]}]"
                lines.append(f"{label:18s} {e['bound_std']:9.4f} {e['rmse']:9.4f} {e['efficiency']:11.2f}")
        return "\n".join(lines).rstrip() + "\n"

    def timing(self):
        """Wall time, runs per minute, jobs and mean simulation time per run (not in the table)."""
        return {
            "wall_time_s": self.wall_time,
            "runs_per_minute": 60.0 * self.runs / self.wall_time,
            "jobs": self.jobs,
            "simulation_s_mean": float(np.mean([r.wall_time for r in self.records])),
        }

    def timing_line(self):
        t = self.timing()
        return (
            f"{self.runs} runs in {t['wall_time_s']:.1f} s with {t['jobs']} job(s): "
            f"{t['runs_per_minute']:.1f} runs/min ({t['simulation_s_mean']:.2f} s simulation per run)"
        )

    def summary(self):
        """JSON-ready dict of every statistic (without the consistency series) and the timing."""
        consistency = [{k: v for k, v in c.items() if k not in ("times", "mean")} for c in self.consistency]
        state = self.state_consistency
        state = None if state is None else dict(zip(cons.STATE_NAMES, state.tolist(), strict=True))
        return _json_ready(
            {
                "scenario": self.scenario.name,
                "runs": self.runs,
                "first_seed": self.scenario.seed,
                "end_time": self.scenario.end_time,
                "criteria": self.criteria,
                "metrics": self.metrics,
                "consistency": consistency,
                "min_in_band": self.min_in_band,
                "state_consistency": state,
                "efficiency": self.efficiency,
                "consistency_passed": self.passed,
                "timing": self.timing(),
            }
        )

    def rows(self):
        """(header, rows) of the per-run CSV: seed, verdicts, metrics, NEES/NIS time means."""
        header = ["run", "seed", "passed"]
        for j, criterion in enumerate(self.scenario.criteria, start=1):
            header += [f"c{j}.passed", f"c{j}.measured"]
            header += [f"c{j}.percent"] if criterion.kind == "sigma" else []
        first = self.records[0]
        header += [f"{name}.{stat}" for name in first.metrics for stat in METRIC_STATS]
        header += [f"{v}.NEES.mean" for v in first.nees]
        header += [f"{v}.NIS.{sensor}.mean" for v, sensor in first.nis]
        rows = []
        for r in self.records:
            row = [r.index, r.seed, int(r.passed)]
            for criterion, verdict in zip(self.scenario.criteria, r.criteria, strict=True):
                row += [int(verdict["passed"]), verdict["measured"]]
                row += [verdict["percent"]] if criterion.kind == "sigma" else []
            row += [r.metrics[name][stat] for name in first.metrics for stat in METRIC_STATS]
            row += [float(np.mean(r.nees[v])) for v in first.nees]
            row += [float(np.mean(r.nis[key][1])) for key in first.nis]
            rows.append([repr(float(x)) if isinstance(x, float) else x for x in row])
        return header, rows

    def save(self, out_dir, plots=True):
        """Write runs.csv, summary.json, table.txt, consistency.npz and (plots) PNGs; returns out_dir."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        header, rows = self.rows()
        with open(out_dir / "runs.csv", "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(header)
            writer.writerows(rows)
        (out_dir / "summary.json").write_text(json.dumps(self.summary(), indent=2) + "\n")
        (out_dir / "table.txt").write_text(self.table())
        arrays = {}
        for c in self.consistency:
            key = c["statistic"].replace(" ", "_")
            arrays[f"{key}_times"], arrays[f"{key}_mean"] = c["times"], c["mean"]
            arrays[f"{key}_band"] = np.array(c["band"])
        if arrays:
            np.savez_compressed(out_dir / "consistency.npz", **arrays)
        if plots:
            write_plots(self, out_dir)
        return out_dir


# ----- plots -------------------------------------------------------------------


def _plot_consistency(campaign, path):
    from matplotlib.figure import Figure

    stats = campaign.consistency
    fig = Figure(figsize=(9, 2.6 * len(stats)), layout="constrained")
    for ax, c in zip(fig.subplots(len(stats), 1, squeeze=False)[:, 0], stats, strict=True):
        ax.axhspan(*c["band"], color="tab:green", alpha=0.3, label="chi2 95% band")
        ax.axhline(c["dof"], color="tab:green", lw=0.8)
        ax.plot(c["times"], c["mean"], lw=0.8, color="tab:blue", label=f"mean of {c['realisations']}")
        ax.set_yscale("log")
        ax.set_ylabel(f"{c['statistic']} ({c['dof']} dof)")
        ax.set_title(f"{c['statistic']}: {100 * c['in_band']:.0f}% of the samples in the band", fontsize=9)
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("t [s]")
    fig.suptitle(f"{campaign.scenario.name}: consistency over {campaign.runs} runs")
    fig.savefig(path, dpi=110)


def _plot_errors(campaign, path):
    from matplotlib.figure import Figure

    keys = list(campaign.metrics)
    unit_of = {key: UNITS.get(key.rsplit(".", 1)[-1], "") for key in keys}
    groups = [g for g in ([k for k in keys if unit_of[k] == u] for u in ("m", "m/s", "rad")) if g]
    bounds = {e["state"]: e["bound_std"] for e in campaign.efficiency}
    fig = Figure(figsize=(3 + 0.9 * len(keys), 3.6), layout="constrained")
    axes = fig.subplots(1, len(groups), squeeze=False, width_ratios=[len(g) for g in groups])[0]
    for ax, group in zip(axes, groups, strict=True):
        data = [
            [
                r.metrics[name]["rms_settled"]
                for r in campaign.records
                for name in r.metrics
                if name.split(".", 1)[1] == key
            ]
            for key in group
        ]
        ax.boxplot(data, whis=(0, 100))
        short = [key.rsplit(".", 1)[-1] for key in group]
        ax.set_xticks(range(1, len(group) + 1), short)
        ax.set_ylabel(f"RMS error per run, settled [{unit_of[group[0]]}]")
        for i, state in enumerate(short, start=1):
            if state in bounds:
                ax.plot([i - 0.35, i + 0.35], [bounds[state]] * 2, color="tab:red", lw=1.5)
    settle = min(SETTLE_TIME, campaign.scenario.end_time / 2)
    fig.suptitle(
        f"{campaign.scenario.name}: RMS errors from t = {settle:g} s of {campaign.runs} runs "
        "(whiskers: min-max; red: Kalman bound)",
        fontsize=10,
    )
    fig.savefig(path, dpi=110)


def write_plots(campaign, out_dir):
    """consistency.png (mean NEES/NIS in the chi^2 band) and errors.png (per-run settled RMS errors)."""
    out_dir = Path(out_dir)
    if campaign.consistency:
        _plot_consistency(campaign, out_dir / "consistency.png")
    if campaign.metrics:
        _plot_errors(campaign, out_dir / "errors.png")


# ----- command line --------------------------------------------------------------


def add_arguments(parser):
    """Arguments of ``quad-drake montecarlo`` on an argparse (sub)parser; returns it."""
    parser.add_argument("name", metavar="NAME", help="scenario name or YAML path")
    parser.add_argument("--runs", type=int, default=100, help="number of runs (default: 100)")
    parser.add_argument(
        "--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: all cores)"
    )
    parser.add_argument("--seed", type=int, help="first seed S; run i uses S+i (default: the scenario's)")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config field, e.g. vehicles.0.ekf.q_yaw_std=0.1",
    )
    parser.add_argument("--out", default="out", help="output folder (default: out)")
    parser.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on a Dask cluster, e.g. tcp://host:8786 (the 'cluster' extra)",
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    return parser
