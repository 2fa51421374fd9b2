"""What a replay assumes: the estimator and its tuning for a real flight controller's sensors.

A :class:`ReplayConfig` is loaded as a scenario is (``config``'s checks and ``--set`` overrides,
one-line ConfigError naming the field), from :func:`default_replay` plus the command line's
``--estimator {kind: ...}`` mapping and ``--set key=value`` overrides, and is written beside
the results as ``config.yaml``.

The defaults are PX4 EKF2's own (``EKF2_GYR_NOISE`` 0.015 rad/s, ``EKF2_ACC_NOISE`` 0.35 m/s^2 at
its 10 ms prediction step, ``EKF2_GPS_P_NOISE`` 0.5 m, ``EKF2_GPS_V_NOISE`` 0.3 m/s horizontally and
1.5 times them vertically, as PX4 fuses them, each GPS sample at no less than its receiver's
reported accuracy,
``EKF2_HEAD_NOISE`` 0.3 rad, ``EKF2_ACC_B_NOISE`` 0.003 m/s^3, ``EKF2_GYR_B_NOISE`` 0.001 rad/s^2,
``EKF2_BARO_NOISE`` 3.5 m, ``EKF2_MAG_NOISE`` 0.05 gauss for the 3-axis field),
not tuned on these logs: the IMU noise is re-expressed per 2 ms sample with the same density
(x sqrt(10 ms / 2 ms)), and the complementary filter's time constant is 0.5 s (the simulated
scenarios' 100 s trusts the gyro of a simulated IMU without bias; a real gyro's bias needs the
accelerometer sooner).
"""

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import yaml
from pydrake.common.yaml import yaml_dump, yaml_dump_typed, yaml_load_typed

from quad_drake.config import (
    PACKAGE_DIR,
    BaroParams,
    ConfigError,
    GpsParams,
    ImuParams,
    MagParams,
    SensorsConfig,
    VehicleConfig,
    apply_override,
    check_node,
    did_you_mean,
    first_line,
    load_yaml,
    override_hint,
    parse_override,
    validate,
)
from quad_drake.config.deprecated import migrate_ekf7_blocks, migrate_ekf7_override
from quad_drake.config.fields import number
from quad_drake.config.loader import dump_resolved
from quad_drake.config.saved import warn_of_absent_settings
from quad_drake.estimation.registry import (
    DEFAULT_KIND,
    KINDS,
    AidingParams,
    Ekf7EstimatorConfig,
    EstimatorConfig,
)
from quad_drake.flightlogs.schedule import IMU_BRIDGE_WINDOW
from quad_drake.models.fidelity import PHYSICAL

LOG_DIR = PACKAGE_DIR / "data" / "flight_logs"
"""The bundled flight logs (package data): pyulog's test logs, BSD-3-Clause (README there)."""
FAKE_VELOCITY_STD = 1e3
"""m/s: the velocity part of a fake position sample, so large that it carries no information."""
UNFUSED_HEIGHT_STD = 1e3
"""m: the GPS height noise of a replay whose height reference is the barometer, so large that the
GPS height carries no information (neither to the filter nor to the baro's bias filter)."""
HEIGHT_REFERENCES = ("log", "baro", "gps")
"""``ReplayConfig.height_reference``: as the log's parameters say (:func:`height_reference`), or forced."""
MAX_SENSOR_DELAY = 0.5
"""s: the largest sensor delay a replay takes (PX4's EKF2_*_DELAY range ends at 300 ms)."""
REST_VELOCITY_STD = 0.2
"""m/s: PX4 EKF2's zero velocity at rest once its tilt is aligned, from v1.14 on
(``controlZeroVelocityUpdate``; 0.001 before the alignment, which the replay's at-rest test,
1 s of rest, comes after)."""
REST_VELOCITY_STD_BY_RELEASE = {(1, 13): 0.001}
"""m/s: PX4 releases whose zero velocity at rest had another std: v1.13 fused it at 0.001 m/s
throughout (the 2022 code before PX4-Autopilot pull request 20611 relaxed it to 0.2 after the tilt
alignment; measured on the SITL ground-truth log, v1.13: PX4's velocity variance falls to 1.0e-6
(m/s)² at every zero-velocity update, 0.2 s apart, before and after its alignment)."""
ZERO_VELOCITY_FROM = (1, 13)
"""The first PX4 release whose EKF2 fuses a zero velocity at rest (PX4-Autopilot pull request
19149, 2022); earlier ones fused none (measured: PX4's vertical velocity variance stays 0.026-0.037
(m/s)² over sample_log_small's 6.5 s at rest, v1.11, and 0.12-0.30 on roboto_test, v1.12)."""
ZERO_VELOCITY_STOPS_WHILE_AIDED_FROM = (1, 14)
"""The first PX4 release whose zero velocity at rest stops while GNSS (or another source) aids the
velocity (PX4-Autopilot pull request 20611, November 2022: with it the filter was "too rigid" to
follow a drifting GNSS position); v1.13 fused it while aided as well. A replay fuses it only
while not GPS-aided (its no-aiding samples), whatever the release: the notes say where a log's
release differed."""
SENSOR_DELAYS = ("gps_delay", "mag_delay", "baro_delay")
"""The ReplayConfig's sensor delay fields (s; None: the log's own, ``px4_parameters.log_delays``)."""


