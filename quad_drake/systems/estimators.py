"""Estimator LeafSystems: complementary attitude filter, 7-state EKF, estimated-state assembly.

Within a tick the attitude filter (offset ATTITUDE_FILTER_OFFSET) integrates the gyro from
the EKF's posterior yaw of the previous tick, then the EKF (offset EKF_OFFSET) takes the
filter's roll, pitch and integrated yaw, predicts, and fuses a fresh magnetometer and then a
fresh GPS sample (the reference's IMU, Mag, GPS order). Fresh means a changed ``stamp``.
"""

import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import (
    ATTITUDE_FILTER_OFFSET,
    ATTITUDE_SIZE,
    EKF_OFFSET,
    EKF_STATE_SIZE,
    GPS_SIZE,
    IMU_SIZE,
    MAG_SIZE,
    NO_SAMPLE_STAMP,
    ONBOARD_PERIOD,
    STATE_SIZE,
)
from quad_drake.estimation import ekf
from quad_drake.estimation.complementary import VARIANTS, complementary_update
from quad_drake.fidelity import PHYSICAL
from quad_drake.rotations import quat_from_euler_tuple
from quad_drake.systems._io import vector_reader

DIAGNOSTICS_SIZE = 5
"""`diagnostics` layout: GPS NIS, its sample stamp (s), mag NIS, its stamp (s), rejected count."""
GPS_SLOT, MAG_SLOT = 0, 1
REJECTED_INDEX = 4


def _finite(values):
    """True if every float in the list is finite (any NaN or inf makes the sum NaN or inf)."""
    return math.isfinite(sum(values))


class ComplementaryFilter(LeafSystem):
    """Complementary roll/pitch filter with gyro-integrated yaw (SPEC §4 UpdateFromIMU).

    Inputs: ``imu`` (6: f_B specific force m/s^2, w_NB_B rad/s; FRD), ``ekf_state`` (7; index 6
    is the EKF posterior yaw, rad, used as the prior yaw). Output: ``attitude`` (3: roll, pitch,
    yaw, rad; state port). Ticks every ONBOARD_PERIOD at ATTITUDE_FILTER_OFFSET with
    dt = ONBOARD_PERIOD. A non-finite IMU sample is skipped (roll, pitch held, yaw = prior).
    With ``fidelity.reference_accelerometer`` the IMU carries the reference's reading and the
    tilt comes from the reference's formulas.
    """

    def __init__(self, params, initial_attitude=(0.0, 0.0, 0.0), fidelity=PHYSICAL):
        super().__init__()
        self._reference_accelerometer = fidelity.reference_accelerometer
        if params.variant not in VARIANTS:
            raise ValueError(f"attitude filter variant {params.variant!r} is not one of {VARIANTS}")
        self._tau = float(params.tau)
        self._variant = params.variant
        self._read_imu = vector_reader(self.DeclareVectorInputPort("imu", IMU_SIZE))
        self._read_ekf_state = vector_reader(self.DeclareVectorInputPort("ekf_state", EKF_STATE_SIZE))
        state = self.DeclareDiscreteState(np.array(initial_attitude, dtype=float))
        self.DeclareStateOutputPort("attitude", state)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, ATTITUDE_FILTER_OFFSET, self._update)

    def _update(self, context, discrete_state):
        imu = self._read_imu(context)
        yaw = self._read_ekf_state(context)[6]
        roll, pitch, _ = discrete_state.value(0).tolist()
        if _finite(imu):
            roll, pitch, yaw = complementary_update(
                roll,
                pitch,
                yaw,
                imu[0:3],
                imu[3:6],
                ONBOARD_PERIOD,
                self._tau,
                self._variant,
                self._reference_accelerometer,
            )
        discrete_state.set_value(0, np.array((roll, pitch, yaw)))


