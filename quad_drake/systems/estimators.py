"""Estimator LeafSystems and the estimator sub-Diagrams a vehicle's config chooses.

Every system here is sized by n vehicles (default 1, a single run; a fleet flies n runs of one
VehicleConfig at once; a replay of n flight logs runs n vehicles, each with the settings of its
own log: the params and sensors given as a sequence of n, which differ only in what the kind
takes per vehicle, ``registry.EstimatorKind.per_vehicle``: the start, the GPS noise, the
magnetic field, the barometer's period and presence): its ports carry the n per-vehicle vectors
vehicle-major (vehicle i at [i k, (i + 1) k)), and a single run and a fleet execute the same
code: the compiled kernels over (n, ...) views of the ports and discrete state,
``kernels/attitude.py``, ``kernels/ekf7.py`` and ``kernels/eskf.py`` (each estimator's equations
in its module docstring), with ``kernels/fusion.py`` for what they share. Each estimator system
holds its measurement updates (``systems/updates.py``: one object per sensor, built once from
the vehicle) and supplies only its prediction and how a correction is applied.

Every estimator is a sub-Diagram (:func:`build_estimator`) with the input ``imu``, one input
per measurement it fuses that the vehicle carries (``gps``, ``mag``, ``baro``) and the outputs
its vocabulary lists (``estimation/vocabulary.py``):
``estimated_state`` (13, the true ``state`` layout), ``covariance``, ``diagnostics`` and its
own logs.

- ``ekf7``: complementary attitude filter, 7-state EKF, estimated-state assembly. Within a
  tick the attitude filter (offset ATTITUDE_FILTER_OFFSET) integrates the gyro from the EKF's
  posterior yaw of the previous tick, then the EKF (offset EKF_OFFSET) takes the filter's
  roll, pitch and integrated yaw, predicts, and fuses a fresh magnetometer and then a fresh
  GPS sample (the reference's IMU, Mag, GPS order).
- ``eskf``: the error-state EKF, one system at EKF_OFFSET (predict, mag, GPS).

Fresh means a changed ``stamp``. Both gate each update (chi^2, ``estimation/gating.py``: the
GPS horizontal position, height and velocity apart), reset a GPS quantity after its run of
rejections or at a GPS regain, repair an unhealthy covariance and count
all of it in ``diagnostics``. Over non-finite IMU samples (a dropout) both dead-reckon on the
running mean of the IMU and report the body rate in ``estimated_state`` as NaN: no rate is
measured, and the controller then commands no body moment (``control.cascade``).
"""

import dataclasses

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder, LeafSystem

from quad_drake.config.schema import GpsParams, MagParams, SensorsConfig
from quad_drake.conventions import (
    ATTITUDE_FILTER_OFFSET,
    ATTITUDE_SIZE,
    EKF_OFFSET,
    EKF_STATE_SIZE,
    IMU_SIZE,
    ONBOARD_PERIOD,
    PX4_UPDATE_PERIOD,
    STATE_SIZE,
)
from quad_drake.estimation import ekf, gating
from quad_drake.estimation.complementary import VARIANTS
from quad_drake.estimation.measurements import MEASUREMENTS
from quad_drake.estimation.registry import KINDS, kind_of, sharing_problem, vocabulary_for
from quad_drake.estimation.vocabulary import DIAG, DIAGNOSTICS_SIZE, NIS_COLUMNS, NIS_DOF, gsf_log_size
from quad_drake.kernels import attitude as attitude_kernel
from quad_drake.kernels import ekf7 as ekf7_kernel
from quad_drake.kernels import fusion
from quad_drake.kernels.imu_hold import HOLD_SIZE, initial_hold
from quad_drake.models.fidelity import PHYSICAL
from quad_drake.models.rotations import quat_from_euler_tuple
from quad_drake.systems import updates
from quad_drake.systems._io import declare_block_output, declare_state_output, discrete_group, row_reader


def _tiled(vector, n):
    """The n vehicles' rows of `vector`, vehicle-major: (k,) for all, or (n, k) each its own."""
    vector = np.asarray(vector, dtype=float)
    return np.broadcast_to(vector, (n, vector.shape[-1])).ravel()


def _per_vehicle(settings, n) -> tuple:
    """(shared, each) of an estimator system's `settings` (its params or its sensors), given once
    for its n vehicles or as a sequence of n, one per vehicle (``registry.sharing_problem`` says
    how they may differ): the first, whose shared figures every vehicle takes, and the sequence
    (None when given once)."""
    if not isinstance(settings, (list, tuple)):
        return settings, None
    if len(settings) != n:
        raise ValueError(f"{len(settings)} per-vehicle settings for {n} vehicles")
    return settings[0], tuple(settings)


