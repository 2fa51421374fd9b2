"""Replay a recorded flight through an estimator sub-Diagram: wiring, run, results.

The Diagram: a ``systems.playback.LogPlayback`` emits the log's samples on the onboard tick; its
``imu``, ``gps``, ``mag`` (the raw 3-axis field where the estimator's kind fuses one, else the
heading) and ``baro`` (where the kind fuses one) outputs feed the estimator of
``systems.estimators.build_estimator`` (the same sub-Diagram a simulated vehicle flies on; the
log's sensors become its vehicle's ``sensors``, ``settings.vehicle_for``); every estimator output
and every playback output is logged by its own ``VectorLogSink`` every LOG_PERIOD. A log without
GPS feeds the estimator PX4's fake position instead (``flightlogs.schedule.fake_position``), a
log with a late first fix zero samples before it (:func:`aiding_gps`); the magnetometer's world
field is ``earth_field.magnetometer_model``'s. ``checks.log_warnings`` refuses a log that cannot
be replayed and says what weakens one that can.

Many logs are one Diagram (:func:`replay_many`): the LogPlayback of n flights and the estimator of
n vehicles, one per log, each with its own log's settings (its start, GPS noise, magnetic field and
barometer: ``registry.EstimatorKind.per_vehicle``), on the common 2 ms tick; each log's results
cut at its own end equal its replay alone.

:func:`replay` is the library call behind ``quad-drake replay``; :func:`save_replay` writes the
run folder (``logs.npz``, ``config.yaml``, ``summary.json`` of kind ``"replay"``; the report and
plots: ``flightlogs.page``). :func:`replay_as_flown` replays a log through a VehicleConfig's
estimator exactly as configured (a simulated run's CSV, ``flightlogs.recording``).
"""

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from quad_drake.config.errors import ConfigError
from quad_drake.config.schema import VehicleConfig
from quad_drake.conventions import LOG_PERIOD, ONBOARD_PERIOD
from quad_drake.estimation.gating import GPS_HEIGHT_TIMEOUT
from quad_drake.estimation.measurements import RECEIVER_POSITION_CAP
from quad_drake.estimation.registry import KINDS, sharing_problem, vocabulary_for
from quad_drake.estimation.vocabulary import EstimatorVocabulary, health_counts, health_line
from quad_drake.flightlogs import comparison, earth_field, px4_parameters, smoothing
from quad_drake.flightlogs.checks import log_warnings
from quad_drake.flightlogs.reader import Samples, read_flight_log
from quad_drake.flightlogs.schedule import (
    NO_AID_TIMEOUT,
    STAMPED,
    STREAM_WIDTHS,
    NoAidNoise,
    RestTest,
    bridged_imu,
    fake_position,
    flag_at,
    fused_by_px4,
    held_position,
    initial_attitude,
    measured_at,
    no_aid_samples,
    playback_streams,
    superseded_samples,
)
from quad_drake.flightlogs.settings import (
    REST_VELOCITY_STD,
    ZERO_VELOCITY_STOPS_WHILE_AIDED_FROM,
    ReplayConfig,
    dump_replay,
    fuses_no_aid,
    height_reference,
    release_rest_velocity_std,
    resolve_log,
    rest_velocity_std,
    vehicle_for,
)
from quad_drake.judging.innovations import UPDATE_DIAGNOSTICS
from quad_drake.kernels import jit
from quad_drake.models.fidelity import PHYSICAL
from quad_drake.output.jsonio import dump_json
from quad_drake.output.outdir import write_binary_atomic, write_text_atomic
from quad_drake.output.results import FORMAT_VERSION
from quad_drake.running.limits import LOG_COPIES, check_memory
from quad_drake.systems.estimators import build_estimator
from quad_drake.systems.playback import LogPlayback

COMPARE_AFTER = 5.0
"""s from the log's start before anything is compared or judged: the estimators start from the
first samples (the EKF7's complementary filter from level, at τ = 0.5 s; both filters' yaw and
biases from their initial σ), and a comparison should see them running, not starting."""
LATE_FIX = 1.0
"""s: a first GPS fix later than this after the log's start is late: zero position and velocity
samples stand in for it before (``aiding_gps``)."""
RUNNER = "drake-replay"
"""What produced a replay: the Drake Diagram of this module."""


@dataclass(frozen=True)
class Aiding:
    """How a replay aided its estimator: fake_position (a log without GPS, PX4's fake position
    throughout), magnetometer (``earth_field.MagnetometerModel`` or None), late_fix (s, the first
    fix before which zero samples stood in, or None), baro_fused (the log's barometer fused), gps_losses
    ([(lost s, regained s)] of the GPS losses the estimator was aided over, ``aiding_gps``),
    baro_height_reference (the barometer was the height reference: the GPS height not fused),
    no_aid_at_rest (the no-aiding samples given on the estimator's own input, at rest and not),
    gps_kept_as_px4 ((GPS samples fused, GPS samples in the log) where PX4's estimator fused only
    some or none of them and the replay followed it, ``schedule.fused_by_px4``; None otherwise),
    gps_at_rest ((GPS samples given while the vehicle was at rest, ``schedule.RestTest``, GPS
    samples given); None where none was given), fake_unlike_px4 ((the no-aiding samples not at
    rest given where PX4's estimator fused no fake position, ``FlightLog.px4_fake_position``, those
    not at rest; on the no-aiding input or, for a kind without one, merged into its GPS); None
    where the log has no such record or the replay gave none)."""

    fake_position: bool = False
    magnetometer: object = None
    late_fix: float | None = None
    baro_fused: bool = False
    gps_losses: list = field(default_factory=list)
    baro_height_reference: bool = False
    no_aid_at_rest: tuple | None = None  # (samples at rest, samples not) on the no_aid input; None: none
    gps_kept_as_px4: tuple | None = None  # (GPS samples fused, in the log) where PX4 fused some or none
    gps_at_rest: tuple | None = None  # (GPS samples given at rest, GPS samples given); None: none
    fake_unlike_px4: tuple | None = None  # (in motion where PX4 fused no fake position, in motion)


