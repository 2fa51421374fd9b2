"""Pure: the magnetometer a replay fuses, as the flight controller calibrated it, and the world
field it is fused against.

The logged field (``vehicle_magnetometer`` or ``sensor_combined``'s) is already corrected by
PX4's calibration (``CAL_MAG*`` offsets and scales); what PX4 subtracts on top is the bias its
EKF2 learned: before v1.13 stored as parameters (``EKF2_MAGBIAS_X/Y/Z``, gauss, body FRD,
subtracted before the estimator sees the field), and in every version its estimator's own bias
state, which the log holds from its first sample (``FlightLog.estimator_mag_bias``: the logger
starts at arming, after the estimator has learned on the ground). The replay subtracts the
parameters, and the state too only where asked (``ReplayConfig.estimator_mag_bias``, off by
default: measured mixed); :func:`learned_bias` sums what is subtracted. The replay's ESKF does not
learn the bias further in flight.
The world field m_N (strength, declination, inclination) comes from, in order:

- the declination: as PX4 chose it. With a fix and ``EKF2_DECL_TYPE`` bit 0 set (its default,
  7), PX4 fuses its parameter ``EKF2_MAG_DECL`` until the fix and its own geo library's value
  from the fix on, and with bit 1 set it saves that value to ``EKF2_MAG_DECL`` at disarm: a
  saved parameter within SAVED_DECLINATION_TOLERANCE of the World Magnetic Model at the fix is
  PX4's own library's value for this place (saved on an earlier flight here), so it is taken,
  PX4's value both before and after its fix; otherwise (not saved, or saved elsewhere) the World
  Magnetic Model at the first fix. PX4's library is a coarse table of the model, a few tenths of
  a degree off it, and a simulator takes its field from that table: on pyulog's SITL log with
  ground truth the saved 2.98° puts our yaw 0.7 mrad RMS from the truth, the model's 3.13° 2.7
  mrad. Without bit 0: the log's own (PX4's parameter ``EKF2_MAG_DECL`` / ``ATT_MAG_DECL``, a
  CSV's ``declination`` row); else the model at the first fix; else 0;
- the strength and inclination: the log's own field, as PX4 EKF2 initialises its earth-field
  states from the measured field at alignment: the median strength over the log, and the median
  inclination against the accelerometer's gravity (mean over HEADING_GRAVITY_WINDOW before each
  field sample) over the first ALIGNMENT_TIME s, sin I = m . (-f / |f|) / |m|. The World
  Magnetic Model's figures at the fix are printed beside them: a simulator's field need not be
  the Earth's (on the bundled SITL log fixing the model's inclination instead tilts the ESKF's
  pitch 5.2 mrad RMS from PX4's, against 1.8 with the log's own).

The World Magnetic Model is ``pygeomag``'s (the NOAA/BGS model of the fix's year: WMM2010 ...
WMM2025), at the first fix and its UTC date.

:func:`magnetometer_model` returns them with one line per choice (printed as the replay's notes).
"""

import math
from dataclasses import dataclass

import numpy as np

from quad_drake.flightlogs.schedule import gravity_directions
from quad_drake.models.rotations import wrap_to_pi

WMM_MODELS = {
    2010: "wmm/WMM_2010.COF",
    2015: "wmm/WMM_2015v2.COF",
    2020: "wmm/WMM_2020.COF",
    2025: "wmm/WMM_2025.COF",
}
"""pygeomag's World Magnetic Model coefficient files by first valid year (each valid 5 years)."""
NANOTESLA_PER_GAUSS = 1e5
EARTH_FIELD_STRENGTH = (0.22, 0.67)
"""gauss: the weakest and strongest field at the Earth's surface (the WMM's range)."""
INCLINATION_MISMATCH = math.radians(10.0)
"""rad: a log's field inclination farther than this from the model's at the fix is flagged (the
model is good to well under 1°; a mounted magnetometer near motors and wires is often 5° off)."""
SAVED_DECLINATION_TOLERANCE = math.radians(1.0)
"""rad: a saved ``EKF2_MAG_DECL`` this close to the World Magnetic Model at the fix is PX4's own
geo library's value for the place (its table's error against the model is a few tenths of a
degree; a declination saved a few hundred km away differs by more)."""
DECL_USE_GEO, DECL_SAVE = 1, 2
"""``EKF2_DECL_TYPE`` bits: look the declination up at the fix; save it to ``EKF2_MAG_DECL``."""
ALIGNMENT_TIME = 1.0
"""s from the first field sample over which the field's inclination is measured (before take-off)."""


