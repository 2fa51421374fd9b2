"""Pure: a recorded flight (PX4 ULog or the CSV format below) as arrays of timestamped samples.

Units and frames are converted here, once, into the package's conventions (``quad_drake``:
NED world, FRD body, SI units, quaternions wxyz body to world); everything downstream reads a
:class:`FlightLog` and never a log's own units. Times are seconds since the log's first IMU
sample (t = 0 of the replay); samples recorded earlier are dropped.

What is read from a PX4 ULog (``pyulog``, PX4's own reader):

- IMU (required): ``sensor_combined``: ``accelerometer_m_s2`` (specific force, m/s^2, FRD: the
  physical convention of ``quad_drake``, (0, 0, -9.81) level at rest) and ``gyro_rad`` (rad/s,
  FRD). PX4 logs each as the mean over the interval ``gyro_integral_dt`` that ends at
  ``timestamp``; a simulated IMU sample taken at t_k is held and integrated over the tick after
  t_k, so a PX4 sample is timed at the start of its interval, ``timestamp - gyro_integral_dt``
  (s in older logs, µs in newer ones): then the interval the estimator integrates it over is the
  one it was measured over. (Measured on the two bundled logs, timing it at ``timestamp``
  instead changes the roll and pitch differences from PX4's estimate by less than 0.1 mrad.)
- magnetometer (optional): ``vehicle_magnetometer.magnetometer_ga``, else the field inside
  ``sensor_combined`` (older PX4, at ``timestamp + magnetometer_timestamp_relative``, each
  sample once): the body field in gauss, FRD, as PX4 calibrated it. Gauss stays (PX4's unit and
  the world field's of issue 32's magnetometer). A log with neither has its raw ``sensor_mag``
  read: the instance PX4's primary estimator fused (else its preferred one), calibrated and
  rotated as the log's ``CAL_MAG*`` and ``SENS_BOARD_*`` parameters say from PX4 v1.12 on
  (``flightlogs.mag_calibration``), as logged before it (the drivers calibrated it);
  ``mag_source`` says which and how.
- barometer (optional): ``vehicle_air_data.baro_alt_meter``, else ``sensor_combined``'s when its
  ``baro_timestamp_relative`` marks it valid: pressure altitude, m, up.
- GPS (optional): ``vehicle_gps_position`` (else ``sensor_gps``) samples with a 3D fix
  (``fix_type >= 3``) at their ``timestamp`` (when the flight controller had them; the SITL
  log's ``timestamp_sample`` is 0): latitude and longitude (``latitude_deg`` or ``lat`` in 1e-7 deg), altitude
  above mean sea level (``altitude_msl_m`` or ``alt`` in mm) and NED velocity (``vel_n_m_s``
  ...). The position becomes NED metres from the first fix (the local origin) with
  ``pymap3d.geodetic2ned`` on the WGS84 ellipsoid; the altitudes are taken as heights above it:
  the geoid's offset is constant over a flight and cancels.
- PX4's land detector (optional): ``vehicle_land_detected.landed`` (1 landed, 0 in the air), which
  the no-aiding samples' rest test requires where logged (``schedule.RestTest``).
- PX4's own estimate, the reference of the comparison (optional): ``vehicle_attitude.q`` (wxyz,
  body FRD to NED; at ``timestamp_sample`` where logged) and ``vehicle_local_position``
  (x, y, z, vx, vy, vz in NED about PX4's origin ``ref_lat``, ``ref_lon``, ``ref_alt``), moved
  into the GPS origin's frame (``geodetic2ned`` of PX4's origin); entries PX4 flags invalid
  (``xy_valid``, ``z_valid``, ``v_xy_valid``, ``v_z_valid``) are NaN. The velocities need no
  common frame and are read with or without GPS. The horizontal position needs one: valid only
  with GPS and PX4's global origin (``xy_global``). The height is moved by PX4's ``ref_alt``
  where it has a global one (``z_global``), else by PX4's own height at the replay's origin
  time (the first fix, or t = 0 without GPS: our estimate's z = 0 there), so a height PX4 marks
  valid is compared whether or not PX4 had a global origin. A sample (valid, global, within the
  GPS samples' time span) that puts PX4's horizontal position more than GPS_MISMATCH from the
  GPS at that time (an origin edited in the file, e.g.
  a location scrubbed in some topics and not in others, or a corrupted sample) is no position in
  the GPS's frame: its x, y, z are NaN; ``gps_mismatches`` counts them.
- the magnetic declination (rad, east of true north): PX4's parameter ``EKF2_MAG_DECL`` or
  ``ATT_MAG_DECL`` (degrees), None when the log has neither (``flightlogs.earth_field`` then
  takes it from the World Magnetic Model at the first fix).
- PX4's parameters (``parameters``: the initial values, e.g. ``EKF2_MAGBIAS_*``), and the UTC
  time of the first GPS fix (``time_utc_usec``) when logged, for the world field's date.
- the magnetometer bias PX4's primary estimator had learned by the log's start (optional):
  ``estimator_sensor_bias.mag_bias`` at its first sample, where valid and for the fused
  magnetometer, as ``estimator_mag_bias`` (what PX4 v1.13 on keeps instead of ``EKF2_MAGBIAS_*``).
- the IMU's clipping flags (optional): ``sensor_combined.accelerometer_clipping`` and
  ``gyro_clipping`` (bit i: axis i at the sensor's range, PX4 v1.12 on), the flagged samples only,
  as ``imu_clipping``.
- whether PX4's primary estimator fused the GPS (optional): ``estimator_status.control_mode_flags``
  bit 2, as ``px4_gps_fusion`` (PX4 starts fusing GNSS only once its quality checks have passed
  for a while, ``EKF2_GPS_CHECK``, ``EKF2_REQ_EPH`` ...: a log's fixes need not have been fused).
- PX4's changes of IMU and of estimator within the replayed stretch (optional): the IMU
  ``sensor_combined`` carries, ``sensor_selection``'s ``accel_device_id`` and ``gyro_device_id``
  (PX4's sensors module switches it on a sensor's failure), as ``imu_switches``, and the primary
  EKF2 instance, ``estimator_selector_status.primary_instance``, as ``estimator_switches``; each
  a change from one logged sample to the next, timed at the sample that shows it.
- the IMU biases the same estimator had learned by then (optional): ``estimator_sensor_bias``'s
  ``accel_bias`` and ``gyro_bias`` at its first sample, where valid, with their stds where it
  logs their variances (v1.12 on), as ``estimator_imu_bias`` (:class:`ImuBiasStart`).
- the simulator's ground truth (a SITL log; optional): ``vehicle_attitude_groundtruth.q`` (wxyz,
  body FRD to NED) as ``truth_attitude``; ``vehicle_global_position_groundtruth`` (lat, lon,
  horizontal) moved into the GPS origin's frame, ``vehicle_local_position_groundtruth``'s z
  (relative as PX4's height above) and (vx, vy, vz) as ``truth_position`` (horizontal NaN
  without a fix: no common frame then).
- whether the file ends mid-message (``truncated``: cut short, e.g. an interrupted download;
  pyulog reads it up to the cut and says nothing).

The CSV format (``.csv``), for data from any source: one sample per row, ``#`` starts a
comment line, an optional header row ``time,sensor,...``. Column 1 is the time in seconds
(any origin; t = 0 becomes the first IMU sample), column 2 the kind of sample, then its values
in the units and frames of :data:`CSV_SENSORS`::

    time,sensor,v0,v1,v2,v3,v4,v5
    0.000,imu,0.06,-0.01,-9.82,0.001,-0.003,0.000
    0.010,mag,0.214,0.012,0.422
    0.020,baro,488.06
    0.100,gps,47.3977418,8.5455939,487.99,0.0,0.0,0.0
    0.004,attitude,0.99999,0.00066,0.00438,-0.00045
    0.100,position,0.0,0.0,0.0,0.0,0.0,0.0
    0.000,declination,0.058
    0.000,date,2024.21

Any bad log raises :class:`FlightLogError`, one line naming the file, the topic or row and what
is wrong: a file that cannot be read, no IMU, time that does not increase, a non-finite value.
"""

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import quad_drake.flightlogs.mag_calibration as cal
from quad_drake.config.errors import ConfigError