@dataclass
class ReplayResult:
    """A replayed flight: its logs, the comparison with the log's own estimate, timing."""

    config: ReplayConfig
    log: object  # reader.FlightLog (declination as replayed)
    times: np.ndarray  # (n,) s, log samples LOG_PERIOD k, k >= 1
    logs: dict  # log name -> (n, width): the estimator's outputs and the playback's; and
    # UPDATE_DIAGNOSTICS -> (m, width): the estimator's diagnostics every ONBOARD_PERIOD (its own times)
    wall_time: float  # s
    fake_position: bool  # a log without GPS, given PX4's fake position
    attitude: list = field(default_factory=list)  # [comparison.StateDifference] roll, pitch, yaw
    position: list = field(default_factory=list)  # [StateDifference] x ... vz; [] without GPS
    nis: list = field(default_factory=list)  # [comparison.NisSummary] per judged sensor
    innovations: dict = field(default_factory=dict)  # sensor -> comparison.innovations (stamps, values)
    superseded: dict = field(default_factory=dict)  # stream -> samples never emitted (> 500 Hz)
    compile_time: float = 0.0  # s, numba compiling kernels during this replay
    aiding: Aiding = field(default_factory=Aiding)
    warnings: list = field(default_factory=list)  # checks.log_warnings: what weakens this replay
    truth: list = field(default_factory=list)  # [comparison.TruthError]; [] without a ground truth
    truth_nees: list = field(default_factory=list)  # [comparison.NeesSummary] of ours against it
    logs_in_diagram: int = 1  # the logs replayed in its Diagram (replay_many); wall_time is the Diagram's

    @property
    def vocabulary(self) -> EstimatorVocabulary:
        return vocabulary_for(self.config.estimator)

    def notes(self) -> list[str]:
        """Lines that say what this replay could and could not judge."""
        lines = [
            "The reference is the flight controller's own estimate (PX4), another estimator and not "
            "the truth: a difference is the two estimators' disagreement."
        ]
        c = self.config
        rested = self.aiding.no_aid_at_rest
        if rested is not None:
            fused = (
                f"PX4's no-aiding samples every {c.fake_position_period:g} s: at rest ({rested[0]} samples; "
                f"PX4's land-detector test on the IMU) a fake position with σ = {c.rest_position_std:g} m "
                f"and {_zero_velocity(c)}, else ({rested[1]}) the fake "
                f"position with σ = {c.fake_position_std:g} m (EKF2_NOAID_NOISE), fused with these σ "
                "(a custom estimator: by its update_no_aid where it has one, else as its GPS samples "
                "with its own GPS noise)"
            )
        elif self.fake_position:
            fused = (
                f"PX4's fake position (0 m every {c.fake_position_period:g} s, with σ = "
                f"{c.fake_position_std:g} m where the kind takes it, else with its own GPS noise)"
            )
        else:
            fused = (
                f"zero position and velocity every {c.fake_position_period:g} s, fused as its GPS "
                "samples (with the GPS noise it assumes)"
            )
        release = self.log.px4_release
        own = release_rest_velocity_std(release)  # what the log's release fused (0: none)
        as_release = release is not None and c.rest_velocity_std == own  # the release's σ was fused
        version = f"PX4 v{release[0]}.{release[1]} (the log's release)" if as_release else ""
        if as_release and rested is not None and rested[0] and own != REST_VELOCITY_STD:
            later = (
                f"--set rest_velocity_std={REST_VELOCITY_STD:g} fuses it as later releases do, once aligned"
            )
            if own:
                said = f"The zero velocity at rest fused with σ = {own:g} m/s, as {version} fused it"
            else:
                said = f"No zero velocity fused at rest, as {version} fused none"
            lines.append(f"{said} ({later}).")
        gps_at_rest = self.aiding.gps_at_rest
        aided_at_rest = gps_at_rest is not None and gps_at_rest[0]
        if as_release and own and aided_at_rest and release < ZERO_VELOCITY_STOPS_WHILE_AIDED_FROM:
            lines.append(
                f"{version} also fused its zero velocity at "
                f"rest (σ = {own:g} m/s) while the GPS aided it, as releases before v1.14 did: "
                f"{gps_at_rest[0]} of the {gps_at_rest[1]} GPS samples fused came at rest, "
                "where the replay fuses the GPS alone (as PX4 from v1.14 on); the velocities at rest "
                "can part there."
            )
        unlike = self.aiding.fake_unlike_px4
        if unlike is not None and unlike[0]:
            lines.append(
                f"PX4's estimator fused no fake position at {unlike[0]} of the {unlike[1]} no-aiding "
                "samples the replay gave in motion (its record, estimator_status_flags.cs_fake_pos): "
                "it dead-reckoned there, its tilt held by its gravity fusion and its magnetometer's "
                "field states, which ours does not have; ours is held by the fake position, so the "
                "roll and pitch compared there are held differently (benchmarks/"
                "tilt_gravity_consistency.py reads both against the accelerometer)."
            )
        kept_as_px4 = self.aiding.gps_kept_as_px4
        if kept_as_px4 is not None:
            lines.append(
                f"PX4's estimator fused {kept_as_px4[0]} of the log's {kept_as_px4[1]} GPS fixes "
                "(estimator_status.control_mode_flags; PX4 fuses GNSS once its quality checks have "
                "passed), and so does the replay; --set gps_where_px4_fused=false fuses every fix."
            )
        if self.fake_position:
            none = "The log has no GPS" if kept_as_px4 is None else "No GPS fix was fused"
            lines.append(
                f"{none}: the estimator was given {fused}; its horizontal position is not "
                "compared and its GPS NIS not judged."
            )
        if self.aiding.late_fix is not None:
            lines.append(
                f"The first GPS fix fused came at {self.aiding.late_fix:.1f} s: before it the estimator was "
                f"given {fused}, as PX4 while not aided; the GPS from the fix on."
            )
        for lost, regained in self.aiding.gps_losses:
            if fuses_no_aid(c):
                height = (
                    "its height the barometer's, not fused"
                    if self.log.baro is not None
                    else f"its height with σ = {c.fake_position_std:g} m"
                )
                held = (
                    f"PX4's no-aiding samples every {c.fake_position_period:g} s: the last fix's "
                    f"horizontal position with σ = {c.fake_position_std:g} m (EKF2_NOAID_NOISE; at rest "
                    f"σ = {c.rest_position_std:g} m and {_zero_velocity(c)}), {height}, fused with these "
                    "σ on its no-aiding input (a custom estimator: by "
                    "its update_no_aid where it has one, else as its GPS samples with its own GPS noise)"
                )
            else:
                held = (
                    f"the last fix's horizontal position with zero horizontal velocity every "
                    f"{c.fake_position_period:g} s (height and vertical velocity the barometer's where "
                    "the log has one), fused as its GPS samples with the GPS noise it assumes"
                )
            lines.append(
                f"The GPS was lost from {lost:.1f} s to {regained:.1f} s: the estimator dead-reckoned "
                f"{NO_AID_TIMEOUT:g} s, then was given {held}, as PX4 holds its last position while "
                "not aided; then a regain: the built-in kinds fuse each GPS group their gate accepts "
                "and reset to the others."
            )
        if self.config.px4_parameters:
            lines.append(
                "The estimator's noise and the sensor delays are the log's own EKF2_* parameters "
                "(PX4's default where the log has none; flightlogs/px4_parameters.py)."
            )
        if self.config.px4_start_biases:
            lines.append(start_biases_note(self.log.estimator_imu_bias))
        accuracy = self.log.gps_accuracy
        fuses_accuracy = c.gps_receiver_accuracy and KINDS[c.estimator.kind].fuses_gps_accuracy
        if fuses_accuracy and accuracy is not None and not self.fake_position:
            eph, epv, sacc = np.median(accuracy.values, axis=0)
            lines.append(
                "Each GPS sample fused as PX4 fuses it: each std the larger of the estimator's own GPS "
                "noise and the receiver's reported accuracy (medians: horizontal position "
                f"{eph:.2f} m, vertical {epv:.2f} m, speed {sacc:.2f} m/s; a position's counted up to "
                f"{RECEIVER_POSITION_CAP:g} m); --set gps_receiver_accuracy=false fuses the "
                "estimator's own alone."
            )
        restarts = health_counts(self.logs["diagnostics"])["gps_height_restarts"]
        if restarts:
            lines.append(
                f"The GPS is the height reference (the log's EKF2_HGT_REF): the height was restarted at "
                f"{restarts} fix{'es' if restarts > 1 else ''}, each reset to a fix that came more than "
                f"{GPS_HEIGHT_TIMEOUT:g} s after the previous one (or after the start), as PX4 restarts "
                "its GNSS height fusion; --set estimator.gps_height_restart=false fuses every fix's "
                "height instead."
            )
        delays = [(s, getattr(self.config, f"{s}_delay")) for s in ("gps", "mag", "baro")]
        if any(d for _, d in delays):
            shown = ", ".join(f"{s} {1e3 * d:g} ms" for s, d in delays)
            lines.append(f"Sensor samples replayed as measured before they were logged: {shown}.")
        if self.log.heading is not None:
            lines.append("The log's magnetometer is a yaw magnetometer (heading rows): fused as such.")
        elif self.log.mag_field is None:
            lines.append("The log has no magnetometer: the yaw is the gyro's alone.")
        else:
            if self.log.mag_source:
                lines.append(f"magnetometer: {self.log.mag_source}")
            lines += list(self.aiding.magnetometer.notes)
        if self.aiding.baro_height_reference:
            lines.append(
                "The height reference is the barometer (PX4's EKF2_HGT_REF / EKF2_HGT_MODE 0, or "
                "--set height_reference=baro): the GPS height is not fused (σ 1000 m), as PX4's; "
                "--set height_reference=gps fuses it."
            )
        if self.log.baro is not None and not self.aiding.baro_fused:
            lines.append(f"The log's barometer is not fused: kind {self.config.estimator.kind} takes none.")
        lines += self.warnings
        if self.logs_in_diagram > 1:
            lines.append(
                f"Replayed in one Diagram with {self.logs_in_diagram - 1} other logs (a vehicle each, "
                "the same estimates as alone); the wall time is that Diagram's."
            )
        if self.log.reference_attitude is None:
            lines.append("The log has no vehicle_attitude: nothing to compare the attitude with.")
        for stream, count in self.superseded.items():
            if count:
                lines.append(f"{count} {stream} samples came faster than the 2 ms tick and were superseded.")
        return lines

    def health_line(self) -> str:
        return health_line("replay", self.config.estimator.kind, health_counts(self.logs["diagnostics"]))

    def summary(self) -> dict:
        """The summary.json dict (kind ``"replay"``)."""
        return {
            "format_version": FORMAT_VERSION,
            "kind": "replay",
            "runner": RUNNER,
            "scenario": self.config.name,
            "log": self.log.source,
            "estimator": self.config.estimator.kind,
            "duration_s": round(self.log.duration, 3),
            "sensors": ["imu", *self.log.sensors()],
            "fake_position": self.fake_position,
            "compare_after_s": COMPARE_AFTER,
            "wall_time_s": round(self.wall_time, 3),
            "real_time_factor": round(self.log.duration / self.wall_time, 2) if self.wall_time > 0 else None,
            "compile_time_s": round(self.compile_time, 3),
            "logs_in_diagram": self.logs_in_diagram,
            "differences": [_difference_dict(d) for d in self.attitude + self.position],
            "nis": [_nis_dict(s) for s in self.nis],
            "truth": [_truth_dict(e) for e in self.truth],
            "truth_nees": [dataclasses.asdict(s) | {"band": list(s.band)} for s in self.truth_nees],
            "notes": self.notes(),
        }


