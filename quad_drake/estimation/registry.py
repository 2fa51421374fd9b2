"""Pure: the estimator kinds, each declared in one place.

A vehicle's ``estimator:`` block names its kind (``estimator: {kind: eskf, ...}``).
The :class:`EstimatorKind` of that name in :data:`KINDS` says everything the package needs
to know of it:

- ``config_type``: the dataclass the block loads into (its ``kind`` field defaults to the kind's
  name); :data:`EstimatorConfig`, the vehicle's field type, is the Union of them all;
- ``vocabulary(config)``: its state vocabulary (``estimation/vocabulary.py``: error states,
  units, logs, errors against the truth), or None for a kind that runs no estimator;
- ``builder``: ``"module:function"`` of the function that adds its systems to a Drake
  ``DiagramBuilder``, ``(builder, vehicle, fidelity, n) -> (inputs {name: [input ports]},
  outputs {name: output port})``; imported on first use, so this module needs no pydrake;
- ``tuning_keys(config)``: the dotted config keys ``quad-drake tune`` searches by default;
- ``fidelity_problem(fidelity)``: why it cannot run under a Fidelity (one line), or None;
- ``problem(config)``: why a config of it cannot fly (one line; a custom estimator's check
  before any flight), or None; ``locate(config, base_dir)``: the config with the paths it names
  made absolute against the scenario file's folder ``base_dir``; ``relative(config, folder)``:
  its inverse, for a scenario saved into ``folder`` (the paths relative to it where they can be).
- ``measurements``: the measurements it fuses, in fusion order (``estimation/measurements.py``);
- for replaying a real flight controller's log (``flightlogs/``): ``replay_defaults()``, its
  config with PX4 EKF2's noise (:data:`PX4_NOISE`); ``started_from_log(config, roll, pitch,
  yaw)``, the config started at the log's first attitude; ``assuming_gps_noise(config, pos_std,
  vel_std)``, the config assuming that GPS noise (a log without GPS gets fake positions);
  ``assuming_baro_height_reference(config, height_std)``, the config of a log whose height
  reference is its barometer: that GPS height noise (the GPS height not fused) and no GPS height
  restart (``gps_height_restart``); ``started_with_biases(config,
  biases)``, the config started from the IMU biases (and their stds where logged) PX4's estimator
  had learned by the log's start (``reader.ImuBiasStart``), None for a kind without bias states;
- ``per_vehicle(config)``: the dotted config fields its system takes per vehicle, so that one
  system sized by n replays n flight logs, each with its own start, GPS noise and magnetic field
  (:func:`sharing_problem`); () for a kind whose n vehicles must fly one config.

Adding an estimator is its config dataclass and one entry in :data:`KINDS`; its builder lives on
the systems side (``tests/test_registry.py`` asserts it). Whether a kind runs under a scenario's
fidelity is checked once, when the scenario loads (``config.validate``).

What the controller flies on is the vehicle's ``flies_on`` (:func:`flies_on_estimate`): the
estimate, or the true state with the estimator running beside it to be judged (the reference's
``UseIdealEstimator``, its default). Kind ``truth`` runs no estimator: its estimate is the true
state, so the controller flies on the truth either way.
"""

import dataclasses
import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Dict, List, Optional, Union

from quad_drake.config.fields import noise_stds, number, vector
from quad_drake.conventions import ONBOARD_PERIOD
from quad_drake.estimation import custom
from quad_drake.estimation.baro import BaroFusionParams
from quad_drake.estimation.gsf import GsfParams
from quad_drake.estimation.mag3 import MagFieldFusionParams
from quad_drake.estimation.measurements import NIS_ORDER, PX4_GPS_VERTICAL_RATIO, measurements_of
from quad_drake.estimation.vocabulary import (
    EKF7,
    ESKF9,
    ESKF15,
    EstimatorVocabulary,
    euler_vocabulary,
    with_gsf,
)
from quad_drake.grading.course import StudentProblem, load_student_module, tuning_of
from quad_drake.models.fidelity import Fidelity


