"""Reference-style plots of one run, and the run folder's artifacts (PNGs, report, replay).

Figures are drawn on matplotlib's Agg canvas without pyplot (no global state, no
GUI), so they are safe in the CLI, in tests and in a notebook. Which figures a run
gets follows from what it logged, so a new scenario needs no plot code:

- one figure per criterion: the signal with its threshold (window) or its samples
  with the ref ± sigma band and the cumulative in-band share (sigma);
- flight traces: position and attitude against the reference, motor thrusts, and
  the top view of the flown, reference and estimated paths;
- for one or two vehicles with an estimator: true vs estimated attitude and
  states, and every EKF error against its ±sigma; with ``run --smooth`` (the logs'
  ``smoothed_state``) the RTS-smoothed position and velocity beside the estimate and the
  smoother's errors against its ±sigma beside the filter's;
- for a fleet (three or more estimating vehicles): every vehicle's x / vx
  (y / vy) error inside the first vehicle's ±sigma envelope (reference 09);
- in wind: the wind at the vehicle, its steady part (mean + gusts) and its turbulence;
- with a barometer, a 3-axis magnetometer or a faulted yaw magnetometer: the measurement
  itself beside what the truth and the estimate make of it (height, body field, yaw);
- with a no-aiding failsafe: the time without position aiding against its timeout, the phase
  and the position's validity, and the height it descends on.

On every time panel: injected faults hatched red (hatching, not a fill, so a fault over a
judged green band stays red and green), gust windows shaded blue, touchdowns as dash-dotted
lines named with their time and descent speed in the first panel's legend, and the failsafe's
phase changes the same way.
"""

import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ..estimation.mag3 import assumed_world_field, predicted_field
from ..estimation.registry import vehicle_vocabulary
from ..estimation.vocabulary import smoothed_errors
from ..judging.consistency import fleet_sigma_fraction
from ..judging.evaluation import judged_criteria, sigma_share
from ..judging.signals import key_unit, signal_unit
from ..models.sensor_models import world_field
from ..models.wind import steady_wind
from .outdir import write_binary_atomic
from .report import failsafe_marks, fault_spans, gust_spans, touchdown_marks, write_report

__all__ = ["make_figures", "write_plots", "write_report", "write_run_artifacts"]

DPI = 80
COLORS = (
    "tab:blue",
    "tab:orange",
    "tab:green",
    "tab:red",
    "tab:purple",
    "tab:brown",
    "tab:pink",
    "tab:gray",
    "tab:olive",
    "tab:cyan",
)
FLEET_SIZE = 3
"""Three or more vehicles with an estimator get the fleet plot instead of per-vehicle ones."""
MOTOR_NAMES = ("front left", "front right", "rear left", "rear right")


def _label(text, unit):
    return f"{text} [{unit}]" if unit else text


def _figure(rows, cols, width=8.0, height_per_row=2.0, title=""):
    fig = Figure(figsize=(width, 0.8 + height_per_row * rows), dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False, sharex=True)
    fig.subplots_adjust(
        left=1.0 / width,
        right=0.98,
        bottom=0.55 / (0.8 + height_per_row * rows),  # room for the time label
        top=1.0 - 0.55 / (0.8 + height_per_row * rows),
        hspace=0.35,
        wspace=0.45,
    )
    fig.suptitle(title, fontsize=11)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    for ax in axes.flat:
        ax.grid(True, alpha=0.3)
        ax.yaxis.set_major_locator(MaxNLocator(nbins=4))
    fig.time_axes = list(axes.flat)  # what shade_faults marks (every panel here has time as x)
    return fig, axes


FAULT_COLOR = "tab:red"
GUST_COLOR = "tab:blue"
TOUCHDOWN_COLOR = "k"
MEASURED_COLOR = "tab:orange"


def shade_faults(fig, spans) -> None:
    """Mark each fault span on every time panel of `fig` (``fig.time_axes``): red hatching between
    two red edges, no fill (a fill over the judged green band would turn brown); a zero-length
    span (one sample) is a vertical line. The first panel's legend names them."""
    for k, ax in enumerate(getattr(fig, "time_axes", ())):
        for start, end, label in spans:
            shown = f"fault: {label}" if k == 0 else None
            if end > start:
                ax.axvspan(
                    start,
                    end,
                    facecolor="none",
                    edgecolor=FAULT_COLOR,
                    hatch="///",
                    lw=0.8,
                    alpha=0.55,
                    label=shown,
                )
            else:
                ax.axvline(start, color=FAULT_COLOR, lw=1.2, alpha=0.6, label=shown)
        if k == 0 and spans:
            ax.legend(loc="best", fontsize=7)


