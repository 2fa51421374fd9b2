"""A replay's plots (PNG) and report.html, in the style of a simulated run's (``report``, ``plots``).

Figures are drawn on matplotlib's Agg canvas without pyplot, as ``plots`` does: the attitude and
(with GPS) the position and velocity against the flight controller's, every difference with
our estimator's ±2σ, and each sensor's NIS with its single-update 95 % χ² band.
"""

import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from scipy.stats import chi2

from quad_drake.flightlogs.comparison import (
    ATTITUDE_STATES,
    INNOVATION_NAMES,
    UNITS,
    attitude_sigmas,
    estimate_angles,
    state_sigmas,
)
from quad_drake.flightlogs.settings import dump_replay
from quad_drake.models.rotations import euler_from_quats
from quad_drake.output.outdir import remove_stale, write_binary_atomic, write_text_atomic
from quad_drake.output.report import esc, figures_html, html_page, html_table, num

DPI = 80
REPLAY_ARTIFACTS = ("report.html", "*.png")
"""What a replay folder holds besides its logs, config and summary (removed before a new replay)."""
STATEMENT = (
    "This replay is judged against the flight controller's own estimate (PX4's vehicle_attitude "
    "and vehicle_local_position), which is another estimator, not the truth. A difference is the "
    "disagreement of two estimators; only the NIS (each sensor's innovations against the "
    "covariance our estimator predicted) judges our estimator on its own."
)


def _figure(rows, title):
    fig = Figure(figsize=(8.0, 0.8 + 2.0 * rows), dpi=DPI)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, squeeze=False, sharex=True)[:, 0]
    fig.suptitle(title)
    axes[-1].set_xlabel("time [s]")
    return fig, axes


def _save(fig, path):
    fig.tight_layout()
    write_binary_atomic(path, lambda f: fig.savefig(f, format="png"))
    return path


def _traces_figure(result, path):
    """Our roll, pitch, yaw against the flight controller's."""
    fig, axes = _figure(3, f"{result.config.name}: attitude, {result.config.estimator.kind} and PX4")
    ours = estimate_angles(result.logs["estimated_state"])
    reference = result.log.reference_attitude
    theirs = np.column_stack(euler_from_quats(reference.values)) if reference is not None else None
    for i, (ax, name) in enumerate(zip(axes, ("roll", "pitch", "yaw"), strict=True)):
        ax.plot(result.times, ours[:, i], label=result.config.estimator.kind, lw=1.0)
        if theirs is not None:
            ax.plot(reference.times, theirs[:, i], label="PX4", lw=1.0, ls="--")
        ax.set_ylabel(f"{name} [rad]")
    axes[0].legend(loc="upper right")
    return _save(fig, path)


def _position_figure(result, path):
    """Our position and velocity against the flight controller's and the GPS samples."""
    fig, axes = _figure(6, f"{result.config.name}: position and velocity (NED, GPS origin)")
    state = result.logs["estimated_state"]
    ours = np.column_stack([state[:, 0:3], state[:, 7:10]])
    reference, gps = result.log.reference_position, result.log.gps
    names = ("x [m]", "y [m]", "z [m]", "vx [m/s]", "vy [m/s]", "vz [m/s]")
    for i, (ax, name) in enumerate(zip(axes, names, strict=True)):
        ax.plot(result.times, ours[:, i], label=result.config.estimator.kind, lw=1.0)
        ax.plot(reference.times, reference.values[:, i], label="PX4", lw=1.0, ls="--")
        ax.plot(gps.times, gps.values[:, i], ".", ms=2, label="GPS")
        ax.set_ylabel(name)
    axes[0].legend(loc="upper right")
    return _save(fig, path)


def _differences_figure(result, differences, title, path):
    """Each difference (ours - PX4) with our ±2σ where our estimator has a σ."""
    fig, axes = _figure(len(differences), title)
    for ax, d in zip(axes, differences, strict=True):
        ax.plot(d.times, d.differences, lw=1.0, label="ours - PX4")
        if math.isfinite(d.sigma_rms):
            sigma = _sigma_at(result, d)
            ax.fill_between(d.times, -2 * sigma, 2 * sigma, color="tab:green", alpha=0.2, label="±2σ (ours)")
        ax.set_ylabel(f"{d.state} [{d.unit}]")
    axes[0].legend(loc="upper right")
    return _save(fig, path)


def _sigma_at(result, d):
    """Our σ of the state of the StateDifference `d` at its times."""
    vocabulary, covariance = result.vocabulary, result.logs["covariance"]
    if d.state in ATTITUDE_STATES:
        yaw = estimate_angles(result.logs["estimated_state"])[:, 2]
        sigmas = attitude_sigmas(vocabulary, covariance, yaw)[:, ATTITUDE_STATES.index(d.state)]
    else:
        sigmas = state_sigmas(vocabulary, covariance, (d.state,))[:, 0]
    return np.interp(d.times, result.times, sigmas)


