"""Scenario configuration: nested dataclasses, loaded with Drake's ``yaml_load_typed``.

Every field carries its unit in a comment and its SPEC default. Value rules
Drake does not check (vector lengths, signs, allowed words) live in field
metadata and are enforced by :func:`validate`; any problem becomes one
:class:`ConfigError` naming the file, the dotted field path and what is wrong.
"""

import dataclasses
import difflib
import math
import re
import typing
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional

import yaml
from pydrake.common.yaml import yaml_dump, yaml_dump_typed, yaml_load_typed

from .config_fields import noise_stds, number, vector
from .conventions import ONBOARD_PERIOD
from .estimation.measurements import unfused_sensor
from .estimation.registry import AidingParams, Ekf7EstimatorConfig, EstimatorConfig, GateParams, kind_of
from .fidelity import FIDELITY_MODES, fidelity_from_mode

PACKAGE_DIR = Path(__file__).resolve().parent
TRAJECTORY_DIR = PACKAGE_DIR / "data" / "traj"


class ConfigError(ValueError):
    """A user mistake in a scenario or an override; str() is one line."""


def did_you_mean(word, choices):
    """`` (did you mean 'x'?)`` naming the choices closest to `word` (stdlib ``difflib``, at most
    three), or "" when none is close: the hint every "unknown name" message carries."""
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=3, cutoff=0.6)
    if not close:
        return ""
    return " (did you mean " + " or ".join(repr(c) for c in close) + "?)"


MAX_SEED = 2**32 - 1
"""Largest seed: Drake's RandomGenerator (a 32-bit Mersenne Twister) keeps the low 32 bits of
a seed, so 2**32 would fly the same noise as 0. A campaign's last run (seed S + runs - 1) must
not pass it either (:func:`check_seed_range`)."""

NAME_PATTERNS = {
    "scenario": (
        re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*"),
        "a letter, digit or _, then letters, digits or _ . + -; default: the file's name",
    ),
    "vehicle": (re.compile(r"[A-Za-z_][A-Za-z0-9_-]*"), "a letter or _, then letters, digits, _ or -"),
}
"""Names that become folders and files (a scenario's results, a vehicle's CSV) and prefixes of
signal names (``Quad.Est.E.Pos``): no path separators, no leading dot, no dot in a vehicle's."""


def check_seed_range(first_seed, runs, what="--seed"):
    """ConfigError unless the seeds first_seed .. first_seed + runs - 1 lie in [0, MAX_SEED]."""
    if first_seed < 0 or first_seed + runs - 1 > MAX_SEED:
        last = f" to {first_seed + runs - 1}" if runs > 1 else ""
        raise ConfigError(f"{what}: seeds must lie in [0, {MAX_SEED}] (2**32 - 1), got {first_seed}{last}")


NOISE_STD_RANGE = (1e-100, 1e100)
"""Allowed magnitudes of a nonzero noise standard deviation (units of its field).

Filters square a std into a covariance (P0, Q, R) and then sum, multiply and invert such
entries: with |std| in this range every square lies in [1e-200, 1e200], so a covariance never
underflows to zero (a singular innovation S = H P H^T + R) nor overflows to inf, with a factor
of 1e100 to spare for P summed over up to 1e8 predict steps and for gains and NIS products.
Outside it no physical quantity of a quadrotor lives. Zero stays allowed where a field is
merely >= 0 (a perfect sensor, a zero Q or P0): R, whose fields are > 0, keeps S invertible.
"""


@dataclass
class PhysicsParams:
    """Truth parameters of the vehicle (what the simulator flies)."""

    mass: float = number(0.5, positive=True)  # kg
    arm_length: float = number(0.17, positive=True)  # m, centre to motor (X layout)
    inertia: List[float] = field(
        default_factory=lambda: [0.0023, 0.0023, 0.0046], metadata={"length": 3, "positive": True}
    )  # kg m^2, Ixx Iyy Izz
    kappa: float = number(0.016, positive=True)  # m, yaw torque per newton of thrust
    min_motor_thrust: float = number(0.1, nonnegative=True)  # N
    max_motor_thrust: float = number(4.5, positive=True)  # N
    motor_tau_up: float = number(0.01, positive=True)  # s, lag time constant, rising thrust
    motor_tau_down: float = number(0.02, positive=True)  # s, lag time constant, falling thrust
    motor_noise: float = number(0.25, nonnegative=True)  # N, half-width of uniform force noise
    com_offset: List[float] = vector(0.0, 0.0)  # m, centre of mass (cx, cy) in body x, y
    x_bounds: List[float] = vector(-30.0, 30.0)  # m, room limits in N
    y_bounds: List[float] = vector(-30.0, 30.0)  # m
    z_bounds: List[float] = vector(-40.0, 0.0)  # m, z = 0 is the (sticky) floor
    # Drag (dynamics.drag_force_body; 0 = none, the default): F_B = -K v_rel - |v_rel| C v_rel on the
    # body-frame velocity relative to the air (wind, VehicleConfig.wind), per body axis x y z.
    rotor_drag: List[float] = field(
        default_factory=lambda: [0.0, 0.0, 0.0], metadata={"length": 3, "nonnegative": True}
    )  # N s/m, K: rotor (induced) drag, linear
    parasitic_drag: List[float] = field(
        default_factory=lambda: [0.0, 0.0, 0.0], metadata={"length": 3, "nonnegative": True}
    )  # N s^2/m^2, C: parasitic body drag, quadratic


