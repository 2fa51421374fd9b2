"""Flight logs, pure parts: the ULog and CSV readers (units and frames once, bad logs refused in
one line), the playback schedule, the tilt-compensated heading and the comparison statistics."""

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog
from scipy.stats import chi2

from quad_drake.conventions import GRAVITY, NO_SAMPLE_STAMP
from quad_drake.flightlogs import comparison
from quad_drake.flightlogs.reader import FlightLogError, Samples, read_flight_log
from quad_drake.flightlogs.schedule import (
    RestTest,
    first_ticks,
    gravity_directions,
    imu_tick_means,
    initial_attitude,
    no_aid_samples,
    playback_streams,
    superseded_samples,
    tilt_compensated_heading,
)
from quad_drake.flightlogs.settings import LOG_DIR
from quad_drake.models.rotations import euler_from_quats, rotation_from_euler

REAL = LOG_DIR / "real_auav_x21_attitude_flight.ulg"
SITL = LOG_DIR / "sitl_takeoff_land_gps.ulg"
ROBOTO = Path(__file__).parent / "data" / "flight_logs" / "roboto_raw_mag.ulg"  # MPL-2.0, see beside it


@pytest.fixture(scope="module")
def real_log():
    return read_flight_log(REAL)


@pytest.fixture(scope="module")
def sitl_log():
    return read_flight_log(SITL)


def test_the_real_flight_reads_as_an_attitude_only_log(real_log):
    assert real_log.sensors() == ["mag"]  # its sensor_combined barometer is marked invalid throughout
    assert len(real_log.imu) == 17070 and real_log.imu.times[0] == 0.0
    assert 68.8 < real_log.duration < 69.0
    assert np.median(np.diff(real_log.imu.times)) == pytest.approx(0.004, abs=1e-6)  # 250 Hz
    assert real_log.gps is None and real_log.origin is None
    assert np.isnan(real_log.reference_position.values[:, 0:2]).all()  # no horizontal frame without GPS
    assert len(real_log.mag_field) == 6758  # each sensor_combined field sample once
    assert 0.3 < np.median(np.linalg.norm(real_log.mag_field.values, axis=1)) < 0.6  # gauss
    assert real_log.mag_declination == 0.0  # ATT_MAG_DECL
    assert len(real_log.reference_attitude) > 6000


def test_the_gps_receivers_reported_accuracy_is_read_with_each_fix(sitl_log):
    data = ULog(str(SITL), ["vehicle_gps_position"]).get_dataset("vehicle_gps_position").data
    fixed = data["fix_type"] >= 3
    accuracy = sitl_log.gps_accuracy
    np.testing.assert_array_equal(accuracy.times, sitl_log.gps.times)
    expected = np.column_stack([data[name][fixed] for name in ("eph", "epv", "s_variance_m_s")])
    np.testing.assert_array_equal(accuracy.values, expected)
    # the SITL receiver's accuracy as it settles after the fix (m, m, m/s)
    assert accuracy.values[0].tolist() == pytest.approx([2.97, 3.07, 0.25], abs=0.01)
    assert accuracy.values[-1].tolist() == pytest.approx([0.30, 0.40, 0.25], abs=0.01)


def test_whether_px4s_estimator_fused_the_gps_is_read_from_its_control_flags(sitl_log):
    data = ULog(str(SITL), ["estimator_status"]).get_dataset("estimator_status").data
    fused = (data["control_mode_flags"].astype(np.int64) >> 2) & 1
    on = data["timestamp"][np.argmax(fused > 0)] * 1e-6 - sitl_log.start_time  # s after the first IMU sample
    record = sitl_log.px4_gps_fusion
    assert record.times.tolist() == pytest.approx([0.0, on], abs=1e-6)  # s, of µs stamps
    assert record.values[:, 0].tolist() == [0.0, 1.0] and 9.7 < record.times[1] < 9.9


