"""Pure: PX4 EKF2's parameters and a replay's ESKF tuning, both ways.

:data:`MAPPING` is the one table: per ``EKF2_*`` parameter its unit, PX4's default (the
registry's ``PX4_NOISE`` for the noise, PX4's own for the delays), the replay field it sets and the
conversion. Both directions use it:

- in (:func:`from_parameters`): a ReplayConfig whose ESKF noise and sensor delays are a log's own
  ``EKF2_*`` values (a parameter the log lacks keeps PX4's default), what ``px4_parameters: true``
  replays (``flightlogs.replay``);
- out (:func:`to_parameters`, :func:`parameter_file`): a tuned ReplayConfig as PX4 parameters, in
  the text format of QGroundControl's parameter files (``vehicle component name value type``),
  each line commented with PX4's default, the tuned value in our units and the conversion.

The conversions: the IMU noise is per 10 ms prediction step in PX4 and per 2 ms sample here, of
equal density (x sqrt(10 ms / 2 ms), ``registry.PX4_PER_SAMPLE``); the bias noises are read 1:1,
as the replay's defaults read them (``registry._eskf_replay_defaults``); PX4's one GPS position
and one velocity noise set the horizontal axes here and 1.5 times them the vertical, as PX4 fuses
them (``registry.px4_gps_noise``), and a tuned vector writes its horizontal mean (PX4 has no
separate vertical GPS noise parameter: the vertical value is stated in a comment);
the delays are ms in PX4 and s here. Parameters with no ESKF field (EKF2_HEAD_NOISE maps to
the yaw magnetometer's ``mag_yaw_std``, used only by a heading-only log) are in the table too.

The gravity-vector fusion: ``EKF2_GRAV_NOISE`` (PX4's default 1.0, unit g0) is the std PX4 fuses
on the accelerometer's unit vector f/|f| per 10 ms update (``Ekf::controlGravityFusion``), a
fraction of g, the quantity our ``estimator.gravity_std`` is (``eskf.gravity_update``): 1:1, not
x 9.81 (the ESKF rescales its variance to its 2 ms tick itself, ``eskf.gravity_variance``). Bit 2
of ``EKF2_IMU_CTRL`` (PX4's default 7: bits 0, 1 the gyro and accelerometer bias estimation, 2
the gravity fusion) switches it: clear, ``gravity_std`` is 0 (off). A log from PX4 before v1.14
holds neither parameter (PX4 had no gravity fusion then) and gets PX4's defaults, as every
missing parameter does: the fusion on at 1.0, the replay's ESKF's own default. Out, gravity_std
0 writes no EKF2_GRAV_NOISE (PX4 takes no 0: it floors the std at 0.01) but a comment to clear
the bit; EKF2_IMU_CTRL itself is not written (its other bits are PX4's bias estimation's).
"""

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

from quad_drake.estimation.registry import PX4_GRAVITY_STD, PX4_NOISE, PX4_PER_SAMPLE, px4_gps_noise

PX4_DEFAULT_DELAYS_MS = {"EKF2_GPS_DELAY": 110.0, "EKF2_MAG_DELAY": 0.0, "EKF2_BARO_DELAY": 0.0}
"""PX4's defaults of the sensor delays (ms; PX4's parameter reference)."""
PARAMETER_TYPE_REAL = 9
"""MAVLink's MAV_PARAM_TYPE_REAL32: the type column of a QGroundControl parameter file."""


@dataclass(frozen=True)
class Px4Switch:
    """A bit of a PX4 bitmask parameter that switches a fusion on: `name` (e.g. EKF2_IMU_CTRL),
    `bit` (0 = least significant) and PX4's `default` of the whole bitmask."""

    name: str
    bit: int
    default: int

    def on(self, parameters) -> bool:
        """Whether the bit is set in `parameters` ({name: value}; a missing name: PX4's default)."""
        return bool(int(parameters.get(self.name, self.default)) >> self.bit & 1)


IMU_CTRL_GRAVITY = Px4Switch("EKF2_IMU_CTRL", 2, 7)
"""``EKF2_IMU_CTRL`` bit 2, PX4's gravity-vector fusion (default 7: bits 0-2 all set; PX4's
parameter reference, ``src/modules/ekf2/module.yaml``)."""


