"""Self-contained HTML: a run's report.html and out/index.html of every run and campaign.

Pages open from disk with no network: plots are embedded as base64 PNG data URIs,
the style is inline, links to sibling files (replay.html, reports) are relative.
A criterion is rendered from the text its analyzer wrote (``CriterionResult.description``,
``measured_text``, ``required_text``); nothing here re-derives a verdict.
"""

import base64
import html
import json
import math
import os
from pathlib import Path

import numpy as np

from ..config.errors import ConfigError
from ..config.loader import dump_scenario
from ..estimation.registry import vehicle_vocabulary
from ..estimation.vocabulary import health_counts, health_line, smoothed_errors
from ..judging.evaluation import sigma_share
from .outdir import locked, write_text_atomic
from .results import read_summary

METRICS = (  # (signal key, what it is, unit)
    ("PosFollowErr", "position tracking error |p_ref - p|", "m"),
    ("Est.E.Pos", "position estimate error |p̂ - p|", "m"),
    ("Est.E.Vel", "velocity estimate error |v̂ - v|", "m/s"),
    ("Est.E.Yaw", "yaw estimate error", "rad"),
    ("Est.E.MaxEuler", "largest Euler-angle estimate error", "rad"),
)

STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 1250px; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.2em; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: left; font-size: 14px; }
td.num { text-align: right; font-family: monospace; }
.PASS { background: #d9f2d9; font-weight: bold; } .FAIL { background: #f7d4d4; font-weight: bold; }
.NONE { background: #eee; }
figure { margin: 1em 0; } figcaption { font-weight: bold; margin-bottom: 0.3em; }
img { max-width: 100%; border: 1px solid #ddd; }
pre { background: #f6f6f6; padding: 0.8em; overflow-x: auto; font-size: 12px; }
code { background: #f2f2f2; padding: 0 3px; }
"""


def esc(value) -> str:
    """HTML-escaped str(value)."""
    return html.escape(str(value))


def num(value, digits=4) -> str:
    """A number with `digits` significant digits; "–" for None, "nan"/"inf" as such."""
    if value is None:
        return "–"
    value = float(value)
    return f"{value:.{digits}g}" if math.isfinite(value) else str(value)


def html_page(title, body) -> str:
    """A complete HTML document with the shared inline style."""
    return (
        f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{esc(title)}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n{body}\n</body>\n</html>\n"
    )


def html_table(header, rows) -> str:
    """HTML table; a row cell is HTML text, or (HTML text, css class)."""
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    lines = [f"<table>\n<tr>{head}</tr>"]
    for row in rows:
        cells = []
        for cell in row:
            text, css = cell if isinstance(cell, tuple) else (cell, "")
            cells.append(f'<td class="{css}">{text}</td>' if css else f"<td>{text}</td>")
        lines.append(f"<tr>{''.join(cells)}</tr>")
    return "\n".join(lines) + "\n</table>"


def verdict_cell(passed) -> tuple[str, str]:
    """("PASS" | "FAIL", css class) of a verdict; ("–", "NONE") for None (nothing judged)."""
    if passed is None:
        return ("–", "NONE")
    word = "PASS" if passed else "FAIL"
    return (word, word)


def criterion_row(verdict) -> list:
    """[criterion, kind, verdict, measured, required] cells (HTML-escaped) of a CriterionResult."""
    return [
        esc(verdict.description),
        esc(verdict.kind),
        verdict_cell(verdict.passed),
        esc(verdict.measured_text),
        esc(verdict.required_text),
    ]


def image_tag(path) -> str:
    """<img> of a PNG file, embedded as a data URI."""
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return f'<img alt="{esc(Path(path).stem)}" src="data:image/png;base64,{data}">'


def figures_html(plots) -> list[str]:
    """<figure>s of [(caption, png path)]."""
    return [
        f"<figure><figcaption>{esc(caption)}</figcaption>{image_tag(png)}</figure>" for caption, png in plots
    ]


def _stats(values):
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return float("nan"), float("nan")
    return float(np.sqrt(np.mean(values * values))), float(np.max(np.abs(values)))


def key_metrics(result) -> list[tuple]:
    """[(vehicle, what, unit, rms, max |.|)] over the whole run, for the signals a run has."""
    rows = []
    for vehicle in (v.name for v in result.scenario.vehicles):
        for key, what, unit in METRICS:
            signal = result.signals.get(f"{vehicle}.{key}")
            if signal is not None:
                rows.append((vehicle, what, unit, *_stats(signal.values)))
    return rows


def _percent_within(error, sigma, multiple):
    inside, total = sigma_share(error, sigma, multiple)
    return 100.0 * inside / total if total else float("nan")


def ekf_consistency(result) -> list[tuple]:
    """[(vehicle, state, unit, rms error, max |error|, % within ±σ, % within ±2σ)] per error state
    of each vehicle's estimator vocabulary."""
    rows = []
    for config in result.scenario.vehicles:
        vehicle, vocabulary = config.name, vehicle_vocabulary(config)
        if vocabulary is None or f"{vehicle}.Est.E.X" not in result.signals:
            continue
        for key, unit in zip(vocabulary.state_names, vocabulary.units, strict=True):
            error = result.signals[f"{vehicle}.Est.E.{key}"].values
            sigma = result.signals[f"{vehicle}.Est.S.{key}"].values
            within = [_percent_within(error, sigma, k) for k in (1, 2)]
            rows.append((vehicle, key, unit, *_stats(error), *within))
    return rows


def smoother_consistency(result) -> list[tuple]:
    """[(vehicle, state, unit, filter rms error, smoother rms error, smoother % within ±σ, ±2σ)] per
    error state of each vehicle the run smoothed (``quad-drake run --smooth``: its logs hold
    ``smoothed_state`` and ``smoothed_sigma``); the filter's error is its ``Est.E.<state>``."""
    rows = []
    for config in result.scenario.vehicles:
        vehicle, logs = config.name, result.logs.get(config.name, {})
        if "smoothed_state" not in logs:
            continue
        vocabulary = vehicle_vocabulary(config)
        errors, sigma = smoothed_errors(logs), logs["smoothed_sigma"]
        for i, (key, unit) in enumerate(zip(vocabulary.state_names, vocabulary.units, strict=True)):
            within = [_percent_within(errors[:, i], sigma[:, i], k) for k in (1, 2)]
            filtered = result.signals[f"{vehicle}.Est.E.{key}"].values
            rows.append((vehicle, key, unit, _stats(filtered)[0], _stats(errors[:, i])[0], *within))
    return rows


def estimator_health(result) -> list[str]:
    """[health line] per vehicle with an estimator: gated samples, resets, covariance repairs."""
    lines = []
    for config in result.scenario.vehicles:
        logs = result.logs.get(config.name, {})
        if vehicle_vocabulary(config) is not None and "diagnostics" in logs:
            lines.append(health_line(config.name, config.estimator.kind, health_counts(logs["diagnostics"])))
    return lines


def write_report(result, path, plots=(), replay=None) -> Path:
    """report.html for a SimulationResult: verdicts, metrics, plots [(caption, png)], config."""
    path = Path(path)
    scenario = result.scenario
    verdicts = result.criteria
    overall = verdict_cell(result.passed if verdicts else None)
    rate = scenario.end_time / result.wall_time if result.wall_time > 0 else float("inf")
    parts = [
        f'<h1>{esc(scenario.name)} <span class="{overall[1]}">&nbsp;{overall[0]}&nbsp;</span></h1>',
        f"<p>{esc(scenario.description)}</p>",
        *faults_html(scenario),
        *events_html(result),
        html_table(
            ["seed", "simulated [s]", "wall time [s]", "× real time", "vehicles"],
            [
                [
                    str(scenario.seed),
                    num(scenario.end_time),
                    num(result.wall_time, 3),
                    num(rate, 3),
                    esc(", ".join(v.name for v in scenario.vehicles)),
                ]
            ],
        ),
    ]
    if replay is not None:
        parts.append(
            f'<p>3D replay: <a href="{esc(os.path.relpath(replay, path.parent))}">'
            "replay.html</a> (Meshcat; opens offline).</p>"
        )
    parts.append("<h2>Criteria</h2>")
    if verdicts:
        parts.append(
            html_table(
                ["criterion", "kind", "result", "measured", "required"], [criterion_row(v) for v in verdicts]
            )
        )
        parts.append("<pre>" + esc("\n".join(v.line for v in verdicts)) + "</pre>")
    else:
        parts.append("<p>This scenario has no pass/fail criteria; judge it from the plots.</p>")
    metrics = key_metrics(result)
    if metrics:
        parts.append("<h2>Key metrics</h2>")
        parts.append(
            html_table(
                ["vehicle", "quantity", "unit", "RMS", "max |·|"],
                [[esc(v), esc(w), esc(u), (num(r), "num"), (num(m), "num")] for v, w, u, r, m in metrics],
            )
        )
    health = estimator_health(result)
    if health:
        parts.append("<h2>Estimator health</h2>")
        parts.append("<pre>" + esc("\n".join(health)) + "</pre>")
    consistency = ekf_consistency(result)
    if consistency:
        parts.append(
            "<h2>Estimator errors against the predicted σ</h2>"
            "<p>A consistent filter has about 68 % of its errors within ±σ and 95 % within ±2σ.</p>"
        )
        parts.append(
            html_table(
                ["vehicle", "state", "unit", "RMS error", "max |error|", "within ±σ [%]", "within ±2σ [%]"],
                [
                    [
                        esc(v),
                        esc(k),
                        esc(u),
                        (num(r), "num"),
                        (num(m), "num"),
                        (num(a, 3), "num"),
                        (num(b, 3), "num"),
                    ]
                    for v, k, u, r, m, a, b in consistency
                ],
            )
        )
    smoothed = smoother_consistency(result)
    if smoothed:
        parts.append(
            "<h2>RTS smoother against the filter</h2>"
            "<p>The fixed-interval Rauch–Tung–Striebel smoother of the ESKF's pass (<code>--smooth</code>): "
            "the estimate given the whole flight, its errors against its own σ.</p>"
        )
        parts.append(
            html_table(
                ["vehicle", "state", "unit", "RMS error filter", "RMS error smoother",
                 "smoother within ±σ [%]", "smoother within ±2σ [%]"],
                [
                    [esc(v), esc(k), esc(u), (num(f), "num"), (num(s), "num"), (num(a, 3), "num"),
                     (num(b, 3), "num")]
                    for v, k, u, f, s, a, b in smoothed
                ],
            )
        )  # fmt: skip
    if plots:
        parts.append("<h2>Plots</h2>")
        parts.extend(figures_html(plots))
    parts.append(
        "<h2>Resolved configuration</h2>"
        "<p>Reproduce with <code>quad-drake run config.yaml</code> in this folder: the new run is "
        "written beside this one (this folder's name with <code>-2</code>), which it leaves as it is.</p>"
    )
    parts.append(f"<pre>{esc(dump_scenario(scenario))}</pre>")
    return write_text_atomic(path, html_page(f"quad_drake: {scenario.name}", "\n".join(parts)))


def fault_spans(scenario) -> list[tuple[float, float, str]]:
    """[(start, end, label)] s of the scenario's injected faults, for shading: a window fault's
    [start, end); a GPS outlier's sample at ``time`` (end = start); a GPS delay over the whole
    flight. Every vehicle's faults, labelled with the vehicle when there are several."""
    spans = []
    several = len(scenario.vehicles) > 1
    for vehicle in scenario.vehicles:
        for fault in vehicle.faults:
            label = f"{vehicle.name}: {fault.kind}" if several else fault.kind
            if fault.kind == "gps_outlier":
                spans.append((fault.time, fault.time, label))
            elif fault.kind == "gps_delay":
                spans.append((0.0, scenario.end_time, f"{label} {fault.delay:g} s"))
            else:
                spans.append((fault.start, fault.end, label))
    return spans


def gust_spans(scenario) -> list[tuple[float, float, str]]:
    """[(start, end, label)] s of the scenario's wind gusts, for shading: each gust's
    [start, start + duration], labelled with its peak and direction (NED) and, when there are
    several vehicles, the vehicle."""
    spans = []
    several = len(scenario.vehicles) > 1
    for vehicle in scenario.vehicles:
        for gust in vehicle.wind.gusts if vehicle.wind is not None else ():
            direction = ", ".join(f"{x:g}" for x in gust.direction)
            label = f"gust {gust.amplitude:g} m/s along ({direction})"
            spans.append(
                (gust.start, gust.start + gust.duration, f"{vehicle.name}: {label}" if several else label)
            )
    return spans


def touchdowns(result) -> dict[str, list[tuple[float, float]]]:
    """{vehicle: [(time s, descent speed m/s)]} of every touchdown after take-off
    (``V.TouchdownSpeed``, ``signals.touchdown_speeds``), in time order; vehicles without one
    left out."""
    found = {}
    for vehicle in result.scenario.vehicles:
        signal = result.signals.get(f"{vehicle.name}.TouchdownSpeed")
        if signal is None:
            continue
        counts = result.signals[f"{vehicle.name}.FloorTouchdowns"].values
        new = np.flatnonzero(np.diff(counts, prepend=counts[:1]) > 0)
        if new.size:
            found[vehicle.name] = [(float(result.times[k]), float(signal.values[k])) for k in new]
    return found


def touchdown_marks(result) -> list[tuple[float, str]]:
    """[(time s, label)] of the touchdowns worth marking: each vehicle's first (the landing) and
    its fastest when that is another; the label names the time and descent speed, the first's
    also how many more there were and how fast (a vehicle at rest on the floor touches it again
    and again at mm/s)."""
    several = len(result.scenario.vehicles) > 1
    marks = []
    for vehicle, found in touchdowns(result).items():
        name = f"{vehicle} " if several else ""
        first = found[0]
        fastest = max(found, key=lambda touchdown: touchdown[1])
        shown = [first] if fastest is first else [first, fastest]
        rest = [speed for time, speed in found if (time, speed) not in shown]
        for time, speed in shown:
            label = f"{name}touchdown {time:.2f} s, {speed:.2f} m/s"
            if time == first[0] and rest:
                label += f" ({len(rest)} more, each ≤ {max(rest):.2g} m/s)"
            marks.append((time, label))
    return marks


def failsafe_marks(result) -> list[tuple[float, str]]:
    """[(time s, label)] of each no-aiding failsafe phase change (``V.Failsafe.Phase``,
    ``control.failsafe``): when the position was declared invalid and the vehicle began to
    descend, landed (motors idle), or resumed its mission."""
    several = len(result.scenario.vehicles) > 1
    words = {
        1.0: "position invalid: failsafe descent",
        2.0: "failsafe: landed, motors idle",
        0.0: "mission resumed",
    }
    marks = []
    for vehicle in result.scenario.vehicles:
        signal = result.signals.get(f"{vehicle.name}.Failsafe.Phase")
        if signal is None:
            continue
        phase = signal.values
        for k in np.flatnonzero(phase[1:] != phase[:-1]) + 1:
            name = f"{vehicle.name} " if several else ""
            marks.append((float(result.times[k]), f"{name}{words[float(phase[k])]} {result.times[k]:.2f} s"))
    return marks


def events_html(result) -> list[str]:
    """[a paragraph naming the gusts and the touchdowns (marked on the plots)], or []."""
    words = [f"{label} in [{start:g}, {end:g}] s" for start, end, label in gust_spans(result.scenario)]
    words += [label for _, label in touchdown_marks(result) + failsafe_marks(result)]
    if not words:
        return []
    return [f"<p>Events (marked on the time plots): {esc('; '.join(words))}.</p>"]


def faults_html(scenario) -> list[str]:
    """[a paragraph naming the injected faults and their windows (shaded on the plots)], or []."""
    spans = fault_spans(scenario)
    if not spans:
        return []
    words = [
        f"{label} at {start:g} s" if end == start else f"{label} in [{start:g}, {end:g}) s"
        for start, end, label in spans
    ]
    return [f"<p>Injected fault (hatched red on the time plots): {esc('; '.join(words))}.</p>"]


# ----- out/index.html ------------------------------------------------------------------------


def find_summaries(out_dir) -> list[tuple[Path, dict]]:
    """[(folder, summary dict)] of every run and campaign folder under out_dir (any depth)
    whose summary.json has the supported format_version, sorted by folder."""
    found = []
    for path in sorted(Path(out_dir).rglob("summary.json")):
        try:
            summary = read_summary(path)
        except ConfigError:  # a batch list, an older format, a foreign file: not linked
            continue
        if summary.get("kind") in ("run", "campaign", "replay"):
            found.append((path.parent, summary))
    return found


def _links(folder, out_dir, names):
    return " · ".join(
        f'<a href="{esc(os.path.relpath(folder / name, out_dir))}">{label}</a>'
        for name, label in names
        if (folder / name).is_file()
    )


def find_tune_sessions(out_dir) -> list[tuple[Path, dict]]:
    """[(folder, tune.json dict)] of every tune session folder under out_dir, sorted by folder."""
    found = []
    for path in sorted(Path(out_dir).rglob("tune.json")):
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError):
            continue
        if isinstance(data, dict) and "best_loss" in data:
            found.append((path.parent, data))
    return found


def _tune_row(folder, data, out_dir):
    holdout = data.get("holdout")
    passes = "–"
    if holdout:
        before, after = holdout["before"], holdout["after"]
        passes = f"{before['passes']}/{before['runs']} → {after['passes']}/{after['runs']}"
    return [
        esc(os.path.relpath(folder, out_dir)),
        esc(data["scenario"]),
        esc(data["settings"]["objective"]),
        (str(data["candidates"]) + (" (interrupted)" if data.get("interrupted") else ""), "num"),
        (f"{num(data['start_loss'], 4)} → {num(data['best_loss'], 4)}", "num"),
        (esc(passes), "num"),
        _links(folder, out_dir, (("report.html", "tune page"), ("tuned.yaml", "tuned.yaml"))) or "–",
    ]


def _run_row(folder, summary, out_dir):
    criteria = summary["criteria"]
    return [
        esc(os.path.relpath(folder, out_dir)),
        esc(summary["scenario"]),
        str(summary["seed"]),
        verdict_cell(summary["passed"] if criteria else None),
        f"{sum(bool(c['passed']) for c in criteria)}/{len(criteria)}",
        (num(summary["wall_time_s"], 3), "num"),
        (num(summary["real_time_factor"], 3), "num"),
        _links(folder, out_dir, (("report.html", "report"), ("replay.html", "3D replay"))) or "–",
        "<br>".join(esc(c["line"]) for c in criteria if "line" in c and not c["passed"]),
    ]


def _campaign_row(folder, summary, out_dir):
    every = [c for c in summary["criteria"] if c["criterion"] == "all criteria"]
    rate = "–"
    if every:
        low, high = every[0]["ci95"]
        rate = f"{num(100 * every[0]['rate'], 3)} % [{num(100 * low, 3)}, {num(100 * high, 3)}]"
    runs = f"{summary['runs']}" + (" (partial)" if summary.get("partial") else "")
    judged = summary["consistency_passed"] if summary["consistency"] else None
    return [
        esc(os.path.relpath(folder, out_dir)),
        esc(summary["scenario"]),
        esc(runs),
        str(summary["first_seed"]),
        verdict_cell(judged),
        (esc(rate), "num"),
        (num(summary["timing"]["wall_time_s"], 3), "num"),
        _links(folder, out_dir, (("report.html", "campaign page"), ("table.txt", "table"))) or "–",
        "<br>".join(esc(line) for line in summary.get("failure_reasons", [])),
    ]


def _replay_row(folder, summary, out_dir):
    """A replay's index row (``flightlogs.replay``): its log, estimator and largest differences."""
    rms = {d["state"]: d["rms"] for d in summary["differences"]}
    nis = ", ".join(
        f"{s['sensor']} {num(s['mean'], 3)}" + (" ✓" if s["in_band"] else "") for s in summary["nis"]
    )
    return [
        esc(os.path.relpath(folder, out_dir)),
        esc(summary["scenario"]),
        esc(summary["estimator"]),
        (", ".join(num(rms.get(s), 3) for s in ("Roll", "Pitch", "Yaw")), "num"),
        (", ".join(num(rms.get(s), 3) for s in ("X", "Y", "Z")) if "X" in rms else "–", "num"),
        esc(nis) or "–",
        _links(folder, out_dir, (("report.html", "report"),)) or "–",
    ]


def _index_section(title, header, rows, hint):
    """[heading, table of rows] of an index section, or [heading, "None yet: <hint>."]."""
    table = html_table(header, rows) if rows else f"<p>None yet: {hint}.</p>"
    return [f"<h2>{esc(title)}</h2>", table]


def write_index(out_dir) -> Path:
    """out_dir/index.html linking every run and campaign folder under out_dir (see find_summaries)."""
    out_dir = Path(out_dir)
    with locked(out_dir):  # concurrent invocations: the last one to write has seen every folder
        return _write_index(out_dir)


def _write_index(out_dir):
    found = find_summaries(out_dir)
    runs = [(f, s) for f, s in found if s["kind"] == "run"]
    campaigns = [(f, s) for f, s in found if s["kind"] == "campaign"]
    graded = [s for _, s in runs if s["criteria"]]
    parts = ["<h1>quad_drake results</h1>", "<h2>Runs</h2>"]
    if graded:
        parts.append(f"<p>{sum(s['passed'] for s in graded)} of {len(graded)} graded runs passed.</p>")
    elif runs:
        parts.append("<p>No run here is graded (none has criteria).</p>")
    else:
        parts.append("<p>None yet: <code>quad-drake run NAME</code> writes one.</p>")
    if runs:
        parts.append(
            html_table(
                [
                    "folder",
                    "scenario",
                    "seed",
                    "result",
                    "criteria",
                    "wall [s]",
                    "× real time",
                    "open",
                    "failed",
                ],
                [_run_row(f, s, out_dir) for f, s in runs],
            )
        )
        parts.append("<p>One line per run; each run's criteria, plots and health are on its report.</p>")
    campaign_header = ["folder", "scenario", "runs", "first seed", "consistency"]
    campaign_header += ["all criteria passed (95% CI)", "wall [s]", "open", "failed"]
    parts += _index_section(
        "Monte Carlo campaigns",
        campaign_header,
        [_campaign_row(f, s, out_dir) for f, s in campaigns],
        "<code>quad-drake montecarlo NAME</code> writes one",
    )
    replay_header = [
        "folder",
        "log",
        "estimator",
        "RMS roll, pitch, yaw − PX4 [rad]",
        "RMS x, y, z − PX4 [m]",
    ]
    replay_header += ["mean NIS (✓ in band)", "open"]
    parts += _index_section(
        "Flight-log replays (compared with PX4's estimate, not the truth)",
        replay_header,
        [_replay_row(f, s, out_dir) for f, s in found if s["kind"] == "replay"],
        "<code>quad-drake replay LOG</code> writes one",
    )
    tune_header = ["folder", "scenario", "objective", "candidates", "loss start → best"]
    tune_header += ["held-out passes start → tuned", "open"]
    parts += _index_section(
        "Tuning sessions",
        tune_header,
        [_tune_row(f, d, out_dir) for f, d in find_tune_sessions(out_dir)],
        "<code>quad-drake tune NAME</code> writes one",
    )
    path = out_dir / "index.html"
    return write_text_atomic(path, html_page("quad_drake results", "\n".join(parts)))