class FlightLogError(ConfigError):
    """A flight log that cannot be replayed; str() is one line (the CLI prints it, exit 2)."""


@dataclass(frozen=True)
class Samples:
    """Timestamped samples of one signal: times (m,) s, strictly increasing; values (m, k)."""

    times: np.ndarray
    values: np.ndarray

    def __len__(self):
        return len(self.times)


@dataclass(frozen=True)
class FlightLog:
    """One recorded flight in ``quad_drake``'s units and frames (module docstring).

    imu: f_B specific force (3, m/s^2) and w_NB_B (3, rad/s), FRD. gps: p_N (3, m, NED from the
    first fix) and v_N (3, m/s, NED), or None. gps_accuracy: the receiver's reported accuracy of
    each GPS sample, at its times (3: horizontal and vertical position m, speed m/s std; PX4's eph,
    epv, s_variance_m_s), or None where the log has none (a CSV). mag_field: the body field (3,
    gauss, FRD), or None. baro: pressure altitude (1, m, up), or None. reference_attitude: PX4's
    q_NB (4, wxyz), or None. reference_position: PX4's p_N (3, m) and v_N (3, m/s) in the replay's
    origin frame, NaN where invalid (x, y always without GPS), or None. origin: (latitude deg,
    longitude deg, altitude m) of the first GPS fix, or None. mag_declination: rad, east of true
    north, None when the log does not say. start_time: the first IMU sample's time in the log's own
    clock (s), t = 0 here. parameters: the flight controller's parameters by name ({} for a CSV).
    fix_date: decimal year (UTC) of the first GPS fix, or None. truncated: the file ends
    mid-message. gps_mismatches: PX4 positions farther than GPS_MISMATCH from the GPS (module
    docstring), not compared. truth_attitude: the simulator's q_NB (4, wxyz), truth_position: its
    p_N (3, m, GPS origin's frame; NaN without GPS) and v_N (3, m/s), or None (a real flight).
    heading: a yaw magnetometer's samples (1, rad) as an estimator received them (a CSV's
    ``heading`` rows, e.g. a simulated run's), or None. mag_source: where mag_field came from, when
    not from a calibrated topic (the raw ``sensor_mag`` and its calibration; "" otherwise). landed:
    PX4's land detector's ``vehicle_land_detected.landed`` (1, 1 landed / 0 in the air) as logged,
    or None. estimator_mag_bias: the magnetometer bias (3, gauss, FRD) PX4's primary estimator had
    learned by the log's first sample (``estimator_sensor_bias.mag_bias``,
    :func:`_ulog_estimator_mag_bias`), or None. estimator_imu_bias: the IMU biases PX4's primary
    estimator had learned by the log's first sample (:class:`ImuBiasStart`,
    :func:`_ulog_estimator_imu_bias`), or None.
    imu_clipping: the IMU samples the log flags as clipped (2: the accelerometer's and the gyro's
    bitmask, bit i = axis i; 0 where a sensor's flags are not logged), at the IMU samples' times,
    or None where none is flagged or no flags are logged (:func:`_ulog_imu_clipping`).
    imu_switches: each change of the IMU ``sensor_combined`` carries within the replayed stretch,
    (t s, (accelerometer, gyro) device ids before, after), :func:`_ulog_switches`; ()
    where none or not logged (a CSV). estimator_switches: each change of PX4's primary EKF2
    instance, (t s, instance before, after), the same way. px4_gps_fusion: whether PX4's primary
    estimator fused GNSS (1, 0) from t = 0 on, each change at its time (:func:`_ulog_px4_gps_fusion`;
    a CSV's ``gps_fused`` rows), or None where not recorded. px4_release: (major, minor) of the
    PX4 release that wrote the log (:func:`px4_release`), or None where it does not say (a CSV).
    px4_fake_position: whether PX4's primary estimator fused a fake position (1, 0) from t = 0 on,
    each change at its time (``estimator_status_flags.cs_fake_pos``, :func:`_ulog_px4_flag`), or
    None where not recorded (PX4 before v1.14, a CSV).
    """

    source: str
    imu: Samples
    gps: Samples | None = None
    gps_accuracy: Samples | None = None
    mag_field: Samples | None = None
    baro: Samples | None = None
    reference_attitude: Samples | None = None
    reference_position: Samples | None = None
    origin: tuple | None = None
    mag_declination: float | None = None
    start_time: float = 0.0
    parameters: dict = field(default_factory=dict)
    fix_date: float | None = None
    truncated: bool = False
    gps_mismatches: int = 0
    truth_attitude: Samples | None = None
    truth_position: Samples | None = None
    heading: Samples | None = None
    mag_source: str = ""
    landed: Samples | None = None
    estimator_mag_bias: tuple | None = None
    estimator_imu_bias: "ImuBiasStart | None" = None
    imu_clipping: Samples | None = None
    imu_switches: tuple = ()
    estimator_switches: tuple = ()
    px4_gps_fusion: Samples | None = None
    px4_release: tuple | None = None
    px4_fake_position: Samples | None = None

    @property
    def duration(self) -> float:
        """s from the first to the last IMU sample."""
        return float(self.imu.times[-1])

    def sensors(self) -> list[str]:
        """Names of the sensors the log holds besides the IMU, e.g. ``["gps", "mag", "baro"]``."""
        present = {"gps": self.gps, "mag": self.mag_field, "heading": self.heading, "baro": self.baro}
        return [name for name, samples in present.items() if samples is not None]


