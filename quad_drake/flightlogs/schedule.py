"""Pure: a FlightLog's samples as the streams the log-playback system emits on the onboard tick.

A sample recorded at t (s since the first IMU sample) is emitted at the first onboard tick
t_k = k ONBOARD_PERIOD >= t and held until the next one, with its own t as its ``stamp`` (so a
consumer sees it fresh once, as it sees a simulated sensor's sample). When two samples of one
stream fall between the same two ticks (faster than 500 Hz), the later one is emitted and the
earlier one is superseded (counted by :func:`superseded_samples`).

The IMU is not held that way: its stream carries at each tick j the mean of the log's IMU signal
over the tick's own interval [t_j, t_j + ONBOARD_PERIOD) (:func:`imu_tick_means`), where the signal
holds each sample from its time (the start of its integration interval, ``reader``) until the next
sample's. The estimators integrate a tick's IMU row over that interval, so their prediction steps
integrate the log's samples exactly, whatever the IMU's rate. Held at the first tick after each
sample instead, a 200 Hz IMU's samples were integrated over 4 and 6 ms in turn; on a vibrating
vehicle (a real multirotor's gyro swings by tenths of rad/s from sample to sample) that
alternation drifts the integrated attitude and velocity by several mrad/s and cm/s^2
(`docs/measurements/replay.md`).

The streams have the simulated sensors' port layouts (``conventions``): ``imu`` (6: f_B m/s^2,
w_NB_B rad/s, FRD; no stamp, a row every tick), ``gps`` (7: p_N m, v_N m/s,
stamp s), ``mag`` (2: yaw rad, stamp s), plus the raw sensors a later estimator may fuse:
``mag_field`` (4: field_B gauss, FRD, stamp s), ``baro`` (2: pressure altitude m, up, stamp s) and
``gps_accuracy`` (4: the GPS receiver's reported accuracy of each GPS sample, horizontal and
vertical position m and speed m/s std, and the GPS sample's stamp s).

The yaw-only ``mag`` sample the estimators take today is the tilt-compensated heading of
:func:`tilt_compensated_heading`: the logged field rotated into the level frame by the roll
and pitch of gravity's direction, which is the mean accelerometer reading over the
:data:`HEADING_GRAVITY_WINDOW` before the field sample. It is derived from the log's sensors
alone, not from PX4's or our own estimate: a measurement, with the error a real one has (the
accelerometer sees gravity plus the vehicle's own acceleration, and a tilt error dθ becomes a
heading error of about dθ tan(inclination), twice dθ at a 63° inclination).
"""

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from quad_drake.conventions import NO_SAMPLE_STAMP, ONBOARD_PERIOD
from quad_drake.flightlogs.reader import Samples
from quad_drake.models.rotations import wrap_angles

HEADING_GRAVITY_WINDOW = 0.1
"""s of accelerometer samples averaged for gravity's direction at a field sample: long enough
to average out motor vibration (a real 250 Hz IMU: 25 samples), short against the manoeuvres
whose own acceleration no average removes."""
NO_AID_TIMEOUT = 5.0
"""s without a GPS sample after which PX4 EKF2 stops dead-reckoning and holds a fake position
(``EKF2_NOAID_TOUT``, 5 s): a gap longer than this is a GPS loss (``aiding_gps``)."""
IMU_BRIDGE_WINDOW = 0.05
"""s: the default of ``ReplayConfig.imu_gap_bridge`` (:func:`bridged_imu`): an IMU gap longer than
this (a logger's dropout) is filled from the mean of the samples within this window before it to
the mean of those within it after it."""
BARO_SLOPE_WINDOW = 1.0
"""s of barometer samples whose least-squares slope is a held position's vertical velocity."""
TICK_TOLERANCE = 1e-6
"""Fraction of a tick by which a sample time may exceed a tick time and still be emitted at it
(the sums that make tick and sample times round differently in their last bits)."""