@dataclass
class GateParams:
    """Gates and resets (``estimation/gating.py``) of an estimator: chi^2 gates on the GPS
    horizontal position, height and velocity apart and on the magnetometer; a GPS group
    rejected for its timeout is reset to the sample; after gps_regain_time s without GPS the
    returning sample is fused or reset; with gps_height_restart a GPS sample after a gap resets
    the height. The EKF7's and the ESKF's configs hold them."""

    gps_gate_sigma: float = number(5.0, nonnegative=True)  # sigma; each GPS group's gate, 0 = off
    mag_gate_sigma: float = number(5.0, nonnegative=True)  # sigma
    gps_reset_timeout: float = number(5.0, nonnegative=True)  # s of rejected horizontal position, 0 = never
    gps_height_reset_timeout: float = number(1.0, nonnegative=True)  # s of rejected height, 0 = never
    gps_vel_reset_timeout: float = number(0.5, nonnegative=True)  # s of rejected velocity, 0 = never
    gps_regain_time: float = number(1.0, nonnegative=True)  # s without GPS that make an outage, 0 = off
    gps_gate_adaptation: float = number(0.1, nonnegative=True, maximum=1.0)  # weight of a sample's NIS/dof
    # the GPS is the height reference (PX4's EKF2_HGT_REF 1): a GPS sample more than
    # gating.GPS_HEIGHT_TIMEOUT (1 s) after the previous one resets the height to it, accepted or not,
    # and the baro bias moves with it (PX4's restart of its GNSS height fusion); a replay takes it
    # from the log's parameters
    gps_height_restart: bool = False


@dataclass
class AidingParams:
    """What an estimator assumes of the aiding sensors (issue 32), each fused only when the vehicle
    carries it: a barometer (``sensors.baro``; ``estimation/baro.py``) and a 3-axis magnetometer
    (``sensors.mag.three_axis``; ``estimation/mag3.py``). The EKF7's and the ESKF's configs hold
    them."""

    baro: BaroFusionParams = field(default_factory=BaroFusionParams)
    mag_field: MagFieldFusionParams = field(default_factory=MagFieldFusionParams)


ATTITUDE_FILTER_VARIANTS = ("nonlinear", "small_angle")


@dataclass
class AttitudeFilterParams:
    """The EKF7's complementary attitude filter (SPEC §4 UpdateFromIMU)."""

    variant: str = field(default="nonlinear", metadata={"choices": ATTITUDE_FILTER_VARIANTS})
    tau: float = number(100.0, positive=True)  # s, accelerometer blend time constant


@dataclass
class Ekf7EstimatorConfig(AidingParams, GateParams):
    """The reference's estimator (SPEC §4): a complementary attitude filter (``attitude_filter``)
    and a 7-state EKF (x, y, z, vx, vy, vz, yaw; NED, rad), with what they assume, independent of
    the sensor truth. (Before 0.3 these were the vehicle's ``ekf:`` and ``attitude_filter:``
    blocks; ``config.deprecated`` still reads them.)"""

    kind: str = field(default="ekf7", metadata={"choices": ("ekf7",)})
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
    attitude_filter: AttitudeFilterParams = field(default_factory=AttitudeFilterParams)