@dataclass
class ControllerParams:
    """Cascade controller: its vehicle model, gains and limits (SPEC §5)."""

    mass: float = number(0.5, positive=True)  # kg, assumed
    arm_length: float = number(0.17, positive=True)  # m
    inertia: List[float] = field(
        default_factory=lambda: [0.0023, 0.0023, 0.0046], metadata={"length": 3, "positive": True}
    )  # kg m^2
    kappa: float = number(0.016, positive=True)  # m
    min_motor_thrust: float = number(0.1, nonnegative=True)  # N
    max_motor_thrust: float = number(4.5, positive=True)  # N
    kp_pos_xy: float = number(2.0, nonnegative=True)  # 1/s
    kp_pos_z: float = number(2.0, nonnegative=True)  # 1/s
    ki_pos_z: float = number(50.0, nonnegative=True)  # 1/s^2
    kp_vel_xy: float = number(8.0, nonnegative=True)  # 1/s
    kp_vel_z: float = number(8.0, nonnegative=True)  # 1/s
    kp_bank: float = number(12.0, nonnegative=True)  # 1/s
    kp_yaw: float = number(3.0, nonnegative=True)  # 1/s
    kp_pqr: List[float] = field(
        default_factory=lambda: [70.0, 70.0, 15.0], metadata={"length": 3, "nonnegative": True}
    )  # 1/s
    max_ascent_rate: float = number(5.0, positive=True)  # m/s
    max_descent_rate: float = number(2.0, positive=True)  # m/s
    max_speed_xy: float = number(5.0, positive=True)  # m/s
    max_horiz_accel: float = number(12.0, positive=True)  # m/s^2
    max_tilt: float = number(0.7, positive=True)  # dimensionless limit on R02, R12


@dataclass
class ImuParams:
    accel_std: List[float] = noise_stds(0.5, 0.5, 1.5)  # m/s^2 per sample, body x y z
    gyro_std: List[float] = noise_stds(0.5, 0.5, 0.5)  # rad/s per sample
    accel_limit: float = number(6 * 9.81, positive=True)  # m/s^2, per-axis saturation
    accel_bias: List[float] = vector(0.0, 0.0, 0.0)  # m/s^2, initial accelerometer bias, body x y z
    gyro_bias: List[float] = vector(0.0, 0.0, 0.0)  # rad/s, initial gyro bias
    accel_bias_walk_std: List[float] = noise_stds(0.0, 0.0, 0.0)  # m/s^2 per sample, bias increment
    gyro_bias_walk_std: List[float] = noise_stds(0.0, 0.0, 0.0)  # rad/s per sample, bias increment
    # true: the accelerometer reads the mean specific force over its 2 ms sample interval (the
    # plant's body-frame delta-velocity / dt, as real IMUs deliver it, so a touchdown's impulse
    # shows); false (default): the specific force of the last 1 ms physics step
    delta_velocity: bool = False
    gyro_limit: float = number(0.0, nonnegative=True)  # rad/s, per-axis gyro saturation, 0 = none


@dataclass
class GpsParams:
    pos_std: List[float] = noise_stds(0.7, 0.7, 2.0)  # m per sample, N x y z
    vel_std: List[float] = noise_stds(0.1, 0.1, 0.3)  # m/s per sample
    pos_random_walk_std: List[float] = noise_stds(0.0, 0.0, 0.0)  # m per sample, bias increment
    period: float = number(0.1, tick_multiple=1)  # s, a multiple of the 2 ms tick; first sample at t = period


@dataclass
class MagParams:
    """Magnetometer truth. Default: the reference's yaw magnetometer, yaw(q_NB) + yaw_std * n.
    With ``three_axis`` the body-frame field m_B = R_NB^T m_N + hard_iron + field_std * n (gauss,
    FRD) of the world field m_N of strength, declination and inclination
    (``sensor_models.world_field``, NED)."""

    yaw_std: float = number(0.1, nonnegative=True, noise_std=True)  # rad per sample (yaw model)
    period: float = number(0.01, tick_multiple=1)  # s, a multiple of the 2 ms onboard tick
    first_sample_time: float = number(0.008, tick_multiple=0)  # s (reference: tick 4)
    three_axis: bool = False  # true: sample the 3-axis field (gauss) instead of the yaw
    field_strength: float = number(0.5, positive=True)  # gauss, |m_N|
    declination: float = number(0.0, minimum=-math.pi, maximum=math.pi)  # rad, field east of true north
    inclination: float = number(1.1, minimum=-math.pi / 2, maximum=math.pi / 2)  # rad, field below horizontal
    hard_iron: List[float] = vector(0.0, 0.0, 0.0)  # gauss, constant offset in body FRD
    field_std: List[float] = noise_stds(0.005, 0.005, 0.005)  # gauss per sample, body x y z


@dataclass
class BaroParams:
    """Barometer truth (``sensor_models.baro_measurement``): pressure altitude above the datum
    z_N = 0, h = -z_N + bias + height_std * n (m), sampled at t = k * period, k >= 1. The bias
    starts at ``bias`` and takes a random-walk step of ``bias_walk_std`` before every sample.
    Below ``ground_effect_height`` m above the floor the rotor wash adds an error growing linearly
    to ``ground_effect_error`` m on the floor (a negative value reads low, as rotor downwash raises
    the static pressure); ground_effect_height = 0 turns it off."""

    height_std: float = number(0.1, nonnegative=True, noise_std=True)  # m per sample, white noise
    bias: float = number(0.0)  # m, the bias at t = 0
    bias_walk_std: float = number(0.001, nonnegative=True, noise_std=True)  # m per sample, bias increment
    period: float = number(0.02, tick_multiple=1)  # s, a multiple of the 2 ms tick; first at t = period
    ground_effect_height: float = number(0.0, nonnegative=True)  # m above the floor, 0 = no ground effect
    ground_effect_error: float = number(0.0)  # m, error on the floor, fading to 0 at ground_effect_height


@dataclass
class SensorsConfig:
    """Which sensors the vehicle carries; a missing entry means no such sensor."""

    imu: Optional[ImuParams] = None
    gps: Optional[GpsParams] = None
    mag: Optional[MagParams] = None
    baro: Optional[BaroParams] = None