def test_the_zero_velocity_at_rest_is_the_logs_px4_releases(sitl_log, tmp_path):
    from quad_drake.flightlogs.reader import px4_release
    from quad_drake.flightlogs.replay import no_aid_noise
    from quad_drake.flightlogs.settings import dump_replay, load_replay, rest_velocity_std

    assert px4_release({"ver_sw_release": 0x010D0000}) == (1, 13)  # 0xMMmmpptt
    assert px4_release({"ver_sw_release": 0x011100C0}) == (1, 17)
    assert px4_release({"ver_sw_release": 0}) is None and px4_release({}) is None
    assert sitl_log.px4_release == (1, 15)
    config = load_replay(SITL, "{kind: eskf}")
    assert config.rest_velocity_std is None  # the default: the log's release's
    # PX4 v1.13 fused its zero velocity at rest at 0.001 m/s (its ground-truth log's own covariance
    # record); from v1.14 on at 0.2 m/s once aligned; before v1.13 none (0: not fused); a log
    # that names no release: the current rule
    releases = ((1, 13), (1, 15), (1, 17), (1, 12), (1, 11), None)
    assert [rest_velocity_std(config, r) for r in releases] == [0.001, 0.2, 0.2, 0.0, 0.0, 0.2]
    assert rest_velocity_std(load_replay(SITL, "{kind: eskf}", ["rest_velocity_std=0.05"]), (1, 13)) == 0.05
    v1_13 = dataclasses.replace(sitl_log, px4_release=(1, 13))
    assert no_aid_noise(v1_13, config).rest_velocity_std == 0.001
    assert no_aid_noise(sitl_log, config).rest_velocity_std == 0.2
    v1_11 = dataclasses.replace(sitl_log, px4_release=(1, 11))
    times = np.arange(1.0, 9.0, 0.2)
    rest = RestTest.of(v1_11.imu, v1_11.landed)
    samples = no_aid_samples(rest, times, no_aid_noise(v1_11, config))
    assert np.isinf(samples.values[:, 9:12]).all()  # no zero velocity (inf: not fused) ...
    assert (samples.values[:, 6:8] == 0.01).any()  # ... and the fake position at rest as before
    none = load_replay(SITL, "{kind: eskf}", ["rest_velocity_std=0"])
    assert no_aid_noise(sitl_log, none).rest_velocity_std == math.inf
    with pytest.raises(Exception, match="rest_velocity_std"):
        load_replay(SITL, "{kind: eskf}", ["rest_velocity_std=-1"])
    # a replay's saved config holds the std it resolved, 0 for none, and loads again as it
    resolved = dataclasses.replace(config, rest_velocity_std=rest_velocity_std(config, (1, 11)))
    saved = tmp_path / "config.yaml"
    saved.write_text(dump_replay(resolved), encoding="utf-8")
    assert load_replay(str(saved)).rest_velocity_std == 0.0


def test_only_the_fixes_px4s_estimator_fused_are_kept():
    from quad_drake.flightlogs.reader import FlightLog
    from quad_drake.flightlogs.schedule import fused_by_px4

    imu = Samples(np.arange(0.0, 12.0, 0.5), np.zeros((24, 6)))
    gps = Samples(np.arange(1.0, 11.0), np.arange(60.0).reshape(10, 6))
    accuracy = Samples(gps.times, np.arange(30.0).reshape(10, 3))
    record = Samples(np.array([0.0, 5.0, 8.0]), np.array([[0.0], [1.0], [0.0]]))  # fused over [5, 8)
    log = FlightLog("x", imu, gps=gps, gps_accuracy=accuracy, px4_gps_fusion=record)
    kept = fused_by_px4(log)
    assert kept.gps.times.tolist() == [5.0, 6.0, 7.0] and kept.gps_accuracy.times.tolist() == [5.0, 6.0, 7.0]
    np.testing.assert_array_equal(kept.gps.values, gps.values[4:7])
    np.testing.assert_array_equal(kept.gps_accuracy.values, accuracy.values[4:7])
    never = fused_by_px4(dataclasses.replace(log, px4_gps_fusion=Samples(np.zeros(1), np.zeros((1, 1)))))
    assert never.gps is None and never.gps_accuracy is None
    always = dataclasses.replace(log, px4_gps_fusion=Samples(np.zeros(1), np.ones((1, 1))))
    assert fused_by_px4(always) is always
    unrecorded = dataclasses.replace(log, px4_gps_fusion=None)  # a CSV: every fix
    assert fused_by_px4(unrecorded) is unrecorded


