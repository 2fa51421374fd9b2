"""Fleet estimator LeafSystems: N vehicles' estimators advanced at once, the sub-Diagram a
vehicle's config chooses (:func:`build_fleet_estimator`), and the estimator side of a GPS delay
(:class:`FleetGpsDelayCompensator`, the fleet form of ``systems.faults.GpsDelayCompensator``).

Each system mirrors its per-vehicle twin in ``systems/estimators.py``: the same ports, periods,
within-tick offsets, freshness rule, gates, resets, covariance health, diagnostics and counters,
and the dead reckoning over non-finite IMU samples. Every vector port carries the N per-vehicle
vectors vehicle-major (size N k, vehicle i at [i k, (i + 1) k)), each in the scalar system's
layout. The maths is ``fleet/estimation_kernels.py``, the scalar functions' array
form; the handlers only reshape the ports and the discrete state (updated in place) and pick the
vehicles each step applies to. All N vehicles share one VehicleConfig.
"""

import numpy as np
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from quad_drake import delay_compensation
from quad_drake.conventions import (
    ATTITUDE_FILTER_OFFSET,
    ATTITUDE_SIZE,
    EKF_OFFSET,
    EKF_STATE_SIZE,
    FAULT_LAG,
    GPS_SIZE,
    IMU_SIZE,
    MAG_SIZE,
    NO_SAMPLE_STAMP,
    ONBOARD_PERIOD,
    P_SLICE,
    STATE_SIZE,
    V_SLICE,
)
from quad_drake.estimation import ekf, eskf
from quad_drake.estimation.complementary import VARIANTS
from quad_drake.estimation.vocabulary import DIAGNOSTICS_SIZE
from quad_drake.fidelity import PHYSICAL
from quad_drake.fleet import estimation_kernels as kernels
from quad_drake.fleet.systems import declare_state_output
from quad_drake.rotations import quat_from_euler_tuple
from quad_drake.systems.estimators import (
    GatedFusion,
    check_eskf_fidelity,
    estimator_diagram,
    wire_ekf7,
    wire_eskf,
)


def _reader(port):
    """``read(context)``: the value of the vector input `port` as a read-only numpy view (no copy)."""
    evaluate = port.EvalBasicVector
    return lambda context: evaluate(context).get_value()


def _tiled(vector, n):
    return np.tile(np.asarray(vector, dtype=float), n)


class FleetComplementaryFilter(LeafSystem):
    """N complementary attitude filters (``systems.estimators.ComplementaryFilter`` per vehicle).

    Inputs: ``imu`` (N*6), ``ekf_state`` (N*7). Outputs (state ports): ``attitude`` (N*3: roll,
    pitch, yaw rad), ``body_rate`` (N*3: each vehicle's last finite gyro sample, rad/s). Ticks
    every ONBOARD_PERIOD at ATTITUDE_FILTER_OFFSET; a vehicle's non-finite IMU sample is skipped
    (roll, pitch and body rate held, yaw = its EKF's posterior yaw).
    """

    def __init__(self, params, n, initial_attitude=(0.0, 0.0, 0.0), fidelity=PHYSICAL):
        super().__init__()
        if params.variant not in VARIANTS:
            raise ValueError(f"attitude filter variant {params.variant!r} is not one of {VARIANTS}")
        self._n = n
        self._tau = float(params.tau)
        self._variant = params.variant
        self._reference_accelerometer = fidelity.reference_accelerometer
        self._float32 = fidelity.float32_estimator
        self._read_imu = _reader(self.DeclareVectorInputPort("imu", n * IMU_SIZE))
        self._read_ekf_state = _reader(self.DeclareVectorInputPort("ekf_state", n * EKF_STATE_SIZE))
        attitude = self.DeclareDiscreteState(_tiled(initial_attitude, n))
        rate = self.DeclareDiscreteState(n * 3)
        self.DeclareDiscreteState(_tiled(kernels.initial_hold(), n))
        declare_state_output(self, "attitude", attitude, n * ATTITUDE_SIZE)
        declare_state_output(self, "body_rate", rate, n * 3)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, ATTITUDE_FILTER_OFFSET, self._update)

    def _update(self, context, discrete_state):
        n = self._n
        attitude, rate = discrete_state.get_mutable_value(0), discrete_state.get_mutable_value(1)
        kernels.complementary_tick(
            attitude.reshape(n, ATTITUDE_SIZE),
            rate.reshape(n, 3),
            discrete_state.get_mutable_value(2).reshape(n, kernels.HOLD_SIZE),
            self._read_imu(context).reshape(n, IMU_SIZE),
            self._read_ekf_state(context).reshape(n, EKF_STATE_SIZE),
            ONBOARD_PERIOD,
            self._tau,
            self._variant,
            self._reference_accelerometer,
        )
        if self._float32:
            kernels.round_to_float32(attitude, rate)