@dataclass(frozen=True)
class MagnetometerModel:
    """What a replay assumes of the log's magnetometer: world field strength (gauss), declination
    (rad, east of true north), inclination (rad, below horizontal), the hard iron subtracted
    (3, gauss, body FRD), and notes (one line per choice, where each figure came from)."""

    field_strength: float
    declination: float
    inclination: float
    hard_iron: tuple
    notes: tuple


def world_field(latitude, longitude, altitude, year) -> tuple[float, float, float]:
    """(declination rad, inclination rad, strength gauss) of the World Magnetic Model at a point
    (deg, deg, m above the ellipsoid) and decimal year, with the model of that year (the nearest
    one outside 2010-2030)."""
    from pygeomag import GeoMag

    base = max([first for first in WMM_MODELS if first <= year], default=min(WMM_MODELS))
    model = GeoMag(coefficients_file=WMM_MODELS[base])
    result = model.calculate(
        glat=float(latitude),
        glon=float(longitude),
        alt=float(altitude) / 1000.0,
        time=float(year),
        allow_date_outside_lifespan=True,
    )
    return math.radians(result.d), math.radians(result.i), result.f / NANOTESLA_PER_GAUSS


def learned_bias(parameters, estimator_bias=None) -> tuple[float, ...]:
    """(3-tuple gauss, FRD) PX4 EKF2's learned magnetometer bias: the parameters
    ``EKF2_MAGBIAS_X/Y/Z`` (zeros where the log does not hold them) plus `estimator_bias`, its
    estimator's bias state at the log's start (3, gauss; None: none logged)."""
    saved = [float(parameters.get(f"EKF2_MAGBIAS_{axis}", 0.0)) for axis in "XYZ"]
    state = (0.0, 0.0, 0.0) if estimator_bias is None else estimator_bias
    return tuple(s + float(b) for s, b in zip(saved, state, strict=True))


def measured_field(log, hard_iron) -> tuple[float, float]:
    """(strength gauss, inclination rad) of the log's own field: the median |m_B - hard_iron| and
    the median inclination against the accelerometer's gravity over the first ALIGNMENT_TIME s."""
    field = log.mag_field.values - np.asarray(hard_iron)
    strength = float(np.median(np.linalg.norm(field, axis=1)))
    early = log.mag_field.times <= log.mag_field.times[0] + ALIGNMENT_TIME
    down = -gravity_directions(log.imu, log.mag_field.times[early])
    down /= np.linalg.norm(down, axis=1, keepdims=True)
    sines = np.sum(field[early] * down, axis=1) / np.linalg.norm(field[early], axis=1)
    return strength, float(np.arcsin(np.clip(np.median(sines), -1.0, 1.0)))