CSV_SENSORS = {
    "imu": ("f_x", "f_y", "f_z", "w_x", "w_y", "w_z"),  # m/s^2 specific force, rad/s; FRD
    "gps": ("latitude", "longitude", "altitude", "v_n", "v_e", "v_d"),  # deg, deg, m (up), m/s NED
    "gps_ned": ("x", "y", "z", "v_n", "v_e", "v_d"),  # m NED about the log's origin, m/s NED (no geodetic)
    # the receiver's reported accuracy of the GPS sample of the same time: m, m, m/s std
    "gps_accuracy": ("horizontal", "vertical", "speed"),
    # whether the flight controller's estimator fused the GPS from this time on: 1 or 0 (PX4's)
    "gps_fused": ("fused",),
    "mag": ("b_x", "b_y", "b_z"),  # gauss, FRD
    "heading": ("yaw",),  # rad, a yaw magnetometer's sample as the estimator received it
    "baro": ("altitude",),  # m, pressure altitude, up
    "attitude": ("q_w", "q_x", "q_y", "q_z"),  # reference estimate: body FRD to NED
    "position": ("x", "y", "z", "v_x", "v_y", "v_z"),  # reference estimate: m, m/s, NED, GPS origin
    "declination": ("declination",),  # rad, east of true north (one row, time ignored)
    "truth": (
        "x",
        "y",
        "z",
        "v_x",
        "v_y",
        "v_z",
        "q_w",
        "q_x",
        "q_y",
        "q_z",
    ),  # the true state: m, m/s NED, q_NB
    "date": ("year",),  # decimal year (UTC) of the first GPS fix, for the world field (one row, time ignored)
}
"""Sample kinds of the CSV format and their values, in order (units and frames in comments)."""

GPS_3D_FIX = 3
"""PX4's ``fix_type`` of a 3D fix; samples with less are not used."""
INVALID_RELATIVE_TIME = 2**31 - 1
"""``*_timestamp_relative`` value by which older PX4 marks a sensor absent from ``sensor_combined``."""
ULOG_TOPICS = (
    "sensor_combined",
    "vehicle_magnetometer",
    "sensor_mag",
    "estimator_selector_status",
    "estimator_sensor_bias",
    "vehicle_air_data",
    "vehicle_gps_position",
    "sensor_gps",
    "vehicle_attitude",
    "vehicle_local_position",
    "vehicle_attitude_groundtruth",
    "vehicle_local_position_groundtruth",
    "vehicle_global_position_groundtruth",
    "vehicle_land_detected",
    "sensor_selection",
    "estimator_status",
    "estimator_status_flags",
)
US = 1e-6
"""s per microsecond (ULog timestamps)."""
GPS_MISMATCH = 100.0
"""m: PX4's horizontal position, moved into the GPS frame by PX4's origin, this far from the GPS
at the same time is not in the GPS's frame (a healthy PX4 estimate stays metres from its GPS)."""
CS_GPS_BIT = 2
"""Bit of ``estimator_status.control_mode_flags`` set while PX4's EKF2 fuses GNSS measurements
(``filter_control_status_u``'s ``gps``, ``gnss_pos`` in later versions; every version's bit 2)."""


def read_flight_log(path) -> FlightLog:
    """FlightLog of a ``.ulg`` (PX4 ULog) or ``.csv`` file (module docstring); FlightLogError if bad."""
    path = Path(path)
    if not path.is_file():
        raise FlightLogError(f"{path}: no such flight log")
    suffix = path.suffix.lower()
    if suffix == ".ulg":
        return read_ulog(path)
    if suffix == ".csv":
        return read_csv(path)
    raise FlightLogError(f"{path}: not a flight log (expected a PX4 .ulg or a .csv file)")


# ----- checks shared by both formats -----------------------------------------------------------


def _checked(where, times, values, unit="s"):
    """Samples of (m,) times (in `unit`) and (m, k) values, or FlightLogError (`where` names the topic)."""
    times = np.asarray(times, dtype=float)
    values = np.asarray(values, dtype=float).reshape(len(times), -1)
    bad_time = np.flatnonzero(~np.isfinite(times))
    if bad_time.size:
        raise FlightLogError(f"{where}: time of sample {bad_time[0]} is not finite")
    backwards = np.flatnonzero(np.diff(times) <= 0)
    if backwards.size:
        i = backwards[0] + 1
        raise FlightLogError(
            f"{where}: time does not increase at sample {i} "
            f"({_time_text(times[i - 1], unit)}, then {_time_text(times[i], unit)})"
        )
    bad = np.argwhere(~np.isfinite(values))
    if bad.size:
        i, j = bad[0]
        raise FlightLogError(
            f"{where}: sample {i} (t = {_time_text(times[i], unit)}) has a non-finite value {values[i, j]}"
        )
    return Samples(times, values)


