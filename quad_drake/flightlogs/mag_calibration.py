"""Pure: a raw PX4 magnetometer (``sensor_mag``) calibrated as the log's own parameters say.

Since PX4 v1.12 a driver publishes ``sensor_mag`` in its chip's own axes and units (gauss), and
the sensors module calibrates it into ``vehicle_magnetometer`` (PX4's
``src/lib/sensor_calibration/Magnetometer``)::

    m_B = R (S (m_raw - o))

with the offsets o = ``CAL_MAGn_XOFF/YOFF/ZOFF`` (gauss), the symmetric scale matrix S of
diagonal ``CAL_MAGn_XSCALE/YSCALE/ZSCALE`` and off-diagonal ``CAL_MAGn_XODIAG`` (xy),
``YODIAG`` (xz), ``ZODIAG`` (yz), and the rotation R into the body's FRD axes: an external
magnetometer's ``CAL_MAGn_ROT`` (>= 0), an internal one's (``CAL_MAGn_ROT`` = -1) the board's
(``SENS_BOARD_ROT`` followed by the trim ``SENS_BOARD_X/Y/Z_OFF``, degrees). A rotation code
stands for the Euler angles of PX4's ``rot_lookup`` (:data:`PX4_ROTATIONS`, roll, pitch, yaw in
degrees, R = Rz(yaw) Ry(pitch) Rx(roll)). The calibration slot n is the one whose
``CAL_MAGn_ID`` is the sensor's ``device_id``. Power compensation (``CAL_MAG_COMP_TYP``) is not
applied: it needs the motors' thrust or current, which a replay does not play; where the log sets
it (a type and a nonzero ``CAL_MAGn_X/Y/ZCOMP``), the calibration's description says so.

Before v1.12 the drivers applied the calibration themselves and ``sensor_mag`` is already the
body field (measured on pyulog's ``sample_log_small.ulg``, v1.11.2: its ``sensor_mag`` equals its
``vehicle_magnetometer``), so :func:`is_raw` says which a log holds by its ``ver_sw_release``.

Which magnetometer (:func:`chosen_instance`): the one PX4's primary estimator fused where the log
says (``estimator_selector_status.mag_device_id`` at its start: with several EKF2 instances,
``EKF2_MULTI_MAG``, the primary's need not be the highest priority), else the enabled one
(``CAL_MAGn_EN`` not 0) of the highest priority (``CAL_MAGn_PRIO``, v1.12 on), else
``CAL_MAG_PRIME``'s device, else the first instance.
"""

import math

import numpy as np

from quad_drake.models.rotations import rotation_from_euler

PX4_ROTATIONS = (
    (0, 0, 0),
    (0, 0, 45),
    (0, 0, 90),
    (0, 0, 135),
    (0, 0, 180),
    (0, 0, 225),
    (0, 0, 270),
    (0, 0, 315),
    (180, 0, 0),
    (180, 0, 45),
    (180, 0, 90),
    (180, 0, 135),
    (0, 180, 0),
    (180, 0, 225),
    (180, 0, 270),
    (180, 0, 315),
    (90, 0, 0),
    (90, 0, 45),
    (90, 0, 90),
    (90, 0, 135),
    (270, 0, 0),
    (270, 0, 45),
    (270, 0, 90),
    (270, 0, 135),
    (0, 90, 0),
    (0, 270, 0),
)
"""(roll, pitch, yaw) degrees of PX4's rotation codes 0..25 (``enum Rotation`` and ``rot_lookup``
of PX4-Autopilot's ``src/lib/conversion/rotation.h``, BSD-3-Clause); later codes are refused."""
CALIBRATED_BY_SENSORS_MODULE = (1, 12)
"""PX4 release (major, minor) from which ``sensor_mag`` is raw and the sensors module calibrates it."""
MAX_SLOTS = 4
"""Calibration slots ``CAL_MAG0`` .. ``CAL_MAG3``."""


class CalibrationError(ValueError):
    """The log's parameters cannot calibrate its magnetometer (one line: why)."""