class FleetEkf(GatedFusion, LeafSystem):
    """N 7-state EKFs (``systems.estimators.Ekf`` per vehicle; same tick, gates, resets and health).

    Inputs: ``imu`` (N*6), ``gps`` (N*7), ``mag`` (N*2), ``attitude`` (N*3). Outputs (state ports):
    ``ekf_state`` (N*7), ``covariance`` (N*49, each P row-major), ``diagnostics``
    (N*DIAGNOSTICS_SIZE).
    """

    def __init__(self, params, n, fidelity=PHYSICAL, tilt=None):
        super().__init__()
        self._gravity_z = kernels.gravity_z(fidelity.reference_accelerometer)
        self._float32 = fidelity.float32_estimator
        self._Q = ekf.process_noise(params)
        self._tilt = tilt
        P0 = ekf.initial_covariance(params)
        self._declare_gating(params, P0, (ekf.mag_noise(params), ekf.gps_noise(params)), fidelity)
        self._read_imu = _reader(self.DeclareVectorInputPort("imu", n * IMU_SIZE))
        self._read_gps = _reader(self.DeclareVectorInputPort("gps", n * GPS_SIZE))
        self._read_mag = _reader(self.DeclareVectorInputPort("mag", n * MAG_SIZE))
        self._read_attitude = _reader(self.DeclareVectorInputPort("attitude", n * ATTITUDE_SIZE))
        x, P, diagnostics = self._declare_fusion_state(n, ekf.initial_state(params), P0)
        self._hold = self.DeclareDiscreteState(_tiled(kernels.initial_hold(), n))
        self._healthy = np.empty(n, dtype=bool)  # scratch of each tick's health check
        declare_state_output(self, "ekf_state", x, n * EKF_STATE_SIZE)
        declare_state_output(self, "covariance", P, n * EKF_STATE_SIZE**2)
        declare_state_output(self, "diagnostics", diagnostics, n * DIAGNOSTICS_SIZE)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, EKF_OFFSET, self._update)

    def _update(self, context, discrete_state):
        n = self._n
        x, P, diagnostics, book = self._views(discrete_state, EKF_STATE_SIZE)
        gps = self._read_gps(context).reshape(n, GPS_SIZE)
        mag = self._read_mag(context).reshape(n, MAG_SIZE)
        quiet = kernels.ekf7_tick(
            x,
            P,
            discrete_state.get_mutable_value(self._hold).reshape(n, kernels.HOLD_SIZE),
            self._read_attitude(context).reshape(n, ATTITUDE_SIZE),
            self._read_imu(context).reshape(n, IMU_SIZE),
            gps,
            mag,
            diagnostics,
            book,
            ONBOARD_PERIOD,
            self._Q,
            kernels.NO_TILT if self._tilt is None else self._tilt.gains(context.get_time()),
            self._gravity_z,
            self._R_mag[0, 0],
            self._mag_threshold,
            self._healthy,
        )
        if not quiet:  # a fresh GPS sample or an unhealthy P somewhere: the full step
            self._fuse_fresh(
                x,
                P,
                diagnostics,
                book,
                gps,
                mag,
                self._healthy,
                kernels.ekf7_gps_update,
                kernels.ekf7_mag_tick,
            )
        if self._float32:
            kernels.round_to_float32(x, P)