def test_the_accelerometer_reads_the_physical_specific_force(sitl_log):
    # On the ground before take-off: f_B = R^T (a - g) = (0, 0, -9.81), the package's convention.
    resting = sitl_log.imu.values[sitl_log.imu.times < 5.0, 0:3].mean(axis=0)
    assert resting == pytest.approx([0.0, 0.0, -GRAVITY], abs=0.1)


def test_an_imu_sample_is_timed_at_the_start_of_its_integration_interval(sitl_log):
    data = ULog(str(SITL), ["sensor_combined"]).get_dataset("sensor_combined").data
    start = (data["timestamp"] - data["gyro_integral_dt"]).astype(float)
    assert sitl_log.start_time == pytest.approx(start[0] * 1e-6)
    assert sitl_log.imu.times == pytest.approx((start - start[0]) * 1e-6, abs=1e-9)


def test_the_sitl_gps_becomes_local_ned_at_its_first_fix(sitl_log):
    gps = sitl_log.gps
    assert sitl_log.origin == pytest.approx((47.3977418, 8.5455939, 488.005), abs=1e-6)
    assert gps.values[0, 0:3] == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
    assert gps.times[0] == pytest.approx(9.172, abs=0.01)  # samples before the 3D fix are not used
    assert gps.values[:, 2].min() == pytest.approx(-2.18, abs=0.02)  # the take-off to about 2 m
    assert sitl_log.mag_declination == pytest.approx(math.radians(3.3230793476104736))
    assert len(sitl_log.baro) == 622 and sitl_log.baro.values[0, 0] == pytest.approx(488.098, abs=1e-3)


def test_px4s_local_position_is_moved_into_the_gps_frame(sitl_log):
    # Both frames' origins are geodetic points; once PX4's is expressed in ours, its horizontal
    # position follows the GPS to the centimetre the SITL GPS is good to.
    reference = sitl_log.reference_position
    valid = np.isfinite(reference.values[:, 0])
    assert not valid[:50].any() and valid[-50:].all()  # no global origin before the GPS
    at = reference.times[valid]
    for axis in (0, 1):
        gps = np.interp(at, sitl_log.gps.times, sitl_log.gps.values[:, axis])
        assert np.sqrt(np.mean((reference.values[valid, axis] - gps) ** 2)) < 0.03


def csv_rows(log):
    """The CSV rows of a FlightLog (the SITL log written in the CSV format)."""
    rows = ["# the SITL log in quad_drake's CSV format", "time,sensor,v0,v1,v2,v3,v4,v5"]
    import pymap3d

    latitude, longitude, altitude = pymap3d.ned2geodetic(*log.gps.values[:, 0:3].T, *log.origin)
    gps = np.column_stack([latitude, longitude, altitude, log.gps.values[:, 3:6]])
    streams = [
        ("imu", log.imu.times, log.imu.values),
        ("gps", log.gps.times, gps),
        ("gps_accuracy", log.gps_accuracy.times, log.gps_accuracy.values),
        ("gps_fused", log.px4_gps_fusion.times, log.px4_gps_fusion.values),
        ("mag", log.mag_field.times, log.mag_field.values),
        ("baro", log.baro.times, log.baro.values),
        ("attitude", log.reference_attitude.times, log.reference_attitude.values),
        ("position", log.reference_position.times, log.reference_position.values),
    ]
    for kind, times, values in streams:
        rows += [
            f"{float(t)!r},{kind}," + ",".join(repr(float(v)) for v in row)
            for t, row in zip(times, values, strict=True)
        ]
    from quad_drake.flightlogs.earth_field import magnetometer_model

    rows.append(f"0,declination,{magnetometer_model(log).declination!r}")  # the one the ULog's replay uses
    rows.append(f"0,date,{log.fix_date!r}")
    return rows


@pytest.fixture(scope="module")
def sitl_csv(sitl_log, tmp_path_factory):
    path = tmp_path_factory.mktemp("csv") / "sitl.csv"
    path.write_text("\n".join(csv_rows(sitl_log)) + "\n", encoding="utf-8")
    return path