ATTITUDE_FILTER_VARIANTS = ("nonlinear", "small_angle")


@dataclass
class AttitudeFilterParams:
    """Complementary filter (SPEC §4 UpdateFromIMU)."""

    variant: str = field(default="nonlinear", metadata={"choices": ATTITUDE_FILTER_VARIANTS})
    tau: float = number(100.0, positive=True)  # s, accelerometer blend time constant


@dataclass
class EkfParams(AidingParams, GateParams):
    """What the 7-state EKF assumes (SPEC §4); independent of the sensor truth."""

    init_state: List[float] = vector(0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0)  # m, m/s, rad
    init_std: List[float] = noise_stds(0.1, 0.1, 0.3, 0.1, 0.1, 0.3, 0.05)
    # m/sqrt(s): Q = diag(std^2) * dt_imu
    q_pos_xy_std: float = number(0.05, nonnegative=True, noise_std=True)
    q_pos_z_std: float = number(0.05, nonnegative=True, noise_std=True)
    q_vel_xy_std: float = number(0.05, nonnegative=True, noise_std=True)  # m/s/sqrt(s)
    q_vel_z_std: float = number(0.1, nonnegative=True, noise_std=True)
    q_yaw_std: float = number(0.05, nonnegative=True, noise_std=True)  # rad/sqrt(s)
    gps_pos_xy_std: float = number(1.0, positive=True, noise_std=True)  # m
    gps_pos_z_std: float = number(3.0, positive=True, noise_std=True)  # m
    gps_vel_xy_std: float = number(0.1, positive=True, noise_std=True)  # m/s
    gps_vel_z_std: float = number(0.3, positive=True, noise_std=True)  # m/s
    mag_yaw_std: float = number(0.1, positive=True, noise_std=True)  # rad
    # Tilt-aware Q (ekf.TiltNoise; 0 = off, the reference's constant Q): the gyro noise the attitude
    # filter integrates, rad/s per IMU sample, and how long its roll/pitch error acts as white noise
    # on the velocity and on the yaw, s.
    tilt_gyro_std: float = number(0.0, nonnegative=True, noise_std=True)
    tilt_velocity_time: float = number(0.25, nonnegative=True)  # s
    tilt_yaw_time: float = number(0.15, nonnegative=True)  # s
    dt_imu: float = number(0.002, positive=True, maximum=1.0)  # s, scales Q (a step, not a flight)


FAULT_KINDS = (
    "gps_outage",
    "gps_outlier",
    "gps_step",
    "gps_delay",
    "mag_bias",
    "mag_outage",
    "mag_disturbance",
    "imu_dropout",
    "baro_outage",
    "baro_step",
)


@dataclass
class FaultConfig:
    """A sensor fault injected between a sensor and the estimators (``quad_drake.faults``).

    Windows are [start, end) s on the sample's measurement time (its stamp):
    gps_outage, mag_outage: no samples in [start, end).
    gps_outlier: the first GPS sample at or after ``time`` is shifted by ``offset`` (3, m, NED).
    gps_step: every GPS position sample in [start, end) is shifted by ``offset`` (3, m, NED).
    gps_delay: every GPS sample reaches the estimators ``delay`` s late, keeping its stamp.
    mag_bias: ``offset`` (1, rad) added to every magnetometer yaw in [start, end) (yaw model).
    mag_disturbance: ``offset`` (3, gauss, body FRD) added to every 3-axis field sample in
    [start, end) (``three_axis``; a magnetic disturbance near the vehicle).
    baro_outage: no barometer samples in [start, end).
    baro_step: ``offset`` (1, m) added to every barometer height in [start, end).
    imu_dropout: every IMU sample in [start, end) is non-finite (NaN).
    """

    kind: str = field(default="gps_outage", metadata={"choices": FAULT_KINDS})
    start: float = number(0.0, nonnegative=True)  # s
    end: float = number(0.0, nonnegative=True)  # s
    time: float = number(0.0, nonnegative=True)  # s, gps_outlier
    # m (gps_outlier, gps_step: 3; baro_step: 1), rad (mag_bias: 1) or gauss (mag_disturbance: 3)
    offset: List[float] = field(default_factory=list)
    delay: float = number(0.0, nonnegative=True)  # s, gps_delay


TURBULENCE_LEVELS = ("none", "light", "moderate", "severe")


@dataclass
class GustConfig:
    """A discrete gust of (1 - cos) shape (the discrete gust of MIL-F-8785C): the air's velocity gains
    amplitude/2 (1 - cos(2 pi (t - start)/duration)) along ``direction`` for t in
    [start, start + duration]."""

    start: float = number(0.0, nonnegative=True)  # s
    duration: float = number(1.0, positive=True)  # s
    amplitude: float = 0.0  # m/s, peak
    direction: List[float] = vector(1.0, 0.0, 0.0)  # NED, normalised (need not be unit)


@dataclass
class WindConfig:
    """The air's velocity around a vehicle (``quad_drake.wind``, ``systems.wind.Wind``), m/s, NED:
    constant + gusts + Dryden turbulence. It acts through the drag of ``physics`` only."""

    mean: List[float] = vector(0.0, 0.0, 0.0)  # m/s, NED, constant wind
    gusts: List[GustConfig] = field(default_factory=list)
    # Dryden low-altitude turbulence (MIL-F-8785C / MIL-HDBK-1797): none, or the level whose
    # wind speed at 6 m (20 ft) sets the intensities: light 7.72, moderate 15.4, severe 23.2 m/s
    turbulence: str = field(default="none", metadata={"choices": TURBULENCE_LEVELS})
    wind_speed_6m: float = number(0.0, nonnegative=True)  # m/s, W20; 0 = the level's
    altitude: float = number(3.048, positive=True)  # m above ground for the scale lengths (>= 10 ft used)
    # m/s, the speed at which the frozen turbulence field passes the vehicle (Taylor); 0 = |mean|, at least 1
    airspeed: float = number(0.0, nonnegative=True)


