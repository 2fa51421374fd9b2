"""The measurement updates of the estimator LeafSystems: one seam for every sensor.

An estimator system (``systems/estimators.py``) holds a :class:`Fusion`: its filter's discrete
state, declared once by name (:class:`Groups`), and the :class:`Update` s built once from its
vehicle (:func:`build_updates`: the measurements its kind declares that the vehicle carries,
``estimation/measurements.py``). Each update owns its input port, its NIS and stamp columns in
``diagnostics``, its book columns, its gate and its compiled update (``kernels/``); the
estimator supplies only its prediction and how a correction is applied (``correct(x, P, dx,
fused)``: added for the EKF7, ``kernels.ekf7.correct``; injected for the ESKF,
``kernels.eskf.correct``) and the measurement models that depend on its state (the yaw
update's compiled step). Everything is sized by n vehicles (a single run: n = 1; a fleet: n runs
of one VehicleConfig; a replay of n flight logs: n vehicles, each with the settings of its own
log, ``registry.EstimatorKind.per_vehicle``) and works IN PLACE on (n, ...) views of the discrete
state. A per-vehicle setting is given once for all vehicles or once per vehicle: the GPS noise
(6, 6) or (n, 6, 6), the magnetometer's field params one or a sequence of n, the barometer's
GPS height noise, period and whether the vehicle carries one a scalar or (n,).

Each tick, after the estimator's prediction, :meth:`Fusion.fuse` checks the covariance (every
vehicle whose per-tick check failed or that has a fresh GPS sample: the full check and repair,
counted) and runs the updates in their order. Adding a sensor is one :class:`Update` subclass
here (its compiled kernel in ``kernels/``) and its name in the kinds that fuse it
(``estimation/registry.py``); the ports, the NIS columns the campaigns tabulate and the fusion
all read the same list.
"""

import collections

import numpy as np

from quad_drake.conventions import GPS_ACCURACY_SIZE, NO_SAMPLE_STAMP
from quad_drake.estimation import baro, eskf, gating
from quad_drake.estimation.measurements import measurements_of, receiver_noise
from quad_drake.estimation.vocabulary import DIAG, DIAGNOSTICS_SIZE, NIS_DOF, initial_diagnostics
from quad_drake.kernels import fusion
from quad_drake.kernels.imu_hold import HOLD_SIZE, initial_hold
from quad_drake.systems._io import discrete_group, row_reader

Groups = collections.namedtuple("Groups", ["x", "P", "diagnostics", "book"])
"""The discrete-state group indices of an estimator's filter: x (its state, n*width), P (n*k*k),
diagnostics (n*``vocabulary.DIAGNOSTICS_SIZE``), book (n*``fusion.BOOK_SIZE``: the last GPS and
magnetometer stamps seen and the GPS policy's book of the n vehicles, then n*``imu_hold.HOLD_SIZE``:
their running means of the IMU; one group, so that a tick fetches one view for both)."""


def _aiding_kernels():
    """``quad_drake.kernels.aiding``, imported on first use: a vehicle without a barometer or a
    3-axis magnetometer creates none of its numba dispatchers."""
    from quad_drake.kernels import aiding

    return aiding


class Update:
    """One measurement update of an estimator system (module docstring): the base of the sensors'.

    measurement: its ``measurements.Measurement`` (port, width, NIS columns). :meth:`declare`
    declares its input port (and a book of its own, if any) on the system; :meth:`fuse` fuses
    this tick's fresh samples of the n vehicles IN PLACE. extra_ports: the names of the input ports
    it declared beyond its measurement's (the GPS receiver's accuracy).
    """

    extra_ports = ()

    def __init__(self, measurement):
        self.measurement = measurement
        self.read = None

    def declare(self, system, n, k) -> None:
        """Declare the input port (n * width) on `system` (n filters of k error states)."""
        m = self.measurement
        self.read = row_reader(system.DeclareVectorInputPort(m.port, n * m.width), n)

    def fuse(self, context, discrete_state, filters, samples) -> None:
        """Fuse this tick's samples (``samples[port]``: (n, width) arrays of every port the
        estimator reads) into the ``fusion.Filters`` `filters` IN PLACE."""
        raise NotImplementedError