def _difference_dict(d):
    """A StateDifference in summary.json: its figures (null where not a number) and, when nothing
    was compared, the reason."""
    entry = {"state": d.state, "unit": d.unit, "count": d.count}
    for name in ("rms", "max_abs", "sigma_rms", "within_2sigma"):
        value = getattr(d, name)
        entry[name] = value if math.isfinite(value) else None
    if d.reason:
        entry["reason"] = d.reason
    return entry


def _truth_dict(e):
    """A TruthError in summary.json (null where not a number; the reason when nothing was judged)."""
    entry = {"state": e.state, "unit": e.unit, "count": e.count}
    for name in ("ours_rms", "px4_rms"):
        value = getattr(e, name)
        entry[name] = value if math.isfinite(value) else None
    if e.reason:
        entry["reason"] = e.reason
    return entry


def _nis_dict(s):
    return {
        "sensor": s.sensor,
        "dof": s.dof,
        "count": s.count,
        "mean": s.mean,
        "band": list(s.band),
        "in_band": s.in_band,
        "single_share": s.single_share,
    }


def baro_pairing_period(baro) -> float:
    """s: the barometer period the estimators' bias filter pairs GPS heights with (a GPS sample
    and the latest baro sample within half of it are taken as simultaneous): twice the log's
    median baro interval, rounded up to the 2 ms tick, so on two clocks at two rates every GPS
    height finds the baro sample before it (at most one interval older)."""
    interval = float(np.median(np.diff(baro.times))) if len(baro) > 1 else ONBOARD_PERIOD
    return ONBOARD_PERIOD * math.ceil(2.0 * interval / ONBOARD_PERIOD - 1e-9)


