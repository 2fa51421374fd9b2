"""A user's own estimator (``estimator: {kind: custom, ...}``, ``estimation/custom.py``) as a
Drake system with the bundled estimators' ports, stamps, gates and diagnostics."""

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import (
    EKF_OFFSET,
    IMU_SIZE,
    NO_SAMPLE_STAMP,
    ONBOARD_PERIOD,
    STATE_SIZE,
)
from quad_drake.estimation import custom, gating
from quad_drake.estimation.measurements import measurements_of
from quad_drake.estimation.registry import KINDS, vocabulary_for
from quad_drake.estimation.vocabulary import DIAG, DIAGNOSTICS_SIZE, initial_diagnostics
from quad_drake.kernels import fusion
from quad_drake.models.rotations import quat_from_euler_tuple
from quad_drake.systems._io import discrete_group, row_reader


class PythonEstimator(LeafSystem):
    """n copies of a custom estimator (one object per vehicle, made by ``factory(**params)``),
    held in the context's abstract state.

    The objects advance in place: each tick is a discrete update (of the outputs' discrete state)
    that steps the context's own objects, not an unrestricted update of a copy. Drake copies a
    Python value with ``copy.deepcopy`` into its update buffer and back at every unrestricted
    update (drake#18740), which cost a quarter to a third of a custom estimator's flight, twice per
    2 ms tick. A context's objects are still its own: ``CreateDefaultContext`` and
    ``Context.Clone`` deep-copy them, so any number of contexts fly independently. Computing a
    tick is taking it, so only a Simulator (which applies each update it computes, once) steps
    this system.

    Inputs and outputs as the bundled estimators' (vehicle-major): ``imu`` (n*6: f_B m/s^2,
    w_NB_B rad/s) and one per measurement of the ``custom`` kind that `sensors` (a SensorsConfig)
    carry (``estimation/measurements.py``): ``mag`` (n*2: yaw rad, stamp s), ``gps`` (n*7: p_N m,
    v_N m/s, stamp s), ``no_aid`` (n*13: a replay's no-aiding samples, :meth:`_fuse_no_aid`);
    ``estimated_state`` (n*13: p_N, q_NB from the estimate's roll, pitch, yaw, v_N, body rate =
    the gyro sample, NaN while the IMU is out), ``covariance`` (n*k*k over the estimator's
    ``state_names``), ``diagnostics`` (n*``vocabulary.DIAGNOSTICS``).

    Each tick (ONBOARD_PERIOD, offset EKF_OFFSET, as the bundled estimators): ``predict`` with
    the IMU sample (the last finite one over a dropout, counted); then a fresh magnetometer
    and a fresh GPS sample (by stamp; a non-finite one is counted and skipped), each gated
    when the estimator gives its innovation (``gate_sigma``, 0 = off) and fused with
    ``update_mag`` / ``update_gps``; then ``estimate()`` and ``covariance()`` are read. A
    method that raises (or returns what cannot be used) stops the flight with
    ``custom.EstimatorRaised`` naming `vehicle` (its name), the method, the copy and the sim time.
    """

    def __init__(self, config, sensors, n=1, vehicle="vehicle"):
        super().__init__()
        self._n, self._config, self._vehicle = n, config, vehicle
        names = vocabulary_for(config).state_names
        self._k = len(names)
        self._gps_threshold = gating.gate_threshold(custom.GPS_DOF, config.gate_sigma)
        self._mag_threshold = gating.gate_threshold(custom.MAG_DOF, config.gate_sigma)
        estimators = [custom.make_estimator(config.factory, config.params) for _ in range(n)]
        self._objects = self.DeclareAbstractState(AbstractValue.Make(estimators))
        initial = np.zeros((n, STATE_SIZE))
        initial[:, 3] = 1.0  # level until the first tick
        for i, estimator in enumerate(estimators):
            self._write_estimate(initial[i], custom.read_estimate(estimator), np.zeros(3))
        covariances = np.stack([custom.read_covariance(e, self._k) for e in estimators])
        diagnostics = np.tile(initial_diagnostics(), (n, 1))
        self._estimate = discrete_group(self, initial.ravel(), "estimated_state")
        self._covariance = discrete_group(self, covariances.ravel(), "covariance")
        self._diagnostics = discrete_group(self, diagnostics.ravel(), "diagnostics")
        self._last_imu = discrete_group(self, np.tile([0.0, 0.0, -9.81, 0.0, 0.0, 0.0], n))
        self._read_imu = row_reader(self.DeclareVectorInputPort("imu", n * IMU_SIZE), n)
        self.measurements = measurements_of(KINDS["custom"].measurements, sensors)
        self._readers = {
            m.name: row_reader(self.DeclareVectorInputPort(m.port, n * m.width), n) for m in self.measurements
        }
        self._no_aid_stamp = discrete_group(self, np.full(n, NO_SAMPLE_STAMP))
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, EKF_OFFSET, self._update)

    @staticmethod
    def _write_estimate(row, estimate, body_rate):
        """The 13-state row of a custom ``estimate()`` (9) and the body rate (3)."""
        row[0:3] = estimate[0:3]
        row[3:7] = quat_from_euler_tuple(estimate[6], estimate[7], estimate[8])
        row[7:10] = estimate[3:6]
        row[10:13] = body_rate

    def _fuse(self, estimator, sensor, sample, stamp, diagnostics, threshold):
        """Gate (when the estimator gives its innovation) and fuse one fresh sample."""
        nis_column, stamp_column = DIAG[f"{sensor}_nis"], DIAG[f"{sensor}_stamp"]
        diagnostics[stamp_column] = stamp
        if not all(np.isfinite(part).all() for part in sample):
            diagnostics[DIAG["nonfinite_samples"]] += 1
            diagnostics[nis_column] = math.nan
            return
        pair = custom.innovation(estimator, sensor, *sample)
        nis = custom.nis(*pair) if pair is not None else math.nan
        diagnostics[nis_column] = nis
        if nis > threshold:
            diagnostics[DIAG[f"{sensor}_gated"]] += 1
            return
        custom.call(estimator, f"update_{sensor}", *sample)

    @staticmethod
    def _fuse_no_aid(estimator, sample, diagnostics):
        """One fresh no-aiding sample (``estimation/custom.py``): ``update_no_aid(position,
        velocity, std)`` where the estimator has it (std (6,): m, m/s; inf = not fused), else
        ``update_gps(position, velocity)`` with its own GPS noise; a non-finite one counted."""
        position, velocity, std = sample[0:3].copy(), sample[3:6].copy(), sample[6:12].copy()
        if not (math.isfinite(sample[-1]) and np.isfinite(sample[0:6]).all()):
            diagnostics[DIAG["nonfinite_samples"]] += 1
        elif hasattr(estimator, "update_no_aid"):
            custom.call(estimator, "update_no_aid", position, velocity, std)
        else:
            custom.call(estimator, "update_gps", position, velocity)

    def _update(self, context, discrete):
        estimators = context.get_abstract_state(self._objects).get_value()  # stepped in place
        estimates = discrete.get_mutable_value(self._estimate).reshape(self._n, STATE_SIZE)
        covariances = discrete.get_mutable_value(self._covariance).reshape(self._n, self._k, self._k)
        diagnostics = discrete.get_mutable_value(self._diagnostics).reshape(self._n, DIAGNOSTICS_SIZE)
        last_imu = discrete.get_mutable_value(self._last_imu).reshape(self._n, IMU_SIZE)
        imu = self._read_imu(context)
        mag = self._readers["yaw"](context) if "yaw" in self._readers else None
        gps = self._readers["gps"](context) if "gps" in self._readers else None
        no_aid = self._readers["no_aid"](context) if "no_aid" in self._readers else None
        no_aid_stamps = discrete.get_mutable_value(self._no_aid_stamp)
        for i, estimator in enumerate(estimators):
            rows = (
                imu[i],
                None if gps is None else gps[i],
                None if mag is None else mag[i],
                estimates[i],
                covariances[i],
                diagnostics[i],
                last_imu[i],
            )
            try:
                self._step(estimator, *rows, None if no_aid is None else no_aid[i], no_aid_stamps[i : i + 1])
            except custom.EstimatorProblem as e:
                raise custom.in_flight(
                    e, self._vehicle, self._config.factory, i, context.get_time()
                ) from None

    def _step(
        self, estimator, imu, gps, mag, estimate, covariance, diagnostics, last_imu, no_aid, no_aid_seen
    ):
        """One tick of one estimator; its rows of the inputs (gps, mag, no_aid: None where the
        vehicle carries no such sensor), and of the state (no_aid_seen (1,): the last no-aiding
        stamp), updated in place."""
        body_rate = imu[3:6]
        if np.isfinite(imu).all():
            last_imu[:] = imu
        else:
            diagnostics[DIAG["nonfinite_samples"]] += 1
            body_rate = np.full(3, math.nan)
        custom.call(estimator, "predict", ONBOARD_PERIOD, last_imu[0:3].copy(), last_imu[3:6].copy())
        if mag is not None and mag[1] > diagnostics[DIAG["mag_stamp"]] + gating.STAMP_TOLERANCE:
            self._fuse(estimator, "mag", (float(mag[0]),), mag[1], diagnostics, self._mag_threshold)
        if gps is not None and gps[6] > diagnostics[DIAG["gps_stamp"]] + gating.STAMP_TOLERANCE:
            sample = (gps[0:3].copy(), gps[3:6].copy())
            self._fuse(estimator, "gps", sample, gps[6], diagnostics, self._gps_threshold)
        if no_aid is not None and fusion.fresh(no_aid[-1], no_aid_seen[0]):
            no_aid_seen[0] = no_aid[-1]
            self._fuse_no_aid(estimator, no_aid, diagnostics)
        self._write_estimate(estimate, custom.read_estimate(estimator), body_rate)
        covariance[:] = custom.read_covariance(estimator, self._k)


def add_custom(builder, vehicle, fidelity, n) -> tuple[dict, dict]:
    """Add the custom estimator of n vehicles to `builder` (the ``custom`` kind's builder,
    ``estimation/registry.py``); (input ports by name, output ports by name)."""
    system = builder.AddNamedSystem(
        "custom_estimator", PythonEstimator(vehicle.estimator, vehicle.sensors, n, vehicle.name)
    )
    ports = ("imu",) + tuple(m.port for m in system.measurements)
    inputs = {name: [system.GetInputPort(name)] for name in ports}
    return inputs, {
        name: system.GetOutputPort(name) for name in ("estimated_state", "covariance", "diagnostics")
    }