def mark_events(fig, gusts, landings) -> None:
    """Mark the flight's events on every time panel of `fig`: each gust window (start, end, label)
    shaded blue, each touchdown (time s, label: ``report.touchdown_marks``) a dash-dotted line;
    the first panel's legend names them."""
    for k, ax in enumerate(getattr(fig, "time_axes", ())):
        for start, end, label in gusts:
            ax.axvspan(start, end, color=GUST_COLOR, alpha=0.1, lw=0, label=label if k == 0 else None)
        for time, label in landings:
            ax.axvline(
                time, color=TOUCHDOWN_COLOR, ls="-.", lw=1.0, alpha=0.8, label=label if k == 0 else None
            )
        if k == 0 and (gusts or landings):
            ax.legend(loc="best", fontsize=7)


def _vehicles(result):
    return [v.name for v in result.scenario.vehicles]


def _estimating(result):
    return [v for v in _vehicles(result) if f"{v}.Est.X" in result.signals]


def _values(result, name):
    return result.signals[name].values


def _color(i):
    return COLORS[i % len(COLORS)]


def _robust_ylim(ax, values, threshold):
    """Keep a threshold readable when the signal runs far outside it (diverged runs)."""
    finite = np.abs(values[np.isfinite(values)])
    if threshold > 0 and finite.size and finite.max() > 8 * threshold:
        low = -8 * threshold if np.min(values[np.isfinite(values)]) < 0 else -0.4 * threshold
        ax.set_ylim(low, 8 * threshold)
        return True
    return False


def _window_figure(result, criterion, verdict):
    times = result.times
    signal = result.signals[criterion.signal]
    unit = signal_unit(criterion.signal)
    fig, axes = _figure(
        1,
        1,
        height_per_row=3.0,
        title=(
            f"{criterion.signal}: |x| ≤ {criterion.threshold:g} {unit} for > {criterion.window:g} s  —  "
            f"{'PASS' if verdict.passed else 'FAIL'} (longest {verdict.measured:.3f} s)"
        ),
    )
    ax = axes[0, 0]
    values = signal.values
    if signal.fresh.all():
        ax.plot(times, values, lw=1.0, color="tab:blue", label=criterion.signal)
    else:
        ax.plot(
            times[signal.fresh],
            values[signal.fresh],
            ".",
            ms=3,
            color="tab:blue",
            label=f"{criterion.signal} (fresh samples)",
        )
    ax.axhline(
        criterion.threshold, color="tab:red", ls="--", lw=1.0, label=f"± threshold {criterion.threshold:g}"
    )
    if np.nanmin(values) < 0:
        ax.axhline(-criterion.threshold, color="tab:red", ls="--", lw=1.0)
    if verdict.series is not None:
        start, end = verdict.series["span"]
        ax.axvspan(
            start,
            end,
            color="tab:green" if verdict.passed else "tab:orange",
            alpha=0.15,
            label=f"longest stretch within ({end - start:.2f} s, needs > {criterion.window:g} s)",
        )
    _robust_ylim(ax, values, criterion.threshold)
    ax.set_ylabel(_label(criterion.signal.split(".", 1)[-1], unit))
    ax.legend(loc="upper right", fontsize=8)
    return fig


def _sigma_inputs(result, criterion):
    n = result.times.size
    ref = _values(result, criterion.ref_signal) if criterion.ref_signal else np.full(n, criterion.ref)
    sigma = _values(result, criterion.sigma_signal) if criterion.sigma_signal else np.full(n, criterion.sigma)
    return ref, sigma


def _sigma_figure(result, criterion, verdict):
    times = result.times
    signal = result.signals[criterion.signal]
    unit = signal_unit(criterion.signal)
    ref, sigma = _sigma_inputs(result, criterion)
    percent = getattr(verdict, "percent", None)
    fig, axes = _figure(
        2,
        1,
        height_per_row=2.4,
        title=(
            f"{criterion.signal}: {percent if percent is not None else float('nan'):.0f} % of samples within "
            f"ref ± σ (needs {criterion.min_percent:g}–{criterion.max_percent:g} % over the last "
            f"{criterion.window:g} s)  —  {'PASS' if verdict.passed else 'FAIL'}"
        ),
    )
    ax = axes[0, 0]
    sigma_label = criterion.sigma_signal or f"{criterion.sigma:g} {unit}"
    ax.fill_between(
        times,
        ref - sigma,
        ref + sigma,
        color="tab:green",
        alpha=0.2,
        lw=0,
        label=f"ref ± σ (σ = {sigma_label})",
    )
    ax.plot(times, ref, color="k", lw=0.8, label=f"ref ({criterion.ref_signal or f'{criterion.ref:g}'})")
    fresh = signal.fresh
    ax.plot(
        times[fresh],
        signal.values[fresh],
        ".",
        ms=3 if fresh.sum() < 0.5 * fresh.size else 1.5,
        color="tab:blue",
        label=f"{criterion.signal} samples",
    )
    for edge in (ref - sigma, ref + sigma):
        ax.plot(times, edge, color="tab:green", lw=1.0, zorder=3)
    ax.set_ylabel(_label(criterion.signal.split(".", 1)[-1], unit))
    ax.legend(loc="upper right", fontsize=8)

    ax = axes[1, 0]
    series = verdict.series or {"times": np.zeros(0), "percent": np.zeros(0)}
    t = series["times"]
    ax.plot(t, series["percent"], color="tab:blue", lw=1.0, label="cumulative share within ±σ")
    ax.axhspan(
        criterion.min_percent,
        criterion.max_percent,
        color="tab:green",
        alpha=0.15,
        label=f"({criterion.min_percent:g}, {criterion.max_percent:g}) %",
    )
    if t.size:
        ax.axvspan(
            t[-1] - criterion.window,
            t[-1],
            color="tab:gray",
            alpha=0.2,
            label=f"last {criterion.window:g} s (must stay inside)",
        )
    ax.set_ylim(0, 100)
    ax.set_ylabel("within ±σ [%]")
    ax.legend(loc="lower right", fontsize=8)
    return fig