@dataclass
class EskfEstimatorConfig(AidingParams, GateParams):
    """Error-state EKF (``estimation/eskf.py``): what it assumes, independent of the sensor truth."""

    kind: str = field(default="eskf", metadata={"choices": ("eskf",)})
    init_position: List[float] = vector(0.0, 0.0, -1.0)  # m, NED
    init_velocity: List[float] = vector(0.0, 0.0, 0.0)  # m/s
    init_ypr: List[float] = vector(0.0, 0.0, 0.0)  # rad, yaw pitch roll
    init_accel_bias: List[float] = vector(0.0, 0.0, 0.0)  # m/s^2, body FRD (the nominal's start)
    init_gyro_bias: List[float] = vector(0.0, 0.0, 0.0)  # rad/s, body FRD
    init_pos_std: List[float] = noise_stds(0.1, 0.1, 0.3)  # m
    init_vel_std: List[float] = noise_stds(0.1, 0.1, 0.3)  # m/s
    init_att_std: List[float] = noise_stds(0.05, 0.05, 0.05)  # rad, about N, E, D
    estimate_biases: bool = True  # false: 9 error states, biases fixed at zero
    init_accel_bias_std: List[float] = noise_stds(0.05, 0.05, 0.05)  # m/s^2
    init_gyro_bias_std: List[float] = noise_stds(0.01, 0.01, 0.01)  # rad/s
    accel_std: List[float] = noise_stds(0.5, 0.5, 1.5)  # m/s^2 per IMU sample, body x y z
    gyro_std: List[float] = noise_stds(0.5, 0.5, 0.5)  # rad/s per IMU sample
    accel_bias_rw_std: float = number(0.001, nonnegative=True, noise_std=True)  # m/s^2/sqrt(s)
    gyro_bias_rw_std: float = number(0.0001, nonnegative=True, noise_std=True)  # rad/s/sqrt(s)
    # rad: > 0 learns the accelerometer bias of a body axis only while that axis is within this
    # angle of the vertical and the vehicle does not manoeuvre hard (PX4 EKF2's inhibition, at
    # 15° = 0.2618: a level axis's bias cannot be told from a tilt), its covariance row
    # uncorrelated otherwise (``eskf.uncorrelate_unobservable_accel_bias``); 0 = off
    accel_bias_learning_tilt: float = number(0.0, minimum=0.0, maximum=1.5)
    # > 0: PX4 EKF2's gravity-vector fusion (EKF2_IMU_CTRL bit 2) while not aided horizontally
    # (no GPS sample for gravity_aiding_timeout s): the accelerometer's direction as a measurement
    # of the tilt while its peak-held magnitude is within 0.9-1.1 g, this std (PX4's
    # EKF2_GRAV_NOISE, of the unit vector per PX4's 10 ms update; ``eskf.gravity_update``); 0 = off
    gravity_std: float = number(0.0, nonnegative=True, noise_std=True)
    gravity_aiding_timeout: float = number(5.0, positive=True)  # s (PX4's EKF2_NOAID_TOUT)
    gps_pos_std: List[float] = noise_stds(0.7, 0.7, 2.0)  # m
    gps_vel_std: List[float] = noise_stds(0.1, 0.1, 0.3)  # m/s
    mag_yaw_std: float = number(0.1, positive=True, noise_std=True)  # rad
    gsf: GsfParams = field(default_factory=GsfParams)  # the EKF-GSF yaw estimator beside it (off)


@dataclass
class TruthEstimatorConfig:
    """No estimator: the controller flies on the true state (an ideal estimator). The vehicle's
    sensors still sample and are logged."""

    kind: str = field(default="truth", metadata={"choices": ("truth",)})


@dataclass
class CustomEstimatorConfig:
    """Your own estimator: a Python class flown through the workbench's adapter
    (``estimation/custom.py`` says what the class provides)."""

    kind: str = field(default="custom", metadata={"choices": ("custom",)})
    factory: str = ""  # "module:name" or "path/to/file.py:name" (relative to the scenario file)
    params: Dict[str, float] = field(default_factory=dict)  # keyword arguments of factory(**params)
    gate_sigma: float = number(5.0, nonnegative=True)  # sigma; chi^2 gate of GPS and mag samples, 0 = off


@dataclass
class CourseEstimatorConfig:
    """A student's course estimator: the six functions of the FCND estimation project in a
    Python module (``grading/course.py``; ``quad-drake grade --template DIR`` writes one)."""

    kind: str = field(default="course", metadata={"choices": ("course",)})
    module: str = ""  # path/to/my_estimator.py (relative to the scenario file, else the working directory)
    init_std: List[float] = field(default_factory=list)  # m, m/s, rad (7); empty: the module's INIT_STD_DEVS


def _no_problem(config):
    return None


def _as_is(config, folder):
    return config


