"""Issue 38: a replay of logs nobody here recorded says what it could not judge (never a silent
NaN), fuses the log's barometer and 3-axis field against the world field PX4 used, reads a SITL
log's ground truth, and replays many logs into one table.

``tests/data/flight_logs/sitl_ground_truth.ulg`` is pyulog's
``test/sample_logging_tagged_and_default_params.ulg`` (PX4 SITL v1.13, 10.8 s, BSD-3-Clause: the
licence file beside it) with only the topics the replay reads (``reader.ULOG_TOPICS``), written
by pyulog's ``ULog.write_ulog``; the replay reads it as the whole file (measured: every field of
its FlightLog equal). Its PX4 fused none of its 30 GPS fixes (its GNSS checks had not passed by
the log's end), so the replay runs it unaided, as PX4 ran. ``sitl_v18_ground_truth.ulg`` is a
second ground-truth log, px4-ulog-rs's PX4 v1.8.0 SITL fixture (26.2 s, GPS throughout, the
barometer its height reference; MIT: the licence file beside it), cut the same way.
"""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from quad_drake.flightlogs import checks, comparison, earth_field
from quad_drake.flightlogs.reader import FlightLogError, Samples, read_flight_log
from quad_drake.flightlogs.replay import COMPARE_AFTER, replay
from quad_drake.flightlogs.settings import LOG_DIR, load_replay

TRUTH_LOG = Path(__file__).parent / "data" / "flight_logs" / "sitl_ground_truth.ulg"
SECOND_TRUTH_LOG = Path(__file__).parent / "data" / "flight_logs" / "sitl_v18_ground_truth.ulg"
REAL = LOG_DIR / "real_auav_x21_attitude_flight.ulg"
SITL = LOG_DIR / "sitl_takeoff_land_gps.ulg"