def _interval_figure(result, criterion, verdict, title, judged, markers):
    """|signal| over the flight against the threshold, the judged interval shaded (judged:
    (start, end, label)), markers: [(time, label)] as vertical lines."""
    signal = result.signals[criterion.signal]
    unit = signal_unit(criterion.signal)
    fig, axes = _figure(1, 1, height_per_row=3.0, title=title)
    ax = axes[0, 0]
    values = np.abs(signal.values)
    if signal.fresh.all():
        ax.plot(result.times, values, lw=1.0, color="tab:blue", label=f"|{criterion.signal}|")
    else:
        fresh = signal.fresh
        ax.plot(
            result.times[fresh], values[fresh], ".", ms=3, color="tab:blue", label=f"|{criterion.signal}|"
        )
    ax.axhline(
        criterion.threshold, color="tab:red", ls="--", lw=1.0, label=f"threshold {criterion.threshold:g}"
    )
    start, end, label = judged
    ax.axvspan(start, end, color="tab:green" if verdict.passed else "tab:orange", alpha=0.15, label=label)
    for time, text in markers:
        ax.axvline(time, color="k", lw=1.0, ls=":", label=text)
    _robust_ylim(ax, values, criterion.threshold)
    ax.set_ylabel(_label(f"|{criterion.signal}|", unit))
    ax.legend(loc="upper left", fontsize=7)
    return fig


def _bound_figure(result, criterion, verdict):
    """A ``bound`` criterion: |x| < threshold on every sample of [start, end)."""
    markers = (
        [] if verdict.trailing is None else [(verdict.trailing, f"first above at {verdict.trailing:.3g} s")]
    )
    title = (
        f"{criterion.signal}: |x| < {criterion.threshold:g} in [{criterion.start:g}, {criterion.end:g}) s"
        f"  —  {'PASS' if verdict.passed else 'FAIL'} ({verdict.measured_text})"
    )
    judged = (criterion.start, criterion.end, f"judged [{criterion.start:g}, {criterion.end:g}) s")
    return _interval_figure(result, criterion, verdict, title, judged, markers)


def _recovery_figure(result, criterion, verdict):
    """A ``recovery`` criterion: back under the threshold within ``window`` s after start, and
    staying there to the end of the run (the shaded part must be all under)."""
    deadline = criterion.start + criterion.window
    markers = [(criterion.start, f"start {criterion.start:g} s")]
    if math.isfinite(verdict.measured) and verdict.measured > 0:
        markers.append(
            (criterion.start + verdict.measured, f"back under at {criterion.start + verdict.measured:.3g} s")
        )
    title = (
        f"{criterion.signal}: |x| < {criterion.threshold:g} within {criterion.window:g} s after "
        f"{criterion.start:g} s  —  {'PASS' if verdict.passed else 'FAIL'} ({verdict.measured_text})"
    )
    judged = (deadline, result.scenario.end_time, f"must stay under from {deadline:g} s")
    return _interval_figure(result, criterion, verdict, title, judged, markers)


CRITERION_FIGURES = {
    "window": _window_figure,
    "sigma": _sigma_figure,
    "bound": _bound_figure,
    "recovery": _recovery_figure,
}
"""Criterion kinds drawn one figure each; fleet_sigma is drawn once in the fleet figure."""


def _traces_figure(result, title, rows, ref_of=None):
    """One panel per (label, key, unit) row, every vehicle's signal; dashed: its reference."""
    fig, axes = _figure(len(rows), 1, height_per_row=1.9, title=title)
    for (label, key, unit), ax in zip(rows, axes[:, 0], strict=True):
        for i, vehicle in enumerate(_vehicles(result)):
            ax.plot(result.times, _values(result, f"{vehicle}.{key}"), color=_color(i), lw=1.0, label=vehicle)
            ref_key = f"{vehicle}.{ref_of[key]}" if ref_of and key in ref_of else None
            if ref_key in result.signals:
                ax.plot(
                    result.times,
                    _values(result, ref_key),
                    color=_color(i),
                    lw=1.0,
                    ls="--",
                    label=f"{vehicle} reference",
                )
        ax.set_ylabel(_label(label, unit))
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=2)
    return fig


