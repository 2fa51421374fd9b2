"""Pure sensor faults: what a configured fault does to one sensor sample at its measurement time.

A sample is a list of floats in its sensor's layout (``conventions``): ``gps`` (7: p_N m,
v_N m/s, stamp s), ``mag`` (2: yaw rad, stamp s; a 3-axis one 4: m_B gauss FRD, stamp s),
``imu`` (6: f_B m/s^2, w_NB_B rad/s), ``baro`` (2: height m up, stamp s).
The measurement time is the sample's stamp (GPS, magnetometer) or its nominal sampling time
(IMU). Every fault is a function ``(sample, time, fault, period) -> sample`` of one sample;
they compose by applying a vehicle's faults of one sensor in list order
(:func:`apply_faults`). Nothing here holds state, draws noise or imports pydrake.

A fault never changes a stamp except to remove a sample: a removed sample (:func:`removed`)
has every value NaN and the stamp NO_SAMPLE_STAMP, the convention for "no sample (yet)", so
a consumer that judges freshness by the stamp sees nothing new, and one that did not would
fail loudly. Windows [start, end) are half-open on the measurement time, with
:data:`TIME_TOLERANCE` so that a stamp equal to a bound up to rounding counts as equal.

``gps_delay`` is not a function of one sample: it holds samples back. :func:`delay_queue_step`
is its pure part, one tick of a FIFO of pending samples released at stamp + delay
(:func:`release_due`); the stamp is kept, so an estimator can fuse a late sample at its
measurement time.
"""

import math

from quad_drake.conventions import NO_SAMPLE_STAMP
from quad_drake.models.rotations import wrap_to_pi

TIME_TOLERANCE = 1e-9
"""s; a measurement time within this of a window bound counts as equal to it."""

SENSORS = ("imu", "gps", "mag", "baro")
STAMPED = {"imu": False, "gps": True, "mag": True, "baro": True}
"""Whether a sensor's sample carries its stamp as its last entry."""


def sensor_of(kind) -> str:
    """The sensor a fault kind acts on: the prefix of its name (``gps_outage`` -> ``gps``)."""
    return kind.split("_", 1)[0]


def in_window(time, start, end) -> bool:
    """True iff start <= time < end (s), each comparison to TIME_TOLERANCE."""
    return start - TIME_TOLERANCE <= time < end - TIME_TOLERANCE


def removed(sample, stamped=True) -> list[float]:
    """The sample taken away: NaN values, and stamp NO_SAMPLE_STAMP where the layout has one."""
    if not stamped:
        return [math.nan] * len(sample)
    return [math.nan] * (len(sample) - 1) + [NO_SAMPLE_STAMP]


def shifted(sample, offset) -> list[float]:
    """The sample with ``offset`` added to its leading entries (len(offset) of them)."""
    n = len(offset)
    return [x + d for x, d in zip(sample[:n], offset, strict=True)] + list(sample[n:])


def gps_outage(sample, time, fault, period) -> list[float]:
    """No GPS sample measured in [start, end)."""
    return removed(sample) if in_window(time, fault.start, fault.end) else sample


def gps_outlier(sample, time, fault, period) -> list[float]:
    """The first GPS sample measured at or after ``fault.time`` shifted by ``fault.offset`` (3, m).

    With samples every ``period`` s that is the one measured in [time, time + period).
    """
    return shifted(sample, fault.offset) if in_window(time, fault.time, fault.time + period) else sample


def gps_step(sample, time, fault, period) -> list[float]:
    """GPS positions measured in [start, end) shifted by ``fault.offset`` (3, m); velocity kept."""
    return shifted(sample, fault.offset) if in_window(time, fault.start, fault.end) else sample


def mag_bias(sample, time, fault, period) -> list[float]:
    """Magnetometer yaw measured in [start, end) offset by ``fault.offset[0]`` rad, wrapped to [-pi, pi)."""
    if not in_window(time, fault.start, fault.end):
        return sample
    return [wrap_to_pi(sample[0] + fault.offset[0])] + list(sample[1:])


def mag_outage(sample, time, fault, period) -> list[float]:
    """No magnetometer sample measured in [start, end)."""
    return removed(sample) if in_window(time, fault.start, fault.end) else sample


def mag_disturbance(sample, time, fault, period) -> list[float]:
    """3-axis magnetometer fields measured in [start, end) shifted by ``fault.offset`` (3, gauss,
    body FRD): a magnetic disturbance near the vehicle."""
    return shifted(sample, fault.offset) if in_window(time, fault.start, fault.end) else sample