@dataclass(frozen=True)
class EstimatorKind:
    """One estimator kind (see the module docstring)."""

    name: str
    config_type: type
    vocabulary: Callable[[object], Optional[EstimatorVocabulary]]
    builder: Optional[str]  # "module:function", None when the kind runs no estimator
    tuning_keys: Callable[[object], tuple]
    fidelity_problem: Callable[[Fidelity], Optional[str]]
    problem: Callable[[object], Optional[str]] = _no_problem
    locate: Callable[[object, object], object] = _as_is
    relative: Callable[[object, object], object] = _as_is
    # the measurements it fuses, in fusion order (names of ``measurements.MEASUREMENTS``); its
    # system builds one update per name the vehicle carries and refuses a name it cannot fuse
    measurements: tuple = ()
    replay_defaults: Optional[Callable[[], object]] = None  # None: the config type's defaults
    started_from_log: Callable[[object, float, float, float], object] = lambda config, roll, pitch, yaw: (
        config
    )
    assuming_gps_noise: Callable[[object, float, float], object] = lambda config, pos_std, vel_std: config
    # the config started from the IMU biases PX4's estimator had at the log's start; None: no bias states
    started_with_biases: Optional[Callable[[object, object], object]] = None
    # the config of a log whose height reference is its baro: this GPS height noise (m), no height restart
    assuming_baro_height_reference: Callable[[object, float], object] = lambda config, height_std: config
    # a fixed-interval RTS smoother exists over its stored pass (``flightlogs.smoothing``)
    smoothable: bool = False
    # its GPS update fuses each sample with the receiver's reported accuracy where a replay gives it
    # (``sensors.gps_accuracy``: ``systems.updates.GpsUpdate``, ``estimation.measurements.receiver_noise``)
    fuses_gps_accuracy: bool = False
    # a log's EKF2_* parameters map onto its config (``flightlogs.px4_parameters``)
    takes_px4_parameters: bool = False
    # the dotted config fields its system takes per vehicle (:func:`sharing_problem`)
    per_vehicle: Callable[[object], tuple] = lambda config: ()

    def replay_config(self) -> object:
        """The kind's config for replaying a flight log (``replay_defaults``, else the defaults)."""
        return self.config_type() if self.replay_defaults is None else self.replay_defaults()

    def build_function(self) -> Callable:
        """The function named by ``builder``, imported."""
        module, _, name = self.builder.partition(":")
        return getattr(importlib.import_module(module), name)


def _any_fidelity(fidelity):
    return None


def _physical_accelerometer_only(fidelity):
    if fidelity.reference_accelerometer:
        return "the error-state EKF is written for the physical accelerometer (fidelity: physical)"
    return None


_EKF7_TUNING = (
    "estimator.q_pos_xy_std",
    "estimator.q_pos_z_std",
    "estimator.q_vel_xy_std",
    "estimator.q_vel_z_std",
    "estimator.q_yaw_std",
    "estimator.tilt_gyro_std",
    "estimator.gps_pos_xy_std",
    "estimator.gps_pos_z_std",
    "estimator.gps_vel_xy_std",
    "estimator.gps_vel_z_std",
    "estimator.mag_yaw_std",
)
_ESKF_TUNING = (
    "estimator.accel_std",
    "estimator.gyro_std",
    "estimator.accel_bias_rw_std",
    "estimator.gyro_bias_rw_std",
    "estimator.gps_pos_std",
    "estimator.gps_vel_std",
    "estimator.mag_yaw_std",
)


PX4_PER_SAMPLE = math.sqrt(0.010 / 0.002)
"""PX4 EKF2's IMU noise is per 10 ms prediction step; ours is per 2 ms sample of equal density."""
PX4_NOISE = {
    "gyro_std": 0.015 * PX4_PER_SAMPLE,  # rad/s per 2 ms sample (EKF2_GYR_NOISE)
    "accel_std": 0.35 * PX4_PER_SAMPLE,  # m/s^2 per 2 ms sample (EKF2_ACC_NOISE)
    "gps_pos_std": 0.5,  # m (EKF2_GPS_P_NOISE)
    "gps_vel_std": 0.3,  # m/s (EKF2_GPS_V_NOISE)
    "heading_std": 0.3,  # rad (EKF2_HEAD_NOISE)
    "baro_height_std": 3.5,  # m (EKF2_BARO_NOISE)
    "mag_field_std": 0.05,  # gauss (EKF2_MAG_NOISE)
}
"""PX4 EKF2's default noise, what a replay of a real flight controller's log assumes (not tuned
on the logs; ``flightlogs/settings.py``)."""