def start_biases_note(biases) -> str:
    """The console line of a replay started from PX4's IMU biases (``--set px4_start_biases=true``):
    `biases` (``reader.ImuBiasStart``), or None where the log holds none."""
    if biases is None:
        return (
            "px4_start_biases: the log holds no valid estimator_sensor_bias: the IMU biases started "
            "from the estimator's own start."
        )

    def triple(values, digits):
        return "(" + ", ".join(f"{v:.{digits}f}" for v in values) + ")"

    stds = (
        f", their σ {triple(biases.accel_std, 4)} m/s² and {triple(biases.gyro_std, 5)} rad/s "
        "(PX4's variances)"
        if biases.accel_std is not None and biases.gyro_std is not None
        else ""
    )
    return (
        "The IMU biases started from those PX4's estimator had learned by the log's start "
        f"(estimator_sensor_bias): accelerometer {triple(biases.accel, 4)} m/s², gyro "
        f"{triple(biases.gyro, 5)} rad/s{stds}."
    )


def magnetometer_for(log, config) -> earth_field.MagnetometerModel | None:
    """The ``earth_field.MagnetometerModel`` of the log's magnetometer (``--set mag_declination``
    overriding its declination; the bias PX4's estimator had learned by the log's start subtracted
    only with ``--set estimator_mag_bias=true``), or None without one."""
    if log.mag_field is None:
        return None
    model = earth_field.magnetometer_model(log, subtract_estimator_bias=config.estimator_mag_bias)
    if config.mag_declination is not None:
        note = (
            f"magnetometer: declination {math.degrees(config.mag_declination):.2f}° (--set mag_declination)"
        )
        notes = tuple(n for n in model.notes if "declination" not in n.split(":", 1)[1][:13]) + (note,)
        model = dataclasses.replace(model, declination=config.mag_declination, notes=notes)
    return model