@dataclass
class ReplayConfig:
    """One replay: the log, the estimator and what it assumes (module docstring)."""

    name: str = field(default="", metadata={"pattern": "scenario"})  # default: the log's file stem
    log: str = ""  # the flight log file (.ulg or .csv)
    estimator: EstimatorConfig = field(default_factory=Ekf7EstimatorConfig)
    mag_declination: Optional[float] = None  # rad, east of true north; None: the log's own
    # m: a log without GPS gets a zero position sample every fake_position_period s with this
    # std (PX4's EKF2_NOAID_NOISE), so the estimator's velocity, and its tilt, stay bounded; 0 = off
    fake_position_std: float = number(10.0, nonnegative=True)
    fake_position_period: float = number(0.2, tick_multiple=1)  # s
    # while not GPS-aided and at rest (``schedule.RestTest``: PX4's test on the log's IMU), the
    # fake position's std (m) and a zero velocity's (m/s), as PX4 EKF2 fuses them on the ground
    # (``controlFakePosFusion``: 0.01 m; ``controlZeroVelocityUpdate``); the built-in kinds and a
    # custom estimator with ``update_no_aid`` fuse each sample with its own std. The zero
    # velocity's None (the default): the std of the log's PX4 release (:func:`rest_velocity_std`);
    # 0: none fused
    rest_position_std: float = number(0.01, positive=True)
    rest_velocity_std: Optional[float] = None
    # what the estimator's height follows on a log with GPS and a barometer: "log" as PX4's
    # EKF2_HGT_REF / EKF2_HGT_MODE say (0: the baro, the GPS height then not fused), "baro", "gps"
    height_reference: str = field(default="log", metadata={"choices": HEIGHT_REFERENCES})
    # the ESKF only: also the fixed-interval RTS smoother of the replayed pass (``flightlogs.smoothing``),
    # logged as smoothed_state (16: p, v, q_NB, b_a, b_g) and smoothed_sigma (the error state's sigmas)
    smooth: bool = False
    # s: how long each sensor's samples took from measurement to the log (PX4's EKF2_GPS_DELAY,
    # EKF2_MAG_DELAY, EKF2_BARO_DELAY): a sample logged at t is replayed as measured at t - delay
    # (the replay reads the log ahead, as PX4 fuses on its delayed horizon); 0 = as logged; None
    # (the default): the log's own EKF2_*_DELAY where it holds one (PX4 takes each sample as
    # measured that long before its stamp), else 0 (a CSV; another estimator's log)
    gps_delay: Optional[float] = None
    mag_delay: Optional[float] = None
    baro_delay: Optional[float] = None
    # true: the estimator's noise and the sensor delays are the log's own EKF2_* parameters where
    # they map (``flightlogs.px4_parameters``; an ESKF only), instead of PX4's defaults
    px4_parameters: bool = False
    # true: the field also less the magnetometer bias PX4's estimator had learned by the log's start
    # (``FlightLog.estimator_mag_bias``, on top of ``EKF2_MAGBIAS_*``); off by default: on the two
    # logs that hold one it moves the yaw 5-10 % nearer PX4's and some roll, pitch, x farther
    estimator_mag_bias: bool = False
    # true: the estimator's IMU biases start at those PX4's primary estimator had learned by the
    # log's start (``FlightLog.estimator_imu_bias``: estimator_sensor_bias), their stds at PX4's
    # where the log holds its variances; a kind with bias states only (the ESKF). Off by default:
    # mixed across the logs measured (docs/measurements/replay.md)
    px4_start_biases: bool = False
    # s: an IMU gap longer than this (a logger's dropout) is filled from the mean of the samples
    # within this window before it to the mean of those within it after it, linearly, instead of
    # the last raw sample held (``schedule.bridged_imu``); 0 = the last sample held
    imu_gap_bridge: float = number(IMU_BRIDGE_WINDOW, nonnegative=True)
    # true: where the log's GPS reports each sample's accuracy (eph, epv, s_variance_m_s), the
    # built-in kinds fuse the sample as PX4 EKF2 does, each std the larger of the receiver's and
    # their own GPS noise (which PX4's EKF2_GPS_P_NOISE, EKF2_GPS_V_NOISE are: floors); false: their
    # own GPS noise alone (``estimation.measurements.receiver_noise``)
    gps_receiver_accuracy: bool = True
    # true: the log's GPS is fused only where PX4's estimator fused it (``FlightLog.px4_gps_fusion``,
    # its control flags: PX4 fuses GNSS only once its quality checks have passed), a log whose GPS
    # PX4 never fused replayed as one without GPS; false: every 3D fix; a log that does not record
    # it (a CSV without gps_fused rows): every 3D fix
    gps_where_px4_fused: bool = True


