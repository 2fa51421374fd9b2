"""Benchmark: do PX4's sensor-correction models explain PX4's own innovations on a log?

Reads a ULog's aid-source topics (PX4 v1.14 on: ``estimator_aid_src_baro_hgt``,
``estimator_aid_src_mag``; no replay) and fits, by ordinary least squares with an intercept,
PX4's own innovation on the regressors of a correction PX4 can apply before its estimator:

- the barometer's static-pressure error (``EKF2_PCOEF_XP/XN/YP/YN/Z``): the dynamic pressure
  ½ρv² along each body axis (Pa; v from ``vehicle_local_position``, rotated into FRD by
  ``vehicle_attitude``), signed on x and z (PX4 has a coefficient per direction there);
- the barometer against the horizontal acceleration ‖a_h‖ (m/s²), where a diagnosis found its
  NIS growing;
- the magnetometer's interference from the motors (``CAL_MAGn_xCOMP``): the battery current (A,
  ``CAL_MAG_COMP_TYP`` 2) or the thrust set-point (``CAL_MAG_COMP_TYP`` 1), per body axis.

It prints each fit's coefficients and R² (the share of the innovation's variance the model
explains) over the airborne samples (PX4's land detector) from START s after the first on. A
model worth building into the replay explains a good share; one that explains a few per cent
cannot bring a channel's NIS into its band.

Usage: ``python benchmarks/px4_innovation_models.py LOG.ulg [LOG.ulg ...]``
"""

import argparse
import warnings

import numpy as np
from pyulog import ULog

from quad_drake.models.rotations import rotation_entries

START = 5.0  # s after the aid source's first sample: the estimator's start-up left out
AIR_DENSITY = 1.225  # kg/m^3, ISA sea level (the scale of the dynamic pressure only)


def topics(path):
    """{topic name: its first instance's data dict} of the ULog at `path`."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pyulog's notes on unregistered message ids
        ulog = ULog(str(path))
    found = {}
    for dataset in ulog.data_list:
        found.setdefault(dataset.name, dataset.data)
    return found


def at(data, times, field):
    """`field` of a topic interpolated at `times` (µs)."""
    return np.interp(times, data["timestamp"], data[field])


def fit(regressors, innovation):
    """(coefficients with the intercept first, R²) of the least-squares fit."""
    design = np.column_stack([np.ones(len(innovation)), *regressors])
    coefficients, *_ = np.linalg.lstsq(design, innovation, rcond=None)
    residual = innovation - design @ coefficients
    return coefficients, 1.0 - residual.var() / innovation.var()


def airborne(found, times):
    """(m,) bool: airborne by PX4's land detector (all where the log lacks it), START s on."""
    kept = times >= times[0] + START * 1e6
    if "vehicle_land_detected" in found:
        kept &= at(found["vehicle_land_detected"], times, "landed") < 0.5
    return kept


def barometer_fits(found):
    """[(label, coefficients, R²)] of the barometer models, or [] without the aid source."""
    source = found.get("estimator_aid_src_baro_hgt")
    if source is None or "vehicle_local_position" not in found:
        return []
    times = source["timestamp"]
    kept = airborne(found, times)
    position, attitude = found["vehicle_local_position"], found["vehicle_attitude"]
    velocity = np.stack([at(position, times, f"v{axis}") for axis in "xyz"], axis=1)
    quaternion = [at(attitude, times, f"q[{i}]") for i in range(4)]
    rotation = np.stack(rotation_entries(*quaternion), axis=-1).reshape(-1, 3, 3)  # R_NB
    body = np.einsum("nji,nj->ni", rotation, velocity)  # R_NBᵀ v_N
    dynamic = 0.5 * AIR_DENSITY * body**2
    pcoef = [dynamic[:, 0] * np.sign(body[:, 0]), dynamic[:, 1], dynamic[:, 2] * np.sign(body[:, 2])]
    accel = np.hypot(at(position, times, "ax"), at(position, times, "ay"))
    innovation = source["innovation"][kept]
    models = (("PCOEF (body q_x, q_y, q_z)", pcoef), ("|a_h|", [accel]), ("both", [*pcoef, accel]))
    return [(label, *fit([r[kept] for r in regressors], innovation)) for label, regressors in models]


def field_fits(found):
    """[(label, axis, coefficients, R²)] of the interference models, or [] without the source."""
    source = found.get("estimator_aid_src_mag")
    if source is None:
        return []
    times = source["timestamp"]
    kept = airborne(found, times)
    drivers = {}
    if "battery_status" in found:
        drivers["current (A)"] = at(found["battery_status"], times, "current_a")
    if "vehicle_thrust_setpoint" in found:
        drivers["thrust set-point"] = at(found["vehicle_thrust_setpoint"], times, "xyz[2]")
    return [
        (label, axis, *fit([driver[kept]], source[f"innovation[{axis}]"][kept]))
        for label, driver in drivers.items()
        for axis in range(3)
    ]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="+", help="ULog files")
    for path in parser.parse_args().logs:
        found = topics(path)
        print(path)
        for label, coefficients, r2 in barometer_fits(found):
            print(f"  barometer ~ {label:28s} R2 {r2:6.3f}  coefficients {np.round(coefficients, 4)}")
        for label, axis, coefficients, r2 in field_fits(found):
            print(
                f"  field {'xyz'[axis]} ~ {label:20s} R2 {r2:6.3f}  coefficients {np.round(coefficients, 5)}"
            )


if __name__ == "__main__":
    main()