TRAJECTORY_KINDS = ("point", "file", "figure_eight")


@dataclass
class TrajectoryConfig:
    """Reference to fly (SPEC §6). ``file`` is a name in the package data or a path."""

    kind: str = field(default="point", metadata={"choices": TRAJECTORY_KINDS})
    point: List[float] = vector(0.0, 0.0, -1.0)  # m, NED, for kind = point
    yaw: float = 0.0  # rad, for kind = point
    file: str = ""  # for kind = file
    position_offset: List[float] = vector(0.0, 0.0, 0.0)  # m, added to every point
    time_offset: float = 0.0  # s, added to the lookup time


FLIES_ON = ("truth", "estimate")


@dataclass
class VehicleConfig:
    name: str = field(default="Quad", metadata={"pattern": "vehicle"})
    initial_position: List[float] = vector(0.0, 0.0, -1.0)  # m, NED
    initial_velocity: List[float] = vector(0.0, 0.0, 0.0)  # m/s, NED
    initial_ypr: List[float] = vector(0.0, 0.0, 0.0)  # rad, yaw pitch roll
    initial_omega: List[float] = vector(0.0, 0.0, 0.0)  # rad/s, body FRD
    physics: PhysicsParams = field(default_factory=PhysicsParams)
    controller: ControllerParams = field(default_factory=ControllerParams)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    sensors: SensorsConfig = field(default_factory=SensorsConfig)
    attitude_filter: AttitudeFilterParams = field(default_factory=AttitudeFilterParams)
    ekf: EkfParams = field(default_factory=EkfParams)
    estimator: EstimatorConfig = field(default_factory=Ekf7EstimatorConfig)
    # What the controller flies on: the true state (the reference's default; the estimator runs
    # beside it and is judged) or the estimator's estimate (estimation/registry.py)
    flies_on: str = field(default="truth", metadata={"choices": FLIES_ON})
    faults: List[FaultConfig] = field(default_factory=list)  # applied in order, see FaultConfig
    # s, the longest GPS lag the estimator compensates (0 = off): a late GPS sample is moved by
    # the estimate's own motion since its stamp (quad_drake.estimation.delay_compensation)
    gps_delay_compensation: float = number(0.0, nonnegative=True)
    wind: Optional[WindConfig] = None  # none: still air (quad_drake.wind)


SAFETY_KINDS = ("floor", "room", "finite", "tracking")
"""Flight-safety criterion kinds (``quad_drake.safety`` adds them to every scenario)."""
CRITERION_KINDS = ("window", "sigma", "fleet_sigma", "bound", "recovery", *SAFETY_KINDS)


@dataclass
class CriterionConfig:
    """A reference analyzer (SPEC §0.5) over a named signal such as ``Quad.Pos.X``.

    window: ABS(signal) < threshold for more than ``window`` seconds (latched).
    sigma:  cumulative share of fresh samples with |signal - ref| <= sigma stays
            strictly inside (min_percent, max_percent) for the final ``window`` s.
            ``ref`` and ``sigma`` are numbers, or signal names when the
            ``*_signal`` field is given.
    fleet_sigma: over every vehicle V, the share of samples with
            |V.<signal>| <= sigma_multiple * V.<sigma_signal> lies in
            [min_percent, max_percent]; ``signal`` and ``sigma_signal`` are suffixes
            such as ``Est.E.X`` and ``Est.S.X``.
    bound:  ABS(signal) < threshold on every sample in [start, end) s (e.g. during a fault).
    recovery: ABS(signal) < threshold on every sample from start + window s to the end of
            the run: back under the threshold within ``window`` s after ``start`` (e.g. the
            end of a fault) and staying there.
    Flight safety (derived by ``quad_drake.safety``; ``signal`` is a vehicle's signal):
    floor:  ``V.FloorTouchdowns`` stays 0 (no touchdown after take-off) until
            ``landing_time`` s (None: the whole run), and V leaves the floor at all.
    room:   ``V.WallContactSteps`` stays 0 (never stopped by a wall or the ceiling).
    finite: ``V.StateFinite`` stays 1 (every true state entry finite).
    tracking: |``V.PosFollowErr``| <= ``threshold`` m at every sample.
    """

    kind: str = field(default="window", metadata={"choices": CRITERION_KINDS})
    signal: str = ""
    threshold: float = number(0.0, nonnegative=True)
    window: float = number(1.0, nonnegative=True)  # s
    ref: float = 0.0
    ref_signal: str = ""
    sigma: float = number(0.0, nonnegative=True)
    sigma_signal: str = ""
    sigma_multiple: float = number(1.0, positive=True)
    min_percent: float = number(0.0, minimum=0.0, maximum=100.0)
    max_percent: float = number(100.0, minimum=0.0, maximum=100.0)
    landing_time: Optional[float] = None  # s, floor: touchdowns from then on are a landing
    start: float = number(0.0, nonnegative=True)  # s, bound and recovery
    end: float = number(0.0, nonnegative=True)  # s, bound


@dataclass
class SafetyConfig:
    """Flight-safety criteria judged on every vehicle's true flight (``quad_drake.safety``).

    ``enabled: false`` switches them all off; each check can be switched off alone.
    tracking applies to vehicles whose position loops are closed (kp_pos_xy, kp_pos_z > 0).
    """

    enabled: bool = True
    floor: bool = True  # no touchdown after take-off (before landing_time)
    room: bool = True  # never stopped by a wall or the ceiling
    finite: bool = True  # the true state stays finite
    tracking: bool = True  # |Vehicle.PosFollowErr| <= tracking_bound
    tracking_bound: float = number(6.0, positive=True)  # m (quad_drake.safety: why 6)
    landing_time: Optional[float] = None  # s, a documented landing: touchdowns from then on pass
    # m/s: with a landing_time, every touchdown's descent speed must stay below it (a landing,
    # not a crash: V.TouchdownSpeed); 0 = not judged
    max_touchdown_speed: float = number(1.0, nonnegative=True)


