"""Self-contained HTML: a run's report.html and the index.html of a batch of runs.

Both open from disk with no network: plots are embedded as base64 PNG data URIs,
the style is inline, links to sibling files (replay.html, reports) are relative.
"""

import base64
import html
import math
import os
from pathlib import Path

import numpy as np

from .config import dump_scenario

EST_KEYS = ("X", "Y", "Z", "VX", "VY", "VZ", "Yaw")
EST_UNITS = {"X": "m", "Y": "m", "Z": "m", "VX": "m/s", "VY": "m/s", "VZ": "m/s", "Yaw": "rad"}
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


def _esc(value):
    return html.escape(str(value))


def _num(value, digits=4):
    if value is None:
        return "–"
    value = float(value)
    return f"{value:.{digits}g}" if math.isfinite(value) else str(value)


def _page(title, body):
    return (
        f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{_esc(title)}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n{body}\n</body>\n</html>\n"
    )


def _table(header, rows):
    """HTML table; a row cell is text, or (text, css class)."""
    head = "".join(f"<th>{_esc(h)}</th>" for h in header)
    lines = [f"<table>\n<tr>{head}</tr>"]
    for row in rows:
        cells = []
        for cell in row:
            text, css = cell if isinstance(cell, tuple) else (cell, "")
            cells.append(f'<td class="{css}">{text}</td>' if css else f"<td>{text}</td>")
        lines.append(f"<tr>{''.join(cells)}</tr>")
    return "\n".join(lines) + "\n</table>"


def _verdict(passed):
    word = "PASS" if passed else "FAIL"
    return (word, word)


def criterion_row(criterion, verdict):
    """[criterion, kind, verdict, measured, required] cells (HTML-escaped) of one criterion."""
    if criterion.kind == "fleet_sigma":
        what = (
            f"|V.{criterion.signal}| ≤ {criterion.sigma_multiple:g} × V.{criterion.sigma_signal} "
            "over every vehicle V"
        )
        measured = f"{_num(verdict.percent, 3)} % of {verdict.samples} samples within"
        required = f"share in [{criterion.min_percent:g} %, {criterion.max_percent:g} %]"
        return [_esc(what), "fleet_sigma", _verdict(verdict.passed), _esc(measured), _esc(required)]
    if criterion.kind == "sigma":
        ref = criterion.ref_signal or f"{criterion.ref:g}"
        sigma = criterion.sigma_signal or f"{criterion.sigma:g}"
        what = f"|{criterion.signal} − {ref}| ≤ {sigma}"
        percent = getattr(verdict, "percent", None)
        measured = (
            f"{_num(percent, 3)} % of {verdict.samples} samples within; "
            f"share inside the band for the last {_num(verdict.measured)} s"
        )
        required = (
            f"share in ({criterion.min_percent:g} %, {criterion.max_percent:g} %) "
            f"for the last ≥ {criterion.window:g} s"
        )
    else:
        what = f"|{criterion.signal}| ≤ {criterion.threshold:g}"
        measured = f"longest stretch within: {_num(verdict.measured)} s"
        required = f"&gt; {criterion.window:g} s"
        return [_esc(what), "window", _verdict(verdict.passed), _esc(measured), required]
    return [_esc(what), "sigma", _verdict(verdict.passed), _esc(measured), _esc(required)]


def _stats(values):
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return float("nan"), float("nan")
    return float(np.sqrt(np.mean(values * values))), float(np.max(np.abs(values)))


def key_metrics(result):
    """[(vehicle, what, unit, rms, max |.|)] over the whole run, for the signals a run has."""
    rows = []
    for vehicle in (v.name for v in result.scenario.vehicles):
        for key, what, unit in METRICS:
            signal = result.signals.get(f"{vehicle}.{key}")
            if signal is not None:
                rows.append((vehicle, what, unit, *_stats(signal.values)))
    return rows


def ekf_consistency(result):
    """[(vehicle, state, unit, rms error, max |error|, % within ±σ, % within ±2σ)] per EKF state."""
    rows = []
    for vehicle in (v.name for v in result.scenario.vehicles):
        if f"{vehicle}.Est.E.X" not in result.signals:
            continue
        for key in EST_KEYS:
            error = np.abs(result.signals[f"{vehicle}.Est.E.{key}"].values)
            sigma = result.signals[f"{vehicle}.Est.S.{key}"].values
            within = [
                float(np.mean(error <= k * sigma) * 100) if error.size else float("nan") for k in (1, 2)
            ]
            rows.append((vehicle, key, EST_UNITS[key], *_stats(error), *within))
    return rows


def _image(path):
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return f'<img alt="{_esc(Path(path).stem)}" src="data:image/png;base64,{data}">'