def test_a_csv_log_reads_as_the_same_flight(sitl_log, sitl_csv):
    log = read_flight_log(sitl_csv)
    from quad_drake.flightlogs.earth_field import magnetometer_model

    assert log.sensors() == sitl_log.sensors() and log.fix_date == sitl_log.fix_date
    assert log.mag_declination == magnetometer_model(sitl_log).declination  # the row csv_rows wrote
    for name in ("imu", "mag_field", "baro", "reference_attitude", "gps_accuracy", "px4_gps_fusion"):
        ours, theirs = getattr(log, name), getattr(sitl_log, name)
        assert ours.times == pytest.approx(theirs.times, abs=1e-12)
        assert ours.values == pytest.approx(theirs.values, abs=1e-12)
    assert log.gps.values == pytest.approx(sitl_log.gps.values, abs=1e-6)  # geodetic and back
    assert log.origin == pytest.approx(sitl_log.origin, abs=1e-6)  # ned2geodetic and back
    np.testing.assert_allclose(log.reference_position.values, sitl_log.reference_position.values)
    # gps_fused rows before the first IMU row give the value at the start: the last of them
    rows = [line for line in sitl_csv.read_text(encoding="utf-8").splitlines() if ",gps_fused," not in line]
    on = float(sitl_log.px4_gps_fusion.times[1])
    early = sitl_csv.parent / "early.csv"
    early.write_text("\n".join([*rows, "-5.0,gps_fused,1", "-1.0,gps_fused,0", f"{on!r},gps_fused,1"]) + "\n")
    record = read_flight_log(early).px4_gps_fusion
    assert record.values[:, 0].tolist() == [0.0, 1.0] and record.times.tolist() == [0.0, on]


def test_a_csv_gps_sample_north_of_the_first_is_that_far_north(tmp_path):
    path = tmp_path / "north.csv"
    rows = ["0,imu,0,0,-9.81,0,0,0", "0.1,gps,47.0,8.0,500.0,0,0,0", "0.2,gps,47.001,8.0,500.0,0,0,0"]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    north, east, down = read_flight_log(path).gps.values[1, 0:3]
    assert north == pytest.approx(111.2, abs=0.2) and abs(east) < 1e-6 and abs(down) < 0.01  # 1e-3 deg


BAD_CSV = [
    ("0,gps,47,8,500,0,0,0\n", "no imu rows"),
    (
        "0,imu,0,0,-9.8,0,0,0\n0.004,imu,0,0,-9.8,0,0,nan\n",
        "imu rows: sample 1 (t = 0.004 s) has a non-finite value nan",
    ),
    (
        "0,imu,0,0,-9.8,0,0,0\n0.004,imu,0,0,-9.8,0,0,0\n0.002,imu,0,0,-9.8,0,0,0\n",
        "time does not increase at sample 2",
    ),
    (
        "0,imu,0,0,-9.8,0,0,0\n0.004,imu,0,0,-9.8,0,0,0\n0.004,imu,0,0,-9.8,0,0,0\n",
        "time does not increase at sample 2",
    ),
    ("0,imu,0,0,-9.8,0,0,0\n0.1,lidar,3\n", "line 2: sensor 'lidar' is not one of imu, gps"),
    ("0,imu,0,0,-9.8,0,0\n", "line 1: imu takes 6 values"),
    ("0,imu,0,0,-9.8,0,0,x\n", "line 1: not a number"),
    (
        "0,imu,0,0,-9.8,0,0,0\n0.1,mag,0.2,0.0,inf\n",
        "mag rows: sample 0 (t = 0.1 s) has a non-finite value inf",
    ),
]


@pytest.mark.parametrize("text, message", BAD_CSV)
def test_a_bad_csv_log_is_one_line_naming_the_file_and_the_problem(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(FlightLogError) as error:
        read_flight_log(path)
    assert str(error.value).startswith(f"{path}: ") and message in str(error.value)
    assert "\n" not in str(error.value)


def _edited_ulog(tmp_path, edit):
    ulog = ULog(str(SITL))
    edit(ulog)
    path = tmp_path / "edited.ulg"
    ulog.write_ulog(str(path))
    return path


def _drop_imu(ulog):
    ulog.data_list[:] = [d for d in ulog.data_list if d.name != "sensor_combined"]


def _imu_backwards(ulog):
    data = ulog.get_dataset("sensor_combined").data
    data["timestamp"][100] = data["timestamp"][98]


def _gps_nan(ulog):
    ulog.get_dataset("vehicle_gps_position").data["vel_n_m_s"][300] = np.nan


@pytest.mark.parametrize(
    "edit, message",
    [
        (_drop_imu, "no sensor_combined topic (the IMU)"),
        (_imu_backwards, "sensor_combined: time does not increase at sample 99"),
        (_gps_nan, "vehicle_gps_position: sample "),
    ],
)
def test_a_bad_ulog_is_one_line_naming_the_topic(tmp_path, edit, message):
    path = _edited_ulog(tmp_path, edit)
    with pytest.raises(FlightLogError, match=re.escape(message)):
        read_flight_log(path)


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("garbage.ulg", b"not a ulog", "not a readable ULog file"),
        ("log.txt", b"", "not a flight log (expected a PX4 .ulg or a .csv file)"),
        ("binary.csv", b"\xff\xfe\x00", "cannot read as CSV"),
    ],
)
def test_a_file_that_is_no_flight_log_is_refused(tmp_path, name, content, message):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(FlightLogError, match=re.escape(message)):
        read_flight_log(path)
    with pytest.raises(FlightLogError, match="no such flight log"):
        read_flight_log(tmp_path / "missing.ulg")