@dataclass
class ScenarioConfig:
    name: str = field(default="", metadata={"pattern": "scenario"})  # default: the file's stem
    description: str = ""
    end_time: float = number(1.0, positive=True)  # s
    seed: int = number(0, nonnegative=True, maximum=MAX_SEED)
    vehicles: List[VehicleConfig] = field(default_factory=lambda: [VehicleConfig()])
    criteria: List[CriterionConfig] = field(default_factory=list)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    # physical: RK4, physical accelerometer, horizontal accel limit, exact clock;
    # reference: the FCND binary's numerics (quad_drake.fidelity, README "Fidelity").
    fidelity: str = field(default="physical", metadata={"choices": FIDELITY_MODES})


# ----- loading and validation -------------------------------------------------


def _type_name(tp):
    return getattr(tp, "__name__", str(tp))


def check_node(node, tp, path):
    """Shape check of raw YAML `node` against annotation `tp`; returns a message or None."""
    origin = typing.get_origin(tp)
    if origin is typing.Union:
        members = [a for a in typing.get_args(tp) if a is not type(None)]
        if node is None:
            return None
        if len(members) > 1:
            return _check_kind_choice(node, members, path)
        return check_node(node, members[0], path)
    if dataclasses.is_dataclass(tp):
        if not isinstance(node, dict):
            return f"{path or 'the file'}: expected a mapping, got {node!r}"
        names = {f.name: f for f in dataclasses.fields(tp)}
        for key, value in node.items():
            if key == "_tag":  # set by _check_kind_choice, or read from a dumped config
                continue
            sub = f"{path}.{key}" if path else str(key)
            if key not in names:
                return f"{sub}: unknown key{did_you_mean(key, names)} (known: {', '.join(names)})"
            message = check_node(value, typing.get_type_hints(tp)[key], sub)
            if message:
                return message
        return None
    if origin in (dict, typing.Dict):
        if not isinstance(node, dict):
            return f"{path}: expected a mapping, got {node!r}"
        key_type, value_type = typing.get_args(tp)
        for key, value in node.items():
            message = check_node(key, key_type, path) or check_node(value, value_type, f"{path}.{key}")
            if message:
                return message
        return None
    if origin in (list, typing.List):
        if not isinstance(node, list):
            return f"{path}: expected a list, got {node!r}"
        (item_type,) = typing.get_args(tp)
        for i, item in enumerate(node):
            message = check_node(item, item_type, f"{path}.{i}")
            if message:
                return message
        return None
    if tp is float:
        ok = isinstance(node, (int, float)) and not isinstance(node, bool)
    elif tp is int:
        ok = isinstance(node, int) and not isinstance(node, bool)
    elif tp is bool:
        ok = isinstance(node, bool)
    else:
        ok = isinstance(node, tp)
    return None if ok else f"{path}: expected {_type_name(tp)}, got {node!r}"


def _kind_of(member):
    return next(f.default for f in dataclasses.fields(member) if f.name == "kind")


def _check_kind_choice(node, members, path):
    """Check a mapping against the Union member its ``kind`` names; tag it for yaml_load_typed.

    Every member is a dataclass whose ``kind`` field defaults to its own name. A config
    written by :func:`dump_scenario` carries a YAML tag instead of (or besides) the kind.
    """
    if not isinstance(node, dict):
        return f"{path}: expected a mapping, got {node!r}"
    by_kind = {_kind_of(m): m for m in members}
    by_tag = {f"!{m.__name__}": m for m in members}
    if "kind" in node:
        member = by_kind.get(node["kind"])
        if member is None:
            return f"{path}.kind: {node['kind']!r} is not one of {', '.join(by_kind)}"
    elif node.get("_tag") in by_tag:
        member = by_tag[node["_tag"]]
    else:
        return f"{path}.kind: missing; one of {', '.join(by_kind)}"
    node["_tag"] = f"!{member.__name__}"
    return check_node(node, member, path)


def validate(config, path=""):
    """Raise ConfigError for the first field of `config` that breaks its metadata rules."""
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        sub = f"{path}.{f.name}" if path else f.name
        if dataclasses.is_dataclass(value):
            validate(value, sub)
            continue
        if isinstance(value, list) and value and dataclasses.is_dataclass(value[0]):
            for i, item in enumerate(value):
                validate(item, f"{sub}.{i}")
            continue
        rules = f.metadata
        if "length" in rules and len(value) != rules["length"]:
            raise ConfigError(f"{sub}: expected {rules['length']} values, got {len(value)}")
        if "pattern" in rules:
            pattern, allowed = NAME_PATTERNS[rules["pattern"]]
            if not pattern.fullmatch(value):
                raise ConfigError(f"{sub}: {value!r} is not a usable name ({allowed})")
        if "choices" in rules and value not in rules["choices"]:
            raise ConfigError(f"{sub}: {value!r} is not one of {', '.join(rules['choices'])}")
        for x in value if isinstance(value, list) else [value]:
            if isinstance(x, float) and not math.isfinite(x):
                raise ConfigError(f"{sub}: must be finite, got {x}")
            if rules.get("positive") and not x > 0:
                raise ConfigError(f"{sub}: must be > 0, got {x}")
            if rules.get("nonnegative") and not x >= 0:
                raise ConfigError(f"{sub}: must be >= 0, got {x}")
            if "minimum" in rules and x < rules["minimum"]:
                raise ConfigError(f"{sub}: must be >= {rules['minimum']}, got {x}")
            if "maximum" in rules and x > rules["maximum"]:
                raise ConfigError(f"{sub}: must be <= {rules['maximum']}, got {x}")
            if rules.get("noise_std") and x and not NOISE_STD_RANGE[0] <= abs(x) <= NOISE_STD_RANGE[1]:
                low, high = NOISE_STD_RANGE
                raise ConfigError(
                    f"{sub}: a noise std must be 0 or within [{low:g}, {high:g}] so that its square "
                    f"is a usable covariance, got {x:g}"
                )
            if "tick_multiple" in rules:
                _check_tick_multiple(x, rules["tick_multiple"], sub)


