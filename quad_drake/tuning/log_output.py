"""The files of ``quad-drake tune LOG ...`` in its output folder (the scenario tuner's layout):

- ``tuned.yaml``: the tuned ReplayConfig (replay it: ``quad-drake replay DIR/tuned.yaml``);
- ``px4_params.params``: the tuned values as PX4 EKF2 parameters (``flightlogs.px4_parameters``);
- ``history.csv``: one row per candidate (stage, loss, consistency loss, per channel NIS per dof,
  values);
- ``objective.png``: the loss per candidate; ``delays.png``: each delay's objective curve;
- ``before_after.txt``: per held-out part and channel, NIS per dof and the largest lag
  autocorrelation, start -> tuned; ``tune.json``; ``report.html``: the page.
"""

import csv
import io
from pathlib import Path

from ..flightlogs.px4_parameters import parameter_file
from ..flightlogs.settings import dump_replay
from ..output.jsonio import dump_json
from ..output.outdir import write_binary_atomic, write_text_atomic
from .logs import trained_part_text, verdict


def _values(result, x):
    return {d.name: d.value(v) for d, v in zip(result.problem.space, x, strict=True)}


def header(result) -> list[str]:
    s, best = result.problem.settings, result.best
    lines = [
        f"quad-drake tune {' '.join(_stem(log) for log in result.problem.logs)}: "
        f"{len(result.search.history)} of {s.budget} replays"
        + (" (interrupted: best so far)" if result.interrupted else ""),
        f"trained on {trained_part_text(s)}; best loss {best.score.loss:.4g} at "
        f"candidate {best.index} (start {result.search.history[0].score.loss:.4g}); its consistency loss "
        f"{best.score.consistency:.4g} (start {result.search.history[0].score.consistency:.4g})",
    ]
    for d, x0, x in zip(result.problem.space, result.search.history[0].x, best.x, strict=True):
        unit = "ms" if d.is_delay else ""
        scale = 1e3 if unit else 1.0
        line = f"{d.name}: {scale * d.value(x0):.4g} -> {scale * d.value(x):.4g} {unit}".rstrip()
        lines.append(line + _at_bound(d, x))
    lines += [f"{name} kept as it was: {why}" for name, why in result.kept.items()]
    return lines


def _at_bound(dimension, x) -> str:
    """The note " (at the search's floor: ...)" where a noise ended within its search tolerance
    of a bound of its range (``logs.DECADES_DOWN``, ``DECADES_UP``): the likelihood may be least
    beyond it, so the value is a bound, not an estimate; "" otherwise and for a delay (0 and PX4's
    300 ms are the delays' own limits)."""
    if dimension.is_delay:
        return ""
    low, high = dimension.bounds
    if x <= low + dimension.tolerance:
        return f" (at the search's floor, 1/{10.0**-low:g} of the start: it may lie lower)"
    if x >= high - dimension.tolerance:
        return f" (at the search's ceiling, {10.0**high:g} times the start: it may lie higher)"
    return ""


def _stem(log):
    return Path(log.source).stem


def before_after(result) -> str:
    """The held-out table: per part and channel, NIS per dof [band] and max |ρ| (band), start -> tuned."""
    lines = header(result) + [
        "",
        f"{'held-out part':34s} {'channel':11s} {'NIS/dof start -> tuned':>26s} "
        f"{'band':>15s} {'max|rho| start -> tuned':>24s} {'band':>6s}",
    ]
    for (label, before), (_, after) in zip(result.before, result.after, strict=True):
        for channel, a in after.items():
            b = before.get(channel)
            nis = f"{b.nis_per_dof:.3g} -> {a.nis_per_dof:.3g}" if b else f"- -> {a.nis_per_dof:.3g}"
            rho = (
                f"{b.max_autocorrelation:.2f} -> {a.max_autocorrelation:.2f}"
                if b
                else f"{a.max_autocorrelation:.2f}"
            )
            mark = "in" if a.in_band else "OUT"
            lines.append(
                f"{label:34s} {channel:11s} {nis:>26s} [{a.band[0]:.3g}, {a.band[1]:.3g}] {mark:3s} "
                f"{rho:>20s} {a.white_band:6.2f}"
            )
    if result.after:
        lines.append(verdict(result)[1])
    return "\n".join(lines) + "\n"


def _history(result):
    space = result.problem.space
    channels = [d.name for d in space if not d.is_delay]
    text = io.StringIO(newline="")
    writer = csv.writer(text)
    writer.writerow(
        [
            "candidate",
            "stage",
            "loss",
            "consistency",
            *[f"nis_per_dof.{c}" for c in channels],
            *[f"value.{d.name}" for d in space],
            "best_loss",
        ]
    )
    best = float("inf")
    for e in result.search.history:
        best = min(best, e.score.loss)
        first = e.score.statistics[0] if e.score.statistics else {}
        nis = [first[c].nis_per_dof if c in first else "" for c in channels]
        writer.writerow(
            [
                e.index,
                e.generation,
                repr(e.score.loss),
                repr(e.score.consistency),
                *nis,
                *[repr(v) for v in _values(result, e.x).values()],
                repr(best),
            ]
        )
    return text.getvalue()