def default_estimator(kind) -> EstimatorConfig:
    """The replay's default estimator config of `kind` (its registry entry's ``replay_config``;
    PX4's noise, module docstring); an unknown kind: the EKF7's."""
    return KINDS.get(kind, KINDS[DEFAULT_KIND]).replay_config()


def default_replay(kind=DEFAULT_KIND) -> "ReplayConfig":
    """ReplayConfig with the defaults of the module docstring for an estimator of `kind`."""
    return ReplayConfig(estimator=default_estimator(kind))


def bundled_logs() -> dict:
    """{name: path} of the flight logs shipped with the package (``quad_drake/data/flight_logs``)."""
    return {p.stem: p for p in sorted(LOG_DIR.glob("*.ulg"))}


def resolve_log(name_or_path) -> Path:
    """Path of a flight log given as a file path or a bundled log's name; ConfigError if neither."""
    path = Path(str(name_or_path))
    if path.is_file():
        return path
    bundled = bundled_logs()
    if str(name_or_path) in bundled:
        return bundled[str(name_or_path)]
    raise ConfigError(
        f"{name_or_path}: no such flight log file, nor a bundled log"
        f"{did_you_mean(name_or_path, bundled)} (bundled: {', '.join(bundled)})"
    )


def distinct_logs(names) -> tuple[list[str], list[str]]:
    """(the logs `names`, each file once in the order given, by the file each resolves to
    (:func:`resolve_log`: a path or a bundled log's name); the names left out as repeats).
    ConfigError for a name that is neither."""
    kept, repeated, seen = [], [], set()
    for name in names:
        key = resolve_log(name).resolve()
        if key in seen:
            repeated.append(str(name))
            continue
        seen.add(key)
        kept.append(str(name))
    return kept, repeated


def load_replay(log, estimator=None, overrides=()) -> ReplayConfig:
    """Validated ReplayConfig of `log` (a flight log's path or bundled name, or the config.yaml of
    an earlier replay), an ``--estimator`` mapping (YAML text, e.g. ``{kind: eskf}``: the defaults
    of that kind with these fields changed) and ``--set`` overrides (``ekf.mag_yaw_std=0.2``,
    ``estimator.gyro_std=[0.05, 0.05, 0.05]``).

    Raises ConfigError (one line naming the file, ``--estimator``, ``--set`` or the field).
    """
    chosen = estimator_mapping(estimator)
    saved = None  # (path, text) of an earlier replay's config.yaml
    if Path(str(log)).suffix in (".yaml", ".yml"):
        raw, text = _replay_file(Path(str(log)))
        saved = Path(str(log)), text
        migrate_ekf7_blocks(raw, "")
        if chosen:
            kind = chosen.get("kind", raw["estimator"].get("kind"))
            base = raw["estimator"] if kind == raw["estimator"].get("kind") else _default_estimator_raw(kind)
            raw["estimator"] = {**_untagged(base), **chosen}
    else:
        kind = chosen.get("kind", DEFAULT_KIND)
        raw = load_yaml(yaml_dump_typed(default_replay(kind if kind in KINDS else DEFAULT_KIND)))
        path = resolve_log(log)
        raw["log"] = str(log) if path.parent == LOG_DIR else str(path.resolve())  # a bundled name stays one
        raw["estimator"] = {**_untagged(raw["estimator"]), **chosen}
    for text in overrides:
        keys, value = parse_override(text)
        for new_keys, new_value in migrate_ekf7_override(raw, keys, value, holder_depth=0):
            apply_override(raw, new_keys, new_value, text)
    hints = list(overrides) + ([f"estimator={estimator}"] if estimator else [])
    try:
        message = check_node(raw, ReplayConfig, "")
        if message:
            raise ConfigError(message)
        config = yaml_load_typed(schema=ReplayConfig, data=yaml_dump(raw))
        check_replay(config)
    except ConfigError as e:
        hint = override_hint(str(e), hints).replace("--set estimator=", "--estimator ")
        raise ConfigError(f"{e}{hint}") from None
    except (RuntimeError, ValueError, TypeError) as e:
        raise ConfigError(first_line(e)) from None
    resolve_log(config.log)
    if saved is not None:
        warn_of_absent_settings(*saved, raw, config)
    located = KINDS[config.estimator.kind].locate(config.estimator, Path.cwd())  # a custom factory's file
    return dataclasses.replace(config, estimator=located)