@dataclass(frozen=True)
class Stream:
    """One output of the playback: per sample the tick it is emitted at (first_tick (m,) ints)
    and its output row (rows (m, width)): its values and, for a stamped stream, its stamp (its
    time, s) last."""

    first_tick: np.ndarray
    rows: np.ndarray
    stamped: bool

    @property
    def width(self) -> int:
        return self.rows.shape[1]

    def initial(self) -> np.ndarray:
        """The output before the first sample: zeros (and stamp NO_SAMPLE_STAMP)."""
        value = np.zeros(self.width)
        if self.stamped:
            value[-1] = NO_SAMPLE_STAMP
        return value


STREAM_WIDTHS = {"imu": 6, "gps": 6, "gps_accuracy": 3, "mag": 1, "mag_field": 3, "baro": 1, "no_aid": 12}
"""Values per sample of each stream (before the stamp): the port layouts of the module docstring."""
STAMPED = {name: name != "imu" for name in STREAM_WIDTHS}


def first_ticks(times, period=ONBOARD_PERIOD) -> np.ndarray:
    """(m,) index k of the first tick t_k = k period >= each sample time (s)."""
    return np.ceil(np.asarray(times, dtype=float) / period - TICK_TOLERANCE).astype(np.int64)


def output_changes(per_vehicle) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ticks (m,), vehicles (m,), rows (m, width)) of one stream of n flights (`per_vehicle`: each
    flight's :class:`Stream`): every change of a vehicle's output, sorted by tick (stable, so
    vehicle-ordered within a tick). A vehicle's output changes at each tick where a sample of it
    is first due, to the latest sample due then (an earlier one at the same tick is superseded)."""
    ticks, vehicles, rows = [], [], []
    for i, stream in enumerate(per_vehicle):
        first = stream.first_tick
        latest = np.flatnonzero(np.append(first[1:] != first[:-1], True)) if len(first) else np.zeros(0, int)
        ticks.append(first[latest])
        vehicles.append(np.full(len(latest), i))
        rows.append(stream.rows[latest])
    ticks = np.concatenate(ticks)
    order = np.argsort(ticks, kind="stable")
    return ticks[order], np.concatenate(vehicles)[order], np.concatenate(rows)[order]


def imu_tick_means(times, values, period=ONBOARD_PERIOD) -> tuple[np.ndarray, np.ndarray]:
    """(ticks (k,) ints, rows (k, w)): per onboard tick from the first sample's first tick to the
    last sample's, the mean over the tick's interval [t_j, t_j + period) of the piecewise-constant
    signal that holds each of the samples `values` (m, w) from its time `times` (m,) s (ascending)
    until the next one's (the first one also before its time, the last one on). A tick whose
    interval meets a non-finite sample's stretch of the signal is NaN in every column (the
    estimators dead-reckon over it, ``kernels.imu_hold``). Samples on the ticks themselves come
    back as they are; samples faster than the tick are averaged, none superseded."""
    t = np.asarray(times, dtype=float)
    nearest = np.round(t / period)
    t = np.where(np.abs(t / period - nearest) < TICK_TOLERANCE, nearest * period, t)  # on a tick, exactly
    v = np.asarray(values, dtype=float).reshape(len(t), -1)
    ticks = np.arange(first_ticks(t[:1])[0], first_ticks(t[-1:])[0] + 1)
    start, end = ticks * period, (ticks + 1) * period
    first = np.maximum(np.searchsorted(t, start, side="right") - 1, 0)  # the sample held at start
    last = np.maximum(np.searchsorted(t, end, side="left") - 1, 0)  # the one held just before end
    finite = np.isfinite(v).all(axis=1)
    held = np.where(finite[:, None], v, 0.0)
    rows = held[first]  # (a new array) a tick within one sample's stretch: that sample
    spans = np.flatnonzero(last > first)
    if len(spans):  # a tick that meets several: the first's part, the whole ones, the last's part
        whole = np.vstack([np.zeros((1, v.shape[1])), np.cumsum(held[:-1] * np.diff(t)[:, None], axis=0)])
        a, b = first[spans], last[spans]
        integral = (
            held[a] * (t[a + 1] - start[spans])[:, None]
            + (whole[b] - whole[a + 1])
            + held[b] * (end[spans] - t[b])[:, None]
        )
        rows[spans] = integral / period
    empty = np.append(np.diff(t) == 0.0, False)  # a sample with another at its time holds nowhere
    nonfinite = np.concatenate([[0], np.cumsum(~finite & ~empty)])
    rows[nonfinite[last + 1] - nonfinite[first] > 0] = np.nan
    return ticks, rows


def superseded_samples(times, period=ONBOARD_PERIOD) -> int:
    """How many samples are never emitted: followed by another before their tick."""
    ticks = first_ticks(times, period)
    return int(np.count_nonzero(ticks[1:] == ticks[:-1]))


def gravity_directions(imu, times, window=HEADING_GRAVITY_WINDOW) -> np.ndarray:
    """(m, 3) mean specific force f_B (m/s^2, FRD) of the IMU samples in (t - window, t] at each
    of `times` (s); the first IMU sample where none is that early. imu: the log's IMU Samples."""
    imu_times = imu.times
    force = imu.values[:, 0:3]
    cumulative = np.vstack([np.zeros((1, 3)), np.cumsum(force, axis=0)])
    last = np.searchsorted(imu_times, times, side="right")  # samples [first, last) are averaged
    first = np.searchsorted(imu_times, np.asarray(times) - window, side="right")
    last = np.maximum(last, 1)
    first = np.minimum(first, last - 1)
    return (cumulative[last] - cumulative[first]) / (last - first)[:, None]