def magnetometer_model(log, current_year=None, subtract_estimator_bias=True) -> MagnetometerModel:
    """MagnetometerModel of a FlightLog with a magnetometer (module docstring). current_year:
    decimal year used when the log has a fix but no UTC time (default: the newest model's epoch).
    subtract_estimator_bias: the bias PX4's estimator had learned by the log's start
    (``log.estimator_mag_bias``, gauss) is part of the hard iron; False: it is not (the replay's
    ``estimator_mag_bias: false``), and a last note says so where the log holds one."""
    state = log.estimator_mag_bias
    learned = state is not None and any(state)
    hard_iron = learned_bias(log.parameters, state if subtract_estimator_bias else None)
    notes = []
    saved = learned_bias(log.parameters)
    if any(saved):
        notes.append(
            "magnetometer: PX4's learned bias EKF2_MAGBIAS_X/Y/Z = "
            f"({saved[0]:.4f}, {saved[1]:.4f}, {saved[2]:.4f}) G subtracted"
        )
    if learned and subtract_estimator_bias:
        notes.append(
            "magnetometer: PX4's estimator's learned bias at the log's start (estimator_sensor_bias) = "
            f"({state[0]:.4f}, {state[1]:.4f}, {state[2]:.4f}) G subtracted"
        )
    strength, inclination = measured_field(log, hard_iron)
    notes.append(
        f"magnetometer: world field {strength:.3f} G, inclination {math.degrees(inclination):.1f}° "
        "(the log's own: median strength; against gravity over its first second)"
    )
    if not EARTH_FIELD_STRENGTH[0] <= strength <= EARTH_FIELD_STRENGTH[1]:
        notes.append(
            f"warning: the log's field strength ({strength:.2f} G) is outside the Earth's "
            f"({EARTH_FIELD_STRENGTH[0]:g}-{EARTH_FIELD_STRENGTH[1]:g} G): the magnetometer is "
            "uncalibrated or disturbed; its yaw and the tilt it constrains cannot be trusted"
        )
    wmm = None
    if log.origin is not None:
        year = log.fix_date
        if year is None:
            year = float(max(WMM_MODELS)) if current_year is None else current_year
            notes.append(f"magnetometer: the log has no UTC time; the WMM is taken at {year:g}")
        wmm = world_field(*log.origin, year)
        where = f"{log.origin[0]:.4f}°, {log.origin[1]:.4f}°"
        notes.append(
            f"magnetometer: the WMM at the first fix ({where}, {year:.1f}): {wmm[2]:.3f} G, "
            f"inclination {math.degrees(wmm[1]):.1f}°, declination {math.degrees(wmm[0]):.2f}°"
        )
        if abs(inclination - wmm[1]) > INCLINATION_MISMATCH:
            notes.append(
                f"warning: the log's field inclination ({math.degrees(inclination):.1f}°) is "
                f"{math.degrees(abs(inclination - wmm[1])):.0f}° from the Earth's there: the "
                "magnetometer is disturbed or its rotation wrong; its yaw cannot be trusted"
            )
    declination_type = int(log.parameters.get("EKF2_DECL_TYPE", 0))
    looks_up = declination_type & DECL_USE_GEO or log.mag_declination is None
    saved_here = (
        wmm is not None
        and log.mag_declination is not None
        and declination_type & DECL_USE_GEO
        and declination_type & DECL_SAVE
        and abs(wrap_to_pi(log.mag_declination - wmm[0])) <= SAVED_DECLINATION_TOLERANCE
    )
    if saved_here:
        declination = log.mag_declination
        notes.append(
            f"magnetometer: declination {math.degrees(declination):.2f}° (the log's EKF2_MAG_DECL: "
            "PX4's own look-up saved at this place, what it fuses before and after its fix)"
        )
    elif wmm is not None and looks_up:
        declination = wmm[0]
        notes.append(f"magnetometer: declination {math.degrees(declination):.2f}° (WMM at the first fix)")
    elif log.mag_declination is not None:
        declination = log.mag_declination
        notes.append(f"magnetometer: declination {math.degrees(declination):.2f}° (the log's parameter)")
    else:
        declination = 0.0
        notes.append("magnetometer: declination 0 (no parameter, no fix): yaw is magnetic, as PX4's then")
    if learned and not subtract_estimator_bias:
        notes.append(
            "magnetometer: PX4's estimator had learned a bias of "
            f"({state[0]:.4f}, {state[1]:.4f}, {state[2]:.4f}) G by the log's start "
            "(estimator_sensor_bias): not subtracted (--set estimator_mag_bias=true subtracts it)"
        )
    return MagnetometerModel(strength, declination, inclination, hard_iron, tuple(notes))