def aiding_gps(
    log, config, separate=False, rest=None
) -> tuple[Samples, Samples | None, bool, float | None, list]:
    """(GPS Samples to emit, no-aiding Samples or None, fake position used, first fix s or None,
    losses [(lost s, regained s)]): the log's GPS, with aiding where PX4 has none.

    Without any GPS: PX4's fake position over the whole log (every fake_position_period s). With
    a late first fix (after LATE_FIX s): those samples before it, as PX4 holds a fake position and
    a zero velocity while not aided, then the GPS from its first fix on (its origin: the first
    fix is at p_N = 0, so the switch is continuous). `separate` (the estimator fuses the
    ``no_aid`` measurement): these are ``schedule.no_aid_samples``, each with PX4's own std
    (:func:`no_aid_noise`: at rest a tight fake position and a zero velocity, else the fake
    position at ``fake_position_std``), the second item; else zero position and velocity samples
    merged into the GPS (fused with the GPS noise the estimator assumes). A loss (no sample for
    more than NO_AID_TIMEOUT s after a fix, PX4's ``EKF2_NOAID_TOUT``): the estimator dead-reckons
    for NO_AID_TIMEOUT s as PX4 does, then is held at the last fix's horizontal position every
    fake_position_period s until a period before the regain: `separate`, by no-aiding samples
    there (PX4's fake position with its σ, ``EKF2_NOAID_NOISE`` in flight, and at rest its rest
    σ and the zero velocity; the height the barometer's where the log has one), no GPS sample in
    the loss, so that the returning GPS ends an outage of the whole loss, a regain
    (``estimation/gating.py``: each group fused where its gate accepts it and reset to it where
    not, as PX4 resets to GNSS when it starts aiding again); else :func:`held_position` samples
    merged into the GPS. rest: the log's ``schedule.RestTest`` (None: built here where needed)."""
    period = config.fake_position_period
    if config.fake_position_std <= 0:
        return log.gps, None, False, None, []
    noise = no_aid_noise(log, config)
    if separate and rest is None:
        rest = RestTest.of(log.imu, log.landed)
    if log.gps is None:
        times = np.arange(period, log.duration + 1e-9, period)
        if separate:
            return None, no_aid_samples(rest, times, noise), True, None, []
        return fake_position(log, period), None, True, None, []
    times, values = [log.gps.times], [log.gps.values]
    first_fix = float(log.gps.times[0])
    late_fix = first_fix if first_fix > LATE_FIX else None
    no_aid = []
    if late_fix is not None:
        held = np.arange(period, first_fix - 1e-9, period)
        if separate:
            no_aid.append(no_aid_samples(rest, held, noise))
        else:
            times.append(held)
            values.append(np.zeros((len(held), 6)))
    losses = []
    for i in np.flatnonzero(np.diff(log.gps.times) > NO_AID_TIMEOUT):
        lost, regained = float(log.gps.times[i]), float(log.gps.times[i + 1])
        losses.append((lost, regained))
        held = np.arange(lost + NO_AID_TIMEOUT, regained - period + 1e-9, period)
        if separate:
            no_aid.append(no_aid_samples(rest, held, noise, log.gps.values[i, 0:3]))
        else:
            times.append(held)
            values.append(held_position(log, lost, log.gps.values[i, 0:3], held))
    no_aid = [s for s in no_aid if len(s)]
    no_aid = (
        Samples(np.concatenate([s.times for s in no_aid]), np.vstack([s.values for s in no_aid]))
        if no_aid
        else None
    )
    if len(times) == 1:
        return log.gps, no_aid, False, late_fix, losses
    order = np.argsort(np.concatenate(times), kind="stable")
    merged = Samples(np.concatenate(times)[order], np.vstack(values)[order])
    return merged, no_aid, False, late_fix, losses


def _zero_velocity(config) -> str:
    """The words for the zero velocity at rest of a resolved ReplayConfig `config`: its σ, or none."""
    if not config.rest_velocity_std:
        return "no zero velocity"
    return f"a zero velocity with σ = {config.rest_velocity_std:g} m/s"


def no_aid_noise(log, config) -> NoAidNoise:
    """The ``schedule.NoAidNoise`` of a replay: PX4's fake position at ``fake_position_std``
    (``EKF2_NOAID_NOISE``) in flight and ``rest_position_std`` at rest, its zero velocity at
    ``settings.rest_velocity_std`` (the log's PX4 release's unless set; inf, not fused, for its
    0); the height fused at ``fake_position_std`` only on a log without a barometer (PX4's height
    is then the barometer's)."""
    height_std = config.fake_position_std if log.baro is None else math.inf
    rest_velocity = rest_velocity_std(config, log.px4_release) or math.inf
    return NoAidNoise(config.fake_position_std, config.rest_position_std, rest_velocity, height_std)


def delayed_log(log, config) -> object:
    """The FlightLog `log` with its GPS, magnetometer and barometer samples at the times they were
    measured (``schedule.measured_at``: logged time less the ReplayConfig's gps_delay, mag_delay,
    baro_delay); `log` itself when every delay is 0."""
    delays = {"gps": config.gps_delay, "mag_field": config.mag_delay, "heading": config.mag_delay}
    delays["gps_accuracy"] = config.gps_delay
    delays["baro"] = config.baro_delay
    if not any(delays.values()):
        return log
    return dataclasses.replace(
        log, **{name: measured_at(getattr(log, name), d) for name, d in delays.items()}
    )


def played_log(log, config) -> object:
    """The FlightLog `log` as its replay plays it: its sensors at the times they were measured
    (:func:`delayed_log`) and its IMU bridged over the logger's dropouts (``schedule.bridged_imu``
    with the ReplayConfig's ``imu_gap_bridge``)."""
    log = delayed_log(log, config)
    imu, bridged = bridged_imu(log.imu, config.imu_gap_bridge)
    return log if not bridged else dataclasses.replace(log, imu=imu)


