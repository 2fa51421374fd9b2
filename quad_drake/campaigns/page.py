"""The campaign page (report.html in the campaign folder): criteria pass rates with their
confidence intervals, error distributions, consistency with its plots, efficiency.
Self-contained like a run's report (:mod:`quad_drake.output.report`)."""

from pathlib import Path

from ..config.loader import dump_scenario
from ..output.outdir import write_text_atomic
from ..output.report import esc, faults_html, figures_html, html_page, html_table, num, verdict_cell
from .campaign import one_run_command
from .records import settle_time


def _percent(fraction):
    return (num(100 * fraction, 3), "num")


def _criteria(campaign):
    rows = []
    for row in campaign.criteria:
        low, high = row["ci95"]
        rows.append(
            [
                esc(row["criterion"]),
                (f"{row['passes']}/{row['runs']}", "num"),
                _percent(row["rate"]),
                (f"[{num(100 * low, 3)}, {num(100 * high, 3)}]", "num"),
            ]
        )
    return html_table(["criterion", "passes", "rate [%]", "95% CI (Clopper-Pearson) [%]"], rows)


def _metrics(campaign):
    rows = []
    for key, m in campaign.metrics.items():
        cells = [esc(key), esc(m["unit"]), (str(m["vehicles"]), "num")]
        cells += [(num(m[stat][q]), "num") for stat in ("rms", "max") for q in ("median", "p95", "max")]
        rows.append(cells)
    header = ["error signal", "unit", "vehicles"]
    header += [f"{stat}: {q}" for stat in ("RMS", "max |·|") for q in ("median", "p95", "max")]
    return html_table(header, rows)


def _consistency(campaign):
    rows = [
        [
            esc(c["statistic"]),
            (str(c["dof"]), "num"),
            (str(c["realisations"]), "num"),
            (num(c["per_dof"], 4), "num"),
            ("[{}, {}]".format(*(num(x, 4) for x in c["per_dof_ci95"])), "num"),
            ("[{}, {}]".format(*(num(x, 3) for x in c["tolerance"])), "num"),
            verdict_cell(c["passed"]),
            (f"[{num(c['band'][0], 3)}, {num(c['band'][1], 3)}]", "num"),
            _percent(c["in_band"]),
            _percent(c["below"]),
            _percent(c["above"]),
        ]
        for c in campaign.consistency
    ]
    parts = [
        "<p>A statistic passes when its average per degree of freedom (over time and the M "
        "realisations, runs × vehicles), with its 95 % confidence interval over the realisations, "
        "meets the tolerance: the filter's covariance is then not shown to be off by more than a "
        f"factor {num(campaign.tolerance, 3)} from its actual error's. The share of samples whose "
        "realisation mean lies in its χ² 95 % band is information only: the band narrows as 1/√M, "
        "so the share falls as runs are added to the same filter.</p>",
        html_table(
            [
                "statistic",
                "dof",
                "M",
                "mean / dof",
                "95% CI",
                "tolerance",
                "result",
                "band",
                "in band [%]",
                "below [%]",
                "above [%]",
            ],
            rows,
        ),
    ]
    if campaign.state_consistency is not None:
        parts.append("<p>Per state, mean e²/P (1 = consistent):</p>")
        parts.append(
            html_table(list(campaign.state_names), [[(num(v, 3), "num") for v in campaign.state_consistency]])
        )
    return parts


def _efficiency(campaign):
    rows = [
        [
            esc(f"{e['vehicle']}.{e['state']}"),
            esc(e["unit"]),
            (num(e["bound_std"]), "num") if e["bound_std"] is not None else "-",
            (num(e["pcrb_std"]), "num") if e["pcrb_std"] is not None else "-",
            (num(e["rmse"]), "num"),
            (num(e["efficiency"], 3), "num") if e["efficiency"] is not None else "-",
            (num(e["pcrb_efficiency"], 3), "num") if e["pcrb_efficiency"] is not None else "-",
        ]
        for e in campaign.efficiency
    ]
    header = ["state", "unit", "hover bound σ", "PCRB σ", "RMSE", "efficiency (hover)", "efficiency (PCRB)"]
    return html_table(header, rows)


def write_page(campaign, path, plots=()) -> Path:
    """report.html of a CampaignResult at `path`; plots: [(caption, png path)] to embed."""
    path = Path(path)
    s = campaign.scenario
    timing = campaign.timing()
    judged = campaign.passed if campaign.consistency else None
    word, css = verdict_cell(judged)
    runs = f"{campaign.runs} of {campaign.planned} (interrupted)" if campaign.partial else str(campaign.runs)
    parts = [
        f'<h1>Monte Carlo {esc(s.name)} <span class="{css}">&nbsp;{word}&nbsp;</span></h1>',
        f"<p>{esc(s.description)}</p>",
        *faults_html(s),
        f"<p><b>{esc(campaign.verdict())}</b></p>",
        html_table(
            ["runs", "seeds", "simulated per run [s]", "runner", "wall time [s]", "runs/min"],
            [
                [
                    esc(runs),
                    esc("{}..{}".format(*campaign.seeds)),
                    num(s.end_time),
                    esc(timing["runner"]),
                    num(timing["wall_time_s"], 4),
                    num(timing["runs_per_minute"], 3),
                ]
            ],
        ),
        "<p>Run <i>i</i> has seed <i>S + i</i>; reproduce one with "
        f"<code>{esc(campaign.run_command or one_run_command(s.name))} --seed SEED</code>. "
        "Per-run values: "
        '<a href="runs.csv">runs.csv</a>; all statistics: <a href="summary.json">summary.json</a>.</p>',
    ]
    if campaign.criteria:
        parts += ["<h2>Criteria: pass rates</h2>", _criteria(campaign)]
    if campaign.metrics:
        parts += [
            f"<h2>Error metrics over runs</h2><p>Settled RMS from t = {settle_time(s.end_time):g} s "
            "in the plot; the table is over the whole run. A diverged run counts as infinite.</p>",
            _metrics(campaign),
        ]
    if campaign.consistency:
        parts += ["<h2>Consistency</h2>", *_consistency(campaign)]
    if campaign.efficiency:
        parts += [
            "<h2>Efficiency against the accuracy bounds</h2>"
            "<p>efficiency = RMSE / bound σ, against the steady-state Kalman σ at hover and the "
            "posterior CRB along each run. The RMSE is pooled over the runs, so a rare diverging run "
            "dominates it; a filter started at the truth can sit below 1 for seconds after the "
            "settling time.</p>",
            _efficiency(campaign),
        ]
    if plots:
        parts += ["<h2>Plots</h2>", *figures_html(plots)]
    parts += ["<h2>Scenario (first seed)</h2>", f"<pre>{esc(dump_scenario(s))}</pre>"]
    return write_text_atomic(path, html_page(f"quad_drake: Monte Carlo {s.name}", "\n".join(parts)))