def baro_outage(sample, time, fault, period) -> list[float]:
    """No barometer sample measured in [start, end)."""
    return removed(sample) if in_window(time, fault.start, fault.end) else sample


def baro_step(sample, time, fault, period) -> list[float]:
    """Barometer heights measured in [start, end) shifted by ``fault.offset[0]`` m (e.g. a
    pressure change: weather, a door, a gust on the static port)."""
    return shifted(sample, fault.offset) if in_window(time, fault.start, fault.end) else sample


def imu_dropout(sample, time, fault, period) -> list[float]:
    """Every IMU sample measured in [start, end) non-finite (NaN)."""
    return removed(sample, stamped=False) if in_window(time, fault.start, fault.end) else sample


SAMPLE_FAULTS = {
    "gps_outage": gps_outage,
    "gps_outlier": gps_outlier,
    "gps_step": gps_step,
    "mag_bias": mag_bias,
    "mag_outage": mag_outage,
    "mag_disturbance": mag_disturbance,
    "imu_dropout": imu_dropout,
    "baro_outage": baro_outage,
    "baro_step": baro_step,
}
"""The faults that are functions of one sample, by kind."""


def sample_faults(faults, sensor) -> tuple:
    """The faults of `faults` (FaultConfig list) that act on single samples of `sensor`, in order."""
    return tuple(f for f in faults if f.kind in SAMPLE_FAULTS and sensor_of(f.kind) == sensor)


def gps_delay_of(faults) -> float:
    """The configured GPS delay, s (0 without a gps_delay fault)."""
    return sum(f.delay for f in faults if f.kind == "gps_delay")


def apply_faults(faults, sample, time, period) -> list[float]:
    """`sample` (list) measured at `time` (s) after each fault of `faults` in order.

    ``faults``: FaultConfig of one sensor (see :func:`sample_faults`); ``period``: s between
    the sensor's samples. A removed sample stays removed (later faults do not act on it).
    """
    for fault in faults:
        if STAMPED[sensor_of(fault.kind)] and sample[-1] == NO_SAMPLE_STAMP:
            break
        sample = SAMPLE_FAULTS[fault.kind](sample, time, fault, period)
    return sample


def release_due(pending, now, delay) -> tuple[list[list[float]], list[list[float]]]:
    """(due, still pending): samples of `pending` whose stamp + delay <= now (s), oldest first.

    ``pending``: stamped samples (lists, stamp last) in the order they were measured. The
    comparison allows TIME_TOLERANCE, so a sample due exactly at `now` is released at `now`.
    """
    count = 0
    while count < len(pending) and pending[count][-1] + delay <= now + TIME_TOLERANCE:
        count += 1
    return pending[:count], pending[count:]


def delay_queue_step(
    pending, sample, last_stamp, now, delay, capacity, sample_faults, period
) -> tuple[list[list[float]], list[list[float]], float]:
    """One tick of a ``gps_delay`` queue: (due, pending, last_stamp) after taking in `sample`.

    ``pending``: the queued samples (stamp last), oldest first, as of the previous tick;
    ``sample``: the sensor's current sample (stamp last, s; NO_SAMPLE_STAMP for none);
    ``last_stamp``: the stamp (s) of the last sample taken in; ``now``: this tick's time (s);
    ``delay``: s a sample is held after its stamp; ``capacity``: the most samples the queue
    holds; ``sample_faults`` and ``period`` (s between samples): the sensor's single-sample
    faults, as for :func:`apply_faults`.

    A sample whose stamp is neither NO_SAMPLE_STAMP nor `last_stamp` is new: its stamp becomes
    the last one, and it is queued after its faults (measured at its stamp) unless they remove
    it. Then every queued sample with stamp + delay <= now is released (:func:`release_due`).
    Returns the released samples (oldest first; the last one is the one to publish), the
    samples still pending and the last stamp. The queue changed iff a sample was released or
    the pending count differs from `pending`'s. Raises RuntimeError if more than `capacity`
    samples stay pending. Entries may be floats or (N,) arrays (a fleet's columns) with the
    stamp a float; `pending` is not modified.
    """
    stamp = sample[-1]
    if stamp != NO_SAMPLE_STAMP and stamp != last_stamp:
        last_stamp = stamp
        faulted = apply_faults(sample_faults, sample, stamp, period)
        if faulted[-1] != NO_SAMPLE_STAMP:
            pending = [*pending, faulted]
    due, pending = release_due(pending, now, delay)
    if len(pending) > capacity:
        raise RuntimeError(f"gps_delay queue overflow at t = {now} s ({len(pending)} samples)")
    return due, pending, last_stamp