def _default_estimator_raw(kind):
    return load_yaml(yaml_dump_typed(default_replay(kind if kind in KINDS else DEFAULT_KIND)))["estimator"]


def _replay_file(path):
    """(raw mapping, text) of a replay's config.yaml (ConfigError naming the file when unreadable
    or not one)."""
    try:
        text = path.read_text(encoding="utf-8")
        raw = load_yaml(text)
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: cannot read ({e})") from None
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML: {first_line(e)}") from None
    if not isinstance(raw, dict) or "log" not in raw:
        raise ConfigError(f"{path}: not a replay's config.yaml (no log: field)")
    return raw, text


def estimator_mapping(text) -> dict:
    """The mapping of an ``--estimator`` YAML text ({} for None); ConfigError naming --estimator."""
    if text is None:
        return {}
    try:
        mapping = load_yaml(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"--estimator {text!r}: not valid YAML ({first_line(e, located=False)})") from None
    if not isinstance(mapping, dict):
        raise ConfigError(f"--estimator {text!r}: expected a mapping such as '{{kind: eskf}}'")
    return mapping


def _untagged(mapping):
    return {k: v for k, v in mapping.items() if k != "_tag"}


def check_replay(config) -> ReplayConfig:
    """`config` (a ReplayConfig) when every field keeps its rules; else ConfigError (one line)."""
    try:
        validate(dataclasses.replace(config, name=config.name or "replay"))
    except (TypeError, AttributeError) as e:
        raise ConfigError(f"a replay field has the wrong type ({e})") from None
    kind = KINDS[config.estimator.kind]
    if kind.builder is None:
        raise ConfigError(f"estimator.kind: {kind.name!r} runs no estimator; nothing to replay")
    problem = kind.fidelity_problem(PHYSICAL) or kind.problem(config.estimator)  # a replay is physical
    if problem:
        raise ConfigError(f"estimator: {problem}")
    if config.px4_parameters and not kind.takes_px4_parameters:
        raise ConfigError(
            f"px4_parameters: maps EKF2_* onto an ESKF only, not kind {config.estimator.kind!r}"
        )
    if config.px4_start_biases and kind.started_with_biases is None:
        raise ConfigError(
            f"px4_start_biases: starts the IMU bias states of an ESKF, not kind {config.estimator.kind!r}"
        )
    if config.mag_declination is not None and not abs(config.mag_declination) <= math.pi:
        raise ConfigError(f"mag_declination: must be within [-pi, pi] rad, got {config.mag_declination}")
    if config.rest_velocity_std is not None and not config.rest_velocity_std >= 0.0:
        given = config.rest_velocity_std
        raise ConfigError(
            f"rest_velocity_std: must be >= 0 m/s (0: none; null: the log's PX4 release's), got {given}"
        )
    for name in SENSOR_DELAYS:
        delay = getattr(config, name)
        if delay is not None and not 0.0 <= delay <= MAX_SENSOR_DELAY:
            bounds = f"[0, {MAX_SENSOR_DELAY:g}] s (or null: the log's own)"
            raise ConfigError(f"{name}: must be within {bounds}, got {delay}")
    return config


def rest_velocity_std(config, release) -> float:
    """m/s: the std of the zero velocity at rest of the ReplayConfig `config` on a log of PX4
    release `release` ((major, minor) or None: ``FlightLog.px4_release``), 0 for none fused:
    `config`'s own where set, else the release's (:func:`release_rest_velocity_std`)."""
    if config.rest_velocity_std is not None:
        return config.rest_velocity_std
    return release_rest_velocity_std(release)


def release_rest_velocity_std(release) -> float:
    """m/s: the std of the zero velocity at rest that PX4 release `release` ((major, minor) or
    None) fused, 0 for none: 0 before :data:`ZERO_VELOCITY_FROM`, the release's own
    (:data:`REST_VELOCITY_STD_BY_RELEASE`), else :data:`REST_VELOCITY_STD` (later releases, and a
    log that does not say)."""
    if release is not None and release < ZERO_VELOCITY_FROM:
        return 0.0
    return REST_VELOCITY_STD_BY_RELEASE.get(release, REST_VELOCITY_STD)


