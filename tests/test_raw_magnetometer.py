"""A log whose only magnetometer is PX4's raw ``sensor_mag``: read, calibrated and rotated as the
log's own ``CAL_MAG*`` / ``SENS_BOARD_*`` parameters say (``flightlogs.mag_calibration``), and
fused as the 3-axis field.

``tests/data/flight_logs/roboto_raw_mag.ulg`` is 6 s of a real PX4 v1.12.3 flight (MPL-2.0, the
licence file beside it) holding both the raw ``sensor_mag`` and PX4's own calibrated
``vehicle_magnetometer``: the raw-only log is that file with ``vehicle_magnetometer`` removed
(:func:`_raw_only`), and PX4's calibration is the reference the one here is held to.
"""

from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog

from quad_drake.flightlogs import mag_calibration
from quad_drake.flightlogs.reader import FlightLogError, read_flight_log

RAW_MAG_LOG = Path(__file__).parent / "data" / "flight_logs" / "roboto_raw_mag.ulg"
EXTERNAL_DEVICE = 396809
"""The roboto log's external magnetometer: CAL_MAG1, priority 75 against the internal one's 50."""
INTERNAL_DEVICE = 396825
"""Its internal magnetometer (CAL_MAG0), the one PX4's primary estimator fused at the start."""


def _raw_only(tmp_path, edit=None, selector=False):
    """The fixture as a raw-only log (``vehicle_magnetometer`` removed; and, unless `selector`,
    ``estimator_selector_status``, whose magnetometer would decide: without it the priority
    does, the external one), `edit`(ulog) applied; its path."""
    ulog = ULog(str(RAW_MAG_LOG))
    removed = {"vehicle_magnetometer"} | (set() if selector else {"estimator_selector_status"})
    ulog.data_list[:] = [d for d in ulog.data_list if d.name not in removed]
    if edit is not None:
        edit(ulog)
    path = tmp_path / "raw_only.ulg"
    ulog.write_ulog(str(path))
    return path


def _px4_field(device):
    """(times µs, (m, 3) gauss) of PX4's own calibrated field of `device` in the fixture."""
    ulog = ULog(str(RAW_MAG_LOG), ["vehicle_magnetometer"])
    (data,) = [d.data for d in ulog.data_list if d.data["device_id"][0] == device]
    return data["timestamp_sample"].astype(float), np.column_stack(
        [data[f"magnetometer_ga[{i}]"] for i in range(3)]
    )


def _raw_field(device):
    """(times µs, (m, 3) gauss) of the fixture's raw sensor_mag of `device`."""
    ulog = ULog(str(RAW_MAG_LOG), ["sensor_mag"])
    (data,) = [d.data for d in ulog.data_list if d.data["device_id"][0] == device]
    return data["timestamp_sample"].astype(float), np.column_stack([data[a] for a in "xyz"])


def test_px4_rotation_codes_rotate_as_px4s_table_says():
    x = np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(mag_calibration.rotation_matrix(2) @ x, [0.0, 1.0, 0.0], atol=1e-15)  # yaw 90
    np.testing.assert_allclose(
        mag_calibration.rotation_matrix(8) @ [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], atol=1e-15
    )  # roll 180
    with pytest.raises(mag_calibration.CalibrationError, match="rotation code 40"):
        mag_calibration.rotation_matrix(40)


def test_the_calibration_is_offsets_then_scale_then_rotation():
    parameters = {
        "CAL_MAG2_ID": 7,
        "CAL_MAG2_XOFF": 0.1,
        "CAL_MAG2_YOFF": -0.2,
        "CAL_MAG2_ZOFF": 0.3,
        "CAL_MAG2_XSCALE": 2.0,
        "CAL_MAG2_YSCALE": 1.0,
        "CAL_MAG2_ZSCALE": 0.5,
        "CAL_MAG2_XODIAG": 0.1,
        "CAL_MAG2_ROT": 2,
    }
    rotation, scale, offsets, description = mag_calibration.calibration(7, parameters)
    raw = np.array([[0.6, 0.3, 0.3]])
    # raw - o = (0.5, 0.5, 0); S = [[2, .1, 0], [.1, 1, 0], [0, 0, .5]]: (1.05, 0.55, 0); yaw 90 turns it
    np.testing.assert_allclose(
        mag_calibration.calibrated(raw, rotation, scale, offsets), [[-0.55, 1.05, 0.0]], atol=1e-15
    )
    assert description == "CAL_MAG2 (offsets, scale, CAL_MAG2_ROT 2)"
    compensated = {**parameters, "CAL_MAG_COMP_TYP": 2, "CAL_MAG2_YCOMP": -0.25}  # PX4's current type
    *_, said = mag_calibration.calibration(7, compensated)
    assert said == (
        "CAL_MAG2 (offsets, scale, CAL_MAG2_ROT 2); its power compensation (CAL_MAG_COMP_TYP 2, "
        "CAL_MAG2_X/Y/ZCOMP 0, -0.25, 0) not applied: a replay plays no thrust or current"
    )
    *_, said = mag_calibration.calibration(7, {**parameters, "CAL_MAG_COMP_TYP": 2})  # no coefficient
    assert said == description
    board = {"CAL_MAG0_ID": 5, "CAL_MAG0_ROT": -1, "SENS_BOARD_ROT": 4, "SENS_BOARD_Z_OFF": 90.0}
    rotation, *_ = mag_calibration.calibration(5, board)  # internal: the board's yaw 180, then its 90° trim
    np.testing.assert_allclose(rotation @ [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], atol=1e-15)


