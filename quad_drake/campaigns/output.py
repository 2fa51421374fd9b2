"""A campaign's files and text: the table, runs.csv, summary.json, table.txt, consistency.npz,
plus the plots and the campaign page (:mod:`.plots`, :mod:`.page`)."""

import csv
import io
from pathlib import Path

import numpy as np

from ..judging.signals import signal_unit
from ..output.jsonio import dump_json
from ..output.outdir import remove_stale, write_binary_atomic, write_text_atomic
from ..output.results import FORMAT_VERSION
from .page import write_page
from .plots import write_plots
from .records import METRIC_STATS, criterion_column, settle_time


def _header(campaign):
    s = campaign.scenario
    if campaign.partial:
        runs = f"{campaign.runs} of {campaign.planned} runs (interrupted)"
    else:
        runs = f"{campaign.runs} runs"
    first, last = campaign.seeds
    return f"Monte Carlo {s.name}: {runs} of {s.end_time:g} s, seeds {first}..{last}"


def table(campaign) -> str:
    """The campaign's statistics as text; identical for the same scenario, runs and seed."""
    lines = [_header(campaign), ""]
    if campaign.criteria:
        lines.append(f"{'criterion':58s} {'passes':>9s} {'rate':>7s}  95% CI")
        for row in campaign.criteria:
            low, high = row["ci95"]
            lines.append(
                f"{row['criterion'][:58]:58s} {row['passes']:4d}/{row['runs']:<4d} "
                f"{100 * row['rate']:6.1f}%  [{100 * low:5.1f}, {100 * high:5.1f}]"
            )
        lines.append("")
    if campaign.metrics:
        lines.append(
            f"{'error signal':24s} {'RMS: median':>12s} {'p95':>8s} {'max':>8s}   "
            f"{'MAX: median':>11s} {'p95':>8s} {'max':>8s}"
        )
        for key, m in campaign.metrics.items():
            label = f"{key} [{m['unit']}]"
            label += f" x{m['vehicles']}" if m["vehicles"] > 1 else ""
            r, x = m["rms"], m["max"]
            lines.append(
                f"{label:24s} {r['median']:12.4f} {r['p95']:8.4f} {r['max']:8.4f}   "
                f"{x['median']:11.4f} {x['p95']:8.4f} {x['max']:8.4f}"
            )
        lines.append("")
    if campaign.consistency:
        low, high = campaign.consistency[0]["tolerance"]
        lines.append(
            "consistency criterion: average statistic per dof (over time and the M realisations, runs x "
            f"vehicles) with its 95% CI must meet [{low:.3g}, {high:.3g}]; the share of samples whose "
            "realisation mean is in its chi2 95% band is information (it falls as M grows)"
        )
        lines.append(
            f"{'statistic':10s} {'dof':>3s} {'M':>5s} {'mean/dof':>8s} {'95% CI':>17s} "
            f"{'band':>17s} {'in band':>8s} {'below':>6s} {'above':>6s}  result"
        )
        for c in campaign.consistency:
            band = f"[{c['band'][0]:.3g}, {c['band'][1]:.3g}]"
            ci = "[{:.3g}, {:.3g}]".format(*c["per_dof_ci95"])
            lines.append(
                f"{c['statistic']:10s} {c['dof']:3d} {c['realisations']:5d} {c['per_dof']:8.3f} {ci:>17s} "
                f"{band:>17s} {100 * c['in_band']:7.1f}% {100 * c['below']:5.1f}% "
                f"{100 * c['above']:5.1f}%  {'PASS' if c['passed'] else 'FAIL'}"
            )
        if campaign.state_consistency is not None:
            lines.append(
                "per state, mean e^2/P (1 = consistent): "
                + "  ".join(
                    f"{n} {v:.3g}"
                    for n, v in zip(campaign.state_names, campaign.state_consistency, strict=True)
                )
            )
        if campaign.counters:
            lines.append(
                "estimator counters (total over runs): "
                + ", ".join(f"{name} {count}" for name, count in campaign.counters.items())
            )
        lines.append("")
    if campaign.efficiency:
        lines.append(
            "accuracy bounds with the true sensor noise: hover = steady-state Kalman sigma of the "
            "tilt-aware hover model (time-averaged), PCRB = posterior Cramer-Rao bound along each "
            f"run's true trajectory; RMSE from t >= {settle_time(campaign.scenario.end_time):g} s; "
            "efficiency = RMSE / bound"
        )
        lines.append(
            f"{'state':20s} {'hover':>9s} {'PCRB':>9s} {'RMSE':>9s} {'eff hover':>10s} {'eff PCRB':>9s}"
        )

        def cell(value, width, digits):
            return f"{value:{width}.{digits}f}" if value is not None else f"{'-':>{width}s}"

        for e in campaign.efficiency:
            label = f"{e['vehicle']}.{e['state']} [{e['unit']}]"
            lines.append(
                f"{label:20s} {cell(e['bound_std'], 9, 4)} {cell(e['pcrb_std'], 9, 4)} {e['rmse']:9.4f} "
                f"{cell(e['efficiency'], 10, 2)} {cell(e['pcrb_efficiency'], 9, 2)}"
            )
    return "\n".join(lines).rstrip() + "\n"