class GpsUpdate(Update):
    """The GPS (p_N m, v_N m/s): the Joseph update of the groups the gates accept, the resets of
    ``estimation/gating.py`` (``fusion.fuse_gps``); NIS 6 dof in ``gps_nis``; book column
    ``fusion.GPS_SLOT`` and the GPS policy's columns. R: (6, 6), or (n, 6, 6) per vehicle.
    receiver_accuracy: the vehicle's GPS reports each sample's accuracy (``sensors.gps_accuracy``,
    a replay's): a second input, ``gps_accuracy`` (n*``GPS_ACCURACY_SIZE``), and each sample fused
    with ``measurements.receiver_noise`` of R and its accuracy, as PX4 fuses it. height_restart:
    bool, or (n,) per vehicle: the GPS is the height reference, its height reset to a sample after
    a gap (``gating.GPS_HEIGHT_TIMEOUT``). The vehicle's :class:`BaroUpdate`, where it has one
    (``baro``), withholds a GPS height that disagrees with its barometer, and its bias follows a
    height reset (in the state: ``fusion.fuse_gps``; in its book: :meth:`BaroUpdate.follow_height_resets`)."""

    def __init__(self, measurement, R, gates, correct, receiver_accuracy=False, height_restart=False):
        super().__init__(measurement)
        self._R, self._gates, self._correct = R, gates, correct
        self._receiver_accuracy = receiver_accuracy
        self._height_restart = np.asarray(height_restart, dtype=bool)
        self._read_accuracy = None
        self._fresh_of = (None, None)  # (the tick's samples, its fresh flags): computed once a tick
        self.baro = None  # the vehicle's BaroUpdate (set by Fusion), or None

    def declare(self, system, n, k) -> None:
        super().declare(system, n, k)
        if self._receiver_accuracy:
            port = system.DeclareVectorInputPort("gps_accuracy", n * GPS_ACCURACY_SIZE)
            self._read_accuracy = row_reader(port, n)
            self.extra_ports = ("gps_accuracy",)

    def fresh(self, samples, filters) -> np.ndarray:
        """(n,) bool: the vehicles with a fresh GPS sample this tick (``samples``: the tick's dict;
        the other updates leave the GPS stamps booked, so it is computed once per tick)."""
        seen, flags = self._fresh_of
        if seen is not samples:
            flags = fusion.fresh(samples[self.measurement.port][:, 6], filters.book[:, fusion.GPS_SLOT])
            self._fresh_of = (samples, flags)
        return flags

    def fuse(self, context, discrete_state, filters, samples) -> None:
        gps_fresh = self.fresh(samples, filters)
        if gps_fresh.any():
            rows = slice(None) if gps_fresh.all() else np.flatnonzero(gps_fresh)
            gps = samples[self.measurement.port]
            n = filters.x.shape[0]
            withheld = bias_index = None
            if self.baro is not None:
                withheld = self.baro.withholds_gps_height(discrete_state, n)
                bias_index = self.baro.bias_index
            restart = None
            if self._height_restart.any():
                restart = np.broadcast_to(self._height_restart, (n,))
            R = self._R
            if self._read_accuracy is not None:
                R = receiver_noise(R, gps, self._read_accuracy(context))
            gates, correct = self._gates, self._correct
            steps = fusion.fuse_gps(filters, gps, rows, correct, R, gates, withheld, restart, bias_index)
            if self.baro is not None and bias_index is None:
                self.baro.follow_height_resets(discrete_state, steps)
        self._fresh_of = (None, None)