def write_report(result, path, plots=(), replay=None):
    """report.html for a SimulationResult: verdicts, metrics, plots [(caption, png)], config."""
    path = Path(path)
    scenario = result.scenario
    criteria = list(zip(scenario.criteria, result.criteria, strict=True))
    overall = ("–", "NONE") if not criteria else _verdict(all(v.passed for _, v in criteria))
    rate = scenario.end_time / result.wall_time if result.wall_time > 0 else float("inf")
    parts = [
        f'<h1>{_esc(scenario.name)} <span class="{overall[1]}">&nbsp;{overall[0]}&nbsp;</span></h1>',
        f"<p>{_esc(scenario.description)}</p>",
        _table(
            ["seed", "simulated [s]", "wall time [s]", "× real time", "vehicles"],
            [
                [
                    str(scenario.seed),
                    _num(scenario.end_time),
                    _num(result.wall_time, 3),
                    _num(rate, 3),
                    _esc(", ".join(v.name for v in scenario.vehicles)),
                ]
            ],
        ),
    ]
    if replay is not None:
        parts.append(
            f'<p>3D replay: <a href="{_esc(os.path.relpath(replay, path.parent))}">'
            "replay.html</a> (Meshcat; opens offline).</p>"
        )
    parts.append("<h2>Criteria</h2>")
    if criteria:
        parts.append(
            _table(
                ["criterion", "kind", "result", "measured", "required"],
                [criterion_row(c, v) for c, v in criteria],
            )
        )
        parts.append("<pre>" + _esc("\n".join(v.line for _, v in criteria)) + "</pre>")
    else:
        parts.append("<p>This scenario has no pass/fail criteria; judge it from the plots.</p>")
    metrics = key_metrics(result)
    if metrics:
        parts.append("<h2>Key metrics</h2>")
        parts.append(
            _table(
                ["vehicle", "quantity", "unit", "RMS", "max |·|"],
                [
                    [_esc(v), _esc(w), _esc(u), (_num(r), "num"), (_num(m), "num")]
                    for v, w, u, r, m in metrics
                ],
            )
        )
    consistency = ekf_consistency(result)
    if consistency:
        parts.append(
            "<h2>EKF errors against the predicted σ</h2>"
            "<p>A consistent filter has about 68 % of its errors within ±σ and 95 % within ±2σ.</p>"
        )
        parts.append(
            _table(
                ["vehicle", "state", "unit", "RMS error", "max |error|", "within ±σ [%]", "within ±2σ [%]"],
                [
                    [
                        _esc(v),
                        _esc(k),
                        _esc(u),
                        (_num(r), "num"),
                        (_num(m), "num"),
                        (_num(a, 3), "num"),
                        (_num(b, 3), "num"),
                    ]
                    for v, k, u, r, m, a, b in consistency
                ],
            )
        )
    if plots:
        parts.append("<h2>Plots</h2>")
        parts.extend(
            f"<figure><figcaption>{_esc(caption)}</figcaption>{_image(png)}</figure>"
            for caption, png in plots
        )
    parts.append(
        "<h2>Resolved configuration</h2>"
        "<p>Reproduce with <code>quad-drake run config.yaml</code> in this folder.</p>"
    )
    parts.append(f"<pre>{_esc(dump_scenario(scenario))}</pre>")
    path.write_text(_page(f"quad_drake: {scenario.name}", "\n".join(parts)), encoding="utf-8")
    return path


def write_index(summaries_with_dirs, out_dir):
    """index.html in out_dir linking every run's report: [(summary dict, run dir)] in order."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for summary, run_dir in summaries_with_dirs:
        run_dir = Path(run_dir)
        criteria = summary["criteria"]
        verdict = ("–", "NONE") if not criteria else _verdict(summary["passed"])
        links = [
            f'<a href="{_esc(os.path.relpath(run_dir / name, out_dir))}">{label}</a>'
            for name, label in (("report.html", "report"), ("replay.html", "3D replay"))
            if (run_dir / name).is_file()
        ]
        lines = "<br>".join(_esc(c["line"]) for c in criteria if "line" in c)
        rows.append(
            [
                _esc(summary["scenario"]),
                str(summary["seed"]),
                verdict,
                f"{sum(bool(c['passed']) for c in criteria)}/{len(criteria)}",
                (_num(summary["wall_time_s"], 3), "num"),
                (_num(summary["real_time_factor"], 3), "num"),
                " · ".join(links) or "–",
                lines,
            ]
        )
    passed = sum(1 for summary, _ in summaries_with_dirs if summary["passed"] and summary["criteria"])
    graded = sum(1 for summary, _ in summaries_with_dirs if summary["criteria"])
    body = f"<h1>quad_drake runs</h1><p>{passed} of {graded} graded scenarios passed.</p>" + _table(
        ["scenario", "seed", "result", "criteria", "wall [s]", "× real time", "open", "analyzer lines"], rows
    )
    path = out_dir / "index.html"
    path.write_text(_page("quad_drake runs", body), encoding="utf-8")
    return path