class FleetEstimatedStateAssembler(LeafSystem):
    """N EKF7 estimates in the true ``state`` layout (``systems.estimators.EstimatedStateAssembler``).

    Inputs: ``attitude`` (N*3), ``ekf_state`` (N*7), ``body_rate`` (N*3). Output:
    ``estimated_state`` (N*13: p, q_NB(roll, pitch, ekf yaw) wxyz, v, body rate); feedthrough.
    """

    def __init__(self, n):
        super().__init__()
        self._n = n
        self._read_attitude = _reader(self.DeclareVectorInputPort("attitude", n * ATTITUDE_SIZE))
        self._read_ekf_state = _reader(self.DeclareVectorInputPort("ekf_state", n * EKF_STATE_SIZE))
        self._read_rate = _reader(self.DeclareVectorInputPort("body_rate", n * 3))
        self.DeclareVectorOutputPort(
            "estimated_state",
            n * STATE_SIZE,
            self._calc,
            prerequisites_of_calc={self.all_input_ports_ticket()},
        )

    def _calc(self, context, output):
        n = self._n
        attitude = self._read_attitude(context).reshape(n, ATTITUDE_SIZE)
        x = self._read_ekf_state(context).reshape(n, EKF_STATE_SIZE)
        rate = self._read_rate(context).reshape(n, 3)
        kernels.ekf7_estimated_state(attitude, x, rate, out=output.get_mutable_value().reshape(n, STATE_SIZE))


class FleetEskf(GatedFusion, LeafSystem):
    """N error-state EKFs (``systems.estimators.Eskf`` per vehicle; same tick, gates, resets, health).

    Inputs: ``imu`` (N*6), ``gps`` (N*7), ``mag`` (N*2). Outputs (state ports): ``estimated_state``
    (N*13: p, q_NB, v, gyro - gyro bias of the last finite sample), ``covariance`` (N*k*k, k = 15
    with bias estimation, 9 without), ``diagnostics`` (N*DIAGNOSTICS_SIZE), ``imu_bias`` (N*6).
    """

    ESTIMATE_GROUP, BIAS_GROUP = 4, 5

    def __init__(self, params, n, fidelity=PHYSICAL):
        super().__init__()
        self._noise = eskf.NoiseModel.from_params(params)
        P0 = eskf.initial_covariance(params)
        self._Q_constant = eskf.noise_buffer(P0.shape[0], self._noise, ONBOARD_PERIOD)
        yaw, pitch, roll = params.init_ypr
        x0 = eskf.initial_nominal(
            params.init_position, params.init_velocity, quat_from_euler_tuple(roll, pitch, yaw)
        )
        self._declare_gating(params, P0, (eskf.mag_noise(params), eskf.gps_noise(params)), fidelity)
        self._read_imu = _reader(self.DeclareVectorInputPort("imu", n * IMU_SIZE))
        self._read_gps = _reader(self.DeclareVectorInputPort("gps", n * GPS_SIZE))
        self._read_mag = _reader(self.DeclareVectorInputPort("mag", n * MAG_SIZE))
        _, P, diagnostics = self._declare_fusion_state(n, x0, P0)
        initial_estimate = np.zeros(STATE_SIZE)  # body rate 0 before the first sample
        eskf.write_estimate(x0, initial_estimate)
        estimate = self.DeclareDiscreteState(_tiled(initial_estimate, n))
        bias = self.DeclareDiscreteState(n * 6)
        self._hold = self.DeclareDiscreteState(_tiled(kernels.initial_hold(), n))
        declare_state_output(self, "estimated_state", estimate, n * STATE_SIZE)
        declare_state_output(self, "covariance", P, n * P0.size)
        declare_state_output(self, "diagnostics", diagnostics, n * DIAGNOSTICS_SIZE)
        declare_state_output(self, "imu_bias", bias, n * 6)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, EKF_OFFSET, self._update)

    def _update(self, context, discrete_state):
        n = self._n
        imu = self._read_imu(context).reshape(n, IMU_SIZE)
        x, P, diagnostics, book = self._views(discrete_state, eskf.NOMINAL_SIZE)
        estimate = discrete_state.get_mutable_value(self.ESTIMATE_GROUP).reshape(n, STATE_SIZE)
        hold = discrete_state.get_mutable_value(self._hold).reshape(n, kernels.HOLD_SIZE)
        healthy = kernels.eskf_predict_tick(
            x, P, hold, imu, estimate, diagnostics, ONBOARD_PERIOD, self._noise, self._Q_constant
        )
        self._fuse_fresh(
            x,
            P,
            diagnostics,
            book,
            self._read_gps(context).reshape(n, GPS_SIZE),
            self._read_mag(context).reshape(n, MAG_SIZE),
            healthy,
            kernels.eskf_gps_update,
            kernels.eskf_mag_tick,
        )
        eskf.write_estimate(x, estimate)
        discrete_state.get_mutable_value(self.BIAS_GROUP)[:] = x[:, 10:16].ravel()