class YawUpdate(Update):
    """The magnetometer's yaw (rad): the estimator's own compiled step ``mag_tick(filters, mag,
    R_mag, threshold)`` (``kernels.ekf7.mag_tick``: yaw a state; ``kernels.eskf.mag_tick``: yaw of
    the attitude), gated at `threshold`; NIS 1 dof in ``mag_nis``; book column ``fusion.MAG_SLOT``."""

    def __init__(self, measurement, mag_tick, R_mag, threshold):
        super().__init__(measurement)
        self._mag_tick, self.R_mag, self.threshold = mag_tick, R_mag, threshold

    def fuse(self, context, discrete_state, filters, samples) -> None:
        self._mag_tick(filters, samples[self.measurement.port], self.R_mag, self.threshold)


class CorrectionUpdate(Update):
    """An update whose kernel writes the corrections dx (n, k) of the vehicles it fused (n,) and
    leaves applying them to the estimator's ``correct`` (the barometer, the 3-axis magnetometer)."""

    def __init__(self, measurement, correct):
        super().__init__(measurement)
        self._correct = correct
        self._dx = self._fused = None  # (n, k) corrections and (n,) fused flags, at declare

    def declare(self, system, n, k) -> None:
        super().declare(system, n, k)
        self._dx, self._fused = np.zeros((n, k)), np.zeros(n, dtype=bool)

    def _apply(self, filters) -> None:
        """Apply the corrections of this tick's fused vehicles."""
        if self._fused.any():
            self._correct(filters.x, filters.P, self._dx, self._fused)


class FieldUpdate(CorrectionUpdate):
    """The ESKF's 3-axis magnetometer field (m_B gauss, ``estimation/mag3.py``): 3 dof, gated,
    axis by axis (``kernels.aiding.field_rows``); NIS in ``field_nis``; book column
    ``fusion.MAG_SLOT`` (the magnetometer's last stamp). params: MagFieldFusionParams, or one per
    vehicle (their world field and hard iron each vehicle's own, ``aiding.field_model``)."""

    def __init__(self, measurement, correct, params, gate_sigma):
        super().__init__(measurement, correct)
        aiding_kernels = _aiding_kernels()
        gate = gating.gate_threshold(NIS_DOF[measurement.nis], gate_sigma)
        self._model, self._rows = aiding_kernels.field_model(params, gate), aiding_kernels.field_rows

    def fuse(self, context, discrete_state, filters, samples) -> None:
        f, dx = filters, self._dx
        mag = samples[self.measurement.port]
        self._rows(f.x, f.P, mag, f.book, fusion.MAG_SLOT, f.diagnostics, self._model, dx, self._fused)
        self._apply(filters)


class HeadingUpdate(CorrectionUpdate):
    """The EKF7's tilt-compensated heading of a 3-axis magnetometer (rad, ``estimation/mag3.py``),
    with the roll and pitch of ``samples["attitude"]`` (the attitude filter's): 1 dof, gated
    (``kernels.aiding.heading_rows``); NIS in ``mag_nis``; book column ``fusion.MAG_SLOT``.
    tilt: the EKF7's ``ekf.TiltNoise`` or None (its roll/pitch error variance at the context time
    then adds to the heading's). params: MagFieldFusionParams, or one per vehicle (their hard
    iron and declination each vehicle's own, ``aiding.heading_model``)."""

    def __init__(self, measurement, correct, params, gate_sigma, tilt=None):
        super().__init__(measurement, correct)
        aiding_kernels = _aiding_kernels()
        gate = gating.gate_threshold(NIS_DOF[measurement.nis], gate_sigma)
        self._model, self._tilt = aiding_kernels.heading_model(params, gate), tilt
        self._rows = aiding_kernels.heading_rows

    def fuse(self, context, discrete_state, filters, samples) -> None:
        f, dx, model = filters, self._dx, self._model
        if self._tilt is not None:
            model = model._replace(tilt_var=model.tilt_var + self._tilt.variance(context.get_time()))
        mag, attitude = samples[self.measurement.port], samples["attitude"]
        self._rows(f.x, f.P, mag, attitude, f.book, fusion.MAG_SLOT, f.diagnostics, model, dx, self._fused)
        self._apply(filters)