def test_a_sample_is_emitted_at_the_first_tick_at_or_after_its_time():
    times = np.array([0.0, 0.002, 0.0021, 0.004 + 1e-12, 0.0059, 0.006])
    assert first_ticks(times).tolist() == [0, 1, 2, 2, 3, 3]
    assert superseded_samples(times) == 2  # 0.0021 by 0.004, 0.0059 by 0.006


def _tick_means_by_overlap(times, values, ticks, period=0.002):
    """The oracle of ``imu_tick_means``: each tick's mean by summing, sample by sample, the value
    times the overlap of its stretch [t_i, t_i+1) (the first from -inf, the last to +inf) with the
    tick's interval."""
    rows = np.zeros((len(ticks), values.shape[1]))
    bounds = np.concatenate([[-np.inf], times[1:], [np.inf]])
    for j, tick in enumerate(ticks):
        start, end = tick * period, tick * period + period
        for i in range(len(times)):
            overlap = min(end, bounds[i + 1]) - max(start, bounds[i])
            if overlap > 0:
                rows[j] = rows[j] + (values[i] * overlap if np.isfinite(values[i]).all() else np.nan)
    return rows / period


def test_each_imu_tick_is_the_mean_of_the_samples_over_its_interval():
    rng = np.random.default_rng(11)
    # a 200 Hz IMU with a jittered clock and a logger's missing sample, a vibration of 0.4 rad/s
    times = np.cumsum(rng.uniform(0.0045, 0.0055, 400))
    times = np.delete(times - times[0], 57)
    values = rng.normal(0.0, 0.4, (len(times), 6))
    ticks, rows = imu_tick_means(times, values)
    assert ticks[0] == 0 and ticks[-1] == first_ticks(times[-1:])[0]
    np.testing.assert_allclose(rows, _tick_means_by_overlap(times, values, ticks), rtol=0, atol=1e-12)
    # the ticks' integral is the samples': no 4 ms / 6 ms alternation of a held sample
    covered = (ticks[-1] + 1) * 0.002
    exact = (values[:-1] * np.diff(times)[:, None]).sum(axis=0) + values[-1] * (covered - times[-1])
    np.testing.assert_allclose(rows.sum(axis=0) * 0.002, exact, rtol=0, atol=1e-12)
    # faster than the tick (1 kHz): averaged, none lost
    fast = np.arange(50) * 0.001
    ticks, rows = imu_tick_means(fast, np.arange(50.0)[:, None])
    assert rows[:, 0].tolist() == pytest.approx([*(np.arange(25) * 2.0 + 0.5), 49.0], abs=1e-12)


