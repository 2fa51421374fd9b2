"""The aiding sensors' fusion inside the estimator LeafSystems (issue 32): the barometer for both
estimators, and a 3-axis magnetometer as the ESKF's field vector or the EKF7's tilt-compensated
heading. A mixin of ``systems.estimators.Ekf`` and ``Eskf`` (thin glue over
``kernels/aiding.py``, which compiles ``estimation/baro.py`` and ``estimation/mag3.py``), so a
single run and a fleet run the same code, sized by n.

What the vehicle carries decides what is fused (:func:`aiding_sensors`): nothing changes for a
vehicle without a barometer and with the yaw magnetometer (the default). With a barometer the
estimator gets an input ``baro`` (n*2: height m up, stamp s), a discrete-state book per vehicle
(``baro.BARO_BOOK_SIZE``: the bias filter, the rejection timer) and fuses each fresh sample after
the GPS; with a 3-axis magnetometer its ``mag`` input is n*4 (m_B gauss FRD, stamp s), the
yaw update of the estimator's own tick is fed no sample, and the field (ESKF) or the heading
(EKF7) is fused here instead, through its gate, with its NIS in the diagnostics. Gates follow the
estimator's: ``fidelity.reference_estimator`` switches them off.
"""

import collections

import numpy as np

from quad_drake.conventions import BARO_SIZE, MAG_FIELD_SIZE, MAG_SIZE, NO_SAMPLE_STAMP
from quad_drake.estimation import baro, gating
from quad_drake.estimation.vocabulary import NIS_DOF
from quad_drake.kernels import aiding as kernels
from quad_drake.systems._io import row_reader

AidingSensors = collections.namedtuple("AidingSensors", ["baro_period", "three_axis"])
"""What an estimator fuses besides IMU, GPS and the yaw magnetometer: baro_period (s, the
barometer's sample period; None: no barometer), three_axis (the magnetometer is 3-axis)."""
NO_AIDING = AidingSensors(None, False)


def aiding_sensors(vehicle) -> AidingSensors:
    """The AidingSensors of a VehicleConfig's sensors."""
    sensors = vehicle.sensors
    return AidingSensors(
        baro_period=None if sensors.baro is None else float(sensors.baro.period),
        three_axis=sensors.mag is not None and bool(sensors.mag.three_axis),
    )


def mag_size(aiding) -> int:
    """Width of one vehicle's ``mag`` input: MAG_FIELD_SIZE for a 3-axis magnetometer, else MAG_SIZE."""
    return MAG_FIELD_SIZE if aiding.three_axis else MAG_SIZE


class AidedFusion:
    """Mixin of an estimator LeafSystem that has declared its fusion state (x, P, diagnostics, the
    book; ``GatedFusion``): the barometer and 3-axis magnetometer fusion of its n vehicles."""

    def _declare_aiding(self, n, params, aiding, fidelity, gps_z_std, tilt=None):
        """Declare the ``baro`` input and book (with a barometer) and the fusion constants.

        params: the estimator's config (its ``baro``: BaroFusionParams, ``mag_field``:
        MagFieldFusionParams); aiding: AidingSensors; gps_z_std: m, the GPS height noise the
        estimator assumes (the bias filter's reference); tilt: the EKF7's ``ekf.TiltNoise`` or None
        (its roll/pitch error variance then adds to the heading's, with ``mag_field.tilt_std``)."""
        self._aiding, self._tilt_noise = aiding, tilt
        safety = not fidelity.reference_estimator
        k = self._k
        self._dx, self._fused = np.zeros((n, k)), np.zeros(n, dtype=bool)
        self._no_yaw = np.tile([0.0, NO_SAMPLE_STAMP], (n, 1))  # the yaw update's input when 3-axis
        if aiding.baro_period is not None:
            gate = gating.gate_threshold(NIS_DOF["baro"], params.baro.gate_sigma if safety else 0.0)
            self._baro_model = kernels.baro_model(params.baro, gps_z_std, gate, aiding.baro_period)
            self._read_baro = row_reader(self.DeclareVectorInputPort("baro", n * BARO_SIZE), n)
            self._baro_book = self.DeclareDiscreteState(np.tile(baro.initial_book(params.baro), n))
        if aiding.three_axis:
            field = params.mag_field
            heading = self._estimates_heading()
            dof = NIS_DOF["mag"] if heading else NIS_DOF["field"]
            gate = gating.gate_threshold(dof, field.gate_sigma if safety else 0.0)
            if heading:
                self._heading_model = kernels.heading_model(field, gate)
            else:
                self._field_model = kernels.field_model(field, gate)

    def _estimates_heading(self) -> bool:
        """True for an estimator that fuses the tilt-compensated heading (EKF7), False for the field."""
        raise NotImplementedError

    def _apply_corrections(self, x, P, dx, fused) -> None:
        """Add (EKF7) or inject (ESKF) the corrections dx of the fused vehicles, in place."""
        raise NotImplementedError

    def _yaw_samples(self, mag):
        """The samples the estimator's own yaw update reads: `mag` itself, none when 3-axis."""
        return self._no_yaw if self._aiding.three_axis else mag

    def _fuse_aiding(self, context, discrete_state, filters, gps, mag, attitude=None) -> None:
        """Fuse this tick's fresh 3-axis and barometer samples of the n vehicles in place.

        filters: (x, P, diagnostics, book), the estimator's (n, ...) views; gps (n, 7), mag (n, 2
        or 4) its samples; attitude (n, 3, rad): the EKF7's attitude-filter input (the heading's
        roll and pitch), None for the ESKF."""
        x, P, diagnostics, book = filters[0], filters[1], filters[2], filters[3]
        dx, fused = self._dx, self._fused
        if self._aiding.three_axis:
            slot = 1  # the book's mag-stamp column, unused by the yaw update when 3-axis
            if attitude is not None:
                hard_iron, field_var, declination, tilt_var, gate = self._heading_model
                if self._tilt_noise is not None:
                    tilt_var = tilt_var + self._tilt_noise.variance(context.get_time())
                model = (hard_iron, field_var, declination, tilt_var, gate)
                kernels.heading_rows(x, P, mag, attitude, book, slot, diagnostics, model, dx, fused)
            else:
                kernels.field_rows(x, P, mag, book, slot, diagnostics, self._field_model, dx, fused)
            if fused.any():
                self._apply_corrections(x, P, dx, fused)
        if self._aiding.baro_period is not None:
            book_view = discrete_state.get_mutable_value(self._baro_book).reshape(
                self._n, baro.BARO_BOOK_SIZE
            )
            kernels.baro_rows(
                x, P, self._read_baro(context), gps, book_view, diagnostics, self._baro_model, dx, fused
            )
            if fused.any():
                self._apply_corrections(x, P, dx, fused)