def replay_setup(log, config) -> tuple[dict, VehicleConfig, Aiding]:
    """(playback streams, VehicleConfig, Aiding) of the FlightLog `log` replayed under the
    ReplayConfig `config`: what its vehicle of a replay Diagram plays (``schedule.playback_streams``
    of the GPS fixes PX4's estimator fused, ``schedule.fused_by_px4`` with ``gps_where_px4_fused``,
    and the log's samples at the times they were measured, its IMU bridged over dropouts,
    :func:`played_log`, with the aiding of :func:`aiding_gps`), the estimator it feeds
    (``settings.vehicle_for``: started at the log's first attitude, the log's magnetic field and
    barometer period, and PX4's start biases where asked) and how it was aided."""
    fused = fused_by_px4(log) if config.gps_where_px4_fused else log  # PX4's fixes, before the delays
    kept_as_px4 = None
    if fused.gps is not log.gps:  # (counted here: a delay drops a fix measured before t = 0)
        kept_as_px4 = (0 if fused.gps is None else len(fused.gps), len(log.gps))
    log = played_log(fused, config)
    rest = RestTest.of(log.imu, log.landed)
    gps, no_aid, fake, late_fix, losses = aiding_gps(log, config, fuses_no_aid(config), rest)
    magnetometer = magnetometer_for(log, config)
    declination, hard_iron = (
        (0.0, (0.0, 0.0, 0.0))
        if magnetometer is None
        else (
            magnetometer.declination,
            magnetometer.hard_iron,
        )
    )
    accuracy = log.gps_accuracy if config.gps_receiver_accuracy else None
    streams = playback_streams(log, gps, declination, hard_iron, no_aid, accuracy)
    baro_period = None if log.baro is None else baro_pairing_period(log.baro)
    baro_reference = log.gps is not None and height_reference(config, log.parameters) == "baro"
    vehicle = vehicle_for(
        config,
        initial_attitude(log, declination, hard_iron),
        fake,
        baro_period,
        magnetometer,
        baro_reference,
        log.estimator_imu_bias if config.px4_start_biases else None,
    )
    baro_fused = vehicle.sensors.baro is not None
    rested = None
    if no_aid is not None:
        resting = int(np.count_nonzero(rest.at(no_aid.times)))
        rested = (resting, len(no_aid) - resting)
    gps_at_rest = None if log.gps is None else (int(np.count_nonzero(rest.at(log.gps.times))), len(log.gps))
    fake_unlike_px4 = None
    if log.px4_fake_position is not None and (no_aid is not None or gps is not log.gps):
        # the no-aiding samples: on their own input, or (a kind without one) merged into its GPS
        logged = np.empty(0) if log.gps is None else log.gps.times
        given = no_aid.times if no_aid is not None else np.setdiff1d(gps.times, logged)
        moving = ~rest.at(given)
        unlike = moving & ~flag_at(log.px4_fake_position, given)
        fake_unlike_px4 = (int(np.count_nonzero(unlike)), int(np.count_nonzero(moving)))
    aiding = Aiding(
        fake,
        magnetometer,
        late_fix,
        baro_fused,
        losses,
        baro_fused and baro_reference,
        rested,
        kept_as_px4,
        gps_at_rest,
        fake_unlike_px4,
    )
    return streams, vehicle, aiding


def _playback_diagram(streams, vehicles, name, ticks=False, every_update=True):
    """(Diagram, {log name: VectorLogSink}, {name: tick sink} or None, the UPDATE_DIAGNOSTICS sink
    or None): a LogPlayback of n flights
    (`streams`: each flight's) feeding the estimator of n vehicles (`vehicles`: each flight's
    VehicleConfig, ``build_estimator`` of one, or of n that ``registry.sharing_problem`` lets share
    it): ``imu``, ``gps``, ``mag`` (the raw field for a 3-axis magnetometer, else the heading) and
    ``baro`` where it has that input; every estimator and playback output (n vehicles wide,
    vehicle-major) logged every LOG_PERIOD; ticks: also the per-tick sinks of
    ``smoothing.tick_sinks`` (an ESKF's, one flight, for its smoother); every_update: the
    estimator's ``diagnostics`` every ONBOARD_PERIOD (``innovations.UPDATE_DIAGNOSTICS``: every
    update's NIS, which the LOG_PERIOD log can miss; a replay judges them, a run-as-log replay does
    not)."""
    builder = DiagramBuilder()
    playback = builder.AddNamedSystem("playback", LogPlayback(streams))
    estimator = builder.AddSystem(build_estimator(vehicles[0] if len(vehicles) == 1 else vehicles, PHYSICAL))
    vehicle = vehicles[0]  # the sensors all share but the barometer (sharing_problem)
    three_axis = vehicle.sensors.mag is not None and vehicle.sensors.mag.three_axis
    wiring = {"imu": "imu", "gps": "gps", "mag": "mag_field" if three_axis else "mag", "baro": "baro"}
    wiring.update(no_aid="no_aid", gps_accuracy="gps_accuracy")
    for port, stream in wiring.items():
        if estimator.HasInputPort(port):
            builder.Connect(playback.GetOutputPort(stream), estimator.GetInputPort(port))
    sinks = {}
    outputs = [(log_name, estimator) for log_name in vocabulary_for(vehicle.estimator).log_widths()]
    outputs += [(log_name, playback) for log_name in streams[0]]
    for log_name, system in outputs:
        sinks[log_name] = LogVectorOutput(system.GetOutputPort(log_name), builder, publish_period=LOG_PERIOD)
        sinks[log_name].set_name(f"{log_name}_log")
    tick = smoothing.tick_sinks(builder, estimator, playback) if ticks else None
    updates = None
    if every_update:
        diagnostics = estimator.GetOutputPort("diagnostics")
        updates = LogVectorOutput(diagnostics, builder, publish_period=ONBOARD_PERIOD)
        updates.set_name(f"{UPDATE_DIAGNOSTICS}_log")
    diagram = builder.Build()
    diagram.set_name(name)
    return diagram, sinks, tick, updates


def replay_as_flown(log, vehicle, ticks=False) -> tuple:
    """(times (n,) s, {log name: (n, width)}) of the FlightLog `log` replayed through the estimator
    of the VehicleConfig `vehicle` exactly as configured (its own initial state and noise; no
    replay defaults, no fake position): a simulated run's CSV (``flightlogs.recording``) replayed
    through the run's own estimator reproduces the run's estimate. ticks: a third item, the
    ``smoothing.TickLogs`` of an ESKF (its pass tick by tick, for the smoother)."""
    diagram, sinks, tick, _ = _playback_diagram(
        [playback_streams(log)], [vehicle], "replay", ticks, every_update=False
    )
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    simulator.Initialize()
    simulator.AdvanceTo(log.duration)
    times, views = _read_sinks(sinks, context)
    logs = {name: np.ascontiguousarray(view) for name, view in views.items()}
    return (times, logs, smoothing.read_tick_sinks(tick, context)) if ticks else (times, logs)


def replay(config, log=None) -> ReplayResult:
    """ReplayResult of the ReplayConfig `config` (its ``log`` file read unless the FlightLog `log`
    is given): the flight replayed to its last IMU sample, compared with the log's own estimate.
    Its logs also hold the estimator's diagnostics every ONBOARD_PERIOD
    (``innovations.UPDATE_DIAGNOSTICS``: every fresh update's NIS, which its NIS summaries and
    ``quad-drake tune LOG`` judge).

    Raises reader.FlightLogError (a ConfigError, one line) for a log that cannot be replayed.
    """
    return _replay_together([_prepare(config, log)])[0]