def test_imu_samples_on_the_ticks_come_back_as_they_are_and_a_nan_stays_local():
    rng = np.random.default_rng(12)
    times = np.cumsum(np.full(100, 0.002)) - 0.002  # a simulated run's 500 Hz IMU, its clock summed
    values = rng.normal(0.0, 1.0, (100, 6))
    ticks, rows = imu_tick_means(times, values)
    np.testing.assert_array_equal(ticks, np.arange(100))
    np.testing.assert_array_equal(rows, values)
    slow = np.arange(40) * 0.005
    held = rng.normal(0.0, 1.0, (40, 6))
    held[10, 3] = np.nan  # its stretch [0.050, 0.055) meets ticks 25, 26, 27
    ticks, rows = imu_tick_means(slow, held)
    bad = np.flatnonzero(np.isnan(rows).any(axis=1))
    assert bad.tolist() == [25, 26, 27] and np.isnan(rows[bad]).all()
    np.testing.assert_allclose(rows, _tick_means_by_overlap(slow, held, ticks), rtol=0, atol=1e-12)
    twice = np.array([0.0, 0.001, 0.001, 0.003])  # a NaN superseded at its own time spoils no tick
    ticks, rows = imu_tick_means(twice, np.array([[1.0], [np.nan], [3.0], [5.0]]))
    assert rows[:, 0].tolist() == pytest.approx([2.0, 4.0, 5.0])


def test_the_heading_of_a_tilted_vehicle_is_its_yaw_plus_the_declination():
    rng = np.random.default_rng(3)
    inclination, declination = math.radians(63.0), 0.06
    m_N = 0.48 * np.array(
        [
            math.cos(inclination) * math.cos(declination),
            math.cos(inclination) * math.sin(declination),
            math.sin(inclination),
        ]
    )
    g_N = np.array([0.0, 0.0, GRAVITY])
    angles = rng.uniform([-0.6, -0.6, -math.pi], [0.6, 0.6, math.pi], size=(50, 3))
    fields, forces = [], []
    for roll, pitch, yaw in angles:
        R = rotation_from_euler(roll, pitch, yaw)
        fields.append(R.T @ m_N)
        forces.append(R.T @ (-g_N))  # at rest: f_B = R^T (0 - g_N)
    heading = tilt_compensated_heading(np.array(fields), np.array(forces), declination)
    error = (heading - angles[:, 2] + math.pi) % (2 * math.pi) - math.pi
    assert np.abs(error).max() < 1e-12


def test_gravity_is_the_mean_specific_force_over_the_window_before_a_sample():
    imu = Samples(np.arange(10) * 0.01, np.column_stack([np.arange(10.0), np.zeros((10, 5))]))
    mean = gravity_directions(imu, [0.045, 0.0, -1.0], window=0.03)
    assert mean[:, 0].tolist() == pytest.approx([3.0, 0.0, 0.0])  # samples 2, 3, 4; then the first


def test_the_streams_have_the_simulated_sensors_layouts(sitl_log, real_log):
    streams = playback_streams(sitl_log)
    assert {name: s.width for name, s in streams.items()} == {
        "imu": 6,
        "gps": 7,
        "mag": 2,
        "mag_field": 4,
        "baro": 2,
        "no_aid": 13,  # the estimators' no_aid input: none here (no no-aiding samples given)
        "gps_accuracy": 4,  # the estimators' gps_accuracy input: none here (none given)
    }
    assert len(streams["no_aid"].rows) == 0 and len(streams["gps_accuracy"].rows) == 0
    ticks, rows = imu_tick_means(sitl_log.imu.times, sitl_log.imu.values)  # the IMU: a mean per tick
    np.testing.assert_array_equal(streams["imu"].first_tick, ticks)
    np.testing.assert_array_equal(streams["imu"].rows, rows)
    assert np.all(np.diff(ticks) == 1) and not streams["imu"].stamped
    given = playback_streams(sitl_log, gps_accuracy=sitl_log.gps_accuracy)["gps_accuracy"]
    assert given.rows[:, -1] == pytest.approx(sitl_log.gps.times)  # each describes its GPS sample
    assert streams["gps"].rows[:, -1] == pytest.approx(sitl_log.gps.times)  # the stamp is the sample's time
    assert streams["mag"].initial().tolist() == [0.0, NO_SAMPLE_STAMP]
    empty = playback_streams(real_log)
    assert len(empty["gps"].first_tick) == 0 and len(empty["baro"].first_tick) == 0


def test_the_replay_starts_at_the_attitude_of_the_first_samples(sitl_log):
    roll, pitch, yaw = initial_attitude(sitl_log)
    px4 = np.array(euler_from_quats(sitl_log.reference_attitude.values[0]))
    assert abs(roll - px4[0]) < 0.01 and abs(pitch - px4[1]) < 0.01 and abs(yaw - px4[2]) < 0.05