def px4_gps_noise(position_std, velocity_std) -> tuple[list, list]:
    """(position std [x, y, z] m, velocity std [vx, vy, vz] m/s) of PX4's one GPS position and one
    velocity noise (``EKF2_GPS_P_NOISE``, ``EKF2_GPS_V_NOISE``): horizontal as given, vertical
    ``measurements.PX4_GPS_VERTICAL_RATIO`` times it, as PX4 fuses them."""

    def vertical(std):  # to 12 digits: 0.45, not 1.5 * 0.3 = 0.44999999999999996, in a saved config
        return float(f"{PX4_GPS_VERTICAL_RATIO * std:.12g}")

    position = [position_std, position_std, vertical(position_std)]
    return position, [velocity_std, velocity_std, vertical(velocity_std)]


PX4_GPS_POSITION_STD, PX4_GPS_VELOCITY_STD = px4_gps_noise(PX4_NOISE["gps_pos_std"], PX4_NOISE["gps_vel_std"])
"""The replay's GPS noise per axis (m; m/s): PX4's defaults, the vertical 1.5 times the horizontal."""
PX4_GRAVITY_STD = 1.0
"""PX4 EKF2's ``EKF2_GRAV_NOISE`` default: the gravity vector's std (of the unit vector f/|f|,
per its 10 ms update; PX4's parameter reference states g0, older ones m/s^2, and fuses it on the
unit vector: a fraction of g, ``gravity_std`` 1:1, ``flightlogs.px4_parameters``)."""


def _ekf7_replay_defaults() -> Ekf7EstimatorConfig:
    """The EKF7 with PX4 EKF2's noise (:data:`PX4_NOISE`; the velocity's process noise is
    EKF2_ACC_NOISE, 0.35 m/s^2 per 10 ms step, as a density), started at rest at the origin with
    a wide prior, its attitude filter trusting the accelerometer within 0.5 s (a real gyro's bias
    needs it sooner than a simulated one's 100 s); the GPS its height reference, as PX4's default
    EKF2_HGT_REF (a log whose parameter names the barometer: ``assuming_baro_height_reference``)."""
    return Ekf7EstimatorConfig(
        init_state=[0.0] * 7,
        init_std=[1.0, 1.0, 1.0, 0.5, 0.5, 0.5, 0.3],
        q_vel_xy_std=0.035,  # m/s/sqrt(s)
        q_vel_z_std=0.035,
        gps_pos_xy_std=PX4_GPS_POSITION_STD[0],
        gps_pos_z_std=PX4_GPS_POSITION_STD[2],
        gps_vel_xy_std=PX4_GPS_VELOCITY_STD[0],
        gps_vel_z_std=PX4_GPS_VELOCITY_STD[2],
        mag_yaw_std=PX4_NOISE["heading_std"],
        attitude_filter=AttitudeFilterParams(tau=0.5),
        gps_height_restart=True,
        **px4_aiding_noise(),
    )


def _ekf7_started(config, roll, pitch, yaw) -> Ekf7EstimatorConfig:
    """The EKF7 started at rest at the origin heading `yaw` (rad); its attitude filter starts
    level and finds roll and pitch from the accelerometer."""
    return dataclasses.replace(config, init_state=[0.0] * 6 + [yaw])


def _ekf7_gps_noise(config, pos_std, vel_std) -> Ekf7EstimatorConfig:
    return dataclasses.replace(
        config, gps_pos_xy_std=pos_std, gps_pos_z_std=pos_std, gps_vel_xy_std=vel_std, gps_vel_z_std=vel_std
    )


def _ekf7_baro_height_reference(config, height_std) -> Ekf7EstimatorConfig:
    return dataclasses.replace(config, gps_pos_z_std=height_std, gps_height_restart=False)


def _eskf_replay_defaults():
    """The ESKF with PX4 EKF2's noise (:data:`PX4_NOISE`; bias walks EKF2_ACC_B_NOISE 0.003 m/s^3,
    EKF2_GYR_B_NOISE 0.001 rad/s^2), started at rest at the origin with a wide prior; the GPS its
    height reference, as the EKF7's (:func:`_ekf7_replay_defaults`)."""
    return EskfEstimatorConfig(
        init_position=[0.0, 0.0, 0.0],
        init_pos_std=[1.0, 1.0, 1.0],
        init_vel_std=[0.5, 0.5, 0.5],
        init_att_std=[0.1, 0.1, 0.3],
        init_gyro_bias_std=[0.02, 0.02, 0.02],
        init_accel_bias_std=[0.2, 0.2, 0.2],
        accel_std=[PX4_NOISE["accel_std"]] * 3,
        gyro_std=[PX4_NOISE["gyro_std"]] * 3,
        accel_bias_rw_std=0.003,
        gyro_bias_rw_std=0.001,
        gravity_std=PX4_GRAVITY_STD,
        gps_pos_std=list(PX4_GPS_POSITION_STD),
        gps_vel_std=list(PX4_GPS_VELOCITY_STD),
        mag_yaw_std=PX4_NOISE["heading_std"],
        gps_height_restart=True,
        **px4_aiding_noise(),
    )


