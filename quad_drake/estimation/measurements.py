"""Pure: the measurements an estimator can fuse, which of them a vehicle's estimator fuses, and
the noise a GPS sample is fused with where its receiver reports its accuracy.

A :class:`Measurement` is what the package knows of one kind of measurement update before any
system exists: the estimator input it reads (``port``, one vehicle's ``width``), the NIS and
stamp columns it writes in ``diagnostics`` (``nis``: a key of ``vocabulary.NIS_DOF``) and
whether a vehicle's sensors carry it. An estimator kind declares the measurements it fuses, in
fusion order (``estimation/registry.py``, ``EstimatorKind.measurements``); its system builds one
update per name (``systems/updates.py``) and refuses a name it has no update for.

:func:`measurements_of` is the one answer to "what does this vehicle's estimator fuse": the
estimator's input ports, its NIS columns (:func:`nis_sensors`, read by the campaigns' tables)
and the updates it runs all read that list.

:func:`receiver_noise` is PX4 EKF2's rule for a GNSS sample: each std no less than the receiver's
reported accuracy, the estimator's own noise the floor.
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from quad_drake.conventions import BARO_SIZE, GPS_SIZE, MAG_FIELD_SIZE, MAG_SIZE, NO_AID_SIZE


@dataclass(frozen=True)
class Measurement:
    """One kind of measurement update (module docstring).

    name: the update's name (a key of :data:`MEASUREMENTS`); port: the estimator input it reads;
    width: one vehicle's sample on that port (the stamp, s, last); nis: its NIS and stamp columns
    in ``diagnostics`` (``vocabulary.NIS_COLUMNS``); carried(sensors) -> bool: whether a
    SensorsConfig has the sensor.
    """

    name: str
    port: str
    width: int
    nis: str
    carried: Callable[[object], bool]


def _three_axis(sensors) -> bool:
    return sensors.mag is not None and bool(sensors.mag.three_axis)


MEASUREMENTS = {
    m.name: m
    for m in (
        Measurement("gps", "gps", GPS_SIZE, "gps", lambda s: s.gps is not None),
        # the magnetometer's yaw (rad): m_B reduced to a heading by the sensor
        Measurement("yaw", "mag", MAG_SIZE, "mag", lambda s: s.mag is not None and not _three_axis(s)),
        # a 3-axis magnetometer (m_B gauss) as a tilt-compensated heading (EKF7; logged as the mag's)
        Measurement("heading", "mag", MAG_FIELD_SIZE, "mag", _three_axis),
        # a 3-axis magnetometer (m_B gauss) as the field vector (ESKF)
        Measurement("field", "mag", MAG_FIELD_SIZE, "field", _three_axis),
        Measurement("baro", "baro", BARO_SIZE, "baro", lambda s: s.baro is not None),
        # a replay's no-aiding sample (PX4's fake position / zero velocity while not GPS-aided):
        # p, v with a std per component (inf: not fused); no NIS of its own (logged nowhere)
        Measurement("no_aid", "no_aid", NO_AID_SIZE, "", lambda s: bool(s.no_aid)),
    )
}
"""Every measurement update the package knows, by name."""

NIS_ORDER = ("gps", "mag", "field", "baro")
"""The order in which tables list an estimator's NIS."""


def measurements_of(declared, sensors) -> tuple:
    """The :class:`Measurement` s of the names `declared` (an estimator kind's, in fusion order)
    that `sensors` (a SensorsConfig) carry, in that order; ValueError for an unknown name."""
    unknown = [name for name in declared if name not in MEASUREMENTS]
    if unknown:
        raise ValueError(f"unknown measurement {unknown[0]!r} (known: {', '.join(MEASUREMENTS)})")
    return tuple(MEASUREMENTS[name] for name in declared if MEASUREMENTS[name].carried(sensors))


def unfused_sensor(declared, sensors) -> str | None:
    """The port of a sensor `sensors` carry in a form none of the `declared` measurements reads
    (e.g. a 3-axis magnetometer for an estimator that takes the yaw only), or None. A barometer
    that an estimator does not fuse is only logged, so it is not one."""
    carried = {m.port for m in MEASUREMENTS.values() if m.carried(sensors)}
    fused = {m.port for m in measurements_of(declared, sensors)}
    missing = carried - fused - {"baro"}
    return min(missing) if missing else None


# ----- the GPS noise a sample is fused with ---------------------------------------------------------

PX4_GPS_VERTICAL_RATIO = 1.5
"""PX4 EKF2 fuses the GPS height with a std of at least 1.5 ``EKF2_GPS_P_NOISE`` and the vertical
velocity at 1.5 times the horizontal's (``controlGnssHeightFusion``, ``updateGnssVel``: "a
typical ratio of vacc/hacc"); a replay's defaults take the same (``registry.px4_gps_noise``)."""
RECEIVER_POSITION_CAP = 10.0
"""m: the largest receiver position accuracy :func:`receiver_noise` takes (PX4's ``EKF2_NOAID_NOISE``
default: PX4 caps the GPS position's noise there while the GPS is its only position aiding)."""


def receiver_noise(R, gps, accuracy) -> np.ndarray:
    """(N, 6, 6): the GPS noise each vehicle's sample is fused with when its receiver reports its
    accuracy, as PX4 EKF2 fuses a GNSS sample (``updateGnssPos``, ``updateGnssVel``,
    ``controlGnssHeightFusion``): each component's std the larger of the estimator's own (`R`'s
    diagonal: its floor, as PX4's ``EKF2_GPS_P_NOISE`` and ``EKF2_GPS_V_NOISE`` are) and the
    receiver's: the horizontal position's (eph, m) on x and y, the vertical's (epv, m) on z, the
    speed's (sacc, m/s) on the horizontal velocity and :data:`PX4_GPS_VERTICAL_RATIO` times it
    on the vertical; a position accuracy counts up to :data:`RECEIVER_POSITION_CAP`.

    R (6, 6) or (N, 6, 6); gps (N, 7) the samples (p, v, stamp s); accuracy (N, 4) the receiver's
    (``conventions.GPS_ACCURACY_SIZE``: eph m, epv m, sacc m/s, the stamp of the sample they
    describe). A vehicle whose accuracy's stamp is not its sample's, or whose accuracy is not
    finite, keeps R.
    """
    R = np.array(np.broadcast_to(R, (gps.shape[0], 6, 6)))
    reported = (accuracy[:, 3] == gps[:, 6]) & np.isfinite(accuracy[:, 0:3]).all(axis=1)
    if reported.any():
        eph, epv, sacc = accuracy[reported, 0], accuracy[reported, 1], accuracy[reported, 2]
        eph, epv = np.minimum(eph, RECEIVER_POSITION_CAP), np.minimum(epv, RECEIVER_POSITION_CAP)
        vertical_speed = PX4_GPS_VERTICAL_RATIO * sacc
        receiver = np.column_stack([eph, eph, epv, sacc, sacc, vertical_speed]) ** 2
        diagonal = np.arange(6)
        R_reported = R[reported]
        R_reported[:, diagonal, diagonal] = np.maximum(R_reported[:, diagonal, diagonal], receiver)
        R[reported] = R_reported
    return R