def test_a_known_difference_and_sigma_are_measured():
    times = np.arange(1, 1001) * 0.005
    ours = np.sin(times)
    sigma = np.full_like(times, 0.1)
    reference_times = times[::3] + 0.001
    reference = np.sin(reference_times) - 0.05
    d = comparison._difference("X", times, ours, sigma, reference_times, reference, 1.0, False)
    assert d.count == np.count_nonzero((reference_times >= 1.0) & (reference_times <= times[-1]))
    assert d.rms == pytest.approx(0.05, abs=1e-4) and d.max_abs == pytest.approx(0.05, abs=2e-4)
    assert d.sigma_rms == pytest.approx(0.1) and d.within_2sigma == 1.0


def test_the_nis_of_a_consistent_filter_is_in_its_band():
    n = 400
    diagnostics = np.zeros((n, 9))
    diagnostics[:, 0] = chi2.ppf((np.arange(n) + 0.5) / n, 6)  # gps_nis: chi^2(6)'s quantiles
    diagnostics[:, 1] = np.arange(n) * 0.1  # gps_stamp
    summary = comparison.nis_summary(diagnostics, "gps")
    assert summary.count == n and summary.dof == 6 and summary.in_band
    assert summary.single_share == pytest.approx(0.95, abs=0.01)
    diagnostics[:, 0] *= 3.0  # innovations larger than the filter predicts
    assert not comparison.nis_summary(diagnostics, "gps").in_band


def _scrub_every_other_origin(ulog):
    # A location scrubbed in some topics' samples and not in others (a public log's edit): PX4's
    # origin 10 degrees north in every other vehicle_local_position sample, the GPS untouched.
    ulog.get_dataset("vehicle_local_position").data["ref_lat"][::2] += 10.0


def test_a_px4_position_far_from_the_gps_is_not_compared_and_said(tmp_path, sitl_log):
    from quad_drake.flightlogs.checks import log_warnings

    assert sitl_log.gps_mismatches == 0
    log = read_flight_log(_edited_ulog(tmp_path, _scrub_every_other_origin))
    edited = np.zeros(len(log.reference_position), dtype=bool)
    edited[::2] = True  # the first sample is at the log's start, as in sitl_log (same topic, same cut)
    honest = np.isfinite(sitl_log.reference_position.values[:, 0])
    assert log.gps_mismatches == (honest & edited).sum() > 100
    for axis in (0, 2):
        np.testing.assert_array_equal(
            np.isfinite(log.reference_position.values[:, axis]),
            np.isfinite(sitl_log.reference_position.values[:, axis]) & ~(honest & edited),
        )
    kept = honest & ~edited
    np.testing.assert_allclose(log.reference_position.values[kept], sitl_log.reference_position.values[kept])
    (warning,) = [w for w in log_warnings(log) if "from the GPS" in w]
    assert f"{log.gps_mismatches} of PX4's {len(log.reference_position)} positions" in warning


def test_px4s_imu_failover_is_read_and_said_in_one_warning(sitl_log):
    # The roboto log (a real PX4 v1.12.3 flight) clips its accelerometer at 2.3 s and PX4 fails
    # over: sensor_selection moves sensor_combined from IMU 4259850 to 3932170 and back and again,
    # estimator_selector_status its primary EKF2 instance 1 -> 0 -> 2 -> 1 -> 0, all within 40 ms.
    from quad_drake.flightlogs.checks import log_warnings

    log = read_flight_log(ROBOTO)
    first, second = (4259850, 4325386), (3932170, 3932170)  # (accelerometer, gyro) device ids
    assert [(before, after) for _, before, after in log.imu_switches] == [
        (first, second), (second, first), (first, second)
    ]  # fmt: skip
    instances = [(before, after) for _, before, after in log.estimator_switches]
    assert instances == [(1, 0), (0, 2), (2, 1), (1, 0)]
    selection = ULog(str(ROBOTO), ["sensor_selection"]).get_dataset("sensor_selection").data["timestamp"]
    selection = selection * 1e-6 - log.start_time
    np.testing.assert_allclose([t for t, _, _ in log.imu_switches], selection[[1, 3, 4]], atol=1e-9)
    assert 2.41 < log.imu_switches[0][0] < log.estimator_switches[0][0] < 2.42
    (warning,) = [w for w in log_warnings(log) if w.startswith("PX4 switched")]
    said = "the IMU sensor_combined carries 3 time(s) (first at 2.41 s: accelerometer 4259850 -> 3932170)"
    assert said in warning
    assert "its primary EKF2 instance 4 time(s) (first at 2.41 s: 1 -> 0)" in warning
    assert "\n" not in warning
    # A log without a switch (the SITL log: one sensor_selection sample, no selector) says nothing.
    assert sitl_log.imu_switches == sitl_log.estimator_switches == ()
    assert not [w for w in log_warnings(sitl_log) if w.startswith("PX4 switched")]