@dataclass(frozen=True)
class Px4Parameter:
    """One EKF2 parameter: its name, unit, PX4's default, the ReplayConfig field it maps to
    (a dotted path below the ReplayConfig) and the factor ours = PX4's * factor; `switch`: the
    bitmask bit that turns it on (clear: the field is 0, off), or None; `per_axis`: our vector
    field's axes from our value (default: the value on each axis)."""

    name: str
    unit: str
    default: float
    field: str  # dotted path in the ReplayConfig, e.g. "estimator.gps_pos_std" or "gps_delay"
    factor: float  # ours = value * factor
    conversion: str  # the conversion in words
    switch: Px4Switch | None = None
    per_axis: Callable[[float], list] | None = None

    def ours(self, value) -> float:
        return float(value) * self.factor

    def theirs(self, ours) -> float:
        return float(ours) / self.factor

    def off(self, ours) -> bool:
        """Whether our value `ours` is the switched-off fusion (0 with a switch): not a value PX4 takes."""
        return self.switch is not None and ours == 0.0


_IMU = f"x sqrt(10 ms / 2 ms) = x {PX4_PER_SAMPLE:.4f}: PX4's per 10 ms step, ours per 2 ms sample"
MAPPING = (
    Px4Parameter(
        "EKF2_GPS_P_NOISE",
        "m",
        PX4_NOISE["gps_pos_std"],
        "estimator.gps_pos_std",
        1.0,
        "1:1 (m); PX4's one value sets our x, y and 1.5 times it our z; out: the mean of our x and y",
        per_axis=lambda value: px4_gps_noise(value, 0.0)[0],
    ),
    Px4Parameter(
        "EKF2_GPS_V_NOISE",
        "m/s",
        PX4_NOISE["gps_vel_std"],
        "estimator.gps_vel_std",
        1.0,
        "1:1 (m/s); PX4's one value sets our x, y and 1.5 times it our z; out: the mean of our x and y",
        per_axis=lambda value: px4_gps_noise(0.0, value)[1],
    ),
    Px4Parameter(
        "EKF2_MAG_NOISE",
        "gauss",
        PX4_NOISE["mag_field_std"],
        "estimator.mag_field.field_std",
        1.0,
        "1:1 (gauss) on each body axis",
    ),
    Px4Parameter(
        "EKF2_HEAD_NOISE",
        "rad",
        PX4_NOISE["heading_std"],
        "estimator.mag_yaw_std",
        1.0,
        "1:1 (rad), the yaw magnetometer's heading",
    ),
    Px4Parameter(
        "EKF2_BARO_NOISE", "m", PX4_NOISE["baro_height_std"], "estimator.baro.height_std", 1.0, "1:1 (m)"
    ),
    Px4Parameter(
        "EKF2_ACC_NOISE",
        "m/s^2",
        PX4_NOISE["accel_std"] / PX4_PER_SAMPLE,
        "estimator.accel_std",
        PX4_PER_SAMPLE,
        _IMU,
    ),
    Px4Parameter(
        "EKF2_GYR_NOISE",
        "rad/s",
        PX4_NOISE["gyro_std"] / PX4_PER_SAMPLE,
        "estimator.gyro_std",
        PX4_PER_SAMPLE,
        _IMU,
    ),
    Px4Parameter(
        "EKF2_ACC_B_NOISE",
        "m/s^3",
        0.003,
        "estimator.accel_bias_rw_std",
        1.0,
        "1:1 (our m/s^2/sqrt(s)), as the replay's defaults read it",
    ),
    Px4Parameter(
        "EKF2_GYR_B_NOISE",
        "rad/s^2",
        0.001,
        "estimator.gyro_bias_rw_std",
        1.0,
        "1:1 (our rad/s/sqrt(s)), as the replay's defaults read it",
    ),
    Px4Parameter(
        "EKF2_GRAV_NOISE",
        "g0",
        PX4_GRAVITY_STD,
        "estimator.gravity_std",
        1.0,
        "1:1, of the unit vector f/|f| per PX4's 10 ms update (g0, not x 9.81); "
        "EKF2_IMU_CTRL bit 2 clear: 0, off",
        IMU_CTRL_GRAVITY,
    ),
    *(
        Px4Parameter(name, "ms", default, field, 1e-3, "ms -> s (x 0.001)")
        for name, default, field in (
            ("EKF2_GPS_DELAY", PX4_DEFAULT_DELAYS_MS["EKF2_GPS_DELAY"], "gps_delay"),
            ("EKF2_MAG_DELAY", PX4_DEFAULT_DELAYS_MS["EKF2_MAG_DELAY"], "mag_delay"),
            ("EKF2_BARO_DELAY", PX4_DEFAULT_DELAYS_MS["EKF2_BARO_DELAY"], "baro_delay"),
        )
    ),
)
"""The EKF2 parameters that map onto a replay's ESKF and delays (module docstring)."""
BY_NAME = {p.name: p for p in MAPPING}


def field_at(config, path) -> object:
    """The value of the dotted field `path` (e.g. ``"estimator.gps_pos_std"``) of the dataclass `config`."""
    node = config
    for part in path.split("."):
        node = getattr(node, part)
    return node