def _position_figure(result):
    rows = [(f"{a.lower()} (NED)", f"Pos.{a}", "m") for a in "XYZ"]
    return _traces_figure(
        result, "Position vs reference (dashed); NED, z down", rows, {f"Pos.{a}": f"Ref.{a}" for a in "XYZ"}
    )


def _attitude_figure(result):
    rows = [("roll", "Roll", "rad"), ("pitch", "Pitch", "rad"), ("yaw", "Yaw", "rad")]
    return _traces_figure(result, "Attitude (yaw reference dashed)", rows, {"Yaw": "Ref.Yaw"})


def _thrust_figure(result):
    """Each vehicle's four motor thrusts (up to three vehicles), else every vehicle's total."""
    vehicles = _vehicles(result)
    physics = result.scenario.vehicles[0].physics
    if len(vehicles) > 3:
        fig, axes = _figure(1, 1, height_per_row=2.6, title="Total thrust per vehicle")
        ax = axes[0, 0]
        for i, vehicle in enumerate(vehicles):
            total = sum(_values(result, f"{vehicle}.Thrust.{m}") for m in "ABCD")
            ax.plot(result.times, total, color=_color(i), lw=0.8, label=vehicle)
        ax.set_ylabel("thrust [N]")
        ax.legend(loc="upper right", fontsize=7, ncol=2)
        return fig
    fig, axes = _figure(
        len(vehicles), 1, height_per_row=2.2, title="Motor thrusts (dotted: the motors' limits)"
    )
    for vehicle, ax in zip(vehicles, axes[:, 0], strict=True):
        for i, (motor, name) in enumerate(zip("ABCD", MOTOR_NAMES, strict=True)):
            ax.plot(
                result.times,
                _values(result, f"{vehicle}.Thrust.{motor}"),
                color=_color(i),
                lw=0.8,
                label=f"{motor} ({name})",
            )
        for limit in (physics.min_motor_thrust, physics.max_motor_thrust):
            ax.axhline(limit, color="k", ls=":", lw=0.8)
        ax.set_ylabel(_label(f"{vehicle} thrust", "N"))
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=2)
    return fig


def _top_view_figure(result):
    fig = Figure(figsize=(6.5, 6.0), dpi=DPI)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    fig.subplots_adjust(left=0.12, right=0.97, bottom=0.1, top=0.9)
    single = len(result.scenario.vehicles) == 1
    for i, vehicle in enumerate(_vehicles(result)):
        color = _color(i)
        if f"{vehicle}.Ref.X" in result.signals:
            ax.plot(
                _values(result, f"{vehicle}.Ref.Y"),
                _values(result, f"{vehicle}.Ref.X"),
                color="k" if single else color,
                ls="--",
                lw=1.0,
                label=f"{vehicle} reference",
            )
        ax.plot(
            _values(result, f"{vehicle}.Pos.Y"),
            _values(result, f"{vehicle}.Pos.X"),
            color=color,
            lw=1.4,
            label=f"{vehicle} true",
        )
        if f"{vehicle}.Est.X" in result.signals:
            ax.plot(
                _values(result, f"{vehicle}.Est.Y"),
                _values(result, f"{vehicle}.Est.X"),
                color="tab:pink" if single else color,
                lw=0.8,
                ls="-.",
                label=f"{vehicle} estimated",
            )
        gps = result.signals.get(f"{vehicle}.GPS.X")
        if gps is not None and single:
            ax.plot(
                _values(result, f"{vehicle}.GPS.Y")[gps.fresh],
                gps.values[gps.fresh],
                ".",
                ms=2,
                color="tab:gray",
                label=f"{vehicle} GPS",
            )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("y (east) [m]")
    ax.set_ylabel("x (north) [m]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=7)
    ax.set_title("Top view: flown vs reference" + (" vs estimated" if _estimating(result) else "") + " path")
    return fig


def _attitude_estimate_figure(result, vehicle):
    fig, axes = _figure(
        2,
        1,
        height_per_row=2.6,
        title=f"{vehicle}: attitude estimation errors; true (solid) vs estimated (dashed)",
    )
    for j, angle in enumerate(("Roll", "Pitch", "Yaw")):
        color = _color(j)
        axes[0, 0].plot(
            result.times,
            _values(result, f"{vehicle}.Est.E.{angle}"),
            color=color,
            lw=1.0,
            label=f"{angle.lower()} error",
        )
        axes[1, 0].plot(
            result.times,
            _values(result, f"{vehicle}.{angle}"),
            color=color,
            lw=1.0,
            label=f"{angle.lower()} true",
        )
        axes[1, 0].plot(
            result.times,
            _values(result, f"{vehicle}.Est.{angle}"),
            color=color,
            lw=1.0,
            ls="--",
            label=f"{angle.lower()} estimated",
        )
    axes[0, 0].set_ylabel(_label("estimate - true", "rad"))
    axes[1, 0].set_ylabel(_label("angle", "rad"))
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=3)
    axes[1, 0].legend(loc="upper right", fontsize=7, ncol=3)
    return fig


