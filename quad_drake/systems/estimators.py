"""Estimator LeafSystems and the estimator sub-Diagrams a vehicle's config chooses.

Every system here is sized by n vehicles (default 1, a single run; a fleet flies n runs of one
VehicleConfig at once): its ports carry the n per-vehicle vectors vehicle-major (vehicle i at
[i k, (i + 1) k)), and a single run and a fleet execute the same code: the compiled kernels over
(n, ...) views of the ports and discrete state, ``kernels/attitude.py``, ``kernels/ekf7.py`` and
``kernels/eskf.py`` (each estimator's equations in its module docstring), with
``kernels/fusion.py`` for what they share.

Every estimator is a sub-Diagram (:func:`build_estimator`) with inputs ``imu``, ``gps``,
``mag`` and the outputs its vocabulary lists (``estimation/vocabulary.py``):
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

import math

import numpy as np
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from quad_drake.config.errors import ConfigError
from quad_drake.conventions import (
    ATTITUDE_FILTER_OFFSET,
    ATTITUDE_SIZE,
    EKF_OFFSET,
    EKF_STATE_SIZE,
    GPS_SIZE,
    IMU_SIZE,
    NO_SAMPLE_STAMP,
    ONBOARD_PERIOD,
    STATE_SIZE,
)
from quad_drake.estimation import ekf, eskf, gating
from quad_drake.estimation.complementary import VARIANTS
from quad_drake.estimation.registry import kind_of, vocabulary_for
from quad_drake.estimation.vocabulary import DIAG, DIAGNOSTICS_SIZE, NIS_DOF
from quad_drake.kernels import aiding as aiding_kernels
from quad_drake.kernels import attitude as attitude_kernel
from quad_drake.kernels import ekf7 as ekf7_kernel
from quad_drake.kernels import eskf as eskf_kernel
from quad_drake.kernels import fusion
from quad_drake.kernels.imu_hold import HOLD_SIZE, initial_hold
from quad_drake.models.fidelity import PHYSICAL
from quad_drake.models.rotations import quat_from_euler_tuple
from quad_drake.systems._io import declare_state_output, row_reader
from quad_drake.systems.aiding import NO_AIDING, AidedFusion, aiding_sensors, mag_size


def initial_diagnostics():
    """One vehicle's ``diagnostics`` before its first update: no NIS (NaN), no stamps, counters 0."""
    values = np.zeros(DIAGNOSTICS_SIZE)
    values[[DIAG["gps_nis"], DIAG["mag_nis"]]] = math.nan
    values[[DIAG["gps_stamp"], DIAG["mag_stamp"]]] = NO_SAMPLE_STAMP
    values[[DIAG["baro_nis"], DIAG["field_nis"], DIAG["baro_bias"], DIAG["baro_bias_std"]]] = math.nan
    values[[DIAG["baro_stamp"], DIAG["field_stamp"]]] = NO_SAMPLE_STAMP
    return values


