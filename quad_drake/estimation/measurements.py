"""Pure: the measurements an estimator can fuse, and which of them a vehicle's estimator fuses.

A :class:`Measurement` is what the package knows of one kind of measurement update before any
system exists: the estimator input it reads (``port``, one vehicle's ``width``), the NIS and
stamp columns it writes in ``diagnostics`` (``nis``: a key of ``vocabulary.NIS_DOF``) and
whether a vehicle's sensors carry it. An estimator kind declares the measurements it fuses, in
fusion order (``estimation/registry.py``, ``EstimatorKind.measurements``); its system builds one
update per name (``systems/updates.py``) and refuses a name it has no update for.

:func:`measurements_of` is the one answer to "what does this vehicle's estimator fuse": the
estimator's input ports, its NIS columns (:func:`nis_sensors`, read by the campaigns' tables)
and the updates it runs all read that list.
"""

from collections.abc import Callable
from dataclasses import dataclass

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