def _time_text(time, unit):
    """A time for a message: whole microseconds as integers, seconds with 9 digits."""
    return f"{time:.0f} {unit}" if unit == "µs" else f"{time:.9g} {unit}"


def _after_start(samples, start, scale=1.0):
    """`samples` (times in the log's clock) from `start` on, times made relative to it and
    multiplied by `scale` (s per unit of the log's clock: ULog's integer µs stay exact until here)."""
    keep = samples.times >= start
    return Samples((samples.times[keep] - start) * scale, samples.values[keep])


def _to_local(latitude, longitude, altitude, origin):
    """(m, 3) NED metres of geodetic points (deg, deg, m) from `origin` (deg, deg, m)."""
    import pymap3d

    north, east, down = pymap3d.geodetic2ned(latitude, longitude, altitude, *origin)
    return np.column_stack([north, east, down])


# ----- ULog ------------------------------------------------------------------------------------


def read_ulog(path) -> FlightLog:
    """FlightLog of a PX4 ULog file (module docstring); FlightLogError for a bad log."""
    from pyulog import ULog

    path = Path(path)
    try:
        ulog = ULog(str(path), list(ULOG_TOPICS))
    except Exception as e:  # pyulog raises whatever its parser meets in a foreign file
        reason = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise FlightLogError(f"{path}: not a readable ULog file ({reason})") from None
    topics, raw_mags, sensor_biases, statuses, status_flags = {}, [], {}, {}, {}
    for dataset in ulog.data_list:
        if dataset.multi_id == 0:
            topics[dataset.name] = dataset.data
        if dataset.name == "sensor_mag":
            raw_mags.append(dataset.data)
        if dataset.name == "estimator_sensor_bias":
            sensor_biases[dataset.multi_id] = dataset.data
        if dataset.name == "estimator_status":
            statuses[dataset.multi_id] = dataset.data
        if dataset.name == "estimator_status_flags":
            status_flags[dataset.multi_id] = dataset.data
    if "sensor_combined" not in topics:
        raise FlightLogError(f"{path}: no sensor_combined topic (the IMU); cannot replay without it")
    combined = topics["sensor_combined"]
    imu = _ulog_samples(
        path,
        "sensor_combined",
        combined,
        combined["timestamp"] - _integration_interval_us(path, combined),
        [f"accelerometer_m_s2[{i}]" for i in range(3)] + [f"gyro_rad[{i}]" for i in range(3)],
    )
    start = float(imu.times[0])
    gps, origin, gps_accuracy = _ulog_gps(path, topics)
    parameters = dict(ulog.initial_parameters)
    release = px4_release(ulog.msg_info_dict)
    declination = parameters.get("EKF2_MAG_DECL", parameters.get("ATT_MAG_DECL"))
    anchor = float(gps.times[0]) if gps is not None else start
    mag_field, mag_source = _ulog_mag(path, topics, raw_mags, parameters, release)
    reference_position, gps_mismatches = _ulog_local_position(path, topics, origin, anchor, gps)
    return FlightLog(
        source=str(path),
        imu=_after_start(imu, start, US),
        gps=_optional(gps, start, US),
        gps_accuracy=_optional(gps_accuracy, start, US),
        mag_field=_optional(mag_field, start, US),
        baro=_optional(_ulog_baro(path, topics), start, US),
        reference_attitude=_optional(_ulog_attitude(path, topics), start, US),
        reference_position=_optional(reference_position, start, US),
        origin=origin,
        mag_declination=None if declination is None else math.radians(float(declination)),
        start_time=start * US,
        parameters=parameters,
        fix_date=_fix_date(topics),
        truncated=ends_mid_message(path),
        gps_mismatches=gps_mismatches,
        truth_attitude=_optional(_ulog_truth_attitude(path, topics), start, US),
        truth_position=_optional(_ulog_truth_position(path, topics, origin, anchor), start, US),
        mag_source=mag_source,
        landed=_optional(_ulog_landed(path, topics), start, US),
        estimator_mag_bias=_ulog_estimator_mag_bias(topics, sensor_biases),
        estimator_imu_bias=_ulog_estimator_imu_bias(topics, sensor_biases),
        imu_clipping=_optional(_ulog_imu_clipping(combined, imu), start, US),
        imu_switches=_ulog_switches(topics, "sensor_selection", ("accel_device_id", "gyro_device_id"), imu),
        estimator_switches=_ulog_switches(topics, "estimator_selector_status", ("primary_instance",), imu),
        px4_gps_fusion=_ulog_px4_gps_fusion(topics, statuses, start),
        px4_release=release,
        px4_fake_position=_ulog_px4_flag(topics, status_flags, "cs_fake_pos", start),
    )


def px4_release(info) -> tuple[int, int] | None:
    """(major, minor) of the PX4 release a ULog's info messages `info` name (``ver_sw_release``,
    the word 0xMMmmpptt), or None where they name none (0 or absent: a development build of old,
    another flight stack)."""
    word = int(info.get("ver_sw_release", 0) or 0)
    if not word:
        return None
    return (word >> 24) & 0xFF, (word >> 16) & 0xFF


def _ulog_px4_gps_fusion(topics, statuses, start):
    """Samples (s after `start`, µs in the log's clock) of whether PX4's primary EKF2 instance
    (:func:`_primary_estimator`) fused GNSS (1) or not (0), from its ``estimator_status``'s
    ``control_mode_flags`` bit :data:`CS_GPS_BIT`: its value at `start` (the last sample at or
    before it, else the first) at t = 0, then each change; None without the topic or field."""
    data = statuses.get(_primary_estimator(topics))
    if data is None or "control_mode_flags" not in data or len(data["timestamp"]) == 0:
        return None
    fused = (np.asarray(data["control_mode_flags"], dtype=np.int64) >> CS_GPS_BIT) & 1
    return _changes_from(np.asarray(data["timestamp"], dtype=float), fused, start, US)