def _nis_figure(result, path):
    """Each judged sensor's NIS with its single-update 95 % χ² band."""
    fig, axes = _figure(len(result.nis), f"{result.config.name}: NIS per sensor")
    for ax, s in zip(axes, result.nis, strict=True):
        low, high = chi2.ppf([0.025, 0.975], s.dof)
        ax.semilogy(s.times, np.maximum(s.values, 1e-6), ".", ms=2, label=f"{s.sensor} NIS")
        ax.axhline(low, color="tab:red", lw=0.8, ls="--", label="95 % band")
        ax.axhline(high, color="tab:red", lw=0.8, ls="--")
        ax.set_ylabel(f"{s.sensor} NIS ({s.dof} dof)")
        ax.legend(loc="upper right")
    return _save(fig, path)


def _innovations_figure(result, path):
    """Each judged sensor's innovations (sample minus our estimate just before it), per component."""
    rows = [
        (sensor, i, name) for sensor in result.innovations for i, name in enumerate(INNOVATION_NAMES[sensor])
    ]
    fig, axes = _figure(len(rows), f"{result.config.name}: innovations (sample - our estimate before it)")
    for ax, (sensor, i, name) in zip(axes, rows, strict=True):
        stamps, values = result.innovations[sensor]
        ax.plot(stamps, values[:, i], ".", ms=2)
        ax.axhline(0.0, color="0.5", lw=0.6)
        ax.set_ylabel(f"{sensor} {name} [{UNITS[name]}]")
    return _save(fig, path)


def _smoothed_figure(result, path):
    """Our filtered and RTS-smoothed position and velocity, the smoother's ±2σ, the truth where logged."""
    fig, axes = _figure(6, f"{result.config.name}: filter and RTS smoother (NED)")
    state, smoothed = result.logs["estimated_state"], result.logs["smoothed_state"]
    filtered = np.column_stack([state[:, 0:3], state[:, 7:10]])
    sigma = result.logs["smoothed_sigma"][:, 0:6]
    truth = result.log.truth_position
    names = ("x [m]", "y [m]", "z [m]", "vx [m/s]", "vy [m/s]", "vz [m/s]")
    for i, (ax, name) in enumerate(zip(axes, names, strict=True)):
        ax.plot(result.times, filtered[:, i], label="filter", lw=1.0)
        ax.plot(result.times, smoothed[:, i], label="smoother", lw=1.0)
        low, high = smoothed[:, i] - 2 * sigma[:, i], smoothed[:, i] + 2 * sigma[:, i]
        ax.fill_between(result.times, low, high, color="tab:orange", alpha=0.2, label="smoother ±2σ")
        if truth is not None:
            ax.plot(truth.times, truth.values[:, i], label="truth", lw=0.8, ls="--", color="k")
        ax.set_ylabel(name)
    axes[0].legend(loc="upper right")
    return _save(fig, path)


def write_plots(result, out_dir) -> list[tuple[str, Path]]:
    """[(caption, png path)] of the replay's figures, written into out_dir."""
    out_dir = Path(out_dir)
    plots = [("Attitude: ours and PX4's", _traces_figure(result, out_dir / "attitude.png"))]
    attitude = [d for d in result.attitude if d.count]  # no empty panel for a state not compared
    position = [d for d in result.position if d.count]
    if attitude:
        title = f"{result.config.name}: attitude differences"
        plots.append(
            ("Attitude differences (ours - PX4) and our ±2σ", _differences_figure(
                result, attitude, title, out_dir / "attitude_differences.png"
            ))
        )  # fmt: skip
    if position and result.log.gps is not None:
        plots.append(
            (
                "Position and velocity: ours, PX4's and the GPS",
                _position_figure(result, out_dir / "position.png"),
            )
        )
    if position:
        title = f"{result.config.name}: position and velocity differences"
        plots.append(
            ("Position and velocity differences (ours - PX4) and our ±2σ", _differences_figure(
                result, position, title, out_dir / "position_differences.png"
            ))
        )  # fmt: skip
    if "smoothed_state" in result.logs:
        caption = "Filter and RTS smoother: position and velocity, the smoother's ±2σ"
        plots.append((caption, _smoothed_figure(result, out_dir / "smoothed.png")))
    if result.nis:
        plots.append(("Innovations: NIS per sensor", _nis_figure(result, out_dir / "nis.png")))
    if result.innovations:
        plots.append(("Innovations per component", _innovations_figure(result, out_dir / "innovations.png")))
    return plots


def _difference_rows(differences):
    return [
        [esc(d.state), esc(d.unit), ("0", "num"), esc(d.reason), "", "", ""]
        if d.count == 0
        else [
            esc(d.state),
            esc(d.unit),
            (str(d.count), "num"),
            (num(d.rms), "num"),
            (num(d.max_abs), "num"),
            (num(d.sigma_rms) if math.isfinite(d.sigma_rms) else "–", "num"),
            (num(100 * d.within_2sigma, 3) if math.isfinite(d.within_2sigma) else "–", "num"),
        ]
        for d in differences
    ]


