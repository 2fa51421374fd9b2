"""The scenario schema: nested dataclasses (defaults, units, value rules) and nothing else.

Every field carries its unit in a comment and its SPEC default. Value rules Drake's YAML loader
does not check (vector lengths, signs, allowed words) live in the field metadata
(:mod:`.fields`) and are enforced by :func:`.validation.validate`; :mod:`.loader` reads and
writes the YAML. Pure: importing the schema loads no pydrake.
"""

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional

from ..estimation.registry import Ekf7EstimatorConfig, EstimatorConfig
from ..models.fidelity import FIDELITY_MODES
from .fields import noise_stds, number, vector

PACKAGE_DIR = Path(__file__).resolve().parent.parent
TRAJECTORY_DIR = PACKAGE_DIR / "data" / "traj"


MAX_SEED = 2**32 - 1
"""Largest seed: Drake's RandomGenerator (a 32-bit Mersenne Twister) keeps the low 32 bits of
a seed, so 2**32 would fly the same noise as 0. A campaign's last run (seed S + runs - 1) must
not pass it either (:func:`check_seed_range`)."""


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
    """IMU truth (SPEC §2): white noise per 2 ms sample, saturation, initial biases and their
    random walk; specific force f_B (m/s^2) and angular rate w_NB_B (rad/s) in body FRD."""

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
    """GPS truth: position and velocity white noise per sample (NED), a position random walk, and
    the sample period (s, a whole number of onboard ticks)."""

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
    # a replay's no-aiding samples (PX4's fake position / zero velocity while not GPS-aided, each
    # with its own std) on the estimator's ``no_aid`` input; only a flight log's replay supplies
    # them (``flightlogs.replay``), so a scenario's vehicle never carries them
    no_aid: bool = False
    # a replay's GPS receiver reports each sample's accuracy (PX4's eph, epv, s_variance_m_s) on the
    # estimator's ``gps_accuracy`` input, and the built-in kinds fuse each sample with the larger of
    # it and their own GPS noise (``estimation.measurements.receiver_noise``); only a flight log's replay
    # supplies it (``flightlogs.replay``)
    gps_accuracy: bool = False


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
    """A sensor fault injected between a sensor and the estimators (``quad_drake.models.faults``).

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
    """The air's velocity around a vehicle (``quad_drake.models.wind``, ``systems.wind.Wind``), m/s, NED:
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
class FailsafeConfig:
    """The no-aiding failsafe of a vehicle that flies on its estimate (``quad_drake.control.failsafe``):
    after ``no_aiding_timeout`` s without a fused GPS position the horizontal position is invalid and
    the vehicle descends and lands instead of flying its trajectory on dead reckoning."""

    no_aiding_timeout: float = number(5.0, positive=True)  # s, PX4's EKF2_NOAID_TOUT default
    descent_rate: float = number(0.5, positive=True)  # m/s, down
    brake: bool = True  # hold zero estimated horizontal velocity (False: zero acceleration, level)
    resume_on_aiding: bool = True  # position valid again in flight: resume the trajectory (False: land)
    landed_lag: float = number(0.5, positive=True)  # m, the set-point below the estimate: on the ground
    landed_time: float = number(1.0, positive=True)  # s, how long that holds before the motors idle


@dataclass
class VehicleConfig:
    """One vehicle: its start (NED, FRD), physics, controller gains, trajectory, sensors, the
    estimator it runs and what that assumes (``estimator``), the state it flies on, its wind and
    its sensor faults."""

    name: str = field(default="Quad", metadata={"pattern": "vehicle"})
    initial_position: List[float] = vector(0.0, 0.0, -1.0)  # m, NED
    initial_velocity: List[float] = vector(0.0, 0.0, 0.0)  # m/s, NED
    initial_ypr: List[float] = vector(0.0, 0.0, 0.0)  # rad, yaw pitch roll
    initial_omega: List[float] = vector(0.0, 0.0, 0.0)  # rad/s, body FRD
    physics: PhysicsParams = field(default_factory=PhysicsParams)
    controller: ControllerParams = field(default_factory=ControllerParams)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    sensors: SensorsConfig = field(default_factory=SensorsConfig)
    estimator: EstimatorConfig = field(default_factory=Ekf7EstimatorConfig)
    # What the controller flies on: the true state (the reference's default; the estimator runs
    # beside it and is judged) or the estimator's estimate (estimation/registry.py)
    flies_on: str = field(default="truth", metadata={"choices": FLIES_ON})
    faults: List[FaultConfig] = field(default_factory=list)  # applied in order, see FaultConfig
    # s, the longest GPS lag the estimator compensates (0 = off): a late GPS sample is moved by
    # the estimate's own motion since its stamp (quad_drake.estimation.delay_compensation)
    gps_delay_compensation: float = number(0.0, nonnegative=True)
    wind: Optional[WindConfig] = None  # none: still air (quad_drake.models.wind)
    failsafe: Optional[FailsafeConfig] = None  # none: no no-aiding failsafe (quad_drake.control.failsafe)