def _state_estimate_figure(result, vehicle):
    fig, axes = _figure(
        2,
        3,
        width=10.0,
        height_per_row=2.4,
        title=f"{vehicle}: true vs estimated position and velocity (NED)",
    )
    smoothed = result.logs.get(vehicle, {}).get("smoothed_state")  # p, v first (run --smooth)
    for j, axis in enumerate("XYZ"):
        for row, (true_key, est_key, gps_key, unit) in enumerate(
            (
                (f"Pos.{axis}", f"Est.{axis}", f"GPS.{axis}", "m"),
                (f"Vel.{axis}", f"Est.V{axis}", f"GPS.V{axis}", "m/s"),
            )
        ):
            ax = axes[row, j]
            gps = result.signals.get(f"{vehicle}.{gps_key}")
            if gps is not None:
                ax.plot(
                    result.times[gps.fresh], gps.values[gps.fresh], ".", ms=2, color="tab:gray", label="GPS"
                )
            ax.plot(result.times, _values(result, f"{vehicle}.{true_key}"), color="k", lw=1.0, label="true")
            ax.plot(
                result.times,
                _values(result, f"{vehicle}.{est_key}"),
                color="tab:blue",
                lw=1.0,
                ls="--",
                label="estimated",
            )
            if smoothed is not None:
                ax.plot(result.times, smoothed[:, 3 * row + j], color="tab:orange", lw=1.0, label="smoothed")
            ax.set_ylabel(_label(("" if row == 0 else "v") + axis.lower(), unit))
    axes[0, 0].legend(loc="upper right", fontsize=7)
    return fig


def _estimate_errors_figure(result, vehicle):
    config = next(v for v in result.scenario.vehicles if v.name == vehicle)
    keys = vehicle_vocabulary(config).state_names[:7]  # 7 panels: the first (navigation) entries
    fig, axes = _figure(
        2, 4, width=12.0, height_per_row=2.4, title=f"{vehicle}: estimate errors (est - true) and their ±σ"
    )
    t = result.times
    for key, ax in zip(keys, axes.flat, strict=False):
        error = _values(result, f"{vehicle}.Est.E.{key}")
        sigma = _values(result, f"{vehicle}.Est.S.{key}")
        ax.fill_between(t, -sigma, sigma, color="tab:green", alpha=0.2, lw=0, label="±σ")
        ax.plot(t, error, color="tab:red", lw=0.8, label="error")
        within, total = sigma_share(error, sigma)
        inside = 100.0 * within / total if total else float("nan")
        ax.set_title(f"{key}: {inside:.0f} % within ±σ", fontsize=9, y=1.0)
        ax.set_ylabel(_label(f"{key} error", signal_unit(f"{vehicle}.Est.E.{key}")))
    ax = axes[1, 3]
    ax.plot(t, _values(result, f"{vehicle}.Est.E.Pos"), color="tab:red", lw=1.0, label="|p̂ - p|")
    ax.plot(t, _values(result, f"{vehicle}.Est.S.Z"), color="k", ls=":", lw=1.0, label="σ z")
    ax.set_title("position error norm and σ z", fontsize=9, y=1.0)
    ax.set_ylabel(_label("error", "m"))
    ax.legend(loc="upper right", fontsize=7)
    axes[0, 0].legend(loc="upper right", fontsize=7)
    return fig


def _smoothed_errors_figure(result, vehicle):
    """The RTS smoother's errors (est - true) of the 9 navigation states against its ±σ, beside the
    filter's (``quad-drake run --smooth``: the logs' ``smoothed_state`` and ``smoothed_sigma``)."""
    config = next(v for v in result.scenario.vehicles if v.name == vehicle)
    keys = vehicle_vocabulary(config).state_names[:9]
    logs = result.logs[vehicle]
    errors, sigma = smoothed_errors(logs), logs["smoothed_sigma"]
    title = f"{vehicle}: filter and RTS smoother errors (est - true), ±σ"
    fig, axes = _figure(3, 3, width=12.0, height_per_row=2.2, title=title)
    t = result.times
    for i, (key, ax) in enumerate(zip(keys, axes.flat, strict=True)):
        filter_sigma = _values(result, f"{vehicle}.Est.S.{key}")
        band = (-sigma[:, i], sigma[:, i])
        ax.fill_between(t, *band, color="tab:orange", alpha=0.25, lw=0, label="smoother ±σ")
        ax.plot(t, filter_sigma, color="tab:blue", ls=":", lw=0.8, label="filter ±σ")
        ax.plot(t, -filter_sigma, color="tab:blue", ls=":", lw=0.8)
        ax.plot(t, _values(result, f"{vehicle}.Est.E.{key}"), color="tab:blue", lw=0.6, label="filter")
        ax.plot(t, errors[:, i], color="tab:orange", lw=0.9, label="smoother")
        within, total = sigma_share(errors[:, i], sigma[:, i])
        inside = 100.0 * within / total if total else float("nan")
        ax.set_title(f"{key}: smoother {inside:.0f} % within ±σ", fontsize=9, y=1.0)
        ax.set_ylabel(_label(f"{key} error", signal_unit(f"{vehicle}.Est.E.{key}")))
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=2)
    return fig