def with_field(config, path, value) -> object:
    """A copy of the dataclass `config` with the dotted field `path` set to `value`."""
    head, _, rest = path.partition(".")
    if not rest:
        return dataclasses.replace(config, **{head: value})
    return dataclasses.replace(config, **{head: with_field(getattr(config, head), rest, value)})


def our_value(parameter, config) -> float:
    """The scalar our ReplayConfig `config` holds for `parameter`, in our units: a vector's
    horizontal mean for the GPS noises, its mean otherwise (IMU noise, the field's)."""
    value = field_at(config, parameter.field)
    if isinstance(value, list):
        value = value[:2] if parameter.field.startswith("estimator.gps_") else value
        value = sum(value) / len(value)
    return float(value)


def to_parameters(config) -> dict[str, float]:
    """{EKF2 name: value in PX4's units} of a ReplayConfig with an ESKF (every MAPPING row but a
    sensor delay left None, the log's own, and a switched fusion that is off: no value of the
    config's)."""
    return {
        p.name: p.theirs(our_value(p, config))
        for p in MAPPING
        if field_at(config, p.field) is not None and not p.off(our_value(p, config))
    }


def from_parameters(config, parameters) -> object:
    """A copy of the ReplayConfig `config` (an ESKF) with every MAPPING field set from
    `parameters` ({name: value}, PX4's units; a missing name: PX4's default): 0 (off) where the
    row's switch bit is clear."""
    for p in MAPPING:
        on = p.switch is None or p.switch.on(parameters)
        value = p.ours(parameters.get(p.name, p.default)) if on else 0.0
        current = field_at(config, p.field)
        if p.per_axis is not None:
            value = p.per_axis(value)
        elif isinstance(current, list):
            value = [value] * len(current)
        config = with_field(config, p.field, value)
    return config


def log_delays(config, parameters) -> object:
    """A copy of the ReplayConfig `config` with each sensor delay left None (its default) set from
    a log's `parameters`: its ``EKF2_*_DELAY`` in s where it holds one (PX4 takes each sample as
    measured that long before its stamp: PX4-Autopilot ``EstimatorInterface::setGpsData`` and the
    magnetometer's and barometer's alike), else 0 (a CSV, another estimator's log: as logged)."""
    for p in MAPPING:
        if p.field.endswith("_delay") and field_at(config, p.field) is None:
            value = p.ours(parameters[p.name]) if p.name in parameters else 0.0
            config = with_field(config, p.field, value)
    return config


def vertical_note(config) -> list[str]:
    """Comment lines for what PX4 has no parameter for: our tuned vertical GPS noise."""
    est = config.estimator
    return [
        f"vertical GPS noise tuned to {est.gps_pos_std[2]:.4g} m and {est.gps_vel_std[2]:.4g} m/s: "
        "PX4 has no separate parameter for it (not written; PX4 fuses 1.5 times the horizontal values "
        "written there)"
    ]


def parameter_file(config, start=None, vehicle=1, component=1) -> str:
    """The text of a QGroundControl parameter file of the ReplayConfig `config`'s MAPPING values:
    one ``vehicle component name value type`` line each, after a comment stating PX4's default,
    the start's value (`start`, a ReplayConfig, when given), the value in our units and the
    conversion."""
    lines = [
        "# PX4 EKF2 parameters written by quad-drake tune (QGroundControl parameter file)",
        "# Vehicle-Id Component-Id Name Value Type",
    ]
    start_values = to_parameters(start) if start is not None else {}
    for p in MAPPING:
        ours = our_value(p, config)
        if p.off(ours):
            lines.append(
                f"# {p.name} [{p.unit}]: off here ({p.field} 0): not written; clear bit {p.switch.bit} "
                f"of {p.switch.name} in PX4 (not written either: its other bits are PX4's own settings)"
            )
            continue
        value = p.theirs(ours)
        was = f"; start {start_values[p.name]:.6g}" if p.name in start_values else ""
        lines.append(
            f"# {p.name} [{p.unit}]: PX4 default {p.default:.6g}{was}; tuned {value:.6g} "
            f"(ours {ours:.6g}; {p.conversion})"
        )
        lines.append(f"{vehicle}\t{component}\t{p.name}\t{_number(value)}\t{PARAMETER_TYPE_REAL}")
    lines += [f"# {line}" for line in vertical_note(config)]
    return "\n".join(lines) + "\n"


def _number(value) -> str:
    return repr(float(value)) if math.isfinite(value) else "nan"


def read_parameter_file(text) -> dict[str, float]:
    """{name: value} of a QGroundControl parameter file's text (comment lines skipped); ValueError
    naming the line when a line is not ``vehicle component name value type``."""
    values = {}
    for number, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 5:
            raise ValueError(f"line {number}: expected 'vehicle component name value type', got {line!r}")
        values[parts[2]] = float(parts[3])
    return values