def tilt_compensated_heading(field_B, f_B, declination=0.0) -> np.ndarray:
    """(m,) yaw (rad, [-pi, pi)) of the body field field_B (m, 3; any unit, FRD) with the tilt of
    the specific force f_B (m, 3, m/s^2, FRD, gravity's direction at rest); declination: rad,
    east of true north.

    roll = atan2(-f_y, -f_z), pitch = atan2(f_x, hypot(f_y, f_z)) (``estimation.complementary``'s
    tilt); the level field m_L = Ry(pitch) Rx(roll) m_B = Rz(yaw)^T m_N, and with m_N's horizontal
    part along the declination, yaw = declination - atan2(m_L,y, m_L,x).
    """
    field_B, f_B = np.asarray(field_B, dtype=float), np.asarray(f_B, dtype=float)
    roll = np.arctan2(-f_B[:, 1], -f_B[:, 2])
    pitch = np.arctan2(f_B[:, 0], np.hypot(f_B[:, 1], f_B[:, 2]))
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    mx, my, mz = field_B[:, 0], field_B[:, 1], field_B[:, 2]
    level_y = cr * my - sr * mz  # Rx(roll) m_B, then Ry(pitch) leaves y alone
    level_x = cp * mx + sp * (sr * my + cr * mz)
    return wrap_angles(declination - np.arctan2(level_y, level_x))


def initial_attitude(log, declination=0.0, hard_iron=(0.0, 0.0, 0.0)) -> tuple[float, float, float]:
    """(roll, pitch, yaw) rad of the first samples, as a flight controller aligns at start: tilt
    from the accelerometer (over HEADING_GRAVITY_WINDOW), yaw from the first heading (0 without a
    magnetometer; declination rad, hard_iron gauss FRD as :func:`heading_samples`)."""
    f_B = gravity_directions(log.imu, [HEADING_GRAVITY_WINDOW])[0]
    roll = math.atan2(-f_B[1], -f_B[2])
    pitch = math.atan2(f_B[0], math.hypot(f_B[1], f_B[2]))
    yaw = 0.0
    if log.heading is not None:
        yaw = float(log.heading.values[0, 0])
    elif log.mag_field is not None:
        yaw = float(heading_samples(log, declination, hard_iron)[0])
    return roll, pitch, yaw