def _check_tick_multiple(seconds, min_ticks, where):
    """ConfigError unless `seconds` is a whole number >= min_ticks of 2 ms onboard ticks
    (to 1e-9 of a tick: what a decimal such as 0.1 s rounds to)."""
    ticks = seconds / ONBOARD_PERIOD
    if round(ticks) < min_ticks or abs(ticks - round(ticks)) > 1e-9 * max(1.0, ticks):
        tick_ms = f"{ONBOARD_PERIOD * 1e3:g} ms"
        least = f", at least {min_ticks * ONBOARD_PERIOD:g} s" if min_ticks else ""
        raise ConfigError(
            f"{where}: must be a whole multiple of the {tick_ms} onboard tick{least}, got {seconds:g}"
        )


def check_scenario(scenario):
    """Raise ConfigError (one line, the field's dotted path) for a ScenarioConfig that breaks a
    rule of :func:`load_scenario`: what every entry point (``simulation.run``, ``run_fleet``,
    ``run_campaign``) checks, so a config built or changed in Python is judged as a file is."""
    if not isinstance(scenario, ScenarioConfig):
        raise ConfigError(f"expected a ScenarioConfig, got {type(scenario).__name__}")
    try:
        validate(dataclasses.replace(scenario, name=scenario.name or "scenario"))  # a name comes later
        _check_semantics(scenario)
    except (TypeError, AttributeError) as e:  # e.g. a string where a number belongs
        raise ConfigError(f"{scenario.name or 'scenario'}: a field has the wrong type ({e})") from None


def ineffective_settings(scenario):
    """Lines naming the criteria and faults that cannot matter for a flight of ``end_time`` s:
    a window (window, sigma) not shorter than the flight, a bound interval or a recovery that
    starts at or after its end (judged on no samples), a fault that starts after the flight.
    Not errors (a short trial run may mean it); the command line prints them as warnings."""
    end, lines = scenario.end_time, []
    for i, c in enumerate(scenario.criteria):
        where = f"criteria.{i} ({c.kind} on {c.signal})"
        if c.kind in ("window", "sigma") and c.window >= end:
            lines.append(f"{where}: its {c.window:g} s window is not shorter than the {end:g} s flight")
        if c.kind == "bound" and c.start >= end:
            lines.append(f"{where}: [{c.start:g}, {c.end:g}) s starts after the {end:g} s flight")
        if c.kind == "recovery" and c.start + c.window > end:
            lines.append(
                f"{where}: judged from {c.start + c.window:g} s (start + window), after the {end:g} s flight"
            )
    for i, v in enumerate(scenario.vehicles):
        if v.wind is not None and not any(v.physics.rotor_drag + v.physics.parasitic_drag):
            lines.append(f"vehicles.{i}.wind: has no effect, physics.rotor_drag and parasitic_drag are 0")
        for j, fault in enumerate(v.faults):
            begins = fault.time if fault.kind == "gps_outlier" else fault.start
            if fault.kind != "gps_delay" and begins >= end:
                where = f"vehicles.{i}.faults.{j} ({fault.kind})"
                lines.append(f"{where}: starts at {begins:g} s, after the {end:g} s flight")
    return lines


def _check_semantics(scenario):
    names = [v.name for v in scenario.vehicles]
    if not names:
        raise ConfigError("vehicles: at least one vehicle is needed")
    if len(set(names)) != len(names):
        raise ConfigError(f"vehicles: names must be unique, got {names}")
    for i, v in enumerate(scenario.vehicles):
        p = v.physics
        if p.min_motor_thrust >= p.max_motor_thrust:
            raise ConfigError(f"vehicles.{i}.physics: min_motor_thrust must be < max_motor_thrust")
        for axis, bounds in enumerate((p.x_bounds, p.y_bounds, p.z_bounds)):
            where = f"vehicles.{i}.physics.{'xyz'[axis]}_bounds"
            if not bounds[0] < bounds[1]:
                raise ConfigError(f"{where}: must be [min, max] with min < max, got {bounds}")
            if not bounds[0] <= v.initial_position[axis] <= bounds[1]:
                raise ConfigError(
                    f"vehicles.{i}.initial_position: {'xyz'[axis]} = {v.initial_position[axis]:g} m is "
                    f"outside the room ({where} {bounds}; NED, z = {p.z_bounds[1]:g} is the floor)"
                )
        if v.trajectory.kind == "file":
            resolve_trajectory_file(v.trajectory.file, f"vehicles.{i}.trajectory.file")
        kind = kind_of(v.estimator)
        if v.flies_on == "estimate" and kind.builder is not None:
            if not (v.sensors.imu and v.sensors.gps and v.sensors.mag):
                raise ConfigError(f"vehicles.{i}.flies_on: estimate needs imu, gps and mag sensors")
        if kind.builder and unfused_sensor(kind.measurements, v.sensors) == "mag":
            raise ConfigError(
                f"vehicles.{i}.sensors.mag.three_axis: estimator kind {kind.name!r} takes the yaw "
                "magnetometer only (ekf7 and eskf fuse a 3-axis one)"
            )
        problem = kind.fidelity_problem(fidelity_from_mode(scenario.fidelity)) or kind.problem(v.estimator)
        if problem:
            raise ConfigError(f"vehicles.{i}.estimator: {problem}")
        if v.gps_delay_compensation > 0 and not (v.sensors.imu and v.sensors.gps):
            raise ConfigError(f"vehicles.{i}.gps_delay_compensation: needs imu and gps sensors")
        for j, fault in enumerate(v.faults):
            _check_fault(fault, v.sensors, f"vehicles.{i}.faults.{j}")
        if sum(f.kind == "gps_delay" for f in v.faults) > 1:
            raise ConfigError(f"vehicles.{i}.faults: at most one gps_delay per vehicle")
        _check_air(v, scenario.fidelity, f"vehicles.{i}")
    for i, c in enumerate(scenario.criteria):
        if not c.signal:
            raise ConfigError(f"criteria.{i}.signal: must name a signal")
        if c.kind == "fleet_sigma" and not c.sigma_signal:
            raise ConfigError(f"criteria.{i}.sigma_signal: fleet_sigma needs a sigma signal suffix")
        if c.kind == "bound" and not c.end > c.start:
            raise ConfigError(f"criteria.{i}.end: must be > start ({c.start}), got {c.end}")
        if c.kind in ("sigma", "fleet_sigma") and c.min_percent >= c.max_percent:
            raise ConfigError(f"criteria.{i}: min_percent must be < max_percent")
        if c.landing_time is not None and not c.landing_time >= 0:
            raise ConfigError(f"criteria.{i}.landing_time: must be >= 0, got {c.landing_time}")
    landing = scenario.safety.landing_time
    if landing is not None and not landing >= 0:
        raise ConfigError(f"safety.landing_time: must be >= 0, got {landing}")