def _stacked(value_of, shared, each) -> np.ndarray:
    """value_of(shared) as an array, or (n, ...) the stack of value_of of each vehicle's settings."""
    if each is None:
        return np.asarray(value_of(shared), dtype=float)
    return np.stack([np.asarray(value_of(s), dtype=float) for s in each])


def _mag_field(params, each):
    """The MagFieldFusionParams of the vehicles: one for all, or a tuple of each vehicle's."""
    return params.mag_field if each is None else tuple(p.mag_field for p in each)


def _carried(sensors, each_sensors):
    """The SensorsConfig an estimator system builds its updates of: `sensors`, with per-vehicle
    sensors the first's with the barometer of the first vehicle that carries one."""
    if each_sensors is None:
        return sensors
    return dataclasses.replace(sensors, baro=next((s.baro for s in each_sensors if s.baro is not None), None))


def _baro_update(
    measurement, correct, params, each, fidelity, gps_z_std_of, sensors, each_sensors, bias_in_state=False
):
    """The BaroUpdate of an estimator system: its params' barometer fusion and gate; per vehicle
    (``each``, ``each_sensors``: None when one for all) the GPS height noise gps_z_std_of(params)
    m, the barometer's period s and whether it carries one; bias_in_state: the estimator carries
    the baro bias in its state (the ESKF)."""
    gps_z_std = gps_z_std_of(params) if each is None else [gps_z_std_of(p) for p in each]
    period, carried = float(sensors.baro.period), True
    if each_sensors is not None:
        period = [float((s.baro or sensors.baro).period) for s in each_sensors]
        carried = [s.baro is not None for s in each_sensors]
    gate = _gate(params.baro.gate_sigma, fidelity)
    return updates.BaroUpdate(
        measurement, correct, params.baro, gate, gps_z_std, period, carried, bias_in_state
    )


GPS_AND_MAG = SensorsConfig(gps=GpsParams(), mag=MagParams())
"""The sensors an estimator system fuses by default: a GPS and a yaw magnetometer."""


def _gate(sigma, fidelity) -> float:
    """A gate's sigma, or 0 (off) under ``fidelity.reference_estimator``."""
    return 0.0 if fidelity.reference_estimator else sigma


class ComplementaryFilter(LeafSystem):
    """n complementary roll/pitch filters with gyro-integrated yaw (SPEC §4 UpdateFromIMU).

    Every port carries the n vehicles' vectors vehicle-major (vehicle i at [i k, (i + 1) k)).
    initial_attitude: (3,) rad for all vehicles, or (n, 3) each its own.
    Inputs: ``imu`` (n*6: f_B specific force m/s^2, w_NB_B rad/s; FRD), ``ekf_state`` (n*7; index
    6 is the EKF posterior yaw, rad, used as the prior yaw). Outputs (state ports): ``attitude``
    (n*3: roll, pitch, yaw, rad), ``body_rate`` (n*3: the gyro sample, rad/s; NaN while the IMU
    is out). Ticks every ONBOARD_PERIOD at ATTITUDE_FILTER_OFFSET with dt = ONBOARD_PERIOD
    (``kernels.attitude.tick``). Over a non-finite IMU sample the filter dead-reckons on the
    running mean of the IMU (``kernels.imu_hold.IMU_HOLD_TIME``) and reports no rate (NaN: the
    controller then commands no body moment).
    With ``fidelity.reference_accelerometer`` the IMU carries the reference's reading and the
    tilt comes from the reference's formulas; with ``fidelity.float32_estimator`` the attitude
    and body rate are rounded to float32 after each tick (``round_to_float32``).
    """

    def __init__(self, params, initial_attitude=(0.0, 0.0, 0.0), fidelity=PHYSICAL, n=1):
        super().__init__()
        if params.variant not in VARIANTS:
            raise ValueError(f"attitude filter variant {params.variant!r} is not one of {VARIANTS}")
        self._n = n
        self._model = attitude_kernel.model(
            ONBOARD_PERIOD, params.tau, params.variant, fidelity.reference_accelerometer
        )
        self._float32 = fidelity.float32_estimator
        self._read_imu = row_reader(self.DeclareVectorInputPort("imu", n * IMU_SIZE), n)
        self._read_ekf_state = row_reader(self.DeclareVectorInputPort("ekf_state", n * EKF_STATE_SIZE), n)
        self._attitude = discrete_group(self, _tiled(initial_attitude, n), "attitude")
        self._rate = discrete_group(self, n * 3, "body_rate")
        self._hold = discrete_group(self, _tiled(initial_hold(), n))
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, ATTITUDE_FILTER_OFFSET, self._update)

    def _update(self, context, discrete_state):
        n, get = self._n, discrete_state.get_mutable_value
        attitude, rate = get(self._attitude), get(self._rate)
        attitude_kernel.tick(
            attitude.reshape(n, ATTITUDE_SIZE),
            rate.reshape(n, 3),
            get(self._hold).reshape(n, HOLD_SIZE),
            self._read_imu(context),
            self._read_ekf_state(context),
            *self._model,
        )
        if self._float32:
            attitude_kernel.round_to_float32(attitude, rate)