class BaroUpdate(CorrectionUpdate):
    """The barometer's height (m up, ``estimation/baro.py``) against the baro bias: 1 dof, gated
    (``kernels.aiding.baro_rows``); NIS in ``baro_nis``; a book of its own (discrete-state group,
    ``baro.BARO_BOOK_SIZE`` per vehicle: the latest sample, the datum, the gate's rejections and
    the GPS-height check).

    params: BaroFusionParams; gps_z_std: m, the GPS height noise the estimator assumes; period: s,
    the barometer's sample period; carried: whether the vehicle has a barometer (one without: its
    row untouched, as without this update). gps_z_std, period and carried: one for all vehicles or
    (n,) per vehicle. bias_in_state: True when the estimator carries the bias in its state (the
    ESKF: its last error entry, so the update corrects the height and the bias together), False
    when a scalar filter in the book estimates it from the GPS heights of ``samples["gps"]`` (the
    EKF7)."""

    def __init__(
        self, measurement, correct, params, gate_sigma, gps_z_std, period, carried=True, bias_in_state=False
    ):
        super().__init__(measurement, correct)
        gate = gating.gate_threshold(NIS_DOF[measurement.nis], gate_sigma)
        self._params = params
        aiding_kernels = _aiding_kernels()
        self._model = aiding_kernels.baro_model(params, gps_z_std, gate, period, carried, bias_in_state)
        self._rows = aiding_kernels.baro_rows
        self._book = self._no_gps = None
        # the index in x of the bias the estimator carries in its state, None: in the book
        self.bias_index = eskf.BARO_BIAS_NOMINAL if bias_in_state else None

    def declare(self, system, n, k) -> None:
        super().declare(system, n, k)
        self._book = discrete_group(system, np.tile(baro.initial_book(self._params), n))
        self._no_gps = np.tile(fusion.NO_GPS_SAMPLE, (n, 1))

    def withholds_gps_height(self, discrete_state, n) -> np.ndarray:
        """(n,) bool: the vehicles whose GPS height disagrees persistently with their barometer
        (``baro.gps_height_disagrees`` of the book's accumulated evidence; all False with the
        check off): their GPS height feeds neither the bias nor the filter's height."""
        p = self._params
        if p.gps_check_offset <= 0.0:
            return np.zeros(n, dtype=bool)
        book = discrete_state.get_value(self._book).reshape(n, baro.BARO_BOOK_SIZE)
        high, low = book[:, baro.EVIDENCE_HIGH], book[:, baro.EVIDENCE_LOW]
        return baro.gps_height_disagrees(high, low, p.gps_check_threshold)

    def follow_height_resets(self, discrete_state, steps) -> None:
        """Move the book's bias of each vehicle whose height a GPS reset moved by steps (n,) (m, NED
        down; NaN: none): ``baro.moved_bias``, the barometer's innovation kept, as PX4's."""
        moved = np.isfinite(steps)
        if moved.any():
            book = discrete_state.get_mutable_value(self._book).reshape(len(steps), baro.BARO_BOOK_SIZE)
            book[moved, baro.BIAS] = baro.moved_bias(book[moved, baro.BIAS], steps[moved])

    def fuse(self, context, discrete_state, filters, samples) -> None:
        f, dx = filters, self._dx
        book = discrete_state.get_mutable_value(self._book).reshape(f.x.shape[0], baro.BARO_BOOK_SIZE)
        gps = samples.get("gps", self._no_gps)
        self._rows(
            f.x, f.P, samples[self.measurement.port], gps, book, f.diagnostics, self._model, dx, self._fused
        )
        self._apply(filters)