SAFETY_KINDS = ("floor", "room", "finite", "tracking", "attitude")
"""Flight-safety criterion kinds (``quad_drake.judging.safety`` adds them to every scenario)."""
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
    Flight safety (derived by ``quad_drake.judging.safety``; ``signal`` is a vehicle's signal):
    floor:  ``V.FloorTouchdowns`` stays 0 (no touchdown after take-off) until
            ``landing_time`` s (None: the whole run), and V leaves the floor at all.
    room:   ``V.WallContactSteps`` stays 0 (never stopped by a wall or the ceiling).
    finite: ``V.StateFinite`` stays 1 (every true state entry finite).
    tracking: |``V.PosFollowErr``| <= ``threshold`` m at every sample (around a GPS outage the
            safety rule judges the same signal with ``bound`` and ``recovery`` criteria).
    attitude: ``V.Tilt`` < ``threshold`` rad on every sample in [start, end) s (judged as a bound).
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
    """Flight-safety criteria judged on every vehicle's true flight (``quad_drake.judging.safety``).

    ``enabled: false`` switches them all off; each check can be switched off alone.
    tracking applies to vehicles whose position loops are closed (kp_pos_xy, kp_pos_z > 0), and
    not while the position of a vehicle flying on its estimate dead-reckons through a GPS outage.
    """

    enabled: bool = True
    floor: bool = True  # no touchdown after take-off (before landing_time)
    room: bool = True  # never stopped by a wall or the ceiling
    finite: bool = True  # the true state stays finite
    tracking: bool = True  # |Vehicle.PosFollowErr| <= tracking_bound
    tracking_bound: float = number(6.0, positive=True)  # m (quad_drake.judging.safety: why 6)
    # s: where a vehicle flying on its estimate has a GPS outage, the tracking is judged before it
    # and from this long after it, not during it (quad_drake.judging.safety: why 3)
    tracking_recovery_time: float = number(3.0, positive=True)
    attitude: bool = True  # the true tilt stays within what the controller commands plus tilt_margin
    tilt_margin: float = number(0.1, nonnegative=True)  # rad (quad_drake.judging.safety: why 0.1)
    landing_time: Optional[float] = None  # s, a documented landing: touchdowns from then on pass
    # m/s: with a landing_time, every touchdown's descent speed must stay below it (a landing,
    # not a crash: V.TouchdownSpeed); 0 = not judged
    max_touchdown_speed: float = number(1.0, nonnegative=True)


@dataclass
class ScenarioConfig:
    """A scenario file: its name, flight length (s), seed, vehicles, pass/fail criteria, the safety
    criteria every run is judged on, and the fidelity mode (README "Fidelity")."""

    name: str = field(default="", metadata={"pattern": "scenario"})  # default: the file's stem
    description: str = ""
    end_time: float = number(1.0, positive=True)  # s
    seed: int = number(0, nonnegative=True, maximum=MAX_SEED)
    vehicles: List[VehicleConfig] = field(default_factory=lambda: [VehicleConfig()])
    criteria: List[CriterionConfig] = field(default_factory=list)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    # physical: RK4, physical accelerometer, horizontal accel limit, exact clock;
    # reference: the FCND binary's numerics (quad_drake.models.fidelity, README "Fidelity").
    fidelity: str = field(default="physical", metadata={"choices": FIDELITY_MODES})