def _objective_plot(result, path):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    losses = [e.score.loss for e in result.search.history]
    fig = Figure(figsize=(7, 3.4), layout="constrained")
    ax = fig.subplots()
    ax.plot(losses, "o", ms=3, color="tab:blue", label="candidate")
    ax.step(
        range(len(losses)),
        [min(losses[: i + 1]) for i in range(len(losses))],
        where="post",
        color="tab:red",
        label="best so far",
    )
    ax.set_yscale("symlog", linthresh=1.0)
    ax.set_xlabel("candidate (0 = the start; then noise matched, delay profiles, Powell)")
    ax.set_ylabel("loss: -log-likelihood of the innovations [-]")
    ax.legend(fontsize=8)
    return write_binary_atomic(path, FigureCanvasAgg(fig).print_png)


def _delay_plot(result, path):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    curves = result.curves
    fig = Figure(figsize=(7, 2.8 * len(curves)), layout="constrained")
    axes = fig.subplots(len(curves), 1, squeeze=False)[:, 0]
    tuned = _values(result, result.best.x)
    for ax, (name, (delays, losses)) in zip(axes, curves.items(), strict=True):
        ax.plot(1e3 * delays, losses, "o-", color="tab:blue")
        ax.axvline(1e3 * tuned[name], color="tab:red", ls="--", label=f"tuned {1e3 * tuned[name]:.0f} ms")
        ax.set_xlabel(f"{name} [ms] (the other values tuned)")
        ax.set_ylabel("training loss [-]")
        ax.legend(fontsize=8)
    return write_binary_atomic(path, FigureCanvasAgg(fig).print_png)


def summary(result) -> dict:
    best = result.best
    start = _values(result, result.search.history[0].x)
    tuned = _values(result, best.x)

    def stats(parts):
        return {
            label: {
                c: {
                    "nis_per_dof": s.nis_per_dof,
                    "band": list(s.band),
                    "in_band": s.in_band,
                    "autocorrelation": list(s.autocorrelation),
                    "white_band": s.white_band,
                    "ljung_box_p": s.ljung_box_p,
                    "count": s.count,
                }
                for c, s in per.items()
            }
            for label, per in parts
        }

    data = {
        "logs": [log.source for log in result.problem.logs],
        "holdout_logs": [log.source for log in result.problem.holdout_logs],
        "settings": {
            k: getattr(result.problem.settings, k)
            for k in ("budget", "train_fraction", "split", "delays", "imu_noise")
        },
        "candidates": len(result.search.history),
        "interrupted": result.interrupted,
        "search_time_s": result.search_time,
        "start_loss": result.search.history[0].score.loss,
        "best_loss": best.score.loss,
        "start_consistency": result.search.history[0].score.consistency,
        "best_consistency": best.score.consistency,
        "parameters": [{"name": n, "start": start[n], "tuned": tuned[n]} for n in start],
        "kept": dict(result.kept),
    }
    if result.after:
        data["holdout"] = {
            "before": stats(result.before),
            "after": stats(result.after),
            "passed": verdict(result)[0],
        }
    return data


def write(result, out_dir) -> list[Path]:
    """Every file the result has (module docstring); the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = [write_text_atomic(out_dir / "history.csv", _history(result))]
    if result.best is None:
        return written
    comments = "".join(f"# {line}\n" for line in header(result))
    written.append(write_text_atomic(out_dir / "tuned.yaml", comments + dump_replay(result.tuned)))
    written.append(
        write_text_atomic(out_dir / "px4_params.params", parameter_file(result.tuned, result.problem.config))
    )
    written.append(_objective_plot(result, out_dir / "objective.png"))
    if result.curves:
        written.append(_delay_plot(result, out_dir / "delays.png"))
    if result.after:
        written.append(write_text_atomic(out_dir / "before_after.txt", before_after(result)))
    dump_json(out_dir / "tune.json", summary(result))
    written.append(out_dir / "tune.json")
    written.append(write_page(result, out_dir))
    return written


def write_page(result, out_dir) -> Path:
    """report.html: the values start -> tuned, the held-out table, the objective and delay curves."""
    from ..output.report import esc, figures_html, html_page

    parts = ["<h1>quad-drake tune (flight logs)</h1>"] + [f"<p>{esc(line)}</p>" for line in header(result)]
    links = ["tuned.yaml", "px4_params.params", "history.csv", "tune.json", "before_after.txt"]
    parts.append(
        "<p>"
        + " · ".join(f'<a href="{esc(p)}">{esc(p)}</a>' for p in links if (out_dir / p).is_file())
        + "</p>"
    )
    if result.after:
        parts += [
            "<h2>Held-out: NIS per dof and innovation autocorrelation, start → tuned</h2>",
            f"<pre>{esc(before_after(result))}</pre>",
        ]
    figures = [("Loss per candidate", out_dir / "objective.png")]
    if (out_dir / "delays.png").is_file():
        figures.append(("Each delay's objective curve", out_dir / "delays.png"))
    parts += ["<h2>Search</h2>", *figures_html(figures)]
    parts.append("<h2>PX4 parameters</h2><pre>" + esc((out_dir / "px4_params.params").read_text()) + "</pre>")
    return write_text_atomic(out_dir / "report.html", html_page("quad_drake: tune logs", "\n".join(parts)))