def _imu_csv(path, rate, seconds=2.0):
    """A CSV log of a level vehicle at rest with its IMU at `rate` Hz."""
    rows = [f"{k / rate!r},imu,0,0,-9.81,0,0,0" for k in range(int(seconds * rate))]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_a_cut_ulog_is_said_to_be_cut(tmp_path):
    data = REAL.read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[: len(data) * 3 // 10])  # the first 30 %, ending inside a message
    log = read_flight_log(cut)
    assert log.truncated and not read_flight_log(REAL).truncated
    warnings = checks.log_warnings(log)
    assert [w for w in warnings if "ends mid-message" in w] == [
        f"The file ends mid-message (cut short): replayed its first {log.duration:.1f} s."
    ]


def test_an_imu_too_slow_for_any_replay_exits_2_with_one_line(quad_drake_cli, tmp_path):
    path = _imu_csv(tmp_path / "slow.csv", 9.0)
    result = quad_drake_cli("replay", path, "--no-plots", "--out", tmp_path / "out")
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.strip().splitlines() == [
        f"quad-drake: {path}: the IMU is logged at 9 Hz, below the 50 Hz a replay needs "
        "(a logger's subsample of sensor_combined?); cannot replay"
    ]


def test_an_imu_below_px4s_rate_or_with_gaps_is_replayed_with_a_warning(tmp_path):
    log = read_flight_log(_imu_csv(tmp_path / "slowish.csv", 80.0))
    assert checks.log_warnings(log) == [
        "The IMU is logged at 80 Hz, below PX4 EKF2's 100 Hz: each sample is held over its whole interval.",
        "The IMU covers 2.0 s: 2.0 s are compared (from 0 s on); "
        "too short a stretch to judge an estimator by.",
    ]
    with pytest.raises(FlightLogError):
        checks.log_warnings(read_flight_log(_imu_csv(tmp_path / "slower.csv", 40.0)))


def test_a_switch_of_gyro_alone_or_of_estimator_alone_is_said_as_such(tmp_path):
    # The roboto log's failover, both topics at once, is tests/test_flightlogs.py's; here each alone.
    import dataclasses

    log = read_flight_log(_imu_csv(tmp_path / "imu.csv", 200.0, seconds=12.0))
    assert checks.log_warnings(log) == []
    gyro = dataclasses.replace(log, imu_switches=((3.5, (7, 8), (7, 9)), (6.0, (7, 9), (7, 8))))
    assert checks.log_warnings(gyro) == [
        "PX4 switched the IMU sensor_combined carries 2 time(s) (first at 3.50 s: gyro 8 -> 9): from "
        "3.50 s on the replay fuses another IMU with the biases it learned on the first; the figures "
        "after it do not compare like with like."
    ]
    instance = dataclasses.replace(log, estimator_switches=((4.25, 0, 1),))
    assert checks.log_warnings(instance) == [
        "PX4 switched its primary EKF2 instance 1 time(s) (first at 4.25 s: 0 -> 1): from 4.25 s on "
        "PX4's estimate is another instance's, built on its own sensors from the start; the figures "
        "after it do not compare like with like."
    ]


def test_a_gyro_clipped_alone_is_said_as_such(tmp_path):
    import dataclasses

    log = read_flight_log(_imu_csv(tmp_path / "imu.csv", 200.0, seconds=12.0))
    assert log.imu_clipping is None  # a CSV carries no flags
    clipped = dataclasses.replace(
        log, imu_clipping=Samples(np.array([4.0, 4.5]), np.array([[0.0, 1.0], [0.0, 5.0]]))
    )
    assert checks.log_warnings(clipped) == [
        "The log flags the IMU as clipped: the gyro on 2 sample(s) (first at 4.00 s; axes x, z). The "
        "replay fuses those samples as logged (PX4 raises a clipped accelerometer axis's noise and learns "
        "no bias on it): the estimates can part there."
    ]


def test_a_state_not_compared_says_why():
    times = np.arange(0.0, 20.0, 0.005)
    ref_times = np.arange(0.0, 20.0, 0.1)
    invalid = np.full(len(ref_times), np.nan)
    assert (
        comparison.missing_reason("VX", times, ref_times, invalid, COMPARE_AFTER)
        == "n/a: PX4 marks it invalid throughout (v_xy_valid = 0)"
    )
    short = np.arange(0.0, 3.0, 0.005)
    assert comparison.missing_reason("Roll", short, ref_times, np.zeros(len(ref_times)), COMPARE_AFTER) == (
        "n/a: the log ends at 3.0 s, before the comparison starts (5 s)"
    )
    assert comparison.missing_reason("Z", times, ref_times[:10], np.zeros(10), COMPARE_AFTER) == (
        "n/a: no PX4 sample between 5 s and the log's end"
    )
    assert comparison.missing_reason("Z", times, ref_times, np.zeros(len(ref_times)), COMPARE_AFTER) == ""
    d = comparison.unavailable("X", "n/a: no GPS, so no common horizontal frame")
    assert d.figure(d.rms) == "n/a: no GPS, so no common horizontal frame"


def test_the_world_magnetic_model_is_the_published_one():
    # NOAA's WMM2020 at Zurich (PX4 SITL's home), 2022.3: D 3.1°, I 63.4°, F 48 200 nT
    declination, inclination, strength = earth_field.world_field(47.3977, 8.5456, 488.0, 2022.3)
    assert math.degrees(declination) == pytest.approx(3.13, abs=0.05)
    assert math.degrees(inclination) == pytest.approx(63.4, abs=0.1)
    assert strength == pytest.approx(0.482, abs=0.002)


def test_the_magnetometer_is_taken_as_px4_calibrated_it():
    import dataclasses

    sitl = read_flight_log(SITL)
    model = earth_field.magnetometer_model(sitl)
    wmm = earth_field.world_field(*sitl.origin, sitl.fix_date)
    # EKF2_DECL_TYPE 7: PX4 fuses its parameter until the fix and its own look-up from it, and saved
    # that look-up as EKF2_MAG_DECL (3.32°, 0.11° from the WMM's 3.43° at the fix): PX4's value here
    assert sitl.parameters["EKF2_DECL_TYPE"] == 7 and model.hard_iron == (0.0, 0.0, 0.0)
    assert model.declination == sitl.mag_declination
    assert abs(sitl.mag_declination - wmm[0]) < math.radians(0.2)
    not_saved = dataclasses.replace(sitl, parameters=sitl.parameters | {"EKF2_DECL_TYPE": 5})
    saved_elsewhere = dataclasses.replace(sitl, mag_declination=wmm[0] - math.radians(1.5))
    for edited in (not_saved, saved_elsewhere):  # PX4's look-up at the fix: the WMM's
        assert earth_field.magnetometer_model(edited).declination == wmm[0]
    # the simulated field is the WMM's: the log's own strength and inclination agree with it
    assert model.field_strength == pytest.approx(wmm[2], rel=0.01)
    assert model.inclination == pytest.approx(wmm[1], abs=0.01)

    parameters = sitl.parameters | {"EKF2_DECL_TYPE": 0, "EKF2_MAGBIAS_Y": -0.033}
    edited = dataclasses.replace(sitl, parameters=parameters)
    model = earth_field.magnetometer_model(edited)
    assert model.declination == sitl.mag_declination  # the parameter, as PX4 then fuses it
    assert model.hard_iron == (0.0, -0.033, 0.0)
    assert any("EKF2_MAGBIAS_X/Y/Z" in note for note in model.notes)

    doubled = dataclasses.replace(sitl.mag_field, values=sitl.mag_field.values * 2.4)
    notes = earth_field.magnetometer_model(dataclasses.replace(sitl, mag_field=doubled)).notes
    assert [n for n in notes if n.startswith("warning: the log's field strength")] == [
        "warning: the log's field strength (1.15 G) is outside the Earth's (0.22-0.67 G): the "
        "magnetometer is uncalibrated or disturbed; its yaw and the tilt it constrains cannot be trusted"
    ]
    real = read_flight_log(REAL)  # no fix: no place to ask the model about, the log's own field
    model = earth_field.magnetometer_model(real)
    assert real.origin is None and model.declination == 0.0
    assert 0.45 < model.field_strength < 0.52 and 1.0 < model.inclination < 1.2


def test_the_bias_px4s_estimator_had_learned_at_the_start_is_subtracted():
    import dataclasses

    # the bundled SITL log (PX4 v1.15): its primary EKF2's estimator_sensor_bias, valid, for the
    # fused magnetometer, learned nothing in the simulator
    sitl = read_flight_log(SITL)
    assert sitl.estimator_mag_bias == (0.0, 0.0, 0.0)
    assert read_flight_log(REAL).estimator_mag_bias is None  # attitude_estimator_q: no such topic
    # a log from PX4 v1.13 on has no EKF2_MAGBIAS_* parameters: the bias state at the log's start
    # is what PX4 subtracts, on top of a saved parameter where an older log has one
    learned = dataclasses.replace(
        sitl,
        estimator_mag_bias=(0.028, -0.0024, -0.0608),
        parameters=sitl.parameters | {"EKF2_MAGBIAS_Y": -0.033},
    )
    model = earth_field.magnetometer_model(learned)
    assert model.hard_iron == pytest.approx((0.028, -0.0354, -0.0608), abs=1e-12)
    assert [n for n in model.notes if "estimator_sensor_bias" in n] == [
        "magnetometer: PX4's estimator's learned bias at the log's start (estimator_sensor_bias) = "
        "(0.0280, -0.0024, -0.0608) G subtracted"
    ]
    # the replay subtracts it only when asked (off by default: measured mixed), and says so
    from quad_drake.flightlogs.replay import magnetometer_for
    from quad_drake.flightlogs.settings import default_replay

    config = default_replay("eskf")
    kept = earth_field.magnetometer_model(learned, subtract_estimator_bias=False)
    assert magnetometer_for(learned, config) == kept
    assert kept.hard_iron == (0.0, -0.033, 0.0)
    # the model of the log without the bias, and one last note that the bias was left in
    unlearned = earth_field.magnetometer_model(dataclasses.replace(learned, estimator_mag_bias=None))
    assert dataclasses.replace(kept, notes=kept.notes[:-1]) == unlearned
    assert kept.notes[-1] == (
        "magnetometer: PX4's estimator had learned a bias of (0.0280, -0.0024, -0.0608) G by the log's "
        "start (estimator_sensor_bias): not subtracted (--set estimator_mag_bias=true subtracts it)"
    )
    assert earth_field.magnetometer_model(
        sitl, subtract_estimator_bias=False
    ) == earth_field.magnetometer_model(sitl)
    asked = dataclasses.replace(config, estimator_mag_bias=True)
    assert magnetometer_for(learned, asked) == model


def test_the_imu_biases_px4s_estimator_had_learned_at_the_start_can_start_the_eskf():
    import dataclasses

    from quad_drake.config import ConfigError
    from quad_drake.flightlogs.reader import ImuBiasStart
    from quad_drake.flightlogs.replay import replay_setup
    from quad_drake.flightlogs.settings import default_replay

    # the bundled SITL log's primary EKF2 started with the log: its biases ~0 (below 1e-8) with
    # PX4's switch-on variances (EKF2_ABIAS_INIT 0.2 m/s^2, EKF2_GBIAS_INIT 0.1 rad/s, float32)
    sitl = read_flight_log(SITL)
    start = sitl.estimator_imu_bias
    assert start.accel == pytest.approx((0.0,) * 3, abs=1e-8) and start.gyro == pytest.approx(
        (0.0,) * 3, abs=1e-8
    )
    assert start.accel_std == pytest.approx((0.2,) * 3, rel=1e-6)
    assert start.gyro_std == pytest.approx((0.1,) * 3, rel=1e-3)
    assert read_flight_log(REAL).estimator_imu_bias is None  # attitude_estimator_q: no such topic
    learned = dataclasses.replace(
        sitl, estimator_imu_bias=ImuBiasStart((-0.006, -0.018, 0.004), (0.0012, 0.0014, -0.0003))
    )
    config = dataclasses.replace(default_replay("eskf"), log="sitl_takeoff_land_gps")
    _, vehicle, _ = replay_setup(learned, config)
    assert vehicle.estimator.init_accel_bias == [0.0, 0.0, 0.0]  # off by default
    _, vehicle, _ = replay_setup(learned, dataclasses.replace(config, px4_start_biases=True))
    e = vehicle.estimator
    assert (e.init_accel_bias, e.init_gyro_bias) == ([-0.006, -0.018, 0.004], [0.0012, 0.0014, -0.0003])
    assert e.init_accel_bias_std == config.estimator.init_accel_bias_std  # no variances: the config's
    with pytest.raises(ConfigError, match="px4_start_biases: starts the IMU bias states of an ESKF"):
        load_replay("sitl_takeoff_land_gps", "{kind: ekf7}", ["px4_start_biases=true"])


def test_the_eskf_nominal_starts_at_each_vehicles_own_biases():
    import dataclasses

    from pydrake.systems.analysis import Simulator

    from quad_drake.conventions import NO_SAMPLE_STAMP
    from quad_drake.estimation.registry import EskfEstimatorConfig
    from quad_drake.systems.estimators import Eskf

    first = EskfEstimatorConfig()
    second = dataclasses.replace(first, init_accel_bias=[0.1, -0.2, 0.3], init_gyro_bias=[0.01, 0.02, -0.03])
    system = Eskf([first, second], n=2)
    context = system.CreateDefaultContext()
    expected = [[0.0] * 6, [0.1, -0.2, 0.3, 0.01, 0.02, -0.03]]
    np.testing.assert_array_equal(system.GetOutputPort("imu_bias").Eval(context).reshape(2, 6), expected)
    system.GetInputPort("imu").FixValue(context, np.tile([0.0, 0.0, -9.81, 0.0, 0.0, 0.0], 2))
    system.GetInputPort("mag").FixValue(context, np.tile([0.0, NO_SAMPLE_STAMP], 2))
    system.GetInputPort("gps").FixValue(context, np.tile([0.0] * 6 + [NO_SAMPLE_STAMP], 2))
    Simulator(system, context).AdvanceTo(0.01)  # five predictions, no measurement: the nominal's biases
    after = system.GetOutputPort("imu_bias").Eval(context).reshape(2, 6)
    np.testing.assert_allclose(after, expected, atol=1e-12)


@pytest.fixture(scope="module")
def truth_replay():
    return replay(load_replay(str(TRUTH_LOG), "{kind: eskf}"))


def test_the_sitl_ground_truth_is_read_and_both_estimates_are_judged_against_it(truth_replay, tmp_path):
    from quad_drake.flightlogs.page import write_report

    log = truth_replay.log
    assert len(log.truth_attitude) > 1000 and len(log.truth_position) > 500
    errors = {e.state: e for e in truth_replay.truth}
    assert set(errors) == set(comparison.TRUTH_STATES)
    # measured (docs/measurements/replay.md): ours 2-3 mrad, PX4's 2-2.4 mrad from the truth
    for state in ("Roll", "Pitch", "Yaw"):
        assert errors[state].count > 1000 and errors[state].ours_rms < 0.005
        assert errors[state].px4_rms < 0.005
    for state in ("X", "Y"):
        assert errors[state].ours_rms < 0.02  # m: measured 9 to 10 mm
    # no GPS fused (as PX4's): the barometer is the height, measured 0.3 mm from the truth
    # against PX4's 16 mm (PX4's height from its own at t = 0)
    assert truth_replay.aiding.baro_fused and truth_replay.fake_position and errors["Z"].ours_rms < 0.1
    # ours no farther from the truth than PX4's in yaw (0.9 against 2.1 mrad: the declination
    # PX4 saved, 2.98°; the WMM's 3.13° put ours 2.7 mrad off), in height and in vertical velocity
    # (1.1 against 1.9 mm/s: PX4 v1.13's zero velocity at rest, 0.001 m/s; 3.3 mm/s at 0.2 m/s)
    for state in ("Roll", "Yaw", "Z", "VZ"):
        assert errors[state].ours_rms <= errors[state].px4_rms, (state, errors[state])
    assert truth_replay.config.rest_velocity_std == 0.001
    assert any(
        line.startswith(
            "The zero velocity at rest fused with σ = 0.001 m/s, as PX4 v1.13 (the log's release)"
        )
        for line in truth_replay.notes()
    )
    given = "PX4's no-aiding samples every 0.2 s: at rest (49 samples; PX4's land-detector test on the IMU)"
    assert any(
        given in line and "a zero velocity with σ = 0.001 m/s" in line for line in truth_replay.notes()
    )
    overridden = replay(load_replay(str(TRUTH_LOG), "{kind: eskf}", ["rest_velocity_std=0.2"]))
    assert overridden.config.rest_velocity_std == 0.2  # the user's, and no note of the release's
    assert not any("as PX4 v1.13 (the log's release)" in line for line in overridden.notes())
    assert errors["VZ"].ours_rms < {e.state: e for e in overridden.truth}["VZ"].ours_rms  # 1.1 < 3.3 mm/s
    # pitch still farther than PX4's (2.9 against 2.3 mrad: docs/measurements/replay.md)
    assert math.isnan(errors["X"].px4_rms) and errors["X"].figure(errors["X"].px4_rms) == "n/a"
    nees = {s.block: s for s in truth_replay.truth_nees}
    assert set(nees) == {"position", "velocity"}
    assert all(s.count > 1000 for s in nees.values())
    # PX4's default accelerometer noise is far above SITL's: the velocity's NEES far below its band;
    # the position's above it, its x, y error (9-10 mm) the truth's own 1.1 cm quantum against a
    # horizontal sigma of a few mm held by PX4's 0.01 m fake position at rest
    assert (
        nees["velocity"].mean < nees["velocity"].band[0] and nees["position"].mean > nees["position"].band[1]
    )
    summary = truth_replay.summary()
    assert summary["truth"][3]["px4_rms"] is None and summary["truth_nees"][0]["block"] == "position"
    report = write_report(truth_replay, tmp_path / "report.html").read_text(encoding="utf-8")
    assert "Against the simulator's ground truth" in report and "mean NEES" in report


def test_on_a_second_ground_truth_log_ours_is_no_farther_from_the_truth_than_px4s():
    # A log nobody here tuned on (docs/measurements/replay.md, "A second ground-truth log"): the
    # ESKF measured 0.7, 0.5, 254 mrad, 15, 12, 8.5 mm, 4.6, 6.9, 4.4 mm/s from the truth against
    # PX4's 2.9, 29.6, 295 mrad, 26, 27, 12 mm, 24, 28, 4.5 mm/s
    result = replay(load_replay(str(SECOND_TRUTH_LOG), "{kind: eskf}"))
    errors = {e.state: e for e in result.truth}
    assert set(errors) == set(comparison.TRUTH_STATES)
    for state, error in errors.items():
        assert error.count > 1000 and error.ours_rms <= error.px4_rms, (state, error)
    assert errors["Pitch"].ours_rms < 0.002 < 0.02 < errors["Pitch"].px4_rms
    # the barometer its height reference (EKF2_HGT_MODE 0): no GPS height fused, as PX4's
    assert result.aiding.baro_height_reference and result.log.gps is not None
    # both yaws 0.25-0.3 rad off: the simulator's field has no declination, the log's
    # EKF2_DECL_TYPE 7 takes the WMM's -12.46° at its fix; with none ours is within 50 mrad
    assert 0.2 < errors["Yaw"].ours_rms < 0.3
    undeclined = replay(load_replay(str(SECOND_TRUTH_LOG), "{kind: eskf}", ["mag_declination=0"]))
    assert {e.state: e for e in undeclined.truth}["Yaw"].ours_rms < 0.05


def test_a_release_that_fused_its_zero_velocity_while_gps_aided_is_said(truth_replay):
    # PX4 v1.13 fused its zero velocity at rest while GNSS aided too (before PX4-Autopilot pull
    # request 20611, v1.14); the replay fuses it only while not aided, and says so where the GPS it
    # fused came at rest: the bundled SITL log (v1.15) tagged as v1.13, against itself as it is
    sitl = read_flight_log(SITL)
    config = load_replay(str(SITL), "{kind: eskf}")
    said = "PX4 v1.13 (the log's release) also fused its zero velocity at rest (σ = 0.001 m/s)"
    as_v1_13 = replay(config, dataclasses.replace(sitl, px4_release=(1, 13)))
    line = next(line for line in as_v1_13.notes() if line.startswith(said))
    at_rest, given = as_v1_13.aiding.gps_at_rest
    assert 0 < at_rest < given == as_v1_13.aiding.gps_kept_as_px4[0]  # the fixes PX4 fused, 411 of 423
    assert f"{at_rest} of the {given} GPS samples fused" in line
    as_logged = replay(config, sitl)
    assert as_logged.aiding.gps_at_rest == (at_rest, given)  # the same samples at rest, and no such line
    assert not any("while the GPS aided it" in line for line in as_logged.notes())
    # a v1.13 log whose GPS its PX4 never fused (the ground-truth log): nothing fused at rest
    assert truth_replay.aiding.gps_at_rest is None
    assert not any("while the GPS aided it" in line for line in truth_replay.notes())


def test_where_px4_fused_no_fake_position_and_the_replay_gave_one_is_said(truth_replay):
    # the bundled SITL log's PX4 (v1.15) fused its fake position until its fix, as the replay
    # gives one: nothing said; a record of none fused (PX4 v1.16 and v1.17 in flight, e.g. the
    # public quadrotor_local log: docs/measurements/replay.md) is said with the samples concerned
    sitl = read_flight_log(SITL)
    record = sitl.px4_fake_position
    assert record.values[0, 0] == 1 and record.values[-1, 0] == 0 and 9.0 < record.times[-1] < 10.0
    config = load_replay(str(SITL), "{kind: eskf}")
    as_logged = replay(config, sitl)
    in_motion = as_logged.aiding.no_aid_at_rest[1]
    assert in_motion > 0 and as_logged.aiding.fake_unlike_px4 == (0, in_motion)
    said = "PX4's estimator fused no fake position at"
    assert not any(line.startswith(said) for line in as_logged.notes())
    none_fused = Samples(np.array([0.0]), np.array([[0.0]]))
    unlike = replay(config, dataclasses.replace(sitl, px4_fake_position=none_fused))
    assert unlike.aiding.fake_unlike_px4 == (in_motion, in_motion)
    line = next(line for line in unlike.notes() if line.startswith(said))
    assert f"at {in_motion} of the {in_motion} no-aiding samples the replay gave in motion" in line
    # the course's estimator takes its no-aiding samples merged into its GPS: the same samples, said
    none_logged = dataclasses.replace(sitl, px4_fake_position=none_fused)
    student = Path(__file__).parent / "grading" / "correct_estimator.py"
    merged = replay(load_replay(str(SITL), f"{{kind: course, module: {student}}}"), none_logged)
    assert merged.aiding.no_aid_at_rest is None and merged.aiding.fake_unlike_px4 == (in_motion, in_motion)
    # a log without the record (PX4 v1.13's flags name no cs_fake_pos): nothing to say
    assert truth_replay.log.px4_fake_position is None and truth_replay.aiding.fake_unlike_px4 is None


def test_the_height_reference_is_the_one_px4s_parameters_name():
    from quad_drake.flightlogs.settings import UNFUSED_HEIGHT_STD, height_reference, vehicle_for

    config = load_replay(SITL, "{kind: eskf}")
    assert height_reference(config, {"EKF2_HGT_MODE": 0}) == "baro"  # before PX4 v1.14
    assert height_reference(config, {"EKF2_HGT_REF": 1, "EKF2_HGT_MODE": 0}) == "gps"  # v1.14 on
    assert height_reference(config, read_flight_log(SITL).parameters) == "gps"  # EKF2_HGT_REF 1
    assert height_reference(config, {}) == "gps"
    forced = load_replay(SITL, "{kind: eskf}", ["height_reference=baro"])
    assert height_reference(forced, {"EKF2_HGT_REF": 1}) == "baro"
    for kind, height_std in (("eskf", lambda e: e.gps_pos_std[2]), ("ekf7", lambda e: e.gps_pos_z_std)):
        config = load_replay(SITL, f"{{kind: {kind}}}")
        baro = vehicle_for(config, (0.0, 0.0, 0.0), False, 0.1, None, baro_reference=True).estimator
        gps = vehicle_for(config, (0.0, 0.0, 0.0), False, 0.1, None, baro_reference=False).estimator
        assert (height_std(baro), height_std(gps)) == (UNFUSED_HEIGHT_STD, 0.75)  # 1.5 x EKF2_GPS_P_NOISE
        no_baro = vehicle_for(config, (0.0, 0.0, 0.0), False, None, None, baro_reference=True).estimator
        assert height_std(no_baro) == 0.75  # without a barometer the GPS stays the height
    with pytest.raises(Exception, match="height_reference"):
        load_replay(SITL, "{kind: eskf}", ["height_reference=sonar"])


def test_the_log_s_barometer_and_3_axis_field_are_fused(truth_replay):
    nis = {s.sensor for s in truth_replay.nis}
    assert {"baro", "field"} <= nis
    assert truth_replay.aiding.baro_fused and truth_replay.aiding.magnetometer is not None


@pytest.mark.slow
def test_the_ekf7_takes_a_log_s_baro_datum_from_its_first_sample():
    """The SITL log's barometer reads 488 m: its first sample sets the EKF7's datum (b = h + p_z,
    as PX4 and the ESKF set theirs), so no sample is gated and the bias is never reset; fused
    against the 1 m prior (as a simulated barometer's) the datum moved 7 % of the way and the
    barometer was gated until its reset after 1 s."""
    from quad_drake.estimation.vocabulary import DIAG

    counts = {}
    for first_sample in (True, False):
        # a baro block replaces the replay's whole default one: PX4's 3.5 m noise spelt out
        flag = str(first_sample).lower()
        estimator = f"{{kind: ekf7, baro: {{height_std: 3.5, datum_from_first_sample: {flag}}}}}"
        result = replay(load_replay(str(TRUTH_LOG), estimator))
        diagnostics = np.asarray(result.logs["diagnostics"])[-1]
        counts[first_sample] = (diagnostics[DIAG["baro_gated"]], diagnostics[DIAG["baro_resets"]])
        assert diagnostics[DIAG["baro_bias"]] == pytest.approx(488.1, abs=0.2)
    assert counts[True] == (0, 0)
    assert counts[False][0] > 10 and counts[False][1] == 1


def test_many_logs_replay_into_one_table_and_a_bad_one_is_said(quad_drake_cli, tmp_path):
    bad = _imu_csv(tmp_path / "slow.csv", 9.0)
    out = tmp_path / "out"
    result = quad_drake_cli(
        "replay", TRUTH_LOG, bad, "--estimator", "{kind: eskf}", "--no-plots", "--out", out
    )
    assert result.returncode == 2
    assert "error: " in result.stdout and "below the 50 Hz a replay needs" in result.stdout
    table = (out / "replay_table.csv").read_text(encoding="utf-8").splitlines()
    assert table[0].startswith("log,estimator,duration_s,Roll,Pitch,Yaw,X,Y,Z,VX,VY,VZ,note")
    assert table[1].startswith("sitl_ground_truth,eskf,10.") and "n/a: no GPS" in table[1]
    assert table[2].startswith("slow,eskf,,n/a: not replayed")
    assert (out / "sitl_ground_truth-eskf" / "summary.json").is_file()


def test_a_log_given_twice_is_replayed_once_and_said(quad_drake_cli, tmp_path):
    # a folder and a file inside it, or a bundled name and its path: the same file, replayed once
    folder = tmp_path / "logs"
    folder.mkdir()
    copy = folder / "truth.ulg"
    copy.write_bytes(TRUTH_LOG.read_bytes())
    out = tmp_path / "out"
    result = quad_drake_cli(
        "replay", folder, copy, "sitl_takeoff_land_gps", SITL, "--estimator", "{kind: eskf}", "--no-plots",
        "--out", out,
    )  # fmt: skip
    assert result.returncode == 0
    note = f"note: {copy}, {SITL}: given more than once (the same file); replayed once"
    assert note in result.stdout
    replayed = [line for line in result.stdout.splitlines() if line.startswith("== replay ")]
    assert len(replayed) == 2
    table = (out / "replay_table.csv").read_text(encoding="utf-8").splitlines()
    assert [row.split(",")[0] for row in table[1:]] == ["truth", "sitl_takeoff_land_gps"]


def test_an_imu_dropout_is_bridged_from_the_mean_motion_before_it_to_the_mean_after_it():
    from quad_drake.flightlogs.reader import Samples
    from quad_drake.flightlogs.schedule import bridged_imu, imu_tick_means

    times = np.concatenate([np.arange(20) * 0.005, [0.45, 0.455, 0.46]])  # a 0.355 s dropout after 0.095 s
    values = np.zeros((len(times), 6))
    values[:20, 0] = np.where(np.arange(20) % 2, 3.0, -1.0)  # a vibrating accelerometer, mean 1 m/s^2
    values[20:, 0] = [2.0, 4.0, 3.0]  # mean 3 m/s^2 after the gap
    values[:20, 5] = 0.2  # a turn at 0.2 rad/s before the gap, 0.6 rad/s after it
    values[20:, 5] = 0.6
    imu = Samples(times, values)
    bridged, count = bridged_imu(imu, 0.047)
    assert count == 1
    filled = np.isin(bridged.times, times, invert=True)
    np.testing.assert_array_equal(bridged.times[~filled], times)  # every logged sample kept as it is
    np.testing.assert_array_equal(bridged.values[~filled], values)
    np.testing.assert_allclose(np.diff(bridged.times[filled]), 0.005, rtol=0, atol=1e-12)
    assert bridged.times[filled][0] == pytest.approx(0.1) and bridged.times[filled][-1] < 0.45
    before, after = values[10:20].mean(axis=0), values[20:].mean(axis=0)  # within 0.047 s of the gap
    assert before[0] == 1.0 and after[0] == 3.0
    ramp = bridged.values[filled]
    assert np.all(np.diff(ramp[:, 0]) > 0) and 1.0 < ramp[0, 0] < ramp[-1, 0] < 3.0  # 1 -> 3 m/s^2
    # the gap's integral is the mean of the two sides' means times its length: the turn's 0.4 rad/s
    ticks, rows = imu_tick_means(bridged.times, bridged.values)
    gap = (ticks * 0.002 >= 0.1) & (ticks * 0.002 < 0.45)
    np.testing.assert_allclose(rows[gap, 5].sum() * 0.002, 0.4 * 0.35, rtol=0, atol=1e-12)
    assert bridged_imu(imu, 0.0) == (imu, 0)  # off: the last sample held, as before
    assert bridged_imu(imu, 0.4) == (imu, 0)  # no interval longer than the window


def test_a_log_whose_gps_px4_never_fused_replays_unaided_as_px4_ran(truth_replay):
    # This log, roboto_test and sample_log_small log 3D fixes their PX4 never fused (its GNSS checks
    # did not pass: estimator_status.control_mode_flags bit 2 clear throughout): replayed as PX4
    # ran, with no GPS, PX4's no-aiding samples throughout, judged as a log without GPS
    log = read_flight_log(TRUTH_LOG)
    assert not log.px4_gps_fusion.values.any() and len(log.gps) == 30
    result = truth_replay
    assert result.fake_position and result.aiding.gps_kept_as_px4 == (0, len(log.gps))
    notes = result.notes()
    assert any(f"fused 0 of the log's {len(log.gps)} GPS fixes" in line for line in notes)
    assert any(line.startswith("No GPS fix was fused:") for line in notes)
    assert not any("receiver's reported accuracy" in line for line in notes)
    position = {d.state: d for d in result.position}
    assert position["X"].reason == "n/a: no GPS, so no common horizontal frame"
    followed = replay(load_replay(TRUTH_LOG, "{kind: eskf}", ["gps_where_px4_fused=false"]))
    assert not followed.fake_position and followed.aiding.gps_kept_as_px4 is None
    assert "gps" not in {s.sensor for s in result.nis} and "gps" in {s.sensor for s in followed.nis}


def test_each_gps_sample_is_fused_with_the_receivers_accuracy():
    # The SITL ground-truth log's receiver reports 2.85 m at its fix (8.4 s), 1.7 m at its end,
    # above the replay's 0.5 m: fused with it (the default), the first samples count for less than
    # with the estimator's own 0.5 m alone, and nothing before the fix moves.
    from quad_drake.estimation.vocabulary import DIAG
    from quad_drake.judging.innovations import UPDATE_DIAGNOSTICS

    every_fix = "gps_where_px4_fused=false"  # this log's PX4 fused none of them
    with_accuracy = replay(load_replay(str(TRUTH_LOG), "{kind: eskf}", [every_fix]))
    without = replay(load_replay(str(TRUTH_LOG), "{kind: eskf}", [every_fix, "gps_receiver_accuracy=false"]))
    assert with_accuracy.aiding.baro_height_reference  # the log's EKF2_HGT_MODE 0: the GPS height not fused
    assert any("the receiver's reported accuracy (medians:" in line for line in with_accuracy.notes())
    assert not any("receiver's reported accuracy" in line for line in without.notes())
    fix = with_accuracy.aiding.late_fix
    before = with_accuracy.times < fix
    np.testing.assert_array_equal(
        with_accuracy.logs["estimated_state"][before], without.logs["estimated_state"][before]
    )
    after = ~before
    moved = with_accuracy.logs["estimated_state"][after, 0:3] - without.logs["estimated_state"][after, 0:3]
    assert np.abs(moved).max() > 5e-4  # m: measured 1.3 mm

    def first_gps_nis(result, count=5):
        updates = result.logs[UPDATE_DIAGNOSTICS]
        stamps, first = np.unique(updates[:, DIAG["gps_stamp"]], return_index=True)
        fused = first[stamps > 0][:count]
        return updates[fused, DIAG["gps_nis"]]

    assert (first_gps_nis(with_accuracy) < first_gps_nis(without)).all()


def test_a_fix_measured_before_the_log_began_is_not_counted_as_one_px4_left_unfused():
    # A delay drops a fix logged within it of the start (measured before t = 0); where PX4's
    # estimator fused every fix the replay says nothing of PX4's choice.
    from quad_drake.flightlogs.replay import replay_setup

    log = read_flight_log(TRUTH_LOG)
    early = Samples(np.concatenate(([0.05], log.gps.times)), np.vstack([log.gps.values[:1], log.gps.values]))
    every = dataclasses.replace(
        log, gps=early, gps_accuracy=None, px4_gps_fusion=Samples(np.zeros(1), np.ones((1, 1)))
    )
    config = load_replay(TRUTH_LOG, "{kind: eskf}", ["gps_delay=0.11", "mag_delay=0", "baro_delay=0"])
    assert replay_setup(every, config)[2].gps_kept_as_px4 is None
    after = dataclasses.replace(every, px4_gps_fusion=Samples(np.array([0.0, 9.0]), np.array([[0.0], [1.0]])))
    kept = int(np.count_nonzero(early.times >= 9.0))
    assert replay_setup(after, config)[2].gps_kept_as_px4 == (kept, len(early))