def test_clipped_imu_samples_are_read_and_said(sitl_log, real_log):
    # The roboto log flags two accelerometer samples at its range (y at 2.30 s, z at 2.32 s), the
    # violent motion before PX4's failover; the SITL log logs the flags, none set; the real AUAV
    # flight (older PX4) none at all.
    from quad_drake.flightlogs.checks import log_warnings

    log = read_flight_log(ROBOTO)
    np.testing.assert_array_equal(log.imu_clipping.values, [[2, 0], [4, 0]])  # bit 1: y, bit 2: z
    data = ULog(str(ROBOTO), ["sensor_combined"]).get_dataset("sensor_combined").data
    flagged = np.flatnonzero(data["accelerometer_clipping"])
    np.testing.assert_array_equal(log.imu_clipping.times, log.imu.times[flagged])
    (warning,) = [w for w in log_warnings(log) if w.startswith("The log flags the IMU as clipped")]
    assert warning.startswith(
        "The log flags the IMU as clipped: the accelerometer on 2 sample(s) (first at 2.30 s; axes y, z). "
    )
    assert sitl_log.imu_clipping is None and real_log.imu_clipping is None
    assert not [w for w in log_warnings(sitl_log) + log_warnings(real_log) if "clipped" in w]


def test_a_vehicle_that_is_not_a_multirotor_is_said(sitl_log):
    # The bundled SITL log is a quadrotor (MAV_TYPE 2) and says nothing; the same log as a fixed
    # wing, a standard VTOL (sample_log_small's MAV_TYPE 22) or a generic vehicle says so in one
    # line; a log without the parameter (a CSV) says nothing.
    from quad_drake.flightlogs.checks import log_warnings

    def said(parameters):
        log = dataclasses.replace(sitl_log, parameters=parameters)
        return [w for w in log_warnings(log) if "MAV_TYPE" in w]

    assert sitl_log.parameters["MAV_TYPE"] == 2 and said(sitl_log.parameters) == []
    assert said({}) == []
    (fixed_wing,) = said({"MAV_TYPE": 1})
    assert fixed_wing.startswith("warning: the log's vehicle is a fixed wing (MAV_TYPE 1): in flight ")
    assert "airspeed" in fixed_wing and "\n" not in fixed_wing
    (vtol,) = said({"MAV_TYPE": 22})
    assert vtol.startswith("warning: the log's vehicle is a VTOL (MAV_TYPE 22): in its fixed-wing flight ")
    (generic,) = said({"MAV_TYPE": 0})
    assert generic.startswith("warning: the log's vehicle is not said to be a multirotor (MAV_TYPE 0)")
    for rotary in (3, 4, 13, 14, 15, 29):
        assert said({"MAV_TYPE": rotary}) == []


def _gps_first_half_then_away(ulog):
    # The GPS logged over the first half only; PX4 then 500 m north of where the GPS left it.
    data = ulog.get_dataset("vehicle_gps_position").data
    half = len(data["timestamp"]) // 2
    for name in data:
        data[name] = data[name][:half]
    position = ulog.get_dataset("vehicle_local_position").data
    position["x"][position["timestamp"] > data["timestamp"][-1] + 1_000_000] += 500.0


def test_px4_positions_after_the_last_gps_sample_are_not_judged_against_it(tmp_path):
    # PX4 flies on after the log's last GPS sample (a VTOL's 1174 s log with 6.5 s of GPS): the
    # GPS track says nothing there, so nothing is taken for an edited origin.
    log = read_flight_log(_edited_ulog(tmp_path, _gps_first_half_then_away))
    after = log.reference_position.times > log.gps.times[-1] + 5.0
    assert log.gps_mismatches == 0
    assert np.isfinite(log.reference_position.values[after, 0]).sum() > 100