def heading_samples(log, declination=0.0, hard_iron=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(m,) the yaw-only magnetometer samples (rad) at the log's field samples, the field less
    hard_iron (3, gauss, FRD), east of true north by declination (rad)."""
    gravity = gravity_directions(log.imu, log.mag_field.times)
    field = log.mag_field.values - np.asarray(hard_iron, dtype=float)
    return tilt_compensated_heading(field, gravity, declination)


def fake_position(log, period) -> Samples:
    """GPS-shaped Samples (p_N = 0 m, v_N = 0 m/s) every `period` s over the log: what a flight
    controller fuses without any position aiding (PX4 EKF2's fake position, ``EKF2_NOAID_NOISE``)
    so that its velocity, and through it its tilt, stays bounded. Not a measurement: its NIS is
    not judged."""
    times = np.arange(period, log.duration + 1e-9, period)
    return Samples(times, np.zeros((len(times), 6)))


AT_REST_GYRO = math.radians(3.0)
"""rad/s: a gyro rate above this is motion (PX4's land detector, ``GYRO_NORM_MAX`` 3°/s)."""
AT_REST_GYRO_VIBRATION = 0.02
"""rad/s: the low-passed change of the gyro rate from one IMU sample to the next above which the
vehicle moves (PX4's land detector, ``GYRO_VIBE_METRIC_MAX``)."""
AT_REST_ACCEL_VIBRATION = 1.2
"""m/s^2: the same of the specific force (PX4's land detector, ``ACCEL_VIBE_METRIC_MAX``)."""
AT_REST_VIBRATION_GAIN = 0.01
"""The vibration metrics' first-order low-pass gain per IMU sample (PX4's ``VehicleIMU``)."""
AT_REST_TIME = 1.0
"""s without motion before the vehicle is at rest (PX4's land detector)."""


@dataclass(frozen=True)
class RestTest:
    """PX4's at-rest test over one log (its land detector's ``vehicle_land_detected.at_rest``,
    which EKF2 takes as ``vehicle_at_rest``), built once from the log's IMU Samples (:meth:`of`:
    the vibration filters over every sample) and asked at any times (:meth:`at`). imu_times (s):
    the IMU's sample times; last_motion (s): at each IMU sample, the latest sample time at or before
    it that showed motion (-inf where none); landed: PX4's land detector's Samples (``landed``, 1
    or 0) or None."""

    imu_times: np.ndarray
    last_motion: np.ndarray
    landed: Samples | None = None

    @classmethod
    def of(cls, imu, landed=None) -> "RestTest":
        """The test of a log whose IMU Samples are `imu` (specific force m/s^2, rate rad/s) and
        land detector `landed` (or None): an IMU sample shows motion where its gyro rate is above
        AT_REST_GYRO or a vibration metric (the low-passed sample-to-sample change of the gyro
        rate or of the specific force) above AT_REST_GYRO_VIBRATION or AT_REST_ACCEL_VIBRATION;
        the first sample always (nothing is known before it)."""
        from scipy.signal import lfilter

        gain = AT_REST_VIBRATION_GAIN

        def vibration(signal):
            change = np.linalg.norm(np.diff(signal, axis=0, prepend=signal[:1]), axis=1)
            return lfilter([gain], [1.0, gain - 1.0], change)

        values = imu.values
        moving = np.linalg.norm(values[:, 3:6], axis=1) > AT_REST_GYRO
        moving |= vibration(values[:, 3:6]) > AT_REST_GYRO_VIBRATION
        moving |= vibration(values[:, 0:3]) > AT_REST_ACCEL_VIBRATION
        moving[0] = True  # nothing is known before the first sample: rest is proven over AT_REST_TIME
        last_motion = np.maximum.accumulate(np.where(moving, imu.times, -np.inf))
        return cls(imu.times, last_motion, landed)

    def at(self, times) -> np.ndarray:
        """(m,) bool: the vehicle at rest at each of `times` (s): no IMU sample in the
        AT_REST_TIME s before t, nor since the log's start, showed motion; and landed: PX4 fuses
        its rest σ only when not in the air, so where the log has PX4's land detector its last
        value at t (its first before it) must be 1. Without it the IMU alone decides: a flying
        multirotor's motors shake its IMU above these limits, a simulator's IMU need not."""
        times = np.asarray(times, dtype=float)
        index = np.searchsorted(self.imu_times, times, side="right") - 1
        before_start = index < 0
        resting = ~before_start & (times - self.last_motion[np.maximum(index, 0)] >= AT_REST_TIME)
        if self.landed is not None:
            resting &= flag_at(self.landed, times)
        return resting


def flag_at(record, times) -> np.ndarray:
    """(len(times),) bool: a logged 1/0 flag's Samples `record` (e.g. PX4's ``landed``) at each of
    `times` (s): its latest sample at or before the time, the first before the first."""
    latest = np.maximum(np.searchsorted(record.times, times, side="right") - 1, 0)
    return record.values[latest, 0] > 0.5


@dataclass(frozen=True)
class NoAidNoise:
    """The stds of PX4 EKF2's no-aiding samples (``no_aid_samples``): position_std (m, the fake
    position in flight, ``EKF2_NOAID_NOISE``), rest_position_std (m, the fake position at rest),
    rest_velocity_std (m/s, the zero velocity at rest), height_std (m, the fake position's height
    or inf: PX4 fuses none, its height is the barometer's)."""

    position_std: float
    rest_position_std: float
    rest_velocity_std: float
    height_std: float = math.inf


def no_aid_samples(rest, times, noise, position=(0.0, 0.0, 0.0)) -> Samples:
    """No-aiding Samples (m, 12: p_N m, v_N m/s, then the std of each of the six, inf = not
    fused) at `times` (s), PX4 EKF2's while it has no position aiding: a fake position at
    `position` (p_N m: the origin before a first fix, the last fix's after a GPS loss; its
    horizontal part, and its height at noise.height_std) every sample, with noise.position_std
    (``EKF2_NOAID_NOISE``); at rest (the log's :class:`RestTest` `rest`) with
    noise.rest_position_std, and a zero velocity (3 axes) with noise.rest_velocity_std (PX4's zero
    velocity update). noise: a :class:`NoAidNoise`."""
    times = np.asarray(times, dtype=float)
    resting = rest.at(times)
    values = np.zeros((len(times), 12))
    values[:, 0:3] = position
    values[:, 6:8] = np.where(resting, noise.rest_position_std, noise.position_std)[:, None]
    values[:, 8] = noise.height_std
    values[:, 9:12] = np.where(resting, noise.rest_velocity_std, math.inf)[:, None]
    return Samples(times, values)


def held_position(log, lost, position, times) -> np.ndarray:
    """(m, 6) fake GPS samples (p_N m, v_N m/s) at `times` (s) of a GPS loss at `lost` (s), for a
    kind that fuses no ``no_aid`` input (:func:`no_aid_samples` otherwise): the last fix's
    horizontal `position` with zero horizontal velocity (PX4's fake position); the height and
    vertical velocity the barometer's (its change since the loss, and its slope over the last
    BARO_SLOPE_WINDOW s: PX4's height follows the baro while the GPS is lost), or the last fix's
    height and zero vertical velocity on a log without one."""
    samples = np.zeros((len(times), 6))
    samples[:, 0:3] = position
    if log.baro is None:
        return samples
    baro_times, altitude = log.baro.times, log.baro.values[:, 0]
    samples[:, 2] = position[2] - (
        np.interp(times, baro_times, altitude) - np.interp(lost, baro_times, altitude)
    )
    for k, t in enumerate(times):
        window = (baro_times > t - BARO_SLOPE_WINDOW) & (baro_times <= t)
        if np.count_nonzero(window) >= 2:
            samples[k, 5] = -np.polyfit(baro_times[window], altitude[window], 1)[0]
    return samples


def measured_at(samples, delay) -> Samples | None:
    """The Samples `samples` (or None) as measured: each logged time less `delay` (s, the sensor's
    delay from measurement to log), those that would fall before the log's start dropped."""
    if samples is None or delay == 0:
        return samples
    times = samples.times - delay
    keep = times >= 0.0
    return Samples(times[keep], samples.values[keep])


def fused_by_px4(log) -> object:
    """The FlightLog `log` with only the GPS samples (and their receiver accuracies) that fall where
    PX4's estimator fused GNSS (``log.px4_gps_fusion`` at the sample's logged time); its GPS None
    where it fused none; `log` itself where the log does not record it (a CSV without ``gps_fused`` rows)."""
    record = log.px4_gps_fusion
    if record is None or log.gps is None:
        return log

    def kept(samples):
        if samples is None:
            return None
        keep = flag_at(record, samples.times)
        return Samples(samples.times[keep], samples.values[keep]) if keep.any() else None

    gps = kept(log.gps)
    if gps is not None and len(gps) == len(log.gps):
        return log
    return dataclasses.replace(log, gps=gps, gps_accuracy=kept(log.gps_accuracy) if gps is not None else None)


def bridged_imu(imu, window) -> tuple[Samples, int]:
    """(IMU Samples, gaps bridged): `imu` (6: f_B m/s^2, w_B rad/s) with each interval between two
    samples longer than `window` s (a dropout of the logger, whose samples PX4's estimator had)
    filled with samples one median sample interval apart, from one interval after the last sample
    before it, whose values run linearly, each at its stretch's middle, from the mean of the
    samples within `window` s before the gap (its last sample included) to the mean of those
    within `window` s after it (its first included): the vehicle's mean motion interpolated
    between the two sides (for a random walk, its mean given both ends). One raw sample of a
    vibrating vehicle (a real multirotor's accelerometer swings by several m/s^2 from sample to
    sample) held over the gap would integrate its vibration into the velocity and the attitude,
    and the mean before the gap held over it misses the turn the vehicle made in it. window 0:
    `imu` as it is."""
    if window <= 0.0 or len(imu) < 2:
        return imu, 0
    times, values = imu.times, imu.values
    gaps = np.flatnonzero(np.diff(times) > window)
    if len(gaps) == 0:
        return imu, 0
    step = float(np.median(np.diff(times)))
    added_times, added_values = [], []
    for i in gaps:
        first = int(np.searchsorted(times, times[i] - window, side="left"))
        last = int(np.searchsorted(times, times[i + 1] + window, side="right"))
        before, after = values[first : i + 1].mean(axis=0), values[i + 1 : last].mean(axis=0)
        start, end = times[i] + step, times[i + 1]  # the gap: after the last sample's own interval
        filled = np.arange(start, end - 0.5 * step, step)
        middles = 0.5 * (filled + np.append(filled[1:], end))
        share = (middles - start) / (end - start)
        added_times.append(filled)
        added_values.append(before + share[:, None] * (after - before))
    times = np.concatenate([times, *added_times])
    order = np.argsort(times, kind="stable")
    return Samples(times[order], np.vstack([values, *added_values])[order]), len(gaps)


def playback_streams(
    log, gps=None, declination=0.0, hard_iron=(0.0, 0.0, 0.0), no_aid=None, gps_accuracy=None
) -> dict[str, Stream]:
    """{stream name: Stream} of a FlightLog for ``systems.playback.LogPlayback`` (module docstring).

    gps: the GPS Samples to emit (default: the log's own); no_aid: the no-aiding Samples
    (:func:`no_aid_samples`) or None; gps_accuracy: the receiver's accuracy Samples to emit, or
    None (none emitted; the log's own ``gps_accuracy`` is emitted only when given); a sensor the
    log lacks has a stream with no samples (its output never carries one). declination (rad) and
    hard_iron (gauss, FRD): the yaw-only heading's (:func:`heading_samples`).
    """
    sources = {
        "imu": log.imu,
        "gps": log.gps if gps is None else gps,
        "gps_accuracy": gps_accuracy,
        "mag_field": log.mag_field,
        "baro": log.baro,
        "no_aid": no_aid,
    }
    streams = {}
    for name, samples in sources.items():
        if samples is None:
            streams[name] = _stream(name, np.zeros(0), np.zeros((0, STREAM_WIDTHS[name])))
        elif name == "imu":
            streams[name] = Stream(*imu_tick_means(samples.times, samples.values), stamped=False)
        else:
            streams[name] = _stream(name, samples.times, samples.values)
    if log.heading is not None:  # a yaw magnetometer's samples as received
        streams["mag"] = _stream("mag", log.heading.times, log.heading.values)
    elif log.mag_field is not None:
        headings = heading_samples(log, declination, hard_iron)
        streams["mag"] = _stream("mag", log.mag_field.times, headings[:, None])
    else:
        streams["mag"] = _stream("mag", np.zeros(0), np.zeros((0, 1)))
    return streams


def _stream(name, times, values):
    values = np.asarray(values, dtype=float).reshape(len(times), STREAM_WIDTHS[name])
    if STAMPED[name]:
        values = np.column_stack([values, times])
    return Stream(first_ticks(times), values, STAMPED[name])