def replay_many(configs, logs=None, together=True) -> list:
    """[ReplayResult, or the ConfigError of a log that cannot be replayed] of each ReplayConfig of
    `configs`, in order (each config's ``log`` file read unless `logs` gives its FlightLog).
    The logs whose vehicles can share one estimator (``registry.sharing_problem``: the same
    kind and settings but for each log's start, GPS noise, magnetic field and barometer) are
    replayed in one Diagram, one vehicle each: a LogPlayback of n flights on the common 2 ms
    tick, each stream with samples where its own log has them, and each vehicle's results
    cut at its own log's end. A smoothed replay, and every replay with together=False, runs
    in a Diagram of its own. Each result equals its log replayed alone."""
    outcomes, prepared = [None] * len(configs), []
    for k, config in enumerate(configs):
        try:
            prepared.append((k, _prepare(config, None if logs is None else logs[k])))
        except ConfigError as e:
            outcomes[k] = e
    groups = []
    for k, p in prepared:
        home = None
        if together and not p.config.smooth:
            home = next((g for g in groups if _can_share(g[0][1], p)), None)
        if home is None:
            groups.append([(k, p)])
        else:
            home.append((k, p))
    for group in groups:
        try:
            results = _replay_together([p for _, p in group])
        except (ArithmeticError, ConfigError) as e:  # a breakdown, or more logs than memory holds
            if len(group) > 1:  # each alone, so that an error is its own log's
                results = [replay_many([p.config], [p.log], together=False)[0] for _, p in group]
            else:
                results = [e if isinstance(e, ConfigError) else breakdown_error(group[0][1].config, e)]
        for (k, _), result in zip(group, results, strict=True):
            outcomes[k] = result
    return outcomes


def breakdown_error(config, error) -> ConfigError:
    """The one-line ConfigError of a replay of `config` that broke down numerically (`error`, an
    ArithmeticError)."""
    return ConfigError(
        f"{config.log}: the replay broke down numerically ({type(error).__name__}: {error}); "
        "check the noise and covariance settings"
    )


@dataclass(frozen=True)
class _Prepared:
    """A log ready to replay: its resolved config, FlightLog, warnings and ``replay_setup``."""

    config: ReplayConfig
    log: object
    warnings: list
    streams: dict
    vehicle: VehicleConfig
    aiding: Aiding


def _prepare(config, log=None) -> _Prepared:
    """The _Prepared replay of `config` (its log read unless `log` is given); a ConfigError (one
    line) for a log that cannot be replayed."""
    log = read_flight_log(resolve_log(config.log)) if log is None else log
    warnings = log_warnings(log, COMPARE_AFTER)
    if config.px4_parameters:
        config = px4_parameters.from_parameters(config, log.parameters)
    config = px4_parameters.log_delays(config, log.parameters)
    config = dataclasses.replace(config, rest_velocity_std=rest_velocity_std(config, log.px4_release))
    if not config.name:
        config = dataclasses.replace(config, name=Path(log.source).stem)
    if config.smooth and not KINDS[config.estimator.kind].smoothable:
        raise ConfigError(f"smooth: the smoother runs over the ESKF only, not kind {config.estimator.kind}")
    _check_replay_memory(config, log.duration, 1, log.source)  # before its streams are built
    streams, vehicle, aiding = replay_setup(log, config)
    if aiding.gps_kept_as_px4 is not None and aiding.gps_kept_as_px4[0] == 0:
        log = judged_without_gps(log)
    return _Prepared(config, log, warnings, streams, vehicle, aiding)


def judged_without_gps(log) -> object:
    """The FlightLog `log` as a replay that fused none of its GPS fixes is judged: as a log without
    GPS (``reader``'s rule there): no horizontal frame in common with PX4's, and PX4's height taken
    relative to its own at t = 0, where the estimate's height starts at 0 (not in the first fix's
    altitude frame, which neither estimator fused)."""
    reference = log.reference_position
    if reference is not None:
        values = reference.values.copy()
        values[:, 0:2] = np.nan
        valid = np.isfinite(values[:, 2])
        if valid.any():
            values[:, 2] -= np.interp(0.0, reference.times[valid], values[valid, 2])
        reference = Samples(reference.times, values)
    return dataclasses.replace(log, gps=None, gps_accuracy=None, reference_position=reference)


def _check_replay_memory(config, end, n, what) -> None:
    """Refuse (ConfigError, one line) a replay of `n` logs in one Diagram to `end` (s) whose logged
    signals would not fit in memory (``limits.check_memory``): the estimator of `config`'s outputs
    and every playback stream with its stamp, every LOG_PERIOD, and its diagnostics every
    ONBOARD_PERIOD, for each log. `what` names it."""
    widths = vocabulary_for(config.estimator).log_widths()
    width = sum(widths.values()) + sum(w + STAMPED[name] for name, w in STREAM_WIDTHS.items())
    width += widths["diagnostics"] * LOG_PERIOD / ONBOARD_PERIOD  # UPDATE_DIAGNOSTICS, per LOG_PERIOD
    check_memory(
        end / LOG_PERIOD * n * width * 8.0 * LOG_COPIES,
        f"{what}: a replay of {end:g} s",
        "replay a shorter stretch of the flight (e.g. cut into a CSV log)",
    )


def _can_share(first, other) -> bool:
    """True when the _Prepared `other` can be replayed in the Diagram of `first`."""
    return not first.config.smooth and sharing_problem([first.vehicle, other.vehicle]) is None