def _fleet_figure(result, vehicles):
    fig, axes = _figure(
        2,
        2,
        width=10.0,
        height_per_row=2.6,
        title=(f"Fleet of {len(vehicles)}: estimation errors and {vehicles[0]}'s ±σ (dotted)"),
    )
    t = result.times
    for key, ax in zip(("X", "Y", "VX", "VY"), axes.T.flat, strict=True):
        for i, vehicle in enumerate(vehicles):
            ax.plot(t, _values(result, f"{vehicle}.Est.E.{key}"), color=_color(i), lw=0.8, label=vehicle)
        sigma = _values(result, f"{vehicles[0]}.Est.S.{key}")
        for sign, style in ((1, ":"), (-1, ":"), (2, "--"), (-2, "--")):
            ax.plot(t, sign * sigma, color="k", ls=style, lw=1.0)
        share = 100.0 * fleet_sigma_fraction(result.signals, f"Est.E.{key}", f"Est.S.{key}", 1.0)
        ax.set_title(f"{key} error: {share:.0f} % within ±σ (±2σ dashed)", fontsize=9, y=1.0)
        ax.set_ylabel(_label(f"{key} error", key_unit(f"Est.E.{key}")))
    axes[0, 0].legend(loc="upper left", fontsize=6, ncol=2)
    return fig


def _wind_figure(result, vehicle):
    """The wind at `vehicle` (``V.Wind.*``, m/s NED), one row per axis: left the wind and its
    steady part (mean + gusts, from its WindConfig), right its turbulence (the rest), when it
    has any."""
    config = next(v for v in result.scenario.vehicles if v.name == vehicle).wind
    t = result.times
    steady = np.array([steady_wind(time, config) for time in t]).reshape(t.size, 3)
    turbulent = config.turbulence != "none"
    fig, axes = _figure(
        3,
        2 if turbulent else 1,
        width=11.0 if turbulent else 8.0,
        height_per_row=1.9,
        title=f"{vehicle}: wind at the vehicle (NED) = steady (mean + gusts)"
        + (" + turbulence" if turbulent else ""),
    )
    for i, axis in enumerate(("north", "east", "down")):
        total = _values(result, f"{vehicle}.Wind.{'XYZ'[i]}")
        ax = axes[i, 0]
        ax.plot(t, total, color="tab:gray", lw=0.8, label="wind")
        ax.plot(t, steady[:, i], color="k", lw=1.6, label="steady: mean + gusts")
        ax.set_ylabel(_label(f"wind {axis}", "m/s"))
        if turbulent:
            axes[i, 1].plot(t, total - steady[:, i], color="tab:blue", lw=0.8, label="turbulence")
            axes[i, 1].set_ylabel(_label(f"turbulence {axis}", "m/s"))
    for ax in axes[0]:
        ax.legend(loc="upper left", fontsize=7, ncol=2)
    return fig


def _gsf_figure(result, vehicle):
    """The EKF-GSF yaw estimator beside `vehicle`'s estimator (``estimation/gsf.py``): top, the
    true yaw, the GSF's yaw with its ±σ band and the estimator's yaw (rad); middle, the weights of
    its hypotheses; bottom, the resets of the estimator's yaw to the GSF's."""
    t = result.times
    fig, axes = _figure(3, 1, height_per_row=2.0, title=f"{vehicle}: EKF-GSF yaw estimator")
    true_yaw = _values(result, f"{vehicle}.Yaw")
    gsf_yaw = _values(result, f"{vehicle}.Est.GsfYaw")
    sigma = _values(result, f"{vehicle}.Est.GsfYawStd")
    ax = axes[0, 0]
    ax.plot(t, true_yaw, color="k", lw=1.4, label="true")
    ax.plot(t, gsf_yaw, color="tab:orange", lw=1.0, label="GSF")
    ax.fill_between(t, gsf_yaw - sigma, gsf_yaw + sigma, color="tab:orange", alpha=0.2, label="GSF ±σ")
    ax.plot(t, _values(result, f"{vehicle}.Est.Yaw"), color="tab:blue", lw=0.8, ls="--", label="estimator")
    ax.set_ylabel(_label("yaw", "rad"))
    ax.legend(loc="upper right", fontsize=7, ncol=4)
    weights = sorted(name for name in result.signals if name.startswith(f"{vehicle}.Est.GsfWeight"))
    for i, name in enumerate(weights):
        axes[1, 0].plot(t, _values(result, name), color=_color(i), lw=0.9, label=name.rsplit(".", 1)[-1])
    axes[1, 0].set_ylabel("weight")
    axes[1, 0].set_ylim(-0.02, 1.05)
    axes[1, 0].legend(loc="upper right", fontsize=7, ncol=len(weights))
    axes[2, 0].step(t, _values(result, f"{vehicle}.Est.GsfResets"), where="post", color="tab:red")
    axes[2, 0].set_ylabel("yaw resets")
    return fig


