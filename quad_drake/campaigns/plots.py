"""A campaign's figures: the run-averaged NEES/NIS in their chi^2 bands, and the per-run
settled RMS errors against the Kalman bound (matplotlib's Agg canvas, no pyplot)."""

from pathlib import Path

from matplotlib.figure import Figure

from ..output.outdir import write_binary_atomic
from ..output.plots import shade_faults
from ..output.report import fault_spans
from .records import settle_time
from .statistics import per_dof_text, tolerance_text

DPI = 110


def consistency_figure(campaign) -> Figure:
    """Mean NEES / NIS over the realisations against the chi^2 95 % band, one panel each."""
    stats = campaign.consistency
    fig = Figure(figsize=(9, 2.6 * len(stats)), layout="constrained")
    for ax, c in zip(fig.subplots(len(stats), 1, squeeze=False)[:, 0], stats, strict=True):
        ax.axhspan(*c["band"], color="tab:green", alpha=0.3, label="chi2 95% band")
        ax.axhline(c["dof"], color="tab:green", lw=0.8)
        ax.plot(c["times"], c["mean"], lw=0.8, color="tab:blue", label=f"mean of {c['realisations']}")
        ax.set_yscale("log")
        ax.set_ylabel(f"{c['statistic']} ({c['dof']} dof) [-]")
        ax.axhspan(*(c["dof"] * x for x in c["tolerance"]), color="tab:gray", alpha=0.12, label="tolerance")
        ax.set_title(
            f"{per_dof_text(c)} ({'PASS' if c['passed'] else 'FAIL'} against {tolerance_text(c)}); "
            f"{100 * c['in_band']:.0f}% of the samples in the band",
            fontsize=9,
        )
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("t [s]")
    fig.suptitle(f"{campaign.scenario.name}: consistency over {campaign.runs} runs")
    fig.time_axes = list(fig.axes)
    shade_faults(fig, fault_spans(campaign.scenario))
    return fig


def errors_figure(campaign) -> Figure:
    """Box plots (min-max whiskers) of the per-run settled RMS errors, grouped by unit; red: bound."""
    keys = list(campaign.metrics)
    unit_of = {key: m["unit"] for key, m in campaign.metrics.items()}
    groups = [[k for k in keys if unit_of[k] == u] for u in dict.fromkeys(unit_of.values())]
    bounds = {e["state"]: e["bound_std"] for e in campaign.efficiency if e["bound_std"] is not None}
    fig = Figure(figsize=(3 + 0.9 * len(keys), 3.6), layout="constrained")
    axes = fig.subplots(1, len(groups), squeeze=False, width_ratios=[len(g) for g in groups])[0]
    for ax, group in zip(axes, groups, strict=True):
        ax.boxplot([campaign.settled_rms(key) for key in group], whis=(0, 100))
        short = [key.rsplit(".", 1)[-1] for key in group]
        ax.set_xticks(range(1, len(group) + 1), short)
        ax.set_ylabel(f"RMS error per run, settled [{unit_of[group[0]]}]")
        for i, state in enumerate(short, start=1):
            if state in bounds:
                ax.plot([i - 0.35, i + 0.35], [bounds[state]] * 2, color="tab:red", lw=1.5)
    fig.suptitle(
        f"{campaign.scenario.name}: RMS errors from t = {settle_time(campaign.scenario.end_time):g} s "
        f"of {campaign.runs} runs (whiskers: min-max; red: Kalman bound)",
        fontsize=10,
    )
    return fig


def write_plots(campaign, out_dir) -> list[tuple[str, Path]]:
    """consistency.png and errors.png (where the campaign has them); [(caption, path)]."""
    out_dir = Path(out_dir)
    written = []
    if campaign.consistency:
        path = out_dir / "consistency.png"
        figure = consistency_figure(campaign)
        write_binary_atomic(path, lambda f: figure.savefig(f, format="png", dpi=DPI))
        written.append(("Run-averaged NEES / NIS against the chi² 95 % band", path))
    if campaign.metrics:
        path = out_dir / "errors.png"
        figure = errors_figure(campaign)
        write_binary_atomic(path, lambda f: figure.savefig(f, format="png", dpi=DPI))
        written.append(("Per-run RMS errors after settling, against the Kalman bound", path))
    return written