def px4_aiding_noise() -> dict:
    """The AidingParams fields with PX4 EKF2's barometer and field noise (:data:`PX4_NOISE`), the
    baro's datum set by its first sample as PX4 sets its baro offset (a log's barometer reads a
    pressure altitude that no prior knows: ``baro.first_datum``)."""
    return {
        "baro": BaroFusionParams(height_std=PX4_NOISE["baro_height_std"], datum_from_first_sample=True),
        "mag_field": MagFieldFusionParams(field_std=[PX4_NOISE["mag_field_std"]] * 3),
    }


def _eskf_started(config, roll, pitch, yaw):
    return dataclasses.replace(config, init_ypr=[yaw, pitch, roll])


def _eskf_started_with_biases(config, biases):
    """The ESKF started from `biases` (``flightlogs.reader.ImuBiasStart``): its nominal biases
    PX4's, and their stds PX4's where the log holds its variances (else the config's)."""
    changes = {"init_accel_bias": list(biases.accel), "init_gyro_bias": list(biases.gyro)}
    if biases.accel_std is not None:
        changes["init_accel_bias_std"] = list(biases.accel_std)
    if biases.gyro_std is not None:
        changes["init_gyro_bias_std"] = list(biases.gyro_std)
    return dataclasses.replace(config, **changes)


def _eskf_gps_noise(config, pos_std, vel_std):
    return dataclasses.replace(config, gps_pos_std=[pos_std] * 3, gps_vel_std=[vel_std] * 3)


def _eskf_baro_height_reference(config, height_std):
    return dataclasses.replace(
        config, gps_pos_std=[*config.gps_pos_std[0:2], height_std], gps_height_restart=False
    )


MAG_FIELD_PER_VEHICLE = (
    "mag_field.field_strength",
    "mag_field.declination",
    "mag_field.inclination",
    "mag_field.hard_iron",
)
"""The magnetometer settings an AidingParams estimator takes per vehicle: each log's own world
field (``flightlogs.earth_field``) and learned hard iron."""
_EKF7_PER_VEHICLE = (
    "init_state",
    "gps_height_restart",
    "gps_pos_xy_std",
    "gps_pos_z_std",
    "gps_vel_xy_std",
    "gps_vel_z_std",
    *MAG_FIELD_PER_VEHICLE,
)


def _eskf_per_vehicle(config) -> tuple:
    """The ESKF's per-vehicle fields: its start, GPS noise (the velocity's not with the EKF-GSF,
    which is built on one) and magnetic field."""
    shared_by_gsf = ("gps_vel_std",) if not config.gsf.enabled else ()
    start = ("init_position", "init_velocity", "init_ypr", "init_accel_bias", "init_gyro_bias")
    return (*start, "gps_pos_std", "gps_height_restart", *shared_by_gsf, *MAG_FIELD_PER_VEHICLE)


def _eskf_vocabulary(config):
    """ESKF15 or ESKF9 (bias states or not), with the EKF-GSF's log when ``gsf.enabled``."""
    vocabulary = ESKF15 if config.estimate_biases else ESKF9
    return with_gsf(vocabulary, config.gsf.models) if config.gsf.enabled else vocabulary


def _eskf_tuning(config):
    """The ESKF's noise fields; without bias states their random walks have no effect."""
    return _ESKF_TUNING if config.estimate_biases else tuple(k for k in _ESKF_TUNING if "_bias_" not in k)


@lru_cache(maxsize=64)
def _custom_state_names(factory, params):
    """The state names of the custom estimator `factory` (``params`` as sorted items), checked by
    one step of each of its methods (``custom.check_estimator``)."""
    return custom.check_estimator(factory, dict(params), ONBOARD_PERIOD)