class NoAidUpdate(CorrectionUpdate):
    """A replay's no-aiding sample (PX4's fake position and zero velocity while not GPS-aided,
    ``flightlogs.schedule.no_aid_samples``): p_N (m) and v_N (m/s) with a std of their own per
    component (inf: that component not fused), the Joseph update of the components it carries
    (``fusion.joseph_rows``, H = those rows of [I6 0], R = diag(std²)), ungated as PX4's; the
    correction applied by the estimator's ``correct``. No NIS of its own; a book of its own
    (discrete-state group, the last stamp per vehicle). A non-finite sample is counted and skipped."""

    def __init__(self, measurement, correct):
        super().__init__(measurement, correct)
        self._book = None

    def declare(self, system, n, k) -> None:
        super().declare(system, n, k)
        self._book = discrete_group(system, np.full(n, NO_SAMPLE_STAMP))

    def fuse(self, context, discrete_state, filters, samples) -> None:
        samples_now = samples[self.measurement.port]
        seen = discrete_state.get_mutable_value(self._book)
        stamps = samples_now[:, -1]
        if stamps.tolist() == seen.tolist():  # 99 ticks in 100: no new sample (0.5 us, not 5)
            return
        fresh = fusion.fresh(stamps, seen)
        if not fresh.any():
            return
        seen[fresh] = stamps[fresh]
        rows = np.flatnonzero(fresh)
        z, std = samples_now[rows, 0:6], samples_now[rows, 6:12]
        mask = np.isfinite(std) & (std > 0.0)
        finite = np.isfinite(stamps[rows]) & np.isfinite(np.where(mask, z, 0.0)).all(axis=1)
        filters.diagnostics[rows[~finite], DIAG["nonfinite_samples"]] += 1.0
        rows, z, std, mask = rows[finite], z[finite], std[finite], mask[finite]
        if len(rows) == 0:
            return
        R = np.zeros((len(rows), 6, 6))
        R[:, range(6), range(6)] = np.where(mask, std, 1.0) ** 2
        x, P = filters.x[rows], filters.P[rows]
        dx, P_new, _, fused, _ = fusion.joseph_rows(x, P, z, R, mask)
        self._correct(x, P_new, dx, fused)
        filters.x[rows], filters.P[rows] = x, P_new


class GsfUpdate(Update):
    """The EKF-GSF yaw estimator beside the ESKF (``estimation/gsf.py``, ``kernels/gsf.py``): not
    a sensor of its own, it reads the tick's GPS (``samples["gps"]``, the GPS update's port) and
    IMU (``samples["imu"]``) samples and the magnetometer's fate in ``diagnostics``, and may reset
    the ESKF's yaw. It runs before the other updates: a vehicle whose magnetometer it has stopped
    fusing (after a yaw emergency reset) gets a ``samples["mag"]`` without a fresh sample.

    params: GsfParams; dt: s, the tick; gps_vel_std: m/s, the GPS velocity std the ESKF assumes;
    mag_columns: the (stamp, gated count) ``diagnostics`` columns of the vehicle's magnetometer
    update, or None without one. A book of its own (discrete-state group, ``kernels.gsf.book_size``
    per vehicle) and the group :attr:`log` (n * ``vocabulary.gsf_log_size``: yaw rad, yaw std rad,
    resets, weights), written each tick."""

    def __init__(self, measurement, params, dt, gps_vel_std, mag_columns):
        super().__init__(measurement)
        from quad_drake.kernels import gsf as gsf_kernel  # imported on first use, as the aiding's

        self._kernel = gsf_kernel
        self._model = gsf_kernel.model(params, dt, gps_vel_std, mag_columns)
        self._book = self.log = self._blocked = None

    def declare(self, system, n, k) -> None:
        """Declare the book and the log groups (no input port: the GPS update declares ``gps``)."""
        models = self._model.models
        book = self._kernel.initial_book(models)
        self._book = discrete_group(system, np.tile(book, n))
        self.log = discrete_group(system, np.tile(self._kernel.log_rows(book, models).ravel(), n))
        self._blocked = np.zeros(n, dtype=bool)

    def fuse(self, context, discrete_state, filters, samples) -> None:
        n, kernel = filters.x.shape[0], self._kernel
        book = discrete_state.get_mutable_value(self._book).reshape(n, -1)
        gps = samples.get("gps")
        if gps is None:
            return
        log = discrete_state.get_mutable_value(self.log).reshape(n, -1)
        kernel.tick(filters, book, log, samples["imu"], gps, context.get_time(), self._model, self._blocked)
        if self._blocked.any() and "mag" in samples:
            mag = samples["mag"].copy()
            mag[self._blocked, -1] = NO_SAMPLE_STAMP
            samples["mag"] = mag