class Ekf(LeafSystem):
    """n 7-state EKFs (SPEC §4): x = (p_N m, v_N m/s, yaw rad), NED; roll/pitch from the attitude filter.

    Ports vehicle-major as :class:`ComplementaryFilter`'s. Inputs: ``imu`` (n*6: f_B m/s^2,
    w_NB_B rad/s), ``gps`` (n*7: p_N m, v_N m/s, stamp s), ``mag`` (n*2: yaw rad, stamp s),
    ``attitude`` (n*3: roll, pitch, yaw rad, this tick's filter output). Outputs (state ports):
    ``ekf_state`` (n*7), ``covariance`` (n*49, each P row-major), ``diagnostics``
    (n*``vocabulary.DIAGNOSTICS``; NIS is NaN before the first update).

    Each tick (ONBOARD_PERIOD, offset EKF_OFFSET; ``kernels.ekf7.tick``, whose module docstring
    carries the equations): yaw <- attitude yaw, predict x' = f(x, f_B), P' = G P G^T + Q with
    dt = ONBOARD_PERIOD (over a non-finite IMU sample with the IMU's running mean); then a fresh
    mag sample, then a fresh GPS sample, is fused through the gates (``mag_gate_sigma``; the GPS policy of
    ``estimation/gating.py``: horizontal position, height and velocity gated, fused and reset
    apart, a returning GPS taken after an outage). A sample is fresh when its stamp differs from
    the last stamp seen and is not NO_SAMPLE_STAMP. P is checked every tick (finite, variances
    >= 0) and fully (PSD) at every GPS sample, and repaired or reset to P0. With
    ``fidelity.reference_accelerometer`` the prediction reads the IMU as the reference's R_NB^T
    (a_NB + g_N): a_N = R f - g_N; with ``fidelity.reference_estimator`` nothing is gated, reset
    or repaired (the reference's EKF); with ``fidelity.float32_estimator`` x and P are rounded
    to float32 after each tick. With ``tilt`` (an ``ekf.TiltNoise``) Q grows with the attitude
    filter's predicted roll/pitch error at the context time.

    The measurement updates are those of the ``ekf7`` kind's ``measurements`` that ``sensors``
    (a SensorsConfig; default a GPS and a yaw magnetometer) carry, in that order
    (``systems/updates.py``): a sensor it lacks has no input port. A barometer adds the input
    ``baro`` (n*2: height m up, stamp s), a 3-axis magnetometer makes ``mag`` n*4 (m_B gauss FRD,
    stamp s, fused as the tilt-compensated heading); each is fused after the GPS through its gate
    (``kernels/aiding.py``). Corrections are added, the yaw wrapped (``kernels.ekf7.correct``;
    the GPS's without the wrap, ``kernels.ekf7.correct_gps``). params and sensors: one for all n
    vehicles, or a sequence of n (module docstring): the initial state, the GPS noise, the
    magnetic field and the barometer each vehicle's own.
    """

    def __init__(self, params, fidelity=PHYSICAL, tilt=None, n=1, sensors=GPS_AND_MAG):
        super().__init__()
        params, each = _per_vehicle(params, n)
        sensors, each_sensors = _per_vehicle(sensors, n)
        sensors = _carried(sensors, each_sensors)
        self._float32 = fidelity.float32_estimator
        self._tilt = tilt
        R_mag = ekf.mag_noise(params)
        mag_threshold = gating.gate_threshold(NIS_DOF["mag"], _gate(params.mag_gate_sigma, fidelity))
        self._model = ekf7_kernel.Model(
            dt=ONBOARD_PERIOD,
            Q=ekf.process_noise(params),
            gravity_z=ekf.gravity_z(fidelity.reference_accelerometer),
            r_mag=float(R_mag[0, 0]),
            mag_threshold=float(mag_threshold),
        )
        correct = ekf7_kernel.correct
        builders = {
            "yaw": lambda m: updates.YawUpdate(m, ekf7_kernel.mag_tick, R_mag, mag_threshold),
            "gps": lambda m: updates.GpsUpdate(
                m, _stacked(ekf.gps_noise, params, each), _gps_gates(params, fidelity),
                ekf7_kernel.correct_gps, sensors.gps_accuracy, _height_restart(params, each, fidelity),
            ),
            "heading": lambda m: updates.HeadingUpdate(
                m, correct, _mag_field(params, each), _gate(params.mag_field.gate_sigma, fidelity), tilt
            ),
            "baro": lambda m: _baro_update(
                m, correct, params, each, fidelity, lambda p: p.gps_pos_z_std, sensors, each_sensors
            ),
            "no_aid": lambda m: updates.NoAidUpdate(m, correct),
        }  # fmt: skip
        self._read_imu = row_reader(self.DeclareVectorInputPort("imu", n * IMU_SIZE), n)
        self._read_attitude = row_reader(self.DeclareVectorInputPort("attitude", n * ATTITUDE_SIZE), n)
        self._fusion = updates.Fusion(
            self,
            n,
            _stacked(ekf.initial_state, params, each),
            ekf.initial_covariance(params),
            updates.build_updates(KINDS["ekf7"].measurements, sensors, builders),
            repairs=not fidelity.reference_estimator,
        )
        # a quiet tick (no fresh GPS sample, every P healthy) fused the yaw in the compiled tick
        # and has no GPS sample to fuse: only the other updates run
        self._after_quiet_tick = tuple(
            u for u in self._fusion.updates if not isinstance(u, (updates.YawUpdate, updates.GpsUpdate))
        )
        # the compiled tick's GPS and yaw samples, read straight from the updates' ports (a
        # quiet tick then builds no samples dict); a sensor the vehicle lacks: no sample
        self._read_gps = _reader_or(self._fusion.update_of(updates.GpsUpdate), fusion.NO_GPS_SAMPLE, n)
        self._read_yaw = _reader_or(self._fusion.update_of(updates.YawUpdate), fusion.NO_MAG_SAMPLE, n)
        self._healthy = np.empty(n, dtype=bool)  # scratch of each tick's health check
        groups = self._fusion.groups
        declare_state_output(self, "ekf_state", groups.x, n * EKF_STATE_SIZE)
        declare_state_output(self, "covariance", groups.P, n * EKF_STATE_SIZE**2)
        declare_state_output(self, "diagnostics", groups.diagnostics, n * DIAGNOSTICS_SIZE)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, EKF_OFFSET, self._update)

    def measurement_ports(self) -> tuple:
        """The input ports of the measurement updates, in fusion order."""
        return self._fusion.ports

    def _update(self, context, discrete_state):
        """The prediction and, on a quiet tick, the yaw update (one compiled call); at a fresh GPS
        sample or an unhealthy P, the health check and every update (``updates.Fusion.fuse``)."""
        seam = self._fusion
        filters = seam.filters(discrete_state)
        attitude = self._read_attitude(context)
        tilt_gains = ekf7_kernel.NO_TILT if self._tilt is None else self._tilt.gains(context.get_time())
        quiet = ekf7_kernel.tick(
            *filters,
            attitude,
            self._read_imu(context),
            self._read_gps(context),
            self._read_yaw(context),
            *self._model,
            tilt_gains,
            self._healthy,
        )
        if not quiet or self._after_quiet_tick:
            samples = seam.read(context)
            samples["attitude"] = attitude
            if quiet:
                seam.fuse(context, discrete_state, filters, samples, None, self._after_quiet_tick)
            else:  # a fresh GPS sample or an unhealthy P somewhere: the full step
                seam.fuse(context, discrete_state, filters, samples, self._healthy)
        if self._float32:
            attitude_kernel.round_to_float32(filters.x, filters.P)


