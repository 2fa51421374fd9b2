"""A student's course estimator (``estimator: {kind: course, module: my_estimator.py}``,
``grading/course.py``) as a Drake system with the bundled estimators' ports and stamps."""

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import (
    EKF_OFFSET,
    GPS_SIZE,
    IMU_SIZE,
    MAG_SIZE,
    NO_SAMPLE_STAMP,
    ONBOARD_PERIOD,
    STATE_SIZE,
)
from quad_drake.estimation import gating
from quad_drake.estimation.vocabulary import DIAG, DIAGNOSTICS_SIZE
from quad_drake.grading.course import CourseFilter
from quad_drake.grading.course_math import quaternion_from_euler
from quad_drake.systems._io import discrete_group, row_reader

COURSE_STATE = 7  # x y z vx vy vz yaw


class CourseEstimator(LeafSystem):
    """The course's complementary filter + 7-state EKF as the student wrote it, for n vehicles,
    each of the six functions called once per tick over all n rows (``grading.course.CourseFilter``,
    held in the context's abstract state).

    Inputs (vehicle-major): ``imu`` (n*6: the accelerometer m/s^2 as the fidelity reads it, the
    gyro rad/s, body FRD), ``gps`` (n*7: p_N m, v_N m/s, stamp s), ``mag`` (n*2: yaw rad, stamp s).
    Outputs: ``estimated_state`` (n*13: p_N, q_NB of (roll_est, pitch_est, yaw), v_N, body rate =
    the gyro sample), ``covariance`` (n*49: the EKF's over x y z vx vy vz yaw), ``diagnostics``
    (n*``vocabulary.DIAGNOSTICS``: the samples' stamps; NIS NaN, nothing gated).

    Each tick (ONBOARD_PERIOD, offset EKF_OFFSET, as the bundled estimators) the filter's
    :meth:`~quad_drake.grading.course.CourseFilter.tick` with the IMU sample and the rows whose
    magnetometer or GPS stamp is new.
    """

    def __init__(self, config, initial_state, n=1):
        super().__init__()
        self._n, self._path = n, config.module
        start = np.tile(np.asarray(initial_state, dtype=float), (n, 1))
        course_filter = CourseFilter(self._path, start, config.init_std)
        self._filter = self.DeclareAbstractState(AbstractValue.Make(course_filter))
        estimates = np.zeros((n, STATE_SIZE))
        self._write_estimates(estimates, course_filter, np.zeros((n, 3)))
        diagnostics = np.full((n, DIAGNOSTICS_SIZE), 0.0)
        for column in ("gps_nis", "mag_nis", "baro_nis", "field_nis", "baro_bias", "baro_bias_std"):
            diagnostics[:, DIAG[column]] = math.nan
        for column in ("gps_stamp", "mag_stamp", "baro_stamp", "field_stamp"):
            diagnostics[:, DIAG[column]] = NO_SAMPLE_STAMP
        self._estimate = discrete_group(self, estimates.ravel(), "estimated_state")
        self._covariance = discrete_group(self, course_filter.ekf_cov.ravel(), "covariance")
        self._diagnostics = discrete_group(self, diagnostics.ravel(), "diagnostics")
        self._read_imu = row_reader(self.DeclareVectorInputPort("imu", n * IMU_SIZE), n)
        self._read_gps = row_reader(self.DeclareVectorInputPort("gps", n * GPS_SIZE), n)
        self._read_mag = row_reader(self.DeclareVectorInputPort("mag", n * MAG_SIZE), n)
        self.DeclarePeriodicUnrestrictedUpdateEvent(ONBOARD_PERIOD, EKF_OFFSET, self._update)

    @staticmethod
    def _write_estimates(rows, course_filter, body_rate):
        """The (n, 13) rows of the filter's estimate and the body rate (n, 3)."""
        x = course_filter.ekf_state
        rows[:, 0:3] = x[:, 0:3]
        rows[:, 3:7] = quaternion_from_euler(course_filter.roll_est, course_filter.pitch_est, x[:, 6])
        rows[:, 7:10] = x[:, 3:6]
        rows[:, 10:13] = body_rate

    def _update(self, context, state):
        course_filter = state.get_mutable_abstract_state(self._filter).get_mutable_value()
        discrete = state.get_mutable_discrete_state()
        estimates = discrete.get_mutable_value(self._estimate).reshape(self._n, STATE_SIZE)
        covariances = discrete.get_mutable_value(self._covariance).reshape(
            self._n, COURSE_STATE, COURSE_STATE
        )
        diagnostics = discrete.get_mutable_value(self._diagnostics).reshape(self._n, DIAGNOSTICS_SIZE)
        imu, gps, mag = self._read_imu(context), self._read_gps(context), self._read_mag(context)
        mag_rows = np.flatnonzero(mag[:, 1] > diagnostics[:, DIAG["mag_stamp"]] + gating.STAMP_TOLERANCE)
        gps_rows = np.flatnonzero(gps[:, 6] > diagnostics[:, DIAG["gps_stamp"]] + gating.STAMP_TOLERANCE)
        diagnostics[mag_rows, DIAG["mag_stamp"]] = mag[mag_rows, 1]
        diagnostics[gps_rows, DIAG["gps_stamp"]] = gps[gps_rows, 6]
        course_filter.tick(
            imu[:, 0:3].copy(), imu[:, 3:6].copy(), mag[mag_rows, 0], mag_rows, gps[gps_rows, 0:6], gps_rows
        )
        self._write_estimates(estimates, course_filter, imu[:, 3:6])
        covariances[:] = course_filter.ekf_cov


def add_course(builder, vehicle, fidelity, n) -> tuple[dict, dict]:
    """Add the course estimator of n vehicles to `builder` (the ``course`` kind's builder,
    ``estimation/registry.py``); (input ports by name, output ports by name). Its estimate starts
    at the vehicle's initial position, velocity and yaw."""
    yaw = vehicle.initial_ypr[0]
    start = [*vehicle.initial_position, *vehicle.initial_velocity, yaw]
    system = builder.AddNamedSystem("course_estimator", CourseEstimator(vehicle.estimator, start, n))
    inputs = {name: [system.GetInputPort(name)] for name in ("imu", "gps", "mag")}
    return inputs, {
        name: system.GetOutputPort(name) for name in ("estimated_state", "covariance", "diagnostics")
    }