class FleetGpsDelayCompensator(LeafSystem):
    """N vehicles' late GPS samples moved to the present (``systems.faults.GpsDelayCompensator`` per vehicle).

    Inputs ``gps`` (N*7) and ``estimated_state`` (N*13); output ``gps`` (N*7, feedthrough): each
    sample with p and v shifted by its vehicle's odometry since its stamp, stamp kept. Books every
    ONBOARD_PERIOD at EKF_OFFSET + FAULT_LAG into a ring of ``history_capacity(max_lag)`` rows per
    vehicle. A sample without a stamp, or with a non-finite one, passes unchanged.
    """

    def __init__(self, max_lag, n):
        super().__init__()
        self._n = n
        self._capacity = delay_compensation.history_capacity(max_lag, ONBOARD_PERIOD)
        self._read_gps = _reader(self.DeclareVectorInputPort("gps", n * GPS_SIZE))
        self._read_estimate = _reader(self.DeclareVectorInputPort("estimated_state", n * STATE_SIZE))
        width = delay_compensation.HISTORY_WIDTH
        self._history = self.DeclareDiscreteState(np.full(n * self._capacity * width, np.nan))
        # per vehicle: previous p_hat, v_hat (6; NaN before the first tick), velocity step (3),
        # odometry (6), last GPS stamp read (1), as the scalar system's memory
        self._memory = self.DeclareDiscreteState(_tiled([np.nan] * 6 + [0.0] * 9 + [NO_SAMPLE_STAMP], n))
        self.DeclareVectorOutputPort(
            "gps",
            n * GPS_SIZE,
            self._calc,
            prerequisites_of_calc={self.all_input_ports_ticket(), self.xd_ticket()},
        )
        self._offset = EKF_OFFSET + FAULT_LAG
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, self._offset, self._book)

    def _estimate(self, context):
        x = self._read_estimate(context).reshape(self._n, STATE_SIZE)
        return np.concatenate((x[:, P_SLICE], x[:, V_SLICE]), axis=1)

    def _book(self, context, discrete_state):
        n = self._n
        estimate = self._estimate(context)
        stamp = self._read_gps(context).reshape(n, GPS_SIZE)[:, 6]
        memory = discrete_state.get_mutable_value(self._memory).reshape(n, 16)
        previous = np.where(np.isnan(memory[:, 0:1]), estimate, memory[:, 0:6])
        fused = (stamp != memory[:, 15]) & (stamp != NO_SAMPLE_STAMP)
        odometry, velocity_step = kernels.odometry_step(
            memory[:, 9:15], estimate, previous, memory[:, 6:9], fused, ONBOARD_PERIOD
        )
        memory[:, 0:6], memory[:, 6:9], memory[:, 9:15], memory[:, 15] = (
            estimate,
            velocity_step,
            odometry,
            stamp,
        )
        tick = round((context.get_time() - self._offset) / ONBOARD_PERIOD) * ONBOARD_PERIOD
        slot = delay_compensation.history_slot(tick, ONBOARD_PERIOD, self._capacity)
        history = discrete_state.get_mutable_value(self._history).reshape(n, self._capacity, -1)
        history[:, slot, 0] = tick
        history[:, slot, 1:] = odometry

    def _calc(self, context, output):
        n = self._n
        sample = self._read_gps(context).reshape(n, GPS_SIZE)
        out = np.array(sample)
        stamped = (sample[:, 6] != NO_SAMPLE_STAMP) & np.isfinite(sample[:, 6])
        if stamped.any():
            rows = np.flatnonzero(stamped)
            memory = context.get_discrete_state(self._memory).value().reshape(n, 16)[rows]
            now = kernels.predicted_odometry(memory[:, 9:15], memory[:, 3:6], memory[:, 6:9], ONBOARD_PERIOD)
            slots = np.rint(sample[rows, 6] / ONBOARD_PERIOD).astype(int) % self._capacity
            history = context.get_discrete_state(self._history).value().reshape(n, self._capacity, -1)
            out[rows] = kernels.compensated_gps(sample[rows], history[rows, slots], now)
        output.get_mutable_value()[:] = out.ravel()