class EstimatedStateAssembler(LeafSystem):
    """n EKF7 estimates in the true ``state`` layout, for the controller and the evaluators.

    Inputs: ``attitude`` (n*3: roll, pitch, yaw rad), ``ekf_state`` (n*7), ``body_rate`` (n*3,
    rad/s, the filter's gyro sample, NaN while the IMU is out). Output: ``estimated_state``
    (n*13: p = x[0:3] m, q_NB = quat(roll, pitch, x[6]) wxyz, v = x[3:6] m/s, w_NB_B = body
    rate); a feedthrough output (its inputs are state ports).
    """

    def __init__(self, n=1):
        super().__init__()
        self._n = n
        self._read_attitude = row_reader(self.DeclareVectorInputPort("attitude", n * ATTITUDE_SIZE), n)
        self._read_ekf_state = row_reader(self.DeclareVectorInputPort("ekf_state", n * EKF_STATE_SIZE), n)
        self._read_rate = row_reader(self.DeclareVectorInputPort("body_rate", n * 3), n)
        self.DeclareVectorOutputPort(
            "estimated_state",
            n * STATE_SIZE,
            self._calc,
            prerequisites_of_calc={self.all_input_ports_ticket()},
        )

    def _calc(self, context, output):
        n = self._n
        ekf7_kernel.estimated_state(
            self._read_attitude(context),
            self._read_ekf_state(context),
            self._read_rate(context),
            out=output.get_mutable_value().reshape(n, STATE_SIZE),
        )