def timing_line(campaign) -> str:
    t = campaign.timing()
    return (
        f"{campaign.runs} runs in {t['wall_time_s']:.1f} s on {t['runner']}: "
        f"{t['runs_per_minute']:.1f} runs/min ({t['simulation_s_mean']:.2f} s simulation per run)"
    )


def summary(campaign) -> dict:
    """The summary.json dict: every statistic (without the consistency series) and the timing."""
    consistency = [{k: v for k, v in c.items() if k not in ("times", "mean")} for c in campaign.consistency]
    state = campaign.state_consistency
    s = campaign.scenario
    return {
        "format_version": FORMAT_VERSION,
        "kind": "campaign",
        "runner": campaign.runner,
        "scenario": s.name,
        "description": s.description,
        "runs": campaign.runs,
        "runs_planned": campaign.planned or campaign.runs,
        "partial": campaign.partial,
        "completed": campaign.completed,
        "first_seed": s.seed,
        "end_time": s.end_time,
        "criteria": campaign.criteria,
        "metrics": campaign.metrics,
        "columns": columns(campaign),
        "consistency": consistency,
        "consistency_tolerance": campaign.tolerance,
        "state_consistency": None
        if state is None
        else dict(zip(campaign.state_names, state.tolist(), strict=True)),
        "efficiency": campaign.efficiency,
        "counters": campaign.counters,
        "consistency_passed": campaign.passed,
        "failure_reasons": campaign.failure_reasons(),
        "verdict": campaign.verdict(),
        "timing": campaign.timing(),
    }


def columns(campaign) -> dict[str, str]:
    """{runs.csv column: unit}, in column order: "" for the run index, seed, pass flags (1 or 0)
    and the NEES/NIS means; a criterion's ``measured`` in its unit (``CriterionResult.measured_unit``)
    and ``percent`` in %; an error metric in its signal's unit."""
    units = {"run": "", "seed": "", "passed": ""}
    if not campaign.records:
        return units
    first = campaign.records[0]
    for j, verdict in enumerate(first.criteria, start=1):
        column = criterion_column(j)
        units.update({f"{column}.passed": "", f"{column}.measured": verdict["unit"]})
        units.update({f"{column}.percent": "%"} if verdict["percent"] is not None else {})
    units.update({f"{name}.{stat}": signal_unit(name) for name in first.metrics for stat in METRIC_STATS})
    units.update({f"{v}.NEES.mean": "" for v in first.nees_mean})
    units.update({f"{v}.NIS.{sensor}.mean": "" for v, sensor in first.nis_mean})
    return units


def rows(campaign) -> tuple[list[str], list[list]]:
    """(header, rows) of the per-run CSV: seed, verdicts, metrics, NEES/NIS time means
    (:func:`columns` names them, with their units)."""
    header = list(columns(campaign))
    if not campaign.records:
        return header, []
    first = campaign.records[0]
    lines = []
    for r in campaign.records:
        row = [r.index, r.seed, int(r.passed)]
        for shape, verdict in zip(first.criteria, r.criteria, strict=True):
            row += [int(verdict["passed"]), verdict["measured"]]
            row += [verdict["percent"]] if shape["percent"] is not None else []
        row += [r.metrics[name][stat] for name in first.metrics for stat in METRIC_STATS]
        row += [r.nees_mean[v] for v in first.nees_mean]
        row += [r.nis_mean[key] for key in first.nis_mean]
        lines.append([repr(float(x)) if isinstance(x, float) else x for x in row])
    return header, lines


CAMPAIGN_ARTIFACTS = ("*.png", "consistency.npz")
"""What a campaign folder may hold from an earlier campaign that this one does not rewrite (its
plots when this one has none, its NEES/NIS series when this one has no estimator): removed
first, so a folder never mixes two campaigns."""


def save(campaign, out_dir, plots=True) -> Path:
    """Write runs.csv, summary.json, table.txt, consistency.npz, (plots) PNGs and report.html
    (the campaign page) into out_dir, after removing an earlier campaign's CAMPAIGN_ARTIFACTS
    there; returns out_dir."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    remove_stale(out_dir, CAMPAIGN_ARTIFACTS)
    header, lines = rows(campaign)
    text = io.StringIO(newline="")
    writer = csv.writer(text)
    writer.writerow(header)
    writer.writerows(lines)
    write_text_atomic(out_dir / "runs.csv", text.getvalue())
    write_text_atomic(out_dir / "table.txt", table(campaign))
    arrays = {}
    for c in campaign.consistency:
        key = c["statistic"].replace(" ", "_")
        arrays[f"{key}_times"], arrays[f"{key}_mean"] = c["times"], c["mean"]
        arrays[f"{key}_band"] = np.array(c["band"])
    if arrays:
        write_binary_atomic(out_dir / "consistency.npz", lambda f: np.savez_compressed(f, **arrays))
    figures = write_plots(campaign, out_dir) if plots else []
    write_page(campaign, out_dir / "report.html", figures)
    dump_json(out_dir / "summary.json", summary(campaign))  # last: the index lists complete folders
    return out_dir