def height_reference(config, parameters) -> str:
    """ "baro" or "gps": what the replay's height follows: `config`'s ``height_reference`` unless
    "log", else PX4's ``EKF2_HGT_REF`` (v1.14 on) or ``EKF2_HGT_MODE`` (before) in the log's
    `parameters` (0: the barometer), else the GPS."""
    if config.height_reference != "log":
        return config.height_reference
    value = parameters.get("EKF2_HGT_REF", parameters.get("EKF2_HGT_MODE"))
    return "baro" if value == 0 else "gps"


def fuses_no_aid(config) -> bool:
    """True when the estimator kind of the ReplayConfig `config` takes PX4's no-aiding samples on
    their own input (its ``measurements`` name ``no_aid``), each with its own std; otherwise they
    are merged into its GPS samples."""
    return "no_aid" in KINDS[config.estimator.kind].measurements


def vehicle_for(
    config,
    initial_attitude,
    fake_position,
    baro_period=None,
    magnetometer=None,
    baro_reference=False,
    imu_biases=None,
) -> VehicleConfig:
    """The VehicleConfig whose estimator ``systems.estimators.build_estimator`` builds:
    `config`'s, started at `initial_attitude` (roll, pitch, yaw rad) at rest at the origin, and
    with `fake_position` (a log without GPS) assuming the fake position's noise for its GPS input
    where its kind takes no ``no_aid`` input (which then carries the fake samples, each with its
    own std: ``sensors.no_aid``).

    The log's aiding sensors, where the estimator's kind fuses them (its
    ``EstimatorKind.measurements``: ``baro``, ``heading`` or ``field``): baro_period (s, the
    barometer's sample period as the bias filter pairs it with GPS heights; None: no barometer)
    and magnetometer (``earth_field.MagnetometerModel``: the 3-axis field with its world field
    and learned bias; None: no magnetometer) become the
    vehicle's ``sensors.baro`` and 3-axis ``sensors.mag``, and the model's figures its
    ``mag_field`` (an AidingParams estimator's: the EKF7's, the ESKF's). baro_reference: the
    barometer is the height reference (:func:`height_reference`): where the kind fuses the baro,
    it assumes the GPS height noise UNFUSED_HEIGHT_STD, as PX4 then fuses no GPS height.
    imu_biases: the IMU biases to start from (``reader.ImuBiasStart``; a kind with
    ``started_with_biases``), or None: the config's own start."""
    roll, pitch, yaw = initial_attitude
    kind = KINDS[config.estimator.kind]
    estimator = kind.started_from_log(config.estimator, roll, pitch, yaw)
    if imu_biases is not None:
        estimator = kind.started_with_biases(estimator, imu_biases)
    no_aid = fuses_no_aid(config)  # the fake samples come on their own input, with their std
    if fake_position and not no_aid:
        estimator = kind.assuming_gps_noise(estimator, config.fake_position_std, FAKE_VELOCITY_STD)
    fused = set(kind.measurements)
    accuracy = config.gps_receiver_accuracy and kind.fuses_gps_accuracy
    sensors = SensorsConfig(
        imu=ImuParams(), gps=GpsParams(), mag=MagParams(), no_aid=no_aid, gps_accuracy=accuracy
    )
    if baro_period is not None and "baro" in fused:
        sensors.baro = BaroParams(period=baro_period)
        if baro_reference and not fake_position:
            estimator = kind.assuming_baro_height_reference(estimator, UNFUSED_HEIGHT_STD)
    if magnetometer is not None and fused & {"heading", "field"}:
        sensors.mag = MagParams(three_axis=True)
        if isinstance(estimator, AidingParams):
            estimator = _with_field(estimator, magnetometer)
    return VehicleConfig(estimator=estimator, sensors=sensors)


def _with_field(params, magnetometer):
    """AidingParams `params` with its mag_field's world field and hard iron the MagnetometerModel's."""
    field_params = dataclasses.replace(
        params.mag_field,
        field_strength=magnetometer.field_strength,
        declination=magnetometer.declination,
        inclination=magnetometer.inclination,
        hard_iron=list(magnetometer.hard_iron),
    )
    return dataclasses.replace(params, mag_field=field_params)


def dump_replay(config) -> str:
    """The resolved ReplayConfig as a saved configuration's text (``config.loader.dump_resolved``)."""
    return dump_resolved(config)