class Eskf(LeafSystem):
    """n error-state EKFs (``estimation/eskf.py``) on the IMU, GPS and magnetometer.

    Ports vehicle-major as :class:`ComplementaryFilter`'s. Inputs: ``imu`` (n*6: f_B m/s^2,
    w_NB_B rad/s), ``gps`` (n*7: p_N m, v_N m/s, stamp s), ``mag`` (n*2: yaw rad, stamp s); a
    sensor ``sensors`` lacks has no input port. Outputs (state ports):
    ``estimated_state`` (n*13: p, q_NB, v, body rate = gyro - gyro bias, NaN while the IMU is
    out), ``covariance`` (n*k*k, k = 15 with bias estimation, 9 without; error state dp, dv,
    dtheta[, db_a, db_g]; with a barometer the filter also carries the baro bias, its error last
    in P (``eskf.carries_baro_bias``), and this port gives P's leading k x k block: the bias and its
    std are in ``diagnostics``), ``diagnostics`` (n*``vocabulary.DIAGNOSTICS``), ``imu_bias`` (n*6: b_a
    m/s^2, b_g rad/s).

    Each tick (ONBOARD_PERIOD, offset EKF_OFFSET; ``kernels/eskf.py``, whose module docstring
    carries the equations): predict with the IMU sample (over a non-finite one, counted, with the
    running mean of the IMU: ``kernels.eskf.predict_tick``), then fuse a fresh mag and a fresh GPS
    sample through the gates and resets of :class:`Ekf`; P is checked as there. The updates are
    the ``eskf`` kind's ``measurements`` that ``sensors`` carry (as :class:`Ekf`'s: a 3-axis
    magnetometer's field vector and the baro height after the GPS); corrections are injected
    (``kernels.eskf.correct``). params and sensors: one for all n vehicles, or a sequence of n
    (module docstring), as :class:`Ekf`'s.
    """

    def __init__(self, params, fidelity=PHYSICAL, n=1, sensors=GPS_AND_MAG):
        super().__init__()
        params, each = _per_vehicle(params, n)
        sensors, each_sensors = _per_vehicle(sensors, n)
        sensors = _carried(sensors, each_sensors)
        # imported on first use: a run without an ESKF creates none of its numba dispatchers
        from quad_drake.estimation import eskf
        from quad_drake.kernels import eskf as eskf_kernel

        self._predict_tick, self._write_estimate = eskf_kernel.predict_tick, eskf.write_estimate
        self._uncorrelate_accel_bias = eskf.uncorrelate_unobservable_accel_bias
        self._manoeuvre_tick = eskf_kernel.manoeuvre_tick
        self._levels_timing = (PX4_UPDATE_PERIOD, eskf.ACCEL_BIAS_LEARNING_TAU)
        self._bias_learning_tilt = params.accel_bias_learning_tilt if params.estimate_biases else 0.0
        correct = eskf_kernel.correct
        builders = {
            "yaw": lambda m: updates.YawUpdate(
                m, eskf_kernel.mag_tick, eskf.mag_noise(params),
                gating.gate_threshold(NIS_DOF["mag"], _gate(params.mag_gate_sigma, fidelity)),
            ),
            "gps": lambda m: updates.GpsUpdate(
                m, _stacked(eskf.gps_noise, params, each), _gps_gates(params, fidelity), correct,
                sensors.gps_accuracy, _height_restart(params, each, fidelity),
            ),
            "field": lambda m: updates.FieldUpdate(
                m, correct, _mag_field(params, each), _gate(params.mag_field.gate_sigma, fidelity)
            ),
            "baro": lambda m: _baro_update(
                m, correct, params, each, fidelity, lambda p: p.gps_pos_std[2], sensors, each_sensors,
                bias_in_state=True,
            ),
            "no_aid": lambda m: updates.NoAidUpdate(m, correct),
        }  # fmt: skip
        self._n = n
        self._read_imu = row_reader(self.DeclareVectorInputPort("imu", n * IMU_SIZE), n)
        sensor_updates = updates.build_updates(KINDS["eskf"].measurements, sensors, builders)
        gsf = _gsf_update(params, sensors, sensor_updates)
        baro = any(isinstance(u, updates.BaroUpdate) for u in sensor_updates)  # its bias in the state
        noise = eskf.NoiseModel.from_params(params)
        P0 = eskf.initial_covariance(params, baro)
        Q_constant = eskf.noise_buffer(P0.shape[0], noise, ONBOARD_PERIOD)
        self._model = eskf_kernel.model(noise, Q_constant, ONBOARD_PERIOD)

        def initial_nominal(p):
            yaw, pitch, roll = p.init_ypr
            attitude = quat_from_euler_tuple(roll, pitch, yaw)
            x = eskf.initial_nominal(
                p.init_position, p.init_velocity, attitude, p.init_accel_bias, p.init_gyro_bias
            )
            return np.append(x, p.baro.bias_init) if baro else x

        x0 = _stacked(initial_nominal, params, each)
        gravity = _gravity_update(params)
        self._levels = self._bias_learning_tilt > 0.0 or gravity is not None  # peak-held |w_B|, |f_B|
        self._fusion = updates.Fusion(
            self,
            n,
            x0,
            P0,
            ((gsf,) if gsf else ()) + sensor_updates + ((gravity,) if gravity else ()),
            repairs=not fidelity.reference_estimator,
        )
        start = np.broadcast_to(x0, (n, x0.shape[-1]))  # each vehicle's nominal before the first tick
        initial_estimate = np.zeros((n, STATE_SIZE))  # body rate 0 before the first sample
        eskf.write_estimate(start, initial_estimate)
        self._estimate = discrete_group(self, initial_estimate.ravel(), "estimated_state")
        groups = self._fusion.groups
        k = eskf.navigation_size(P0.shape[0])
        if k == P0.shape[0]:
            declare_state_output(self, "covariance", groups.P, n * P0.size)
        else:  # the navigation block: the baro bias is logged in ``diagnostics`` (its estimate, its std)
            declare_block_output(self, "covariance", groups.P, n, P0.shape[0], k)
        declare_state_output(self, "diagnostics", groups.diagnostics, n * DIAGNOSTICS_SIZE)
        self._bias = discrete_group(self, start[:, 10:16].ravel(), "imu_bias")
        if self._levels:  # the peak-held |w_B|, |f_B| (eskf.manoeuvre_levels)
            self._manoeuvre = discrete_group(self, n * eskf.MANOEUVRE_SIZE)
        if gsf is not None:
            declare_state_output(self, "gsf", gsf.log, n * gsf_log_size(params.gsf.models))
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, EKF_OFFSET, self._update)

    def measurement_ports(self) -> tuple:
        """The input ports of the measurement updates, in fusion order."""
        return self._fusion.ports

    def _update(self, context, discrete_state):
        """The prediction compiled, then the health check and every update (``updates.Fusion.fuse``)."""
        seam = self._fusion
        filters = seam.filters(discrete_state)
        estimate = discrete_state.get_mutable_value(self._estimate).reshape(self._n, STATE_SIZE)
        imu = self._read_imu(context)
        healthy = self._predict_tick(filters, imu, estimate, self._model)
        samples = seam.read(context)
        samples["imu"] = imu
        if self._levels:
            manoeuvre = discrete_state.get_mutable_value(self._manoeuvre).reshape(self._n, -1)
            self._manoeuvre_tick(manoeuvre, imu, ONBOARD_PERIOD, *self._levels_timing)  # manoeuvre_levels
            samples["manoeuvre"] = manoeuvre[:, 0:2]  # read by updates.GravityUpdate
        if self._bias_learning_tilt > 0.0:  # PX4's accelerometer-bias inhibition
            self._uncorrelate_accel_bias(filters.x, filters.P, self._bias_learning_tilt, samples["manoeuvre"])
        seam.fuse(context, discrete_state, filters, samples, healthy)
        self._write_estimate(filters.x, estimate)
        discrete_state.get_mutable_value(self._bias)[:] = filters.x[:, 10:16].ravel()