def _replay_together(prepared) -> list[ReplayResult]:
    """The ReplayResults of the _Prepared logs `prepared` replayed in one Diagram, a vehicle each
    (:func:`replay_many`), to the end of the longest; each cut at its own log's end and judged."""
    n, first = len(prepared), prepared[0]
    end = max(p.log.duration for p in prepared)
    if n > 1:  # each log alone passed it in _prepare
        _check_replay_memory(first.config, end, n, f"{n} logs in one Diagram")
    smooth = first.config.smooth
    diagram_name = first.config.name or "replay" if n == 1 else "replays"
    diagram, sinks, ticks, updates = _playback_diagram(
        [p.streams for p in prepared], [p.vehicle for p in prepared], diagram_name, smooth
    )
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    compiled = jit.compile_seconds()
    start = time.perf_counter()
    simulator.Initialize()
    simulator.AdvanceTo(end)
    compile_time = jit.compile_seconds() - compiled
    wall_time = time.perf_counter() - start - compile_time
    times, logs = _read_sinks(sinks, context)
    update_times, update_logs = _read_sinks({UPDATE_DIAGNOSTICS: updates}, context)
    results = []
    for i, p in enumerate(prepared):
        kept = times <= p.log.duration
        own = {name: _vehicle_rows(data, i, n, kept) for name, data in logs.items()}
        own[UPDATE_DIAGNOSTICS] = _vehicle_rows(
            update_logs[UPDATE_DIAGNOSTICS], i, n, update_times <= p.log.duration
        )
        if ticks is not None:  # the smoothed pass, sampled as the other logs (one log: smooth)
            tick_logs = smoothing.read_tick_sinks(ticks, context)
            own |= smoothing.smoothed_logs(
                tick_logs, smoothing.smooth_pass(tick_logs, p.config.estimator), times[kept]
            )
        result = ReplayResult(
            p.config,
            p.log,
            times[kept].copy(),
            own,
            wall_time,
            p.aiding.fake_position,
            compile_time=compile_time,
            aiding=p.aiding,
            warnings=p.warnings,
            logs_in_diagram=n,
        )
        _judge(result)
        results.append(result)
    return results


def _vehicle_rows(data, i, n, kept) -> np.ndarray:
    """Vehicle i's samples `kept` ((samples,) bool) of a log of n vehicles (samples, n width, a
    view of :func:`_read_sinks`): a new C-ordered (kept samples, width) array of its own."""
    width = data.shape[1] // n
    return np.ascontiguousarray(data[kept, i * width : (i + 1) * width])


def _read_sinks(sinks, context):
    """(times (n,), {name: (n, width)}) of the LOG_PERIOD samples k >= 1 of every sink; each
    array a read-only view of its sink's memory, valid while `context` lives: a caller copies what
    it keeps (each vehicle's rows, :func:`_vehicle_rows`), so no log is copied twice."""
    logs, times = {}, None
    for name, sink in sinks.items():
        found = sink.FindLog(context)
        logs[name] = found.data()[:, 1:].T
        times = found.sample_times()[1:].copy()
    return times, logs


def _judge(result):
    """Fill `result`'s comparison, NIS summaries and superseded-sample counts."""
    log, vocabulary = result.log, result.vocabulary
    if log.reference_attitude is not None:
        result.attitude = comparison.compare_attitude(
            vocabulary, result.times, result.logs, log.reference_attitude, COMPARE_AFTER
        )
    if log.reference_position is not None:
        horizontal = "" if log.gps is not None else "n/a: no GPS, so no common horizontal frame"
        result.position = comparison.compare_position(
            vocabulary, result.times, result.logs, log.reference_position, COMPARE_AFTER, horizontal
        )
    else:
        reason = "n/a: the log has no vehicle_local_position"
        result.position = [comparison.unavailable(s, reason) for s in comparison.POSITION_STATES]
    if log.reference_attitude is None:
        reason = "n/a: the log has no vehicle_attitude"
        result.attitude = [comparison.unavailable(s, reason) for s in comparison.ATTITUDE_STATES]
    judged = ["mag", "field", "baro"] + ([] if result.fake_position else ["gps"])
    every_update = result.logs[UPDATE_DIAGNOSTICS]  # the LOG_PERIOD log can miss one of two close updates
    summaries = [comparison.nis_summary(every_update, s, COMPARE_AFTER) for s in judged]
    result.nis = [s for s in summaries if s is not None]
    result.innovations = {
        s.sensor: comparison.innovations(result.logs, s.sensor, COMPARE_AFTER)
        for s in result.nis
        if s.sensor in comparison.INNOVATION_NAMES
    }
    result.truth = comparison.truth_errors(result.times, result.logs, log, COMPARE_AFTER)
    result.truth_nees = comparison.truth_nees(vocabulary, result.times, result.logs, log, COMPARE_AFTER)
    sources = {"gps": log.gps, "mag": log.mag_field, "baro": log.baro}  # the IMU's are averaged
    result.superseded = {name: superseded_samples(s.times) for name, s in sources.items() if s is not None}


def save_replay(result, out_dir) -> Path:
    """Write logs.npz (``times`` and ``replay/<log name>``, every log sampled at those times: not
    UPDATE_DIAGNOSTICS, whose NIS summary.json holds), config.yaml (the resolved ReplayConfig) and
    summary.json into out_dir; returns out_dir."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    sampled = {name: data for name, data in result.logs.items() if name != UPDATE_DIAGNOSTICS}
    arrays = {"times": result.times} | {f"replay/{name}": data for name, data in sampled.items()}
    write_binary_atomic(out_dir / "logs.npz", lambda f: np.savez_compressed(f, **arrays))
    write_text_atomic(out_dir / "config.yaml", dump_replay(result.config))
    dump_json(out_dir / "summary.json", result.summary())
    return out_dir