def _ulog_px4_flag(topics, status_flags, field, start):
    """Samples (s after `start`, µs in the log's clock) of a flag `field` of PX4's primary EKF2
    instance's ``estimator_status_flags`` (1 or 0; :func:`_changes_from`), or None without the
    topic or that field (its flags are named from PX4 v1.13 on, some later)."""
    data = status_flags.get(_primary_estimator(topics))
    if data is None or field not in data or len(data["timestamp"]) == 0:
        return None
    flags = np.asarray(data[field], dtype=np.int64) & 1
    return _changes_from(np.asarray(data["timestamp"], dtype=float), flags, start, US)


def _changes_from(times, flags, start, scale=1.0):
    """Samples of a flag's value at `start` (the last of `times` at or before it, else the first)
    at t = 0, then each change after it, at (time - start) * scale."""
    first = max(int(np.searchsorted(times, start, side="right")) - 1, 0)
    changed = first + 1 + np.flatnonzero(flags[first + 1 :] != flags[first:-1])
    rows = np.concatenate(([first], changed))
    relative = np.concatenate(([0.0], (times[changed] - start) * scale))
    return Samples(relative, np.asarray(flags, dtype=float)[rows, None])


CLIPPING_FIELDS = ("accelerometer_clipping", "gyro_clipping")
"""``sensor_combined``'s clipping bitmasks (bit i: axis i of that sensor at its range)."""


def _ulog_imu_clipping(combined, imu):
    """Samples (µs, the IMU samples' times) of the (accelerometer, gyro) clipping bitmasks of the
    flagged IMU samples, or None where none is flagged or the log has no clipping flags."""
    if not any(name in combined for name in CLIPPING_FIELDS):
        return None
    flags = np.column_stack(
        [np.asarray(combined.get(name, np.zeros(len(imu))), dtype=np.int64) for name in CLIPPING_FIELDS]
    )
    flagged = np.flatnonzero(np.any(flags != 0, axis=1))
    return Samples(imu.times[flagged], flags[flagged].astype(float)) if flagged.size else None


def _ulog_switches(topics, topic, fields, imu) -> tuple:
    """((t s, before, after), ...): each change of `fields` (before and after: a tuple of their
    int values, or the one value where `fields` has one) of `topic` from one logged sample to the
    next, timed at the sample that shows it, s after the first sample of the Samples `imu` (µs;
    changes outside the IMU's stretch left out); () where the log lacks the topic or a field."""
    data = topics.get(topic, {})
    if any(name not in data for name in fields):
        return ()
    values = np.column_stack([np.asarray(data[name], dtype=np.int64) for name in fields])
    times = np.asarray(data["timestamp"], dtype=float)
    changed = np.flatnonzero(np.any(values[1:] != values[:-1], axis=1)) + 1
    first, last = float(imu.times[0]), float(imu.times[-1])

    def value(row):
        return tuple(int(v) for v in values[row]) if len(fields) > 1 else int(values[row, 0])

    return tuple(
        (float((times[i] - first) * US), value(i - 1), value(i)) for i in changed if first <= times[i] <= last
    )


def _ulog_truth_attitude(path, topics):
    topic = "vehicle_attitude_groundtruth"
    if topic not in topics:
        return None
    data = topics[topic]
    return _ulog_samples(path, topic, data, _sample_times(data), [f"q[{i}]" for i in range(4)])


def _ulog_truth_position(path, topics, origin, anchor):
    """The simulator's p_N and v_N at the local ground truth's times, or None: horizontal from
    the global ground truth in the GPS origin's frame (NaN without a fix); the height from the
    local ground truth's z, less its value at `anchor` (µs: the first fix, else the first IMU
    sample), as PX4's relative height (SITL logs its global ground-truth altitude as 0)."""
    topic = "vehicle_local_position_groundtruth"
    if topic not in topics:
        return None
    data = topics[topic]
    times = np.asarray(_sample_times(data), dtype=float)
    velocity = np.column_stack([_field(path, topic, data, n) for n in ("vx", "vy", "vz")])
    position = np.full((len(times), 3), np.nan)
    where = "vehicle_global_position_groundtruth"
    if origin is not None and where in topics:
        fix = topics[where]
        fix_times = np.asarray(_sample_times(fix), dtype=float)
        geodetic = [np.interp(times, fix_times, _field(path, where, fix, n)) for n in ("lat", "lon")]
        position = _to_local(*geodetic, np.full(len(times), origin[2]), origin)
    z = _field(path, topic, data, "z")
    position[:, 2] = z - np.interp(anchor, times, z)
    _checked(f"{path}: {topic}", times, velocity, "µs")
    return Samples(times, np.column_stack([position, velocity]))


ULOG_HEADER_SIZE = 16
"""Bytes of a ULog file's header (magic, version, timestamp) before its first message."""


def ends_mid_message(path) -> bool:
    """True when the ULog file at `path` ends inside a message (its last message cut short):
    every ULog message starts with a 3-byte header (uint16 payload size, uint8 type), so walking
    them from the file header on must land exactly on the file's end."""
    data = Path(path).read_bytes()
    position, size = ULOG_HEADER_SIZE, len(data)
    while position + 3 <= size:
        position += 3 + int.from_bytes(data[position : position + 2], "little")
    return position != size


def _fix_date(topics):
    """Decimal year (UTC) of the first GPS sample with a 3D fix and a UTC time, or None."""
    import datetime

    topic = next((t for t in ("vehicle_gps_position", "sensor_gps") if t in topics), None)
    if topic is None or "time_utc_usec" not in topics[topic]:
        return None
    data = topics[topic]
    usable = np.flatnonzero((data["fix_type"] >= GPS_3D_FIX) & (data["time_utc_usec"] > 0))
    if usable.size == 0:
        return None
    when = datetime.datetime.fromtimestamp(int(data["time_utc_usec"][usable[0]]) * US, datetime.UTC)
    start = datetime.datetime(when.year, 1, 1, tzinfo=datetime.UTC)
    days = (datetime.datetime(when.year + 1, 1, 1, tzinfo=datetime.UTC) - start).total_seconds()
    return when.year + (when - start).total_seconds() / days