def _gravity_update(params) -> updates.GravityUpdate | None:
    """The ESKF's gravity-vector fusion while not aided (``params.gravity_std``), or None: off."""
    if params.gravity_std <= 0.0:
        return None
    from quad_drake.estimation import eskf
    from quad_drake.kernels import eskf as eskf_kernel

    return updates.GravityUpdate(
        eskf_kernel.gravity_tick,
        eskf.gravity_variance(params.gravity_std, ONBOARD_PERIOD),
        params.gravity_std**2,
        params.gravity_aiding_timeout,
        eskf.GRAVITY_ACCEL_BAND,
        eskf.GRAVITY_GATE,
    )


def _gsf_update(params, sensors, sensor_updates) -> updates.GsfUpdate | None:
    """The ESKF's EKF-GSF yaw estimator (``params.gsf``), fed by the GPS and told of the
    magnetometer update among `sensor_updates`; None when it is off or the vehicle has no GPS."""
    if not params.gsf.enabled or sensors.gps is None:
        return None
    columns = None
    for update in sensor_updates:
        if isinstance(update, (updates.YawUpdate, updates.FieldUpdate)):
            stamp = NIS_COLUMNS[update.measurement.nis][1]
            columns = (stamp, DIAG["mag_gated"])
    return updates.GsfUpdate(MEASUREMENTS["gps"], params.gsf, ONBOARD_PERIOD, params.gps_vel_std[0], columns)