def _build_ekf7(builder, vehicle, n, fidelity):
    """Fleet CF + EKF7 + assembler in `builder`; returns (input ports by name, output ports by name)."""
    tilt = ekf.TiltNoise.from_params(vehicle.ekf, vehicle.attitude_filter, ONBOARD_PERIOD)
    ekf_system = builder.AddNamedSystem("ekf", FleetEkf(vehicle.ekf, n, fidelity, tilt))
    attitude_filter = builder.AddNamedSystem(
        "attitude_filter",
        FleetComplementaryFilter(
            vehicle.attitude_filter,
            n,
            initial_attitude=(0.0, 0.0, vehicle.ekf.init_state[6]),
            fidelity=fidelity,
        ),
    )
    assembler = builder.AddNamedSystem("estimated_state", FleetEstimatedStateAssembler(n))
    return wire_ekf7(builder, ekf_system, attitude_filter, assembler)


def _build_eskf(builder, vehicle, n, fidelity):
    check_eskf_fidelity(fidelity)
    return wire_eskf(builder.AddNamedSystem("eskf", FleetEskf(vehicle.estimator, n, fidelity)))


_BUILDERS = {"ekf7": _build_ekf7, "eskf": _build_eskf}


def build_fleet_estimator(vehicle, n, fidelity=PHYSICAL):
    """The estimator sub-Diagram of N vehicles flying one VehicleConfig, named ``estimator``.

    The fleet form of ``systems.estimators.build_estimator``: inputs ``imu`` (N*6), ``gps``
    (N*7), ``mag`` (N*2) (a never-sampled constant for a missing sensor); outputs named as
    ``vocabulary_for(vehicle.estimator).log_widths()``, each of width N times the scalar one,
    vehicle-major.
    """
    if n < 1:
        raise ValueError(f"a fleet needs at least one vehicle, got n = {n}")
    builder = DiagramBuilder()
    inputs, outputs = _BUILDERS[vehicle.estimator.kind](builder, vehicle, n, fidelity)
    return estimator_diagram(builder, inputs, outputs, vehicle.estimator)