def _failsafe_figure(result, vehicle):
    """The no-aiding failsafe of `vehicle` (``V.Failsafe.*``, ``control.failsafe``): the time without
    position aiding against its timeout, the phase with the position's validity, and the true
    and estimated height the descent flies on."""
    timeout = next(v for v in result.scenario.vehicles if v.name == vehicle).failsafe.no_aiding_timeout
    t = result.times
    fig, axes = _figure(3, 1, height_per_row=1.9, title=f"{vehicle}: position aiding and the failsafe")
    ax = axes[0, 0]
    ax.plot(
        t, _values(result, f"{vehicle}.Failsafe.NoAidTime"), color="tab:blue", lw=1.0, label="no aiding for"
    )
    ax.axhline(timeout, color="tab:red", ls="--", lw=1.0, label=f"timeout {timeout:g} s")
    ax.set_ylabel(_label("time without aiding", "s"))
    ax.legend(loc="upper left", fontsize=7)
    ax = axes[1, 0]
    ax.step(t, _values(result, f"{vehicle}.Failsafe.Phase"), where="post", color="k", lw=1.2, label="phase")
    ax.step(t, _values(result, f"{vehicle}.Failsafe.PositionValid"), where="post", color="tab:green", lw=1.0,
            ls="--", label="position valid (1 / 0)")  # fmt: skip
    ax.set_yticks([0, 1, 2], ["0 nominal", "1 descending", "2 landed"], fontsize=7)
    ax.legend(loc="upper left", fontsize=7)
    ax = axes[2, 0]
    ax.plot(t, -_values(result, f"{vehicle}.Pos.Z"), color="k", lw=1.2, label="true")
    if f"{vehicle}.Est.Z" in result.signals:
        ax.plot(t, -_values(result, f"{vehicle}.Est.Z"), color="tab:orange", lw=1.0, label="estimate")
    ax.set_ylabel(_label("height", "m"))
    ax.legend(loc="upper left", fontsize=7)
    return fig


def _field_assumed(config):
    """(m_N, hard iron) the vehicle's estimator assumes of a 3-axis magnetometer, or None."""
    params = getattr(config.estimator, "mag_field", None)
    if params is None:
        return None
    return np.array(assumed_world_field(params)), np.asarray(params.hard_iron, dtype=float)


def _measurement_panels(result, vehicle):
    """[(label, unit, times of the samples, measured samples, truth, estimate or None)] of the
    vehicle's measurements worth drawing beside the truth and the estimate: the barometer's
    height, the 3-axis magnetometer's body field, the yaw magnetometer's yaw when a fault acts on
    it (GPS has its own figure)."""
    config = next(v for v in result.scenario.vehicles if v.name == vehicle)
    t, signals = result.times, result.signals
    estimated = f"{vehicle}.Est.X" in signals
    panels = []
    baro = signals.get(f"{vehicle}.Baro.Height")
    if baro is not None:
        estimate = -_values(result, f"{vehicle}.Est.Z") if estimated else None
        panels.append(
            (
                "height, up",
                "m",
                t[baro.fresh],
                baro.values[baro.fresh],
                -_values(result, f"{vehicle}.Pos.Z"),
                estimate,
            )
        )
    if f"{vehicle}.Mag.X" in signals:
        mag = config.sensors.mag
        m_N = world_field(mag.field_strength, mag.declination, mag.inclination)
        q = result.logs[vehicle]["state"][:, 3:7].T
        truth = np.array(predicted_field(*q, *m_N)).T + np.asarray(mag.hard_iron)
        assumed = _field_assumed(config) if estimated else None
        estimate = None
        if assumed is not None:
            q_hat = result.logs[vehicle]["estimated_state"][:, 3:7].T
            estimate = np.array(predicted_field(*q_hat, *assumed[0])).T + assumed[1]
        for i, axis in enumerate("xyz"):
            sample = signals[f"{vehicle}.Mag.{axis.upper()}"]
            panels.append(
                (
                    f"field {axis} (body)",
                    "gauss",
                    t[sample.fresh],
                    sample.values[sample.fresh],
                    truth[:, i],
                    None if estimate is None else estimate[:, i],
                )
            )
    yaw = signals.get(f"{vehicle}.MagYaw")
    if yaw is not None and any(f.kind.startswith("mag_") for f in config.faults):
        estimate = _values(result, f"{vehicle}.Est.Yaw") if estimated else None
        panels.append(
            ("yaw", "rad", t[yaw.fresh], yaw.values[yaw.fresh], _values(result, f"{vehicle}.Yaw"), estimate)
        )
    return panels