def _custom_names(config):
    return _custom_state_names(config.factory, tuple(sorted(config.params.items())))


def _custom_problem(config):
    if not config.factory:
        return "kind custom needs a factory ('module:name' or 'path/to/file.py:name')"
    try:
        _custom_names(config)
    except custom.EstimatorProblem as e:
        return str(e)
    return None


def _custom_located(config, base_dir):
    return dataclasses.replace(config, factory=custom.absolute_factory(config.factory, base_dir))


def _custom_relative(config, folder):
    return dataclasses.replace(config, factory=custom.relative_factory(config.factory, folder))


def _custom_tuning(config):
    """The custom estimator's noise parameters: those named ``*_std``."""
    return tuple(f"estimator.params.{name}" for name in config.params if name.endswith("_std"))


def _course_problem(config):
    if not config.module:
        return "kind course needs a module (path/to/my_estimator.py)"
    try:
        tuning_of(load_student_module(config.module))
    except StudentProblem as e:
        return str(e)
    return None


def _course_located(config, base_dir):
    path = Path(config.module)
    if not config.module or path.is_absolute():
        return config
    for base in (Path(base_dir), Path.cwd()):
        if (base / path).is_file():
            return dataclasses.replace(config, module=str((base / path).resolve()))
    return config


COURSE_STATES = ("X", "Y", "Z", "VX", "VY", "VZ", "Yaw")


KINDS = {
    kind.name: kind
    for kind in (
        EstimatorKind(
            name="ekf7",
            config_type=Ekf7EstimatorConfig,
            vocabulary=lambda config: EKF7,
            builder="quad_drake.systems.estimators:add_ekf7",
            tuning_keys=lambda config: _EKF7_TUNING,
            fidelity_problem=_any_fidelity,
            measurements=("yaw", "gps", "no_aid", "heading", "baro"),
            replay_defaults=_ekf7_replay_defaults,
            started_from_log=_ekf7_started,
            assuming_gps_noise=_ekf7_gps_noise,
            assuming_baro_height_reference=_ekf7_baro_height_reference,
            fuses_gps_accuracy=True,
            per_vehicle=lambda config: _EKF7_PER_VEHICLE,
        ),
        EstimatorKind(
            name="eskf",
            config_type=EskfEstimatorConfig,
            vocabulary=_eskf_vocabulary,
            builder="quad_drake.systems.estimators:add_eskf",
            tuning_keys=_eskf_tuning,
            fidelity_problem=_physical_accelerometer_only,
            measurements=("yaw", "gps", "no_aid", "field", "baro"),
            replay_defaults=_eskf_replay_defaults,
            started_from_log=_eskf_started,
            started_with_biases=_eskf_started_with_biases,
            assuming_gps_noise=_eskf_gps_noise,
            assuming_baro_height_reference=_eskf_baro_height_reference,
            smoothable=True,
            fuses_gps_accuracy=True,
            takes_px4_parameters=True,
            per_vehicle=_eskf_per_vehicle,
        ),
        EstimatorKind(
            name="custom",
            config_type=CustomEstimatorConfig,
            vocabulary=lambda config: euler_vocabulary("custom", _custom_names(config)),
            builder="quad_drake.systems.custom_estimator:add_custom",
            tuning_keys=_custom_tuning,
            fidelity_problem=_any_fidelity,
            problem=_custom_problem,
            locate=_custom_located,
            measurements=("yaw", "gps", "no_aid"),
            relative=_custom_relative,
        ),
        EstimatorKind(
            name="course",
            config_type=CourseEstimatorConfig,
            vocabulary=lambda config: euler_vocabulary("course", COURSE_STATES),
            builder="quad_drake.systems.course_estimator:add_course",
            tuning_keys=lambda config: (),
            fidelity_problem=_any_fidelity,
            problem=_course_problem,
            locate=_course_located,
            measurements=("yaw", "gps"),
        ),
        EstimatorKind(
            name="truth",
            config_type=TruthEstimatorConfig,
            vocabulary=lambda config: None,
            builder=None,
            tuning_keys=lambda config: (),
            fidelity_problem=_any_fidelity,
        ),
    )
}
"""Every estimator kind by name."""