def write_report(result, path, plots=()) -> Path:
    """report.html of a ReplayResult: the statement, what was judged, differences, NIS, plots, config."""
    path = Path(path)
    config, log = result.config, result.log
    rate = log.duration / result.wall_time if result.wall_time > 0 else float("inf")
    parts = [
        f"<h1>{esc(config.name)}: replay on {esc(config.estimator.kind)}</h1>",
        f"<p><strong>{esc(STATEMENT)}</strong></p>",
        html_table(
            ["log", "estimator", "duration [s]", "sensors", "wall time [s]", "× real time"],
            [
                [
                    esc(Path(log.source).name),
                    esc(config.estimator.kind),
                    num(log.duration),
                    esc(", ".join(["imu", *log.sensors()])),
                    num(result.wall_time, 3),
                    num(rate, 3),
                ]
            ],
        ),
        "<ul>" + "".join(f"<li>{esc(line)}</li>" for line in result.notes()[1:]) + "</ul>",
        "<h2>Differences from PX4's estimate</h2>",
        f"<p>From {result.summary()['compare_after_s']:g} s on (the estimators' start-up is not "
        "compared), at PX4's sample times; σ is our estimator's own (the EKF7's roll and pitch come "
        "from its complementary filter, which has none).</p>",
    ]
    header = ["state", "unit", "samples", "RMS", "max |·|", "our σ (RMS)", "within ±2σ [%]"]
    differences = result.attitude + result.position
    parts.append(
        html_table(header, _difference_rows(differences)) if differences else "<p>Nothing to compare.</p>"
    )
    parts.append("<h2>NIS per sensor</h2>")
    if result.nis:
        parts.append(
            "<p>The mean of m independent χ²(dof) NIS lies in its 95 % band when the filter's "
            "innovation covariance matches its innovations; below it the assumed noise is too large, "
            "above it too small. 95 % of single updates lie in the single-update band.</p>"
        )
        rows = [
            [
                esc(s.sensor),
                (str(s.dof), "num"),
                (str(s.count), "num"),
                (num(s.mean), "num"),
                (f"[{num(s.band[0])}, {num(s.band[1])}]", "num"),
                ("yes" if s.in_band else "no", "PASS" if s.in_band else "FAIL"),
                (num(100 * s.single_share, 3), "num"),
            ]
            for s in result.nis
        ]
        header = [
            "sensor",
            "dof",
            "updates",
            "mean NIS",
            "95 % band of the mean",
            "in band",
            "single in band [%]",
        ]
        parts.append(html_table(header, rows))
    else:
        parts.append("<p>No sensor updates to judge.</p>")
    if result.truth:
        parts.append("<h2>Against the simulator's ground truth</h2>")
        parts.append(
            "<p>The log carries the simulator's true state: ours and PX4's estimates are both judged "
            "against it (RMS error from the comparison's start, at our log samples).</p>"
        )
        rows = [
            [
                esc(e.state),
                esc(e.unit),
                (str(e.count), "num"),
                esc(e.figure(e.ours_rms)),
                esc(e.figure(e.px4_rms)),
            ]
            for e in result.truth
        ]
        parts.append(html_table(["state", "unit", "samples", "ours", "PX4's"], rows))
        rows = [
            [esc(s.block), (str(s.dof), "num"), (str(s.count), "num"), (num(s.mean), "num"),
             (f"[{num(s.band[0])}, {num(s.band[1])}]", "num")]
            for s in result.truth_nees
        ]  # fmt: skip
        if rows:
            parts.append("<p>Our NEES (samples correlated in time: the band is a guide).</p>")
            parts.append(html_table(["block", "dof", "samples", "mean NEES", "95 % band of the mean"], rows))
    parts.append("<h2>Estimator health</h2>")
    parts.append(f"<pre>{esc(result.health_line())}</pre>")
    if plots:
        parts.append("<h2>Plots</h2>")
        parts.extend(figures_html(plots))
    parts.append(
        "<h2>Resolved configuration</h2><p>Reproduce with <code>quad-drake replay config.yaml</code> "
        "in this folder: the new replay is written beside this one.</p>"
    )
    parts.append(f"<pre>{esc(dump_replay(config))}</pre>")
    return write_text_atomic(path, html_page(f"quad_drake replay: {config.name}", "\n".join(parts)))


def write_replay_artifacts(result, out_dir) -> Path:
    """The replay folder's plots and report.html (after removing an earlier replay's); the report's path."""
    remove_stale(out_dir, REPLAY_ARTIFACTS)
    return write_report(result, Path(out_dir) / "report.html", write_plots(result, out_dir))