def _integration_interval_us(path, combined):
    """(m,) µs over which each ``sensor_combined`` sample was integrated (``gyro_integral_dt``:
    float seconds in older PX4, integer µs in newer)."""
    interval = combined.get("gyro_integral_dt")
    if interval is None:
        return 0.0
    if np.issubdtype(interval.dtype, np.floating):
        return np.round(np.asarray(interval, dtype=float) / US)
    return interval.astype(float)


def _optional(samples, start, scale=1.0):
    """:func:`_after_start` of `samples`; None when there are none (or none from `start` on)."""
    if samples is None:
        return None
    kept = _after_start(samples, start, scale)
    return kept if len(kept) else None


def _field(path, topic, data, name):
    if name not in data:
        raise FlightLogError(f"{path}: {topic} has no field {name!r}")
    return np.asarray(data[name], dtype=float)


def _ulog_samples(path, topic, data, timestamps_us, fields, rows=slice(None)):
    """Checked Samples of `fields` of a ULog topic at timestamps_us (µs, kept in µs), rows selected."""
    values = np.column_stack([_field(path, topic, data, name)[rows] for name in fields])
    times = np.asarray(timestamps_us, dtype=float)[rows]
    return _checked(f"{path}: {topic}", times, values, "µs")


def _sample_times(data):
    """µs: ``timestamp_sample`` where the topic logs it (the measurement's time), else ``timestamp``."""
    sampled = data.get("timestamp_sample")
    if sampled is not None and np.all(sampled > 0):
        return sampled
    return data["timestamp"]


def _combined_samples(path, combined, sensor, label, fields):
    """The `sensor` samples ("magnetometer", "baro") sensor_combined repeats at its own rate: each
    kept once, at its own time (``<sensor>_timestamp_relative``), invalid ones dropped; or None."""
    if f"{sensor}_timestamp_relative" not in combined:
        return None
    relative = combined[f"{sensor}_timestamp_relative"].astype(np.int64)
    valid = relative != INVALID_RELATIVE_TIME
    stamps = combined["timestamp"].astype(np.int64) + relative
    _, first = np.unique(stamps, return_index=True)  # each sample is repeated until the next
    rows = np.sort(first[valid[first]])
    if rows.size == 0:
        return None
    return _ulog_samples(path, f"sensor_combined ({label})", combined, stamps, fields, rows)


def _ulog_mag(path, topics, raw_mags, parameters, release):
    """(Samples of the body field or None, mag_source): ``vehicle_magnetometer``, else
    ``sensor_combined``'s field, else the raw ``sensor_mag`` (:func:`_raw_mag`)."""
    fields = [f"magnetometer_ga[{i}]" for i in range(3)]
    if "vehicle_magnetometer" in topics:
        data = topics["vehicle_magnetometer"]
        return _ulog_samples(path, "vehicle_magnetometer", data, data["timestamp"], fields), ""
    combined = _combined_samples(path, topics["sensor_combined"], "magnetometer", "magnetometer", fields)
    if combined is not None or not raw_mags:
        return combined, ""
    return _raw_mag(path, topics, raw_mags, parameters, release)


@dataclass(frozen=True)
class ImuBiasStart:
    """The IMU biases PX4's estimator had learned by a log's first sample (body FRD): accel
    (3, m/s^2) and gyro (3, rad/s), each subtracted from its sensor's reading as the ESKF's
    nominal biases are; accel_std (3, m/s^2) and gyro_std (3, rad/s): the square roots of PX4's
    variances of them, or None where the log does not hold them (PX4 before v1.12) or holds a
    variance that is not positive."""

    accel: tuple
    gyro: tuple
    accel_std: tuple | None = None
    gyro_std: tuple | None = None


def _primary_estimator(topics) -> int:
    """PX4's primary EKF2 instance at the log's start (``estimator_selector_status``), else 0."""
    selector = topics.get("estimator_selector_status", {})
    return int(selector["primary_instance"][0]) if "primary_instance" in selector else 0


def _ulog_estimator_imu_bias(topics, sensor_biases):
    """ImuBiasStart of PX4's primary EKF2 instance (:func:`_primary_estimator`) at its first
    ``estimator_sensor_bias`` sample, or None: no such topic or fields, or either bias marked
    invalid (``accel_bias_valid``, ``gyro_bias_valid``). The logger starts at arming, long after
    the estimator started learning (PX4-Autopilot ``src/modules/ekf2/EKF2.cpp``,
    ``PublishSensorBias``): what the flight began with."""
    data = sensor_biases.get(_primary_estimator(topics))
    if data is None or "accel_bias[0]" not in data or "gyro_bias[0]" not in data:
        return None
    if any(f"{s}_bias_valid" in data and not data[f"{s}_bias_valid"][0] for s in ("accel", "gyro")):
        return None

    def first(name):
        return tuple(float(data[f"{name}[{axis}]"][0]) for axis in range(3))

    def std(sensor):
        name = f"{sensor}_bias_variance"
        if f"{name}[0]" not in data:
            return None
        variance = np.array(first(name))
        return tuple(float(s) for s in np.sqrt(variance)) if np.all(variance > 0.0) else None

    accel, gyro = first("accel_bias"), first("gyro_bias")
    if not all(math.isfinite(b) for b in accel + gyro):
        return None
    return ImuBiasStart(accel, gyro, std("accel"), std("gyro"))


def _ulog_estimator_mag_bias(topics, sensor_biases):
    """(3-tuple gauss, FRD) the magnetometer bias PX4's primary EKF2 instance
    (``estimator_selector_status.primary_instance`` at its first sample, else instance 0) had
    learned by its first ``estimator_sensor_bias`` sample, or None: no such topic or field, the
    bias marked invalid (``mag_bias_valid`` 0: its variance outside (0, 0.1] G^2), or learned for
    another magnetometer than the fused one (``mag_device_id`` against ``vehicle_magnetometer``'s
    ``device_id``).

    PX4's EKF2 fuses ``vehicle_magnetometer`` less this bias state (its 3-axis field model is
    h = R^T m_N + b); the logger starts at arming, long after the estimator started learning, and
    from v1.13 on the bias is no longer saved as ``EKF2_MAGBIAS_*`` (the sensors module writes a
    stable one into ``CAL_MAGn_*OFF`` at disarm, for the next boot): the first sample is what the
    flight began with (PX4-Autopilot ``src/modules/ekf2/EKF2.cpp``, ``PublishSensorBias``)."""
    data = sensor_biases.get(_primary_estimator(topics))
    if data is None or "mag_bias[0]" not in data:
        return None
    if "mag_bias_valid" in data and not data["mag_bias_valid"][0]:
        return None
    fused = topics.get("vehicle_magnetometer", {})
    if "mag_device_id" in data and "device_id" in fused and data["mag_device_id"][0] != fused["device_id"][0]:
        return None
    return tuple(float(data[f"mag_bias[{axis}]"][0]) for axis in range(3))