def _check_air(vehicle, fidelity, where):
    """One-line ConfigError for a wind gust without a direction, or a delta-velocity IMU under the
    reference's accelerometer (``fidelity: reference``)."""
    for j, gust in enumerate(vehicle.wind.gusts if vehicle.wind is not None else ()):
        if not any(gust.direction):
            raise ConfigError(f"{where}.wind.gusts.{j}.direction: must not be zero")
    imu = vehicle.sensors.imu
    if imu is not None and imu.delta_velocity and fidelity_from_mode(fidelity).reference_accelerometer:
        raise ConfigError(
            f"{where}.sensors.imu.delta_velocity: the reference's accelerometer reads the last step "
            "(fidelity: physical only)"
        )


FAULT_OFFSET_LENGTHS = {"gps_outlier": 3, "gps_step": 3, "mag_bias": 1, "mag_disturbance": 3, "baro_step": 1}
"""Number of ``offset`` values each fault kind takes (the others take none)."""
WINDOW_FAULT_KINDS = tuple(kind for kind in FAULT_KINDS if kind not in ("gps_outlier", "gps_delay"))
"""The faults that act over a [start, end) window (gps_outlier acts at ``time``, gps_delay always)."""
MAG_MODEL_FAULTS = {"mag_bias": False, "mag_disturbance": True}
"""The magnetometer faults that need one model: False the yaw model, True ``three_axis``."""


def _check_fault(fault, sensors, where):
    """One-line ConfigError for a fault the vehicle cannot have or whose fields do not fit its kind."""
    sensor = fault.kind.split("_")[0]
    if getattr(sensors, sensor) is None:
        raise ConfigError(f"{where}.kind: {fault.kind} needs a {sensor} sensor on the vehicle")
    if fault.kind in MAG_MODEL_FAULTS and sensors.mag.three_axis != MAG_MODEL_FAULTS[fault.kind]:
        model = "a 3-axis (three_axis: true)" if MAG_MODEL_FAULTS[fault.kind] else "a yaw (three_axis: false)"
        raise ConfigError(f"{where}.kind: {fault.kind} needs {model} magnetometer")
    if fault.kind in WINDOW_FAULT_KINDS and not fault.end > fault.start:
        raise ConfigError(f"{where}.end: must be > start ({fault.start}), got {fault.end}")
    expected = FAULT_OFFSET_LENGTHS.get(fault.kind, 0)
    if len(fault.offset) != expected:
        raise ConfigError(f"{where}.offset: {fault.kind} takes {expected} values, got {len(fault.offset)}")
    if fault.kind == "gps_delay":
        ticks = fault.delay / ONBOARD_PERIOD
        if not fault.delay > 0 or abs(ticks - round(ticks)) > 1e-6:
            raise ConfigError(
                f"{where}.delay: must be a positive multiple of {ONBOARD_PERIOD} s, got {fault.delay}"
            )


def resolve_trajectory_file(name, where="trajectory.file"):
    """Path of a trajectory file: a packaged name (e.g. ``Square.txt``) or a path."""
    if not name:
        raise ConfigError(f"{where}: kind 'file' needs a file name")
    for candidate in (Path(name), TRAJECTORY_DIR / name):
        if candidate.is_file():
            return candidate
    raise ConfigError(f"{where}: no such trajectory file {name!r}")


