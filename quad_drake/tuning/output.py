"""The files of ``quad-drake tune`` in its output folder.

- ``tuned.yaml``: the scenario with the tuned values (runnable: ``quad-drake run DIR/tuned.yaml``);
- ``history.csv``: one row per candidate (loss, its parts, multipliers and values);
- ``objective.png``: the loss per candidate and the best so far;
- ``tune.json``: settings, start and tuned values, timing, and (after the held-out campaigns)
  the before/after statistics;
- ``before_after.txt`` and ``holdout_before/``, ``holdout_after/`` (campaign folders): the start
  and the tuned scenario on the held-out seeds.
"""

import csv
import dataclasses
import io
from pathlib import Path

from .. import campaigns
from ..config.loader import dump_scenario
from ..config.schema import ScenarioConfig
from ..output.jsonio import dump_json
from ..output.outdir import write_binary_atomic, write_text_atomic
from .objective import score

TUNED_SUFFIX = "_tuned"


def tuned_scenario(scenario) -> ScenarioConfig:
    """The tuned ScenarioConfig under its own name (``<name>_tuned``: its outputs do not
    overwrite the original's)."""
    name = scenario.name if scenario.name.endswith(TUNED_SUFFIX) else scenario.name + TUNED_SUFFIX
    return dataclasses.replace(scenario, name=name)


def _changes(result):
    """[(key, start text, tuned text)] of every searched parameter."""
    best = result.search.best
    return [(p.key, p.label(0.0), p.label(x)) for p, x in zip(result.problem.space, best.x, strict=True)]


def _number(value):
    """A parameter's value for JSON and history.csv: a float, or a list of floats for a vector
    field (the csv writer prints either in full precision: repr, ``[a, b, c]``)."""
    return list(value) if isinstance(value, tuple) else value


def _header(result):
    s = result.problem.settings
    best = result.search.best
    lines = [
        f"quad-drake tune {result.problem.scenario.name}: objective {s.objective}, "
        f"{len(result.search.history)} of {s.budget} candidates"
        + (" (interrupted: best so far)" if result.search.interrupted else ""),
        f"training seeds {s.train_seed}..{s.train_seed + s.train_runs - 1}; "
        f"best loss {best.score.loss:.4g} at candidate {best.index} "
        f"(start {result.search.history[0].score.loss:.4g})",
    ]
    lines += [f"{key}: {start} -> {tuned}" for key, start, tuned in _changes(result)]
    return lines