def rotation_matrix(code) -> np.ndarray:
    """(3, 3) R of PX4 rotation `code` (:data:`PX4_ROTATIONS`); CalibrationError for an unknown code."""
    code = int(code)
    if not 0 <= code < len(PX4_ROTATIONS):
        known = len(PX4_ROTATIONS) - 1
        raise CalibrationError(f"rotation code {code} is not one of PX4's 0..{known} read here")
    return rotation_from_euler(*(math.radians(a) for a in PX4_ROTATIONS[code]))


def is_raw(release) -> bool | None:
    """Whether ``sensor_mag`` of a log of PX4 release `release` ((major, minor), ``reader.px4_release``)
    is raw (True) or already calibrated (False); None when the log does not say (None)."""
    if release is None:
        return None
    return release >= CALIBRATED_BY_SENSORS_MODULE


def slot_of(device_id, parameters) -> int | None:
    """The calibration slot n whose ``CAL_MAGn_ID`` is `device_id`, or None."""
    for n in range(MAX_SLOTS):
        if parameters.get(f"CAL_MAG{n}_ID") == device_id:
            return n
    return None


def chosen_instance(device_ids, parameters, primary=None) -> int:
    """Index into `device_ids` (each instance's ``device_id``) of the magnetometer PX4 prefers
    (module docstring); primary: the device PX4's primary estimator fused, or None."""
    if primary in device_ids:
        return list(device_ids).index(primary)
    candidates = []
    for i, device in enumerate(device_ids):
        n = slot_of(device, parameters)
        if n is None or parameters.get(f"CAL_MAG{n}_EN", 1) == 0:
            continue
        candidates.append((parameters.get(f"CAL_MAG{n}_PRIO", 0), -i))
    prime = parameters.get("CAL_MAG_PRIME")
    if candidates and any(priority for priority, _ in candidates):
        return -max(candidates)[1]
    if prime in device_ids:
        return list(device_ids).index(prime)
    return -candidates[0][1] if candidates else 0


def calibration(device_id, parameters) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(R (3, 3), S (3, 3), o (3,) gauss, description) of the magnetometer `device_id` from the
    log's `parameters` (module docstring); CalibrationError without a slot for it."""
    n = slot_of(device_id, parameters)
    if n is None:
        raise CalibrationError(f"no CAL_MAGn_ID is its device_id {device_id}")

    def value(name, default=0.0):
        return float(parameters.get(f"CAL_MAG{n}_{name}", default))

    scale = np.diag([value("XSCALE", 1.0), value("YSCALE", 1.0), value("ZSCALE", 1.0)])
    for (i, j), name in (((0, 1), "XODIAG"), ((0, 2), "YODIAG"), ((1, 2), "ZODIAG")):
        scale[i, j] = scale[j, i] = value(name)
    offsets = np.array([value("XOFF"), value("YOFF"), value("ZOFF")])
    code = int(value("ROT", -1))
    if code >= 0:
        rotation, where = rotation_matrix(code), f"CAL_MAG{n}_ROT {code}"
    else:
        trim = [math.radians(float(parameters.get(f"SENS_BOARD_{a}_OFF", 0.0))) for a in "XYZ"]
        board = int(parameters.get("SENS_BOARD_ROT", 0))
        rotation = rotation_from_euler(*trim) @ rotation_matrix(board)
        where = f"internal: SENS_BOARD_ROT {board}"
    description = f"CAL_MAG{n} (offsets, scale, {where})"
    compensation = [value(f"{axis}COMP") for axis in "XYZ"]
    kind = int(parameters.get("CAL_MAG_COMP_TYP", 0))
    if kind and any(compensation):
        description += (
            f"; its power compensation (CAL_MAG_COMP_TYP {kind}, CAL_MAG{n}_X/Y/ZCOMP "
            f"{', '.join(f'{c:g}' for c in compensation)}) not applied: a replay plays no thrust or current"
        )
    return rotation, scale, offsets, description


def calibrated(raw, rotation, scale, offsets) -> np.ndarray:
    """(m, 3) body field m_B = R (S (m_raw - o)) (gauss, FRD) of (m, 3) raw samples (gauss)."""
    return (np.asarray(raw, dtype=float) - offsets) @ scale.T @ rotation.T