class GravityUpdate(Update):
    """PX4 EKF2's gravity-vector fusion (``EKF2_IMU_CTRL`` bit 2), an ESKF's: the accelerometer's
    direction as a measurement of the tilt (``kernels.eskf.gravity_tick``: ``eskf.gravity_update``
    compiled) for each vehicle not aided horizontally (no GPS sample seen for `timeout` s) whose
    peak-held specific-force magnitude lies in `band` (m/s^2; PX4's 0.9-1.1 g) and whose IMU
    sample is finite. It reads no port of its own: the estimator puts this tick's IMU sample
    (``samples["imu"]``, (n, IMU_SIZE): f_B m/s^2 first) and the peak-held levels
    (``samples["manoeuvre"]``, (n, 2): |w_B| rad/s, |f_B| m/s^2; ``eskf.manoeuvre_levels``) into
    the samples. Placed after the sensors' updates, as PX4's ``controlFusionModes`` orders them.

    gravity_tick: the compiled update; var: the measurement variance per tick (of the unit
    vector); gate_var: PX4's variance per its 10 ms update, for the innovation gate `gate`
    (standard deviations)."""

    def __init__(self, gravity_tick, var, gate_var, timeout, band, gate):
        super().__init__(None)
        self._tick, self._var, self._gate_var, self._gate = gravity_tick, var, gate_var, gate
        self._timeout, (self._low, self._high) = timeout, band

    def declare(self, system, n, k) -> None:
        """Nothing to declare: the IMU is the estimator's own input."""

    def fuse(self, context, discrete_state, filters, samples) -> None:
        """The kernel tests each vehicle (unaided, in the band, finite) and fuses those it passes:
        an aided tick costs one call."""
        self._tick(
            filters.x,
            filters.P,
            samples["imu"],
            samples["manoeuvre"],
            filters.book,
            context.get_time(),
            self._timeout,
            self._low,
            self._high,
            self._var,
            self._gate_var,
            self._gate,
        )


def build_updates(declared, sensors, builders) -> tuple:
    """The :class:`Update` s of a vehicle's estimator: for each measurement of `declared` (the
    kind's ``measurements``) that `sensors` (the vehicle's SensorsConfig) carry, in order,
    ``builders[name](measurement)``.

    builders: {measurement name: function} of the estimator system. ValueError (naming the
    measurement) for a declared measurement the system has no update for: an estimator kind that
    declares a sensor its system cannot fuse fails when it is built, never by logging NaN.
    """
    updates = []
    for measurement in measurements_of(declared, sensors):
        if measurement.name not in builders:
            raise ValueError(
                f"the estimator declares the {measurement.name!r} measurement but its system has no "
                f"update for it (it fuses {', '.join(builders)})"
            )
        updates.append(builders[measurement.name](measurement))
    return tuple(updates)


