"""A student's course estimator (``estimator: {kind: course, module: my_estimator.py}``,
``grading/course.py``) as a Drake system with the bundled estimators' ports and stamps."""

import copy
import math

import numpy as np
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
    each of the six functions called once per tick over all n rows (``grading.course.CourseFilter``).

    The filter's state lives in the context's discrete state: its EKF state (n*7), roll and
    pitch (n*2, rad) and covariance (the ``covariance`` output). Not the filter object in an
    abstract state: Drake copies a Python value (``copy.deepcopy``) into its update scratch and
    back at every update event, which cost about a fifth of a graded flight. The system keeps
    one filter for the student's module and constants; each tick a shallow copy of it carries
    the context's state through the six functions, so any number of contexts can fly it.

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
        self._filter = course_filter  # the module and constants; its state is the context's
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
        self._ekf_state = discrete_group(self, course_filter.ekf_state.ravel())
        self._attitude = discrete_group(
            self, np.column_stack([course_filter.roll_est, course_filter.pitch_est]).ravel()
        )
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
        discrete = state.get_mutable_discrete_state()
        ekf_state = discrete.get_mutable_value(self._ekf_state).reshape(self._n, COURSE_STATE)
        attitude = discrete.get_mutable_value(self._attitude).reshape(self._n, 2)
        estimates = discrete.get_mutable_value(self._estimate).reshape(self._n, STATE_SIZE)
        covariances = discrete.get_mutable_value(self._covariance).reshape(
            self._n, COURSE_STATE, COURSE_STATE
        )
        diagnostics = discrete.get_mutable_value(self._diagnostics).reshape(self._n, DIAGNOSTICS_SIZE)
        course_filter = copy.copy(self._filter)  # this tick's: the context's state, its own arrays
        course_filter.ekf_state, course_filter.ekf_cov = ekf_state.copy(), covariances.copy()
        course_filter.roll_est, course_filter.pitch_est = attitude[:, 0].copy(), attitude[:, 1].copy()
        imu, gps, mag = self._read_imu(context), self._read_gps(context), self._read_mag(context)
        mag_rows = np.flatnonzero(mag[:, 1] > diagnostics[:, DIAG["mag_stamp"]] + gating.STAMP_TOLERANCE)
        gps_rows = np.flatnonzero(gps[:, 6] > diagnostics[:, DIAG["gps_stamp"]] + gating.STAMP_TOLERANCE)
        diagnostics[mag_rows, DIAG["mag_stamp"]] = mag[mag_rows, 1]
        diagnostics[gps_rows, DIAG["gps_stamp"]] = gps[gps_rows, 6]
        course_filter.tick(
            imu[:, 0:3].copy(), imu[:, 3:6].copy(), mag[mag_rows, 0], mag_rows, gps[gps_rows, 0:6], gps_rows
        )
        self._write_estimates(estimates, course_filter, imu[:, 3:6])
        ekf_state[:] = course_filter.ekf_state
        covariances[:] = course_filter.ekf_cov
        attitude[:, 0], attitude[:, 1] = course_filter.roll_est, course_filter.pitch_est


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