class GatedFusion:
    """Shared update logic of the estimators, for n vehicles (n = 1 for a single run): freshness,
    gates, GPS resets and covariance health, on (n, ...) views of the discrete state.

    Discrete state groups: x (0), P (1), diagnostics (DIAGNOSTICS_GROUP), book (BOOK_GROUP,
    ``fusion.BOOK_SIZE`` per vehicle), and the IMU hold (``self._hold``). :meth:`_fuse_fresh` runs
    the per-tick sequence after the prediction: the covariance health check, then the fresh
    magnetometer and GPS samples.
    """

    DIAGNOSTICS_GROUP, BOOK_GROUP = 2, 3

    def _declare_gating(self, params, P0, noises, fidelity):
        """Gates and resets from params (``gps_gate_sigma``, ``mag_gate_sigma``, the GPS reset
        and regain times: ``gating.GpsGates``), the fallback covariance P0 and noises = (R_mag,
        R_gps). ``fidelity.reference_estimator`` switches gates, resets and repairs off."""
        safety = not fidelity.reference_estimator
        self._gates = gating.GpsGates.from_params(params, enabled=safety)
        self._mag_threshold = gating.gate_threshold(NIS_DOF["mag"], params.mag_gate_sigma if safety else 0.0)
        self._repairs = safety
        self._P0 = P0
        self._R_mag, self._R_gps = noises

    def _declare_fusion_state(self, n, x0, P0):
        """Declare x, P, diagnostics and the book of n vehicles (groups 0-3); their indices."""
        self._n, self._k = n, P0.shape[0]
        x = self.DeclareDiscreteState(np.tile(np.asarray(x0, dtype=float), n))
        P = self.DeclareDiscreteState(np.tile(P0.ravel(), n))
        diagnostics = self.DeclareDiscreteState(np.tile(initial_diagnostics(), n))
        self.DeclareDiscreteState(np.tile(fusion.initial_book(), n))
        return x, P, diagnostics

    def _views(self, discrete_state, width):
        """The ``fusion.Filters``: writable (n, ...) views of x, P, diagnostics, the book and the hold."""
        n, k = self._n, self._k
        return fusion.Filters(
            x=discrete_state.get_mutable_value(0).reshape(n, width),
            P=discrete_state.get_mutable_value(1).reshape(n, k, k),
            diagnostics=discrete_state.get_mutable_value(self.DIAGNOSTICS_GROUP).reshape(n, DIAGNOSTICS_SIZE),
            book=discrete_state.get_mutable_value(self.BOOK_GROUP).reshape(n, fusion.BOOK_SIZE),
            hold=discrete_state.get_mutable_value(self._hold).reshape(n, HOLD_SIZE),
        )

    def _fuse_fresh(self, filters, gps, mag, healthy, kernel):
        """Repair P where the per-tick check (``healthy`` (n,)) or, at a fresh GPS sample, the full
        check finds it unhealthy (counted); then fuse the fresh mag (n, 2) and GPS (n, 7) samples
        through the gates with the estimator's `kernel` module (its ``mag_tick``, ``gps_update``).
        In place on the ``fusion.Filters`` `filters`."""
        gps_fresh = fusion.fresh(gps[:, 6], filters.book[:, fusion.GPS_SLOT])
        check = gps_fresh | ~healthy
        if self._repairs and check.any():
            outcomes = fusion.repair_covariances(filters.P, check, self._P0)
            filters.diagnostics[outcomes != gating.COVARIANCE_OK, DIAG["covariance_repairs"]] += 1.0
        kernel.mag_tick(filters, mag, self._R_mag, self._mag_threshold)
        if gps_fresh.any():
            rows = slice(None) if gps_fresh.all() else np.flatnonzero(gps_fresh)
            fusion.fuse_gps(filters, gps, rows, kernel.gps_update, self._R_gps, self._gates)


def _tiled(vector, n):
    return np.tile(np.asarray(vector, dtype=float), n)