EstimatorConfig = Union[tuple(kind.config_type for kind in KINDS.values())]
"""A vehicle's estimator, chosen by ``kind`` (``estimator: {kind: eskf, ...}``); default ekf7."""
DEFAULT_KIND = Ekf7EstimatorConfig().kind
"""The kind of a vehicle (or a replay) that names none."""


def kind_of(config) -> EstimatorKind:
    """The EstimatorKind of an estimator config."""
    return KINDS[config.kind]


def vocabulary_for(config) -> Optional[EstimatorVocabulary]:
    """The EstimatorVocabulary of an estimator config; None for a kind that runs no estimator."""
    return kind_of(config).vocabulary(config)


def vehicle_vocabulary(vehicle) -> Optional[EstimatorVocabulary]:
    """The EstimatorVocabulary of a VehicleConfig's estimator; None when no estimator runs (no
    IMU, or kind ``truth``)."""
    return vocabulary_for(vehicle.estimator) if vehicle.sensors.imu is not None else None


def flies_on_estimate(vehicle) -> bool:
    """True when the vehicle's controller flies on an estimator's estimate (``flies_on:
    estimate`` and an estimator runs), False when on the true state."""
    return vehicle.flies_on == "estimate" and vehicle_vocabulary(vehicle) is not None


def fused_measurements(vehicle) -> tuple:
    """The ``measurements.Measurement`` s a VehicleConfig's estimator fuses, in fusion order: its
    kind's that the vehicle's sensors carry; () when no estimator runs. Its input ports and NIS
    columns (:func:`nis_sensors`) read this list, as its system's updates do."""
    if vehicle_vocabulary(vehicle) is None:
        return ()
    return measurements_of(kind_of(vehicle.estimator).measurements, vehicle.sensors)


def nis_sensors(vehicle) -> tuple:
    """The NIS a VehicleConfig's estimator logs (keys of ``vocabulary.NIS_DOF``, in
    ``measurements.NIS_ORDER``): "gps" with a GPS, "mag" with a yaw magnetometer (or the EKF7's
    heading of a 3-axis one), "field" (the ESKF's 3-axis field), "baro" with a barometer it
    fuses; () when no estimator runs."""
    names = {m.nis for m in fused_measurements(vehicle)}
    return tuple(name for name in NIS_ORDER if name in names)


def sharing_problem(vehicles) -> Optional[str]:
    """None when the VehicleConfigs `vehicles` (one per vehicle) can share one estimator system
    sized by their number, else why not (one line): all equal, or of one kind whose configs differ
    only in the fields it takes per vehicle (``EstimatorKind.per_vehicle``) and whose sensors differ
    only in the barometer (a vehicle may lack one; its period is its own)."""
    first = vehicles[0]
    if all(v == first for v in vehicles[1:]):
        return None
    kinds = sorted({v.estimator.kind for v in vehicles})
    if len(kinds) > 1:
        return f"estimator kinds {', '.join(kinds)} differ"
    kind = kind_of(first.estimator)
    if not kind.per_vehicle(first.estimator):
        return f"estimator kind {kind.name!r} takes no per-vehicle settings: every vehicle needs one config"
    shared = _shared_part(first.estimator, kind.per_vehicle(first.estimator))
    for v in vehicles[1:]:
        differing = _differing_field(shared, _shared_part(v.estimator, kind.per_vehicle(v.estimator)))
        if differing:
            return f"estimator.{differing} differs (kind {kind.name} takes it for all vehicles)"
        if dataclasses.replace(v.sensors, baro=None) != dataclasses.replace(first.sensors, baro=None):
            return "the sensors differ in more than the barometer"
    return None


def _shared_part(config, per_vehicle) -> object:
    """`config` with its per-vehicle fields (dotted names) set to None: what all vehicles share."""
    for dotted in per_vehicle:
        head, _, rest = dotted.partition(".")
        inner = None if not rest else _shared_part(getattr(config, head), (rest,))
        config = dataclasses.replace(config, **{head: inner})
    return config


def _differing_field(a, b) -> str:
    """The dotted name of the first field where the dataclasses a and b differ; "" when equal."""
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if x != y:
            nested = _differing_field(x, y) if dataclasses.is_dataclass(x) and type(x) is type(y) else ""
            return f.name + (f".{nested}" if nested else "")
    return ""