def _raw_mag(path, topics, raw_mags, parameters, release):
    """(Samples, mag_source) of the preferred ``sensor_mag`` instance, calibrated as the log's
    parameters say where it is raw (``flightlogs.mag_calibration``, by the log's PX4 `release`,
    :func:`px4_release`)."""
    devices = [int(data["device_id"][0]) if "device_id" in data else 0 for data in raw_mags]
    selector = topics.get("estimator_selector_status", {})
    primary = int(selector["mag_device_id"][0]) if "mag_device_id" in selector else None
    chosen = cal.chosen_instance(devices, parameters, primary)
    data = raw_mags[chosen]
    samples = _ulog_samples(path, "sensor_mag", data, _sample_times(data), ["x", "y", "z"])
    what = f"the raw sensor_mag (instance {chosen}, device {devices[chosen]})"
    raw = cal.is_raw(release)
    if raw is False:
        return samples, f"{what}, calibrated by its driver (PX4 before v1.12): taken as logged"
    try:
        rotation, scale, offsets, description = cal.calibration(devices[chosen], parameters)
    except cal.CalibrationError as e:
        raise FlightLogError(f"{path}: sensor_mag cannot be calibrated: {e}") from None
    field_B = cal.calibrated(samples.values, rotation, scale, offsets)
    version = "" if raw else " (the log does not say its PX4 version: taken as v1.12 or later)"
    return Samples(samples.times, field_B), f"{what}, calibrated here by {description}{version}"


def _ulog_baro(path, topics):
    if "vehicle_air_data" in topics:
        data = topics["vehicle_air_data"]
        return _ulog_samples(path, "vehicle_air_data", data, data["timestamp"], ["baro_alt_meter"])
    return _combined_samples(path, topics["sensor_combined"], "baro", "barometer", ["baro_alt_meter"])


def _ulog_landed(path, topics):
    """Samples of PX4's land detector's ``landed`` (1 or 0), or None where the log lacks it."""
    if "vehicle_land_detected" not in topics:
        return None
    data = topics["vehicle_land_detected"]
    return _ulog_samples(path, "vehicle_land_detected", data, data["timestamp"], ["landed"])


GPS_ACCURACY_FIELDS = ("eph", "epv", "s_variance_m_s")
"""The GPS topic's accuracy of each sample as the receiver reports it: horizontal and vertical
position (m) and speed (m/s) std (PX4's hacc, vacc, sacc)."""


def _ulog_gps(path, topics):
    """(Samples of p_N, v_N in the local frame, origin, Samples of the receiver's accuracy at the
    same times (``GPS_ACCURACY_FIELDS``) or None where the topic lacks them) of the 3D fixes, or
    (None, None, None)."""
    topic = next((t for t in ("vehicle_gps_position", "sensor_gps") if t in topics), None)
    if topic is None:
        return None, None, None
    data = topics[topic]
    fixed = np.flatnonzero(_field(path, topic, data, "fix_type") >= GPS_3D_FIX)
    if fixed.size == 0:
        return None, None, None
    accuracy = None
    if all(name in data for name in GPS_ACCURACY_FIELDS):
        accuracy = _ulog_samples(path, topic, data, data["timestamp"], list(GPS_ACCURACY_FIELDS), fixed)
    if "latitude_deg" in data:
        geodetic = ["latitude_deg", "longitude_deg", "altitude_msl_m"]
        scales = (1.0, 1.0, 1.0)
    else:  # PX4 before v1.14: integers in 1e-7 deg and mm
        geodetic, scales = ["lat", "lon", "alt"], (1e-7, 1e-7, 1e-3)
    fields = geodetic + ["vel_n_m_s", "vel_e_m_s", "vel_d_m_s"]
    raw = _ulog_samples(path, topic, data, data["timestamp"], fields, fixed)
    values = raw.values.copy()
    values[:, 0:3] *= scales
    return *_geodetic_gps(raw.times, values), accuracy


def _geodetic_gps(times, values):
    """(Samples of p_N (local NED from the first sample), v_N; origin) of (m, 6) rows of
    latitude deg, longitude deg, altitude m, v_N m/s."""
    origin = tuple(float(x) for x in values[0, 0:3])
    position = _to_local(values[:, 0], values[:, 1], values[:, 2], origin)
    return Samples(times, np.column_stack([position, values[:, 3:6]])), origin


def _ulog_attitude(path, topics):
    if "vehicle_attitude" not in topics:
        return None
    data = topics["vehicle_attitude"]
    fields = [f"q[{i}]" for i in range(4)]
    return _ulog_samples(path, "vehicle_attitude", data, _sample_times(data), fields)