class ComplementaryFilter(LeafSystem):
    """n complementary roll/pitch filters with gyro-integrated yaw (SPEC §4 UpdateFromIMU).

    Every port carries the n vehicles' vectors vehicle-major (vehicle i at [i k, (i + 1) k)).
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
        attitude = self.DeclareDiscreteState(_tiled(initial_attitude, n))
        rate = self.DeclareDiscreteState(n * 3)
        self.DeclareDiscreteState(_tiled(initial_hold(), n))
        declare_state_output(self, "attitude", attitude, n * ATTITUDE_SIZE)
        declare_state_output(self, "body_rate", rate, n * 3)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, ATTITUDE_FILTER_OFFSET, self._update)

    def _update(self, context, discrete_state):
        n = self._n
        attitude, rate = discrete_state.get_mutable_value(0), discrete_state.get_mutable_value(1)
        attitude_kernel.tick(
            attitude_kernel.Filters(
                attitude=attitude.reshape(n, ATTITUDE_SIZE),
                rate=rate.reshape(n, 3),
                hold=discrete_state.get_mutable_value(2).reshape(n, HOLD_SIZE),
            ),
            attitude_kernel.Samples(imu=self._read_imu(context), ekf_state=self._read_ekf_state(context)),
            self._model,
        )
        if self._float32:
            attitude_kernel.round_to_float32(attitude, rate)


class Ekf(AidedFusion, GatedFusion, LeafSystem):
    """n 7-state EKFs (SPEC §4): x = (p_N m, v_N m/s, yaw rad), NED; roll/pitch from the attitude filter.

    Ports vehicle-major as :class:`ComplementaryFilter`'s. Inputs: ``imu`` (n*6: f_B m/s^2,
    w_NB_B rad/s), ``gps`` (n*7: p_N m, v_N m/s, stamp s), ``mag`` (n*2: yaw rad, stamp s),
    ``attitude`` (n*3: roll, pitch, yaw rad, this tick's filter output). A sensor the vehicle
    lacks must be wired to a constant with stamp NO_SAMPLE_STAMP. Outputs (state ports):
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

    With ``aiding`` (``systems.aiding.AidingSensors``; none by default): a barometer adds the input
    ``baro`` (n*2: height m up, stamp s), a 3-axis magnetometer makes ``mag`` n*4 (m_B gauss FRD,
    stamp s); after the GPS each tick the tilt-compensated heading and the baro height are fused
    through their gates (``systems.aiding.AidedFusion``, ``kernels/aiding.py``).
    """

    def __init__(self, params, fidelity=PHYSICAL, tilt=None, n=1, aiding=NO_AIDING):
        super().__init__()
        self._float32 = fidelity.float32_estimator
        self._tilt = tilt
        P0 = ekf.initial_covariance(params)
        self._declare_gating(params, P0, (ekf.mag_noise(params), ekf.gps_noise(params)), fidelity)
        self._model = ekf7_kernel.Model(
            dt=ONBOARD_PERIOD,
            Q=ekf.process_noise(params),
            gravity_z=ekf.gravity_z(fidelity.reference_accelerometer),
            r_mag=float(self._R_mag[0, 0]),
            mag_threshold=float(self._mag_threshold),
        )
        self._read_imu = row_reader(self.DeclareVectorInputPort("imu", n * IMU_SIZE), n)
        self._read_gps = row_reader(self.DeclareVectorInputPort("gps", n * GPS_SIZE), n)
        self._read_mag = row_reader(self.DeclareVectorInputPort("mag", n * mag_size(aiding)), n)
        self._read_attitude = row_reader(self.DeclareVectorInputPort("attitude", n * ATTITUDE_SIZE), n)
        x, P, diagnostics = self._declare_fusion_state(n, ekf.initial_state(params), P0)
        self._declare_aiding(n, params, aiding, fidelity, params.gps_pos_z_std, tilt)
        self._hold = self.DeclareDiscreteState(_tiled(initial_hold(), n))
        self._healthy = np.empty(n, dtype=bool)  # scratch of each tick's health check
        declare_state_output(self, "ekf_state", x, n * EKF_STATE_SIZE)
        declare_state_output(self, "covariance", P, n * EKF_STATE_SIZE**2)
        declare_state_output(self, "diagnostics", diagnostics, n * DIAGNOSTICS_SIZE)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, EKF_OFFSET, self._update)

    def _estimates_heading(self):
        return True  # the tilt-compensated heading: the EKF7 has no roll/pitch states

    def _apply_corrections(self, x, P, dx, fused):
        aiding_kernels.add_corrections(x, dx, fused, ekf.YAW_INDEX)

    def _update(self, context, discrete_state):
        """The prediction and, on a quiet tick, the mag fusion (one compiled call); at a fresh GPS
        sample or an unhealthy P, the health check and the fusions of :meth:`_fuse_fresh`."""
        filters = self._views(discrete_state, EKF_STATE_SIZE)
        mag_samples = self._read_mag(context)
        samples = ekf7_kernel.Samples(
            attitude=self._read_attitude(context),
            imu=self._read_imu(context),
            gps=self._read_gps(context),
            mag=self._yaw_samples(mag_samples),
        )
        tilt_gains = ekf7_kernel.NO_TILT if self._tilt is None else self._tilt.gains(context.get_time())
        quiet = ekf7_kernel.tick(filters, samples, self._model, tilt_gains, self._healthy)
        if not quiet:  # a fresh GPS sample or an unhealthy P somewhere: the full step
            self._fuse_fresh(filters, samples.gps, samples.mag, self._healthy, ekf7_kernel)
        self._fuse_aiding(context, discrete_state, filters, samples.gps, mag_samples, samples.attitude)
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


class Eskf(AidedFusion, GatedFusion, LeafSystem):
    """n error-state EKFs (``estimation/eskf.py``) on the IMU, GPS and magnetometer.

    Ports vehicle-major as :class:`ComplementaryFilter`'s. Inputs: ``imu`` (n*6: f_B m/s^2,
    w_NB_B rad/s), ``gps`` (n*7: p_N m, v_N m/s, stamp s), ``mag`` (n*2: yaw rad, stamp s); a
    missing sensor is wired to a constant with stamp NO_SAMPLE_STAMP. Outputs (state ports):
    ``estimated_state`` (n*13: p, q_NB, v, body rate = gyro - gyro bias, NaN while the IMU is
    out), ``covariance`` (n*k*k, k = 15 with bias estimation, 9 without; error state dp, dv,
    dtheta[, db_a, db_g]), ``diagnostics`` (n*``vocabulary.DIAGNOSTICS``), ``imu_bias`` (n*6: b_a
    m/s^2, b_g rad/s).

    Each tick (ONBOARD_PERIOD, offset EKF_OFFSET; ``kernels/eskf.py``, whose module docstring
    carries the equations): predict with the IMU sample (over a non-finite one, counted, with the
    running mean of the IMU: ``kernels.eskf.predict_tick``), then fuse a fresh mag and a fresh GPS
    sample through the gates and resets of :class:`Ekf`; P is checked as there. With ``aiding``
    (as :class:`Ekf`'s) the 3-axis field vector and the baro height are fused after the GPS.
    """

    ESTIMATE_GROUP, BIAS_GROUP = 4, 5

    def __init__(self, params, fidelity=PHYSICAL, n=1, aiding=NO_AIDING):
        super().__init__()
        noise = eskf.NoiseModel.from_params(params)
        P0 = eskf.initial_covariance(params)
        Q_constant = eskf.noise_buffer(P0.shape[0], noise, ONBOARD_PERIOD)
        self._model = eskf_kernel.model(noise, Q_constant, ONBOARD_PERIOD)
        yaw, pitch, roll = params.init_ypr
        x0 = eskf.initial_nominal(
            params.init_position, params.init_velocity, quat_from_euler_tuple(roll, pitch, yaw)
        )
        self._declare_gating(params, P0, (eskf.mag_noise(params), eskf.gps_noise(params)), fidelity)
        self._read_imu = row_reader(self.DeclareVectorInputPort("imu", n * IMU_SIZE), n)
        self._read_gps = row_reader(self.DeclareVectorInputPort("gps", n * GPS_SIZE), n)
        self._read_mag = row_reader(self.DeclareVectorInputPort("mag", n * mag_size(aiding)), n)
        _, P, diagnostics = self._declare_fusion_state(n, x0, P0)
        initial_estimate = np.zeros(STATE_SIZE)  # body rate 0 before the first sample
        eskf.write_estimate(x0, initial_estimate)
        estimate = self.DeclareDiscreteState(_tiled(initial_estimate, n))
        bias = self.DeclareDiscreteState(n * 6)
        self._hold = self.DeclareDiscreteState(_tiled(initial_hold(), n))
        declare_state_output(self, "estimated_state", estimate, n * STATE_SIZE)
        declare_state_output(self, "covariance", P, n * P0.size)
        declare_state_output(self, "diagnostics", diagnostics, n * DIAGNOSTICS_SIZE)
        declare_state_output(self, "imu_bias", bias, n * 6)
        self._declare_aiding(n, params, aiding, fidelity, params.gps_pos_std[2])
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, EKF_OFFSET, self._update)

    def _estimates_heading(self):
        return False  # the field vector, against the error state's attitude

    def _apply_corrections(self, x, P, dx, fused):
        rows = np.flatnonzero(fused)
        x[rows], P[rows] = eskf_kernel.inject(x[rows], P[rows], dx[rows])

    def _update(self, context, discrete_state):
        """The prediction compiled, then the health check and the fusions of :meth:`_fuse_fresh`."""
        filters = self._views(discrete_state, eskf.NOMINAL_SIZE)
        estimate = discrete_state.get_mutable_value(self.ESTIMATE_GROUP).reshape(self._n, STATE_SIZE)
        healthy = eskf_kernel.predict_tick(filters, self._read_imu(context), estimate, self._model)
        gps, mag = self._read_gps(context), self._read_mag(context)
        self._fuse_fresh(filters, gps, self._yaw_samples(mag), healthy, eskf_kernel)
        self._fuse_aiding(context, discrete_state, filters, gps, mag)
        eskf.write_estimate(filters.x, estimate)
        discrete_state.get_mutable_value(self.BIAS_GROUP)[:] = filters.x[:, 10:16].ravel()


def _wire_ekf7(builder, ekf_system, attitude_filter, assembler):
    """Connect an EKF7, its complementary filter and its assembler (added to `builder`);
    (input ports by name, output ports by name)."""
    builder.Connect(ekf_system.GetOutputPort("ekf_state"), attitude_filter.GetInputPort("ekf_state"))
    builder.Connect(attitude_filter.GetOutputPort("attitude"), ekf_system.GetInputPort("attitude"))
    builder.Connect(attitude_filter.GetOutputPort("attitude"), assembler.GetInputPort("attitude"))
    builder.Connect(attitude_filter.GetOutputPort("body_rate"), assembler.GetInputPort("body_rate"))
    builder.Connect(ekf_system.GetOutputPort("ekf_state"), assembler.GetInputPort("ekf_state"))
    inputs = {
        "imu": [ekf_system.GetInputPort("imu"), attitude_filter.GetInputPort("imu")],
        "gps": [ekf_system.GetInputPort("gps")],
        "mag": [ekf_system.GetInputPort("mag")],
    }
    outputs = {
        "estimated_state": assembler.GetOutputPort("estimated_state"),
        "attitude": attitude_filter.GetOutputPort("attitude"),
    }
    for name in ("ekf_state", "covariance", "diagnostics"):
        outputs[name] = ekf_system.GetOutputPort(name)
    return inputs, outputs


def _wire_eskf(system):
    """(input ports by name, output ports by name) of an ESKF system."""
    inputs = {name: [system.GetInputPort(name)] for name in ("imu", "gps", "mag")}
    names = ("estimated_state", "covariance", "diagnostics", "imu_bias")
    return inputs, {name: system.GetOutputPort(name) for name in names}


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


def add_ekf7(builder, vehicle, fidelity, n):
    """Add the CF + EKF7 + assembler of n vehicles to `builder` (the ``ekf7`` kind's builder,
    ``estimation/registry.py``); (input ports by name, output ports by name)."""
    tilt = ekf.TiltNoise.from_params(vehicle.ekf, vehicle.attitude_filter, ONBOARD_PERIOD)
    aiding = aiding_sensors(vehicle)
    ekf_system = builder.AddNamedSystem("ekf", Ekf(vehicle.ekf, fidelity, tilt, n=n, aiding=aiding))
    attitude_filter = builder.AddNamedSystem(
        "attitude_filter",
        ComplementaryFilter(
            vehicle.attitude_filter,
            initial_attitude=(0.0, 0.0, vehicle.ekf.init_state[6]),
            fidelity=fidelity,
            n=n,
        ),
    )
    assembler = builder.AddNamedSystem("estimated_state", EstimatedStateAssembler(n))
    inputs, outputs = _wire_ekf7(builder, ekf_system, attitude_filter, assembler)
    if aiding.baro_period is not None:
        inputs["baro"] = [ekf_system.GetInputPort("baro")]
    return inputs, outputs


def add_eskf(builder, vehicle, fidelity, n):
    """Add the ESKF of n vehicles to `builder` (the ``eskf`` kind's builder); (input ports by
    name, output ports by name)."""
    aiding = aiding_sensors(vehicle)
    system = builder.AddNamedSystem("eskf", Eskf(vehicle.estimator, fidelity, n=n, aiding=aiding))
    inputs, outputs = _wire_eskf(system)
    if aiding.baro_period is not None:
        inputs["baro"] = [system.GetInputPort("baro")]
    return inputs, outputs


def build_estimator(vehicle, fidelity=PHYSICAL, n=1):
    """The estimator sub-Diagram of n vehicles flying one VehicleConfig (``estimator.kind``),
    named ``estimator``.

    fidelity: the scenario's Fidelity (the EKF7 follows the reference's accelerometer reading;
    the ESKF supports the physical one only). Inputs ``imu`` (n*6), ``gps`` (n*7), ``mag``
    (n*2), exported (connect a never-sampled constant for a missing sensor); outputs as
    ``vocabulary_for(vehicle.estimator).log_widths()``, each n times as wide, vehicle-major.
    """
    if n < 1:
        raise ValueError(f"an estimator needs at least one vehicle, got n = {n}")
    kind = kind_of(vehicle.estimator)
    if kind.builder is None:
        raise ValueError(f"estimator kind {kind.name!r} runs no estimator")
    problem = kind.fidelity_problem(fidelity)
    if problem:
        raise ConfigError(problem)
    builder = DiagramBuilder()
    inputs, outputs = kind.build_function()(builder, vehicle, fidelity, n)
    return _estimator_diagram(builder, inputs, outputs, vehicle.estimator)