def write_search(result, out_dir) -> list[Path]:
    """tuned.yaml (when a candidate finished), history.csv, objective.png, tune.json; the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = [_write_history(result, out_dir / "history.csv")]
    if result.search.best is None:
        return written
    tuned = out_dir / "tuned.yaml"
    write_text_atomic(
        tuned, "".join(f"# {line}\n" for line in _header(result)) + dump_scenario(result.tuned, out_dir)
    )
    written += [tuned, _write_plot(result, out_dir / "objective.png")]
    dump_json(out_dir / "tune.json", summary(result))
    return written + [out_dir / "tune.json", write_page(result, out_dir)]


def _write_history(result, path):
    space = result.problem.space
    history = result.search.history
    statistics = sorted({name for e in history for name in e.score.in_band})
    header = ["candidate", "generation", "loss", "consistency", "accuracy", "pass_rate"]
    header += [f"in_band.{name}" for name in statistics]
    header += [f"log10_multiplier.{p.key}" for p in space] + [f"value.{p.key}" for p in space]
    header += ["best_loss"]
    best = float("inf")
    text = io.StringIO(newline="")
    writer = csv.writer(text)
    writer.writerow(header)
    for e in history:
        best = min(best, e.score.loss)
        row = [
            e.index,
            e.generation,
            e.score.loss,
            e.score.consistency,
            e.score.accuracy,
            e.score.pass_rate,
        ]
        row += [e.score.in_band.get(name, "") for name in statistics]
        row += list(e.x) + [_number(p.values(x)[0]) for p, x in zip(space, e.x, strict=True)] + [best]
        writer.writerow([repr(v) if isinstance(v, float) else v for v in row])
    return write_text_atomic(path, text.getvalue())


def _write_plot(result, path):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    history = result.search.history
    losses = [e.score.loss for e in history]
    best = [min(losses[: i + 1]) for i in range(len(losses))]
    fig = Figure(figsize=(7, 3.6), layout="constrained")
    ax = fig.subplots()
    for feasible, marker, label in ((True, "o", "candidate"), (False, "x", "candidate with a failed run")):
        points = [(e.index, e.score.loss) for e in history if e.score.feasible == feasible]
        if points:
            ax.plot(*zip(*points, strict=True), marker, ms=5, color="tab:blue", label=label)
    ax.step(range(len(best)), best, where="post", color="tab:red", label="best so far")
    if min(losses) > 0 and max(losses) / min(losses) > 30:
        ax.set_yscale("log")
    ax.set_xlabel("candidate (0 = the start)")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylabel(f"loss ({result.problem.settings.objective}) [-]")
    ax.set_title(f"tune {result.problem.scenario.name}: loss over the training seeds", fontsize=10)
    ax.legend(fontsize=8)
    return write_binary_atomic(path, FigureCanvasAgg(fig).print_png)


def _campaign_stats(campaign, objective):
    every = [r for r in campaign.criteria if r["criterion"] == "all criteria"]
    return {
        "runs": campaign.runs,
        "passes": every[0]["passes"] if every else campaign.runs,
        "pass_ci95": every[0]["ci95"] if every else None,
        "consistency": {
            c["statistic"]: {"dof": c["dof"], "in_band": c["in_band"], "time_mean": c["time_mean"]}
            for c in campaign.consistency
        },
        "efficiency": [
            {k: e[k] for k in ("vehicle", "state", "rmse", "efficiency", "pcrb_efficiency")}
            for e in campaign.efficiency
        ],
        "loss": score(campaign, objective, campaign.runs).loss,
    }


def summary(result) -> dict:
    """The tune.json dict."""
    s = result.problem.settings
    best = result.search.best
    data = {
        "scenario": result.problem.scenario.name,
        "settings": dataclasses.asdict(s),
        "candidates": len(result.search.history),
        "interrupted": result.interrupted,
        "search_time_s": result.search_time,
        "start_loss": result.search.history[0].score.loss,
        "best_loss": best.score.loss,
        "best_candidate": best.index,
        "parameters": [
            {"key": p.key, "start": _number(p.values(0.0)[0]), "tuned": _number(p.values(x)[0])}
            for p, x in zip(result.problem.space, result.search.best.x, strict=True)
        ],
    }
    if result.before is not None:
        data["holdout_time_s"] = result.holdout_time
        data["holdout"] = {
            "seeds": [s.holdout_seed, s.holdout_seed + s.holdout_runs - 1],
            "before": _campaign_stats(result.before, s.objective),
            "after": _campaign_stats(result.after, s.objective),
        }
    return data


def before_after(result) -> str:
    """The before/after table on the held-out seeds, as text."""
    s = result.problem.settings
    before, after = result.before, result.after
    b, a = _campaign_stats(before, s.objective), _campaign_stats(after, s.objective)
    lines = _header(result) + [
        "",
        f"held-out seeds {s.holdout_seed}..{s.holdout_seed + s.holdout_runs - 1} "
        f"({before.scenario.end_time:g} s each): start vs tuned",
        f"{'':34s} {'before':>24s} {'after':>24s}",
    ]

    def passes(stats):
        low, high = stats["pass_ci95"] or (1.0, 1.0)
        return f"{stats['passes']}/{stats['runs']} [{100 * low:.1f}, {100 * high:.1f}] %"

    lines.append(f"{'every criterion passed (95% CI)':34s} {passes(b):>24s} {passes(a):>24s}")
    for name, cb in b["consistency"].items():
        ca = a["consistency"][name]
        label = f"{name} in band ({cb['dof']} dof), mean"
        cells = [f"{100 * c['in_band']:.1f} %, {c['time_mean']:.3g}" for c in (cb, ca)]
        lines.append(f"{label:34s} {cells[0]:>24s} {cells[1]:>24s}")

    def efficiency(row):
        cells = [row["efficiency"], row["pcrb_efficiency"]]
        return " / ".join("-" if v is None else f"{v:.2f}" for v in cells) + f" ({row['rmse']:.4g})"

    for eb, ea in zip(b["efficiency"], a["efficiency"], strict=True):
        label = f"eff hover / PCRB (RMSE) {eb['vehicle']}.{eb['state']}"
        lines.append(f"{label:34s} {efficiency(eb):>24s} {efficiency(ea):>24s}")
    lines.append(f"{'loss (' + s.objective + ', held-out bands)':34s} {b['loss']:24.4g} {a['loss']:24.4g}")
    return "\n".join(lines) + "\n"


def write_holdout(result, out_dir) -> list[Path]:
    """before_after.txt, the two held-out campaign folders, tune.json updated; the paths."""
    out_dir = Path(out_dir)
    table = out_dir / "before_after.txt"
    write_text_atomic(table, before_after(result))
    folders = [
        campaigns.save(result.before, out_dir / "holdout_before", plots=False),
        campaigns.save(result.after, out_dir / "holdout_after", plots=False),
    ]
    dump_json(out_dir / "tune.json", summary(result))
    write_page(result, out_dir)
    return [table, *folders]


def write_page(result, out_dir) -> Path:
    """report.html of a tune session in out_dir: what was searched, start and tuned values, the
    objective plot, the held-out before/after table and links to its files; -> its path."""
    from ..output.report import esc, figures_html, html_page, html_table

    out_dir = Path(out_dir)
    name = result.problem.scenario.name
    parts = [f"<h1>quad-drake tune {esc(name)}</h1>"]
    parts += [f"<p>{esc(line)}</p>" for line in _header(result)[:2]]
    parts.append(
        html_table(
            ["parameter", "start", "tuned"], [[esc(k), esc(a), esc(b)] for k, a, b in _changes(result)]
        )
    )
    links = [
        ("tuned.yaml", "tuned.yaml (run it: quad-drake run DIR/tuned.yaml)"),
        ("history.csv", "history.csv"),
    ]
    links += [("tune.json", "tune.json"), ("before_after.txt", "before_after.txt")]
    links += [(f"holdout_{w}/report.html", f"held-out campaign {w}") for w in ("before", "after")]
    shown = [f'<a href="{esc(path)}">{esc(label)}</a>' for path, label in links if (out_dir / path).is_file()]
    parts.append("<p>" + " · ".join(shown) + "</p>")
    if result.after is not None:
        parts += ["<h2>Held-out seeds: start against tuned</h2>", f"<pre>{esc(before_after(result))}</pre>"]
    if (out_dir / "objective.png").is_file():
        parts += ["<h2>Search</h2>", *figures_html([("Loss per candidate", out_dir / "objective.png")])]
    return write_text_atomic(out_dir / "report.html", html_page(f"quad_drake: tune {name}", "\n".join(parts)))