def _ulog_local_position(path, topics, origin, anchor, gps):
    """(PX4's position and velocity in the replay's origin frame, NaN where invalid (module
    docstring), or None without ``vehicle_local_position``; the number of samples far from
    the GPS). anchor: µs, the replay's origin time (the first fix, else the first
    IMU sample). gps: the GPS Samples (µs, NED m from `origin`), or None."""
    topic = "vehicle_local_position"
    if topic not in topics:
        return None, 0
    data = topics[topic]
    times = np.asarray(_sample_times(data), dtype=float)
    _checked(f"{path}: {topic}", times, np.zeros((len(times), 1)), "µs")  # time only: NaN marks invalid
    values = np.column_stack([_field(path, topic, data, n) for n in ("x", "y", "z", "vx", "vy", "vz")])
    reference = np.column_stack([_field(path, topic, data, n) for n in ("ref_lat", "ref_lon", "ref_alt")])
    xy_global = _field(path, topic, data, "xy_global") > 0
    z_global = _field(path, topic, data, "z_global") > 0
    known = np.isfinite(reference).all(axis=1) & (origin is not None)
    offsets = np.full((len(times), 3), np.nan)
    if known.any():
        offsets[known] = _to_local(reference[known, 0], reference[known, 1], reference[known, 2], origin)
    mismatched = np.zeros(len(times), dtype=bool)
    if known.any() and gps is not None:
        track = np.column_stack([np.interp(times, gps.times, gps.values[:, i]) for i in (0, 1)])
        distance = np.linalg.norm(values[:, 0:2] + offsets[:, 0:2] - track, axis=1)
        horizontal = (_field(path, topic, data, "xy_valid") > 0) & xy_global
        during_gps = (times >= gps.times[0]) & (times <= gps.times[-1])
        mismatched = known & horizontal & during_gps & ~(distance <= GPS_MISMATCH)
        known &= ~mismatched
        offsets[mismatched] = np.nan
    z_valid = _field(path, topic, data, "z_valid") > 0
    z = values[:, 2].copy()
    values[:, 0:3] += offsets
    relative = z_valid & ~(z_global & known)  # a valid height without a global origin
    if relative.any():
        values[relative, 2] = z[relative] - np.interp(anchor, times[relative], z[relative])
    for columns, flag in (
        ([0, 1], (_field(path, topic, data, "xy_valid") > 0) & xy_global & known),
        ([2], z_valid),
        ([3, 4], _field(path, topic, data, "v_xy_valid") > 0),
        ([5], _field(path, topic, data, "v_z_valid") > 0),
    ):
        values[np.ix_(~flag, columns)] = np.nan
    values[mismatched, 0:3] = np.nan
    return Samples(times, values), int(mismatched.sum())


# ----- CSV -------------------------------------------------------------------------------------


def read_csv(path) -> FlightLog:
    """FlightLog of a CSV file in the format of the module docstring; FlightLogError if bad."""
    path = Path(path)
    rows = {kind: [] for kind in CSV_SENSORS}
    try:
        with path.open(newline="", encoding="utf-8") as f:
            for line_number, row in enumerate(csv.reader(f), start=1):
                if not row or row[0].lstrip().startswith("#") or row[0].strip() == "time":
                    continue
                rows[_csv_kind(path, line_number, row)].append((line_number, row))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise FlightLogError(f"{path}: cannot read as CSV ({e})") from None
    if not rows["imu"]:
        raise FlightLogError(f"{path}: no imu rows; cannot replay without an IMU")
    parsed = {kind: _csv_samples(path, kind, found) for kind, found in rows.items() if found}
    start = float(parsed["imu"].times[0])
    gps, origin = (None, None)
    if "gps" in parsed and "gps_ned" in parsed:
        raise FlightLogError(f"{path}: both gps and gps_ned rows; give the GPS one way")
    if "gps" in parsed:
        gps, origin = _geodetic_gps(parsed["gps"].times, parsed["gps"].values)
    elif "gps_ned" in parsed:
        gps = parsed["gps_ned"]
    declination = float(parsed["declination"].values[-1, 0]) if "declination" in parsed else None
    fix_date = float(parsed["date"].values[-1, 0]) if "date" in parsed else None
    return FlightLog(
        source=str(path),
        imu=_after_start(parsed["imu"], start),
        gps=_optional(gps, start),
        gps_accuracy=_optional(parsed.get("gps_accuracy"), start),
        mag_field=_optional(parsed.get("mag"), start),
        baro=_optional(parsed.get("baro"), start),
        reference_attitude=_optional(parsed.get("attitude"), start),
        reference_position=_optional(parsed.get("position"), start),
        origin=origin,
        mag_declination=declination,
        start_time=start,
        fix_date=fix_date,
        heading=_optional(parsed.get("heading"), start),
        truth_position=_optional(_part(parsed.get("truth"), slice(0, 6)), start),
        truth_attitude=_optional(_part(parsed.get("truth"), slice(6, 10)), start),
        px4_gps_fusion=_csv_gps_fused(parsed.get("gps_fused"), start),
    )


def _csv_gps_fused(samples, start):
    """A CSV's ``gps_fused`` rows as ``FlightLog.px4_gps_fusion`` (:func:`_changes_from`), or None."""
    if samples is None:
        return None
    return _changes_from(samples.times, (samples.values[:, 0] > 0.5).astype(np.int64), start)


def _part(samples, columns):
    """Samples of some columns of `samples` (None for None)."""
    return None if samples is None else Samples(samples.times, samples.values[:, columns])


def _csv_kind(path, line_number, row):
    kind = row[1].strip() if len(row) > 1 else ""
    if kind not in CSV_SENSORS:
        raise FlightLogError(
            f"{path}: line {line_number}: sensor {kind!r} is not one of {', '.join(CSV_SENSORS)}"
        )
    return kind


def _csv_samples(path, kind, found):
    """Checked Samples of one kind's CSV rows [(line number, row)]."""
    width = len(CSV_SENSORS[kind])
    times, values = [], []
    for line_number, row in found:
        cells = [cell.strip() for cell in row[2:]]
        while cells and not cells[-1]:  # trailing empty columns of a wider table
            cells.pop()
        if len(cells) != width:
            raise FlightLogError(
                f"{path}: line {line_number}: {kind} takes {width} values "
                f"({', '.join(CSV_SENSORS[kind])}), got {len(cells)}"
            )
        try:
            times.append(float(row[0]))
            values.append([float(cell) for cell in cells])
        except ValueError as e:
            raise FlightLogError(f"{path}: line {line_number}: not a number ({e})") from None
    if kind in ("position", "truth"):  # NaN marks an invalid entry (a position without a frame)
        return Samples(_checked(f"{path}: {kind} rows", times, np.zeros(len(times))).times, np.array(values))
    return _checked(f"{path}: {kind} rows", times, values)