def first_line(error, located=True):
    """One line of an error; for a YAML syntax error its problem, where it is (line, column;
    unless not `located`: a ``--set`` value is parsed inside a wrapper) and its context."""
    problem, mark = getattr(error, "problem", None), getattr(error, "problem_mark", None)
    if problem and mark is not None:
        context = getattr(error, "context", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if located else ""
        return f"{problem}{where}" + (f" ({context})" if context else "")
    return " ".join(str(error).split("\n")[:2]).strip()


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader reading numbers as people write them.

    PyYAML implements YAML 1.1, where a float needs a dot and a signed exponent: ``1e9``,
    ``-3e2`` or ``1.e3`` load as strings. YAML 1.2 (and Drake's C++ parser) read them as
    numbers; this loader adds the 1.2 exponent forms to the float resolver. A key given twice in
    one mapping is refused (PyYAML keeps the last silently); a merge key (``<<``) may still
    override.
    """

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                    continue
                if key_node.value in seen:
                    raise yaml.constructor.ConstructorError(
                        None,
                        None,
                        f"duplicate key {key_node.value!r} (first at line {seen[key_node.value]})",
                        key_node.start_mark,
                    )
                seen[key_node.value] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)


def _tagged_mapping(loader, tag, node):
    """A ``!Name {...}`` mapping (how ``yaml_dump_typed`` writes a Union member) as a dict with
    ``_tag``, as Drake's ``yaml_load`` reads it; :func:`_check_kind_choice` picks the member."""
    return {**loader.construct_mapping(node, deep=True), "_tag": tag}


_Loader.add_multi_constructor("!", _tagged_mapping)
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def load_yaml(text):
    """Raw YAML data of `text` (merge keys and anchors resolved; 1.2 number forms read as
    numbers); top-level keys starting with ``_`` are dropped (templates for anchors), as
    Drake's ``yaml_load`` does."""
    data = yaml.load(text, Loader=_Loader)  # noqa: S506 (a SafeLoader subclass)
    if isinstance(data, dict):
        data = {k: v for k, v in data.items() if not (isinstance(k, str) and k.startswith("_"))}
    return data


def parse_override(text):
    """Split ``dotted.key=value`` into (['dotted', 'key'], value parsed as YAML)."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip() or any(not part for part in key.strip().split(".")):
        raise ConfigError(f"--set {text!r}: expected dotted.key=value")
    try:
        value = load_yaml(f"value: {raw}")["value"] if raw.strip() else None
    except yaml.YAMLError as e:
        reason = first_line(e, located=False)
        raise ConfigError(f"--set {text!r}: value is not valid YAML ({reason})") from None
    return key.strip().split("."), value


def apply_override(raw, keys, value, text):
    """Set raw[k0][k1]... = value in a nested dict/list; list indices are integers."""
    node = raw
    for depth, key in enumerate(keys):
        last = depth == len(keys) - 1
        if isinstance(node, list):
            if not key.isdigit() or int(key) >= len(node):
                raise ConfigError(f"--set {text!r}: {key!r} is not an index of a list of {len(node)}")
            key = int(key)
        elif not isinstance(node, dict):
            raise ConfigError(f"--set {text!r}: {'.'.join(keys[:depth])} is not a mapping")
        if last:
            node[key] = value
        else:
            if isinstance(node, dict) and key not in node:
                node[key] = {}
            node = node[key]


def load_scenario(path, overrides=()):
    """ScenarioConfig from a YAML file plus ``dotted.key=value`` overrides; validated.

    Raises ConfigError with one line naming the file and the field.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such scenario file")
    try:
        raw = load_yaml(path.read_text())
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML: {first_line(e)}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: cannot read: {e}") from None
    if raw is None:
        raise ConfigError(f"{path}: the file is empty (a scenario is a mapping of fields)")
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: expected a mapping of fields at the top level, got {type(raw).__name__}")
    try:
        for text in overrides:
            keys, value = parse_override(text)
            apply_override(raw, keys, value, text)
        _migrate_use_ideal_estimator(raw)
        message = check_node(raw, ScenarioConfig, "")
        if message:
            raise ConfigError(message)
        scenario = yaml_load_typed(schema=ScenarioConfig, data=yaml_dump(raw))
        if not scenario.name:
            scenario.name = path.stem
        for vehicle in scenario.vehicles:
            vehicle.estimator = kind_of(vehicle.estimator).locate(vehicle.estimator, path.parent)
        check_scenario(scenario)
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}{override_hint(str(e), overrides)}") from None
    except (RuntimeError, ValueError, TypeError) as e:
        raise ConfigError(f"{path}: {first_line(e)}") from None
    return scenario


def _migrate_use_ideal_estimator(raw):
    """Rewrite each vehicle's deprecated ``use_ideal_estimator`` (raw YAML, in place) into its
    ``flies_on`` (true: truth, false: estimate), with a FutureWarning saying what to write
    instead; ConfigError where both are given and disagree."""
    vehicles = raw.get("vehicles")
    for i, vehicle in enumerate(vehicles if isinstance(vehicles, list) else []):
        if not isinstance(vehicle, dict) or "use_ideal_estimator" not in vehicle:
            continue
        where, ideal = f"vehicles.{i}.use_ideal_estimator", vehicle.pop("use_ideal_estimator")
        if not isinstance(ideal, bool):
            raise ConfigError(f"{where}: expected bool, got {ideal!r}")
        flies_on = "truth" if ideal else "estimate"
        if vehicle.setdefault("flies_on", flies_on) != flies_on:
            raise ConfigError(f"{where}: contradicts vehicles.{i}.flies_on (drop the deprecated field)")
        warnings.warn(
            f"{where} is deprecated: write vehicles.{i}.flies_on: {flies_on}"
            + (" (or estimator: {kind: truth} to run no estimator)" if ideal else ""),
            FutureWarning,
            stacklevel=3,
        )


def override_hint(message, overrides):
    """`` (--set KEY=VALUE)`` when the field a validation message starts with ("field: ...")
    is, contains or lies in the key of one of the `overrides`, else ``""``: the mistake is on
    the command line, not in the file."""
    field_path = message.split(":", 1)[0]
    for text in reversed(overrides):  # the last override of a key wins
        key = text.partition("=")[0].strip()
        if field_path == key or field_path.startswith(key + ".") or key.startswith(field_path + "."):
            return f" (--set {text})"
    return ""


def dump_scenario(scenario):
    """The resolved scenario as YAML text (loads back to an equal ScenarioConfig)."""
    return yaml_dump_typed(scenario)