class Fusion:
    """An estimator system's filter state and measurement updates (module docstring).

    system: the LeafSystem (n vehicles); x0 (width), or (n, width) each vehicle's own: the initial
    state; P0 (k, k): the initial covariance, also the fallback of a covariance reset; updates:
    from :func:`build_updates`; repairs: False switches the covariance repair off
    (``fidelity.reference_estimator``). Declares the groups of :class:`Groups` (``groups``) and
    the updates' ports.
    """

    def __init__(self, system, n, x0, P0, updates, repairs):
        x0 = np.asarray(x0, dtype=float)
        self.n, self.width, self.k = n, x0.shape[-1], P0.shape[0]
        self._P0, self._repairs = P0, repairs
        self.groups = Groups(
            x=discrete_group(system, np.broadcast_to(x0, (n, self.width)).ravel()),
            P=discrete_group(system, np.tile(P0.ravel(), n)),
            diagnostics=discrete_group(system, np.tile(initial_diagnostics(), n)),
            book=discrete_group(
                system, np.concatenate((np.tile(fusion.initial_book(), n), np.tile(initial_hold(), n)))
            ),
        )
        for update in updates:
            update.declare(system, n, self.k)
        self.updates = updates
        read = [u for u in updates if u.read is not None]
        self.ports = tuple(dict.fromkeys(port for u in read for port in (u.measurement.port, *u.extra_ports)))
        g = self.groups  # (group, the shape of its view) of each Filters field, for filters()
        self._views = (
            (g.x, (n, self.width)),
            (g.P, (n, self.k, self.k)),
            (g.diagnostics, (n, DIAGNOSTICS_SIZE)),
            (g.book, (n, fusion.BOOK_SIZE), n * fusion.BOOK_SIZE, (n, HOLD_SIZE)),
        )
        self._readers = tuple((u.measurement.port, u.read) for u in updates if u.read is not None)
        self._gps = next((u for u in updates if isinstance(u, GpsUpdate)), None)
        if self._gps is not None:
            self._gps.baro = self.update_of(BaroUpdate)

    def update_of(self, kind) -> object | None:
        """This estimator's update of class `kind`, or None when the vehicle has no such sensor."""
        return next((u for u in self.updates if isinstance(u, kind)), None)

    def filters(self, discrete_state) -> fusion.Filters:
        """Writable (n, ...) views of x, P, diagnostics, the book and the hold (valid inside the
        handler that takes them: Drake may hand the next one another DiscreteValues)."""
        get = discrete_state.get_mutable_value
        (x, x_shape), (P, P_shape), (diagnostics, d_shape), (book, b_shape, split, h_shape) = self._views
        book_and_hold = get(book)
        return fusion.Filters(
            get(x).reshape(x_shape),
            get(P).reshape(P_shape),
            get(diagnostics).reshape(d_shape),
            book_and_hold[:split].reshape(b_shape),
            book_and_hold[split:].reshape(h_shape),
        )

    def read(self, context) -> dict:
        """{port: (n, width) samples} of every update's input this tick."""
        return {port: read(context) for port, read in self._readers}

    def fuse(self, context, discrete_state, filters, samples, healthy, updates=None) -> None:
        """The covariance check, then the updates (all, or `updates`), IN PLACE on `filters`.

        healthy (n,) bool: the prediction's per-tick check (``fusion.covariance_looks_healthy``);
        where it failed or a GPS sample is fresh, the full check and repair (counted in
        ``covariance_repairs``); None: nothing to check (every P healthy, no fresh GPS sample)."""
        if self._repairs and healthy is not None:
            check = ~healthy
            if self._gps is not None:
                check = self._gps.fresh(samples, filters) | check
            if check.any():
                outcomes = fusion.repair_covariances(filters.P, check, self._P0)
                filters.diagnostics[outcomes != gating.COVARIANCE_OK, DIAG["covariance_repairs"]] += 1.0
        for update in self.updates if updates is None else updates:
            update.fuse(context, discrete_state, filters, samples)