def _reader_or(update, no_sample, n):
    """``read(context) -> (n, width)``: the samples of `update`'s input port, or (no such update:
    the vehicle lacks the sensor) `no_sample` (a row) for each vehicle."""
    if update is not None:
        return update.read
    rows = np.tile(no_sample, (n, 1))
    return lambda context: rows


def _gps_gates(params, fidelity) -> gating.GpsGates:
    """The GPS gates and resets of an estimator's params; none under ``fidelity.reference_estimator``."""
    return gating.GpsGates.from_params(params, enabled=not fidelity.reference_estimator)


def _height_restart(params, each, fidelity) -> np.ndarray:
    """``gps_height_restart`` of the vehicles (one for all, or (n,)); off under
    ``fidelity.reference_estimator`` (no resets)."""
    restart = _stacked(lambda p: p.gps_height_restart, params, each).astype(bool)
    return restart & (not fidelity.reference_estimator)


def _wire_ekf7(builder, ekf_system, attitude_filter, assembler):
    """Connect an EKF7, its complementary filter and its assembler (added to `builder`);
    (input ports by name, output ports by name)."""
    builder.Connect(ekf_system.GetOutputPort("ekf_state"), attitude_filter.GetInputPort("ekf_state"))
    builder.Connect(attitude_filter.GetOutputPort("attitude"), ekf_system.GetInputPort("attitude"))
    builder.Connect(attitude_filter.GetOutputPort("attitude"), assembler.GetInputPort("attitude"))
    builder.Connect(attitude_filter.GetOutputPort("body_rate"), assembler.GetInputPort("body_rate"))
    builder.Connect(ekf_system.GetOutputPort("ekf_state"), assembler.GetInputPort("ekf_state"))
    inputs = {"imu": [ekf_system.GetInputPort("imu"), attitude_filter.GetInputPort("imu")]}
    inputs.update({port: [ekf_system.GetInputPort(port)] for port in ekf_system.measurement_ports()})
    outputs = {
        "estimated_state": assembler.GetOutputPort("estimated_state"),
        "attitude": attitude_filter.GetOutputPort("attitude"),
    }
    for name in ("ekf_state", "covariance", "diagnostics"):
        outputs[name] = ekf_system.GetOutputPort(name)
    return inputs, outputs


def _estimator_diagram(builder, inputs, outputs, estimator):
    """Export `inputs` (name -> ports fed by one exported input) and the outputs the vocabulary
    of `estimator` (an estimator config) lists; the built Diagram, named ``estimator``."""
    for name, ports in inputs.items():
        exported = builder.ExportInput(ports[0], name)
        for port in ports[1:]:
            builder.ConnectInput(exported, port)
    for name in vocabulary_for(estimator).log_widths():
        builder.ExportOutput(outputs[name], name)
    diagram = builder.Build()
    diagram.set_name("estimator")
    return diagram