def test_px4s_preferred_magnetometer_is_chosen():
    slots = {"CAL_MAG0_ID": 10, "CAL_MAG1_ID": 11}
    assert mag_calibration.chosen_instance([10, 11], slots | {"CAL_MAG0_PRIO": 50, "CAL_MAG1_PRIO": 75}) == 1
    assert mag_calibration.chosen_instance([10, 11], slots | {"CAL_MAG_PRIME": 11}) == 1
    assert mag_calibration.chosen_instance([10, 11], slots | {"CAL_MAG0_EN": 0}) == 1
    assert mag_calibration.chosen_instance([10, 11], slots) == 0
    preferred = slots | {"CAL_MAG0_PRIO": 50, "CAL_MAG1_PRIO": 75}
    assert mag_calibration.chosen_instance([10, 11], preferred, primary=10) == 0  # the primary EKF's


def test_a_log_with_only_the_raw_sensor_mag_is_calibrated_as_px4_calibrated_it(tmp_path):
    with_px4s = read_flight_log(RAW_MAG_LOG)
    assert with_px4s.mag_source == ""  # vehicle_magnetometer first
    log = read_flight_log(_raw_only(tmp_path))
    assert log.mag_source == (
        f"the raw sensor_mag (instance 1, device {EXTERNAL_DEVICE}), calibrated here by CAL_MAG1 "
        "(offsets, scale, CAL_MAG1_ROT 0)"
    )
    times, px4 = _px4_field(EXTERNAL_DEVICE)
    raw_times, raw_values = _raw_field(EXTERNAL_DEVICE)
    after = raw_times * 1e-6 >= log.start_time  # samples before the first IMU sample are dropped
    raw_times, raw_values = raw_times[after], raw_values[after]
    np.testing.assert_allclose(log.mag_field.times + log.start_time, raw_times * 1e-6, atol=1e-9)
    at_ours = np.column_stack([np.interp(raw_times, times, px4[:, i]) for i in range(3)])  # PX4's field
    ours_error = np.median(np.linalg.norm(log.mag_field.values - at_ours, axis=1))
    raw_error = np.median(np.linalg.norm(raw_values - at_ours, axis=1))
    assert ours_error < 0.02 and raw_error > 0.1  # gauss (measured 0.012 and 0.145); the field is 0.50 G
    # With PX4's estimator selector logged, the magnetometer its primary EKF2 instance fused at the
    # start (mag_device_id): the internal one, on the board's rotation.
    primary = read_flight_log(_raw_only(tmp_path, selector=True))
    assert primary.mag_source == (
        f"the raw sensor_mag (instance 0, device {INTERNAL_DEVICE}), calibrated here by CAL_MAG0 "
        "(offsets, scale, internal: SENS_BOARD_ROT 0)"
    )
    times, px4 = _px4_field(INTERNAL_DEVICE)
    raw_times, raw_values = _raw_field(INTERNAL_DEVICE)
    after = raw_times * 1e-6 >= primary.start_time
    at_ours = np.column_stack([np.interp(raw_times[after], times, px4[:, i]) for i in range(3)])
    ours_error = np.median(np.linalg.norm(primary.mag_field.values - at_ours, axis=1))
    raw_error = np.median(np.linalg.norm(raw_values[after] - at_ours, axis=1))
    assert ours_error < 0.02 and raw_error > 0.05  # gauss (measured 0.011 and 0.083)


def test_a_log_before_px4_v1_12_takes_sensor_mag_as_its_driver_calibrated_it(tmp_path):
    def release_1_11(ulog):
        ulog.msg_info_dict["ver_sw_release"] = 0x010B02FF

    log = read_flight_log(_raw_only(tmp_path, release_1_11))
    assert log.mag_source.endswith("calibrated by its driver (PX4 before v1.12): taken as logged")
    np.testing.assert_array_equal(log.mag_field.values, _raw_field(EXTERNAL_DEVICE)[1][-len(log.mag_field) :])


def test_a_raw_magnetometer_without_its_calibration_slot_is_one_line(tmp_path):
    def no_slot(ulog):
        for n in range(4):
            ulog.initial_parameters.pop(f"CAL_MAG{n}_ID", None)

    path = _raw_only(tmp_path, no_slot)
    with pytest.raises(FlightLogError) as error:
        read_flight_log(path)
    reason = "no CAL_MAGn_ID is its device_id 396825"
    assert str(error.value) == f"{path}: sensor_mag cannot be calibrated: {reason}"


@pytest.mark.slow
def test_the_raw_field_is_fused_by_the_eskf(tmp_path):
    from quad_drake.estimation.vocabulary import DIAG
    from quad_drake.flightlogs.replay import replay
    from quad_drake.flightlogs.settings import load_replay

    path = _raw_only(tmp_path)
    result = replay(load_replay(path, "{kind: eskf}"))
    notes = result.notes()
    assert any(n.startswith("magnetometer: the raw sensor_mag (instance 1") for n in notes)
    field_stamps = result.logs["diagnostics"][:, DIAG["field_stamp"]]
    fused = np.unique(field_stamps[field_stamps >= 0.0])
    np.testing.assert_array_equal(fused, result.log.mag_field.times)  # every sample fused as the field
    assert 0.45 < result.aiding.magnetometer.field_strength < 0.55  # gauss: calibrated 0.499, raw 0.384