class Ekf(LeafSystem):
    """7-state EKF (SPEC §4): x = (p_N m, v_N m/s, yaw rad), NED; roll/pitch from the attitude filter.

    Inputs: ``imu`` (6: f_B m/s^2, w_NB_B rad/s), ``gps`` (7: p_N m, v_N m/s, stamp s),
    ``mag`` (2: yaw rad, stamp s), ``attitude`` (3: roll, pitch, yaw rad, this tick's filter
    output). A sensor the vehicle lacks must be wired to a constant with stamp NO_SAMPLE_STAMP.
    Outputs (state ports): ``ekf_state`` (7), ``covariance`` (49, P row-major),
    ``diagnostics`` (5: last GPS NIS, stamp of its sample, last mag NIS, its stamp, number of
    rejected non-finite IMU/GPS/mag samples; NIS is NaN before the first update).

    Each tick (ONBOARD_PERIOD, offset EKF_OFFSET): yaw <- attitude yaw, predict with dt =
    ONBOARD_PERIOD; then a fresh mag sample, then a fresh GPS sample, is fused. A sample is
    fresh when its stamp differs from the last stamp seen and is not NO_SAMPLE_STAMP.
    With ``fidelity.reference_accelerometer`` the prediction reads the IMU as the reference's
    R_NB^T (a_NB + g_N): a_N = R f - g_N.
    """

    def __init__(self, params, fidelity=PHYSICAL):
        super().__init__()
        self._reference_accelerometer = fidelity.reference_accelerometer
        self._Q = ekf.process_noise(params)
        self._R_gps = ekf.gps_noise(params)
        self._R_mag = ekf.mag_noise(params)
        self._G = ekf.predict_jacobian(np.zeros(EKF_STATE_SIZE), 0.0, 0.0, (0.0, 0.0, 0.0), ONBOARD_PERIOD)
        self._read_imu = vector_reader(self.DeclareVectorInputPort("imu", IMU_SIZE))
        self._read_gps = vector_reader(self.DeclareVectorInputPort("gps", GPS_SIZE))
        self._read_mag = vector_reader(self.DeclareVectorInputPort("mag", MAG_SIZE))
        self._read_attitude = vector_reader(self.DeclareVectorInputPort("attitude", ATTITUDE_SIZE))
        x = self.DeclareDiscreteState(ekf.initial_state(params))
        P = self.DeclareDiscreteState(ekf.initial_covariance(params).ravel())
        diagnostics = self.DeclareDiscreteState(
            np.array([math.nan, NO_SAMPLE_STAMP, math.nan, NO_SAMPLE_STAMP, 0.0])
        )
        self.DeclareDiscreteState(np.full(2, NO_SAMPLE_STAMP))  # last stamps seen: GPS, mag
        self.DeclareStateOutputPort("ekf_state", x)
        self.DeclareStateOutputPort("covariance", P)
        self.DeclareStateOutputPort("diagnostics", diagnostics)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, EKF_OFFSET, self._update)

    def _update(self, context, discrete_state):
        imu = self._read_imu(context)
        attitude = self._read_attitude(context)
        mag = self._read_mag(context)
        gps = self._read_gps(context)
        x = discrete_state.value(0)
        P = discrete_state.value(1).reshape(EKF_STATE_SIZE, EKF_STATE_SIZE)
        if _finite(imu + attitude):
            x, P = ekf.predict_with_yaw(
                x.tolist(), P, attitude, imu, ONBOARD_PERIOD, self._Q, self._G, self._reference_accelerometer
            )
        else:
            self._book_rejection(discrete_state)
        seen = discrete_state.value(3).tolist()
        if mag[1] != seen[MAG_SLOT] and mag[1] != NO_SAMPLE_STAMP:
            x, P = self._fuse(MAG_SLOT, mag[1], ekf.mag_update, mag[0], self._R_mag, x, P, discrete_state)
        if gps[6] != seen[GPS_SLOT] and gps[6] != NO_SAMPLE_STAMP:
            x, P = self._fuse(GPS_SLOT, gps[6], ekf.gps_update, gps[0:6], self._R_gps, x, P, discrete_state)
        discrete_state.set_value(0, np.asarray(x, dtype=float))
        discrete_state.set_value(1, P.ravel())

    @staticmethod
    def _book_rejection(discrete_state):
        discrete_state.get_mutable_value(2)[REJECTED_INDEX] += 1.0

    def _fuse(self, slot, stamp, update, z, R, x, P, discrete_state):
        """(x, P) after fusing the fresh sample z (stamp s); books the stamp, the NIS or a rejection."""
        discrete_state.get_mutable_value(3)[slot] = stamp
        x = np.asarray(x, dtype=float)
        x_new, P_new, nis = update(x, P, z, R) if math.isfinite(stamp) else (x, P, math.nan)
        if math.isnan(nis):
            self._book_rejection(discrete_state)
            return x, P
        diagnostics = discrete_state.get_mutable_value(2)
        diagnostics[2 * slot] = nis
        diagnostics[2 * slot + 1] = stamp
        return x_new, P_new


class EstimatedStateAssembler(LeafSystem):
    """The estimate in the true ``state`` layout, for the controller and the evaluators.

    Inputs: ``attitude`` (3: roll, pitch, yaw rad), ``ekf_state`` (7), ``imu`` (6). Output:
    ``estimated_state`` (13: p = x[0:3] m, q_NB = quat(roll, pitch, x[6]) wxyz,
    v = x[3:6] m/s, w_NB_B = gyro rad/s); a feedthrough output (its inputs are state ports).
    """

    def __init__(self):
        super().__init__()
        self._read_attitude = vector_reader(self.DeclareVectorInputPort("attitude", ATTITUDE_SIZE))
        self._read_ekf_state = vector_reader(self.DeclareVectorInputPort("ekf_state", EKF_STATE_SIZE))
        self._read_imu = vector_reader(self.DeclareVectorInputPort("imu", IMU_SIZE))
        self.DeclareVectorOutputPort(
            "estimated_state", STATE_SIZE, self._calc, prerequisites_of_calc={self.all_input_ports_ticket()}
        )

    def _calc(self, context, output):
        roll, pitch, _ = self._read_attitude(context)
        x = self._read_ekf_state(context)
        gyro = self._read_imu(context)[3:6]
        q = list(quat_from_euler_tuple(roll, pitch, x[6]))
        output.SetFromVector(np.array(x[0:3] + q + x[3:6] + gyro))