def _estimators_and_sensors(vehicle) -> tuple:
    """(estimator config, SensorsConfig) of a VehicleConfig, or (tuples of them) of a sequence of
    VehicleConfigs, one per vehicle."""
    if isinstance(vehicle, (list, tuple)):
        return tuple(v.estimator for v in vehicle), tuple(v.sensors for v in vehicle)
    return vehicle.estimator, vehicle.sensors


def add_ekf7(builder, vehicle, fidelity, n) -> tuple[dict, dict]:
    """Add the CF + EKF7 + assembler of n vehicles to `builder` (the ``ekf7`` kind's builder,
    ``estimation/registry.py``; vehicle: a VehicleConfig, or a sequence of n, one per vehicle);
    (input ports by name: ``imu`` and the measurement updates', output ports by name)."""
    estimators, sensors = _estimators_and_sensors(vehicle)  # Ekf7EstimatorConfig(s)
    params, each = _per_vehicle(estimators, n)
    tilt = ekf.TiltNoise.from_params(params, params.attitude_filter, ONBOARD_PERIOD)
    ekf_system = builder.AddNamedSystem("ekf", Ekf(estimators, fidelity, tilt, n=n, sensors=sensors))
    attitude_filter = builder.AddNamedSystem(
        "attitude_filter",
        ComplementaryFilter(
            params.attitude_filter,
            initial_attitude=_stacked(lambda p: (0.0, 0.0, p.init_state[6]), params, each),
            fidelity=fidelity,
            n=n,
        ),
    )
    assembler = builder.AddNamedSystem("estimated_state", EstimatedStateAssembler(n))
    return _wire_ekf7(builder, ekf_system, attitude_filter, assembler)


def add_eskf(builder, vehicle, fidelity, n) -> tuple[dict, dict]:
    """Add the ESKF of n vehicles to `builder` (the ``eskf`` kind's builder; vehicle as
    :func:`add_ekf7`'s); (input ports by name: ``imu`` and the measurement updates', output ports
    by name)."""
    estimators, sensors = _estimators_and_sensors(vehicle)
    system = builder.AddNamedSystem("eskf", Eskf(estimators, fidelity, n=n, sensors=sensors))
    inputs = {port: [system.GetInputPort(port)] for port in ("imu",) + system.measurement_ports()}
    names = ("estimated_state", "covariance", "diagnostics", "imu_bias")
    names += ("gsf",) if system.HasOutputPort("gsf") else ()
    return inputs, {name: system.GetOutputPort(name) for name in names}


def build_estimator(vehicle, fidelity=PHYSICAL, n=1) -> Diagram:
    """The estimator sub-Diagram of n vehicles flying one VehicleConfig (``estimator.kind``),
    named ``estimator``; or of a sequence of VehicleConfigs, one per vehicle (n = their number),
    that may differ only in what their kind takes per vehicle (``registry.sharing_problem``;
    ValueError with its reason otherwise): n replayed flight logs, each with its own settings.

    fidelity: the scenario's Fidelity (the EKF7 follows the reference's accelerometer reading;
    whether a kind runs under it is checked when the scenario loads,
    ``EstimatorKind.fidelity_problem``). Inputs ``imu`` (n*6) and one per measurement the
    estimator fuses of the vehicle's sensors (``estimation.measurements.measurements_of``:
    ``gps`` n*7, ``mag`` n*2 or n*4, ``baro`` n*2), exported; outputs as
    ``vocabulary_for(vehicle.estimator).log_widths()``, each n times as wide, vehicle-major.
    """
    if isinstance(vehicle, (list, tuple)):
        problem = sharing_problem(vehicle) if vehicle else "no vehicles"
        if problem:
            raise ValueError(f"these vehicles cannot share one estimator: {problem}")
        n = len(vehicle)
        vehicle = vehicle[0] if all(v == vehicle[0] for v in vehicle) else tuple(vehicle)
    if n < 1:
        raise ValueError(f"an estimator needs at least one vehicle, got n = {n}")
    first = vehicle[0] if isinstance(vehicle, tuple) else vehicle
    kind = kind_of(first.estimator)
    if kind.builder is None:
        raise ValueError(f"estimator kind {kind.name!r} runs no estimator")
    builder = DiagramBuilder()
    inputs, outputs = kind.build_function()(builder, vehicle, fidelity, n)
    return _estimator_diagram(builder, inputs, outputs, first.estimator)