def _measurement_figure(result, vehicle, panels):
    """Each measurement's samples (dots) beside the truth (black) and the estimate's own view of
    it (dashed): what a fault did to the sensor and what the filter made of it."""
    fig, axes = _figure(
        len(panels),
        1,
        height_per_row=2.0 if len(panels) > 1 else 3.0,
        title=f"{vehicle}: measured (dots) vs true (solid) vs estimated (dashed)",
    )
    for (label, unit, times, samples, truth, estimate), ax in zip(panels, axes[:, 0], strict=True):
        ax.plot(times, samples, ".", ms=2, color=MEASURED_COLOR, label="measured")
        ax.plot(result.times, truth, color="k", lw=1.0, label="true")
        if estimate is not None:
            ax.plot(result.times, estimate, color="tab:blue", lw=1.0, ls="--", label="estimated")
        ax.set_ylabel(_label(label, unit))
    axes[0, 0].legend(loc="upper left", fontsize=7, ncol=3)
    return fig


def make_figures(result) -> dict[str, tuple[str, Figure]]:
    """Ordered {file stem: (caption, Figure)} for a SimulationResult (see the module doc)."""
    figures = {}
    judged = zip(judged_criteria(result.scenario), result.criteria, strict=True)
    for i, (criterion, verdict) in enumerate(judged, start=1):
        draw = CRITERION_FIGURES.get(criterion.kind)
        if draw is not None:
            figures[f"criterion_{i}"] = (
                f"Criterion {i}: {verdict.description}",
                draw(result, criterion, verdict),
            )
    estimating = _estimating(result)
    if len(estimating) >= FLEET_SIZE:
        figures["fleet_errors"] = (
            "Fleet estimation errors against the predicted σ",
            _fleet_figure(result, estimating),
        )
    else:
        for vehicle in estimating:
            figures[f"estimate_errors_{vehicle}"] = (
                f"{vehicle}: EKF errors against ±σ",
                _estimate_errors_figure(result, vehicle),
            )
            figures[f"attitude_estimate_{vehicle}"] = (
                f"{vehicle}: true vs estimated attitude",
                _attitude_estimate_figure(result, vehicle),
            )
            figures[f"state_estimate_{vehicle}"] = (
                f"{vehicle}: true vs estimated states",
                _state_estimate_figure(result, vehicle),
            )
    for vehicle in estimating[: FLEET_SIZE - 1]:
        if "smoothed_state" in result.logs.get(vehicle, {}):
            figures[f"smoothed_errors_{vehicle}"] = (
                f"{vehicle}: filter and RTS smoother errors against their ±σ",
                _smoothed_errors_figure(result, vehicle),
            )
    if len(estimating) < FLEET_SIZE:
        for vehicle in estimating:
            panels = _measurement_panels(result, vehicle)
            if panels:
                figures[f"measurements_{vehicle}"] = (
                    f"{vehicle}: measured vs true vs estimated",
                    _measurement_figure(result, vehicle, panels),
                )
    for vehicle in estimating[: FLEET_SIZE - 1]:
        if f"{vehicle}.Est.GsfYaw" in result.signals:
            figures[f"gsf_{vehicle}"] = (
                f"{vehicle}: EKF-GSF yaw, weights and resets",
                _gsf_figure(result, vehicle),
            )
    windy = [
        v.name
        for v in result.scenario.vehicles
        if v.wind is not None and f"{v.name}.Wind.X" in result.signals
    ]
    for vehicle in windy[: FLEET_SIZE - 1]:
        figures[f"wind_{vehicle}"] = (
            f"{vehicle}: wind, steady and turbulent parts",
            _wind_figure(result, vehicle),
        )
    for vehicle in [v.name for v in result.scenario.vehicles if v.failsafe is not None][: FLEET_SIZE - 1]:
        figures[f"failsafe_{vehicle}"] = (
            f"{vehicle}: position aiding and the no-aiding failsafe",
            _failsafe_figure(result, vehicle),
        )
    figures["position"] = ("Position vs reference", _position_figure(result))
    figures["top_view"] = ("Top view of the paths", _top_view_figure(result))
    figures["attitude"] = ("Attitude and body rates", _attitude_figure(result))
    figures["thrust"] = ("Motor thrusts", _thrust_figure(result))
    spans, gusts, landings = (
        fault_spans(result.scenario),
        gust_spans(result.scenario),
        touchdown_marks(result) + failsafe_marks(result),
    )
    for _, fig in figures.values():
        shade_faults(fig, spans)
        mark_events(fig, gusts, landings)
    return figures


def write_plots(result, run_dir) -> list[tuple[str, Path]]:
    """Save every figure of `make_figures` as run_dir/<stem>.png; [(caption, path)] in order."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for stem, (caption, fig) in make_figures(result).items():
        path = run_dir / f"{stem}.png"
        write_binary_atomic(path, lambda f, fig=fig: fig.savefig(f, format="png", dpi=DPI))
        written.append((caption, path))
    return written


def write_run_artifacts(result, run_dir) -> dict[str, object]:
    """PNG plots, replay.html (Meshcat) and report.html in run_dir; {kind: path}."""
    from .meshcat_animation import write_replay

    run_dir = Path(run_dir)
    plots = write_plots(result, run_dir)
    replay = write_replay(result, run_dir / "replay.html")
    report = write_report(result, run_dir / "report.html", plots, replay=replay)
    return {"plots": [path for _, path in plots], "replay": replay, "report": report}
