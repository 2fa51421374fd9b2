"""Pure sensor faults on hand-made samples: windows, stamps, composition, the delay queue."""

import math

import pytest

from quad_drake.config.schema import FaultConfig
from quad_drake.conventions import NO_SAMPLE_STAMP
from quad_drake.models import faults

GPS_PERIOD = 0.1


def gps(stamp, p=(1.0, 2.0, -3.0), v=(0.5, -0.5, 0.1)):
    return list(p) + list(v) + [stamp]


def is_removed(sample):
    return sample[-1] == NO_SAMPLE_STAMP and all(math.isnan(x) for x in sample[:-1])


def test_window_is_half_open_up_to_rounding():
    assert faults.in_window(10.0, 10.0, 15.0)
    assert faults.in_window(100 * 0.1, 10.0, 15.0)  # 10.000000000000002 or 9.99..: still inside
    assert faults.in_window(14.9, 10.0, 15.0)
    assert not faults.in_window(15.0, 10.0, 15.0)
    assert not faults.in_window(150 * 0.1, 10.0, 15.0)
    assert not faults.in_window(9.9, 10.0, 15.0)


def test_outage_removes_samples_measured_in_the_window_only():
    fault = FaultConfig(kind="gps_outage", start=10.0, end=15.0)
    for k, expect_removed in ((99, False), (100, True), (149, True), (150, False)):
        stamp = k * GPS_PERIOD
        out = faults.gps_outage(gps(stamp), stamp, fault, GPS_PERIOD)
        assert is_removed(out) == expect_removed, k
        if not expect_removed:
            assert out == gps(stamp)


def test_outlier_shifts_the_first_sample_at_or_after_its_time_only():
    fault = FaultConfig(kind="gps_outlier", time=12.03, offset=[50.0, -20.0, 5.0])
    stamps = [k * GPS_PERIOD for k in range(119, 123)]  # 11.9, 12.0, 12.1, 12.2
    out = [faults.gps_outlier(gps(s), s, fault, GPS_PERIOD) for s in stamps]
    assert out[0] == gps(stamps[0]) and out[1] == gps(stamps[1]) and out[3] == gps(stamps[3])
    assert out[2] == pytest.approx(gps(stamps[2], p=(51.0, -18.0, 2.0)), abs=1e-12)
    assert out[2][-1] == stamps[2]  # the stamp is the measurement time, untouched


def test_step_shifts_position_not_velocity_over_its_window():
    fault = FaultConfig(kind="gps_step", start=10.0, end=15.0, offset=[3.0, 0.0, -1.0])
    inside = faults.gps_step(gps(12.0), 12.0, fault, GPS_PERIOD)
    assert inside == pytest.approx(gps(12.0, p=(4.0, 2.0, -4.0)), abs=1e-12)
    assert faults.gps_step(gps(15.0), 15.0, fault, GPS_PERIOD) == gps(15.0)


def test_mag_bias_wraps_and_keeps_the_stamp():
    fault = FaultConfig(kind="mag_bias", start=1.0, end=2.0, offset=[0.5])
    assert faults.mag_bias([3.0, 1.5], 1.5, fault, 0.01) == pytest.approx([3.5 - 2 * math.pi, 1.5], abs=1e-12)
    assert faults.mag_bias([3.0, 2.0], 2.0, fault, 0.01) == [3.0, 2.0]


def test_mag_outage_removes_magnetometer_samples_in_its_window():
    fault = FaultConfig(kind="mag_outage", start=1.0, end=2.0)
    assert is_removed(faults.mag_outage([0.3, 1.0], 1.0, fault, 0.01))
    assert faults.mag_outage([0.3, 2.0], 2.0, fault, 0.01) == [0.3, 2.0]


def test_mag_disturbance_shifts_the_three_axis_field_over_its_window():
    fault = FaultConfig(kind="mag_disturbance", start=1.0, end=2.0, offset=[0.1, -0.2, 0.3])
    sample = [0.2, 0.0, 0.45, 1.5]
    assert faults.mag_disturbance(sample, 1.5, fault, 0.01) == pytest.approx(
        [0.3, -0.2, 0.75, 1.5], abs=1e-12
    )
    assert faults.mag_disturbance([0.2, 0.0, 0.45, 2.0], 2.0, fault, 0.01) == [0.2, 0.0, 0.45, 2.0]


def test_baro_outage_and_step_act_on_the_height_in_their_window():
    outage = FaultConfig(kind="baro_outage", start=1.0, end=2.0)
    assert is_removed(faults.baro_outage([1.2, 1.0], 1.0, outage, 0.02))
    assert faults.baro_outage([1.2, 2.0], 2.0, outage, 0.02) == [1.2, 2.0]
    step = FaultConfig(kind="baro_step", start=1.0, end=2.0, offset=[-3.0])
    assert faults.baro_step([1.2, 1.98], 1.98, step, 0.02) == pytest.approx([-1.8, 1.98], abs=1e-12)
    assert faults.baro_step([1.2, 0.98], 0.98, step, 0.02) == [1.2, 0.98]
    assert faults.sensor_of("baro_step") == "baro" and faults.STAMPED["baro"]


def test_imu_dropout_gives_non_finite_samples_in_its_window():
    fault = FaultConfig(kind="imu_dropout", start=1.0, end=1.2)
    sample = [0.1, 0.2, -9.8, 0.01, 0.02, 0.03]
    assert all(math.isnan(x) for x in faults.imu_dropout(sample, 1.0, fault, 0.002))
    assert faults.imu_dropout(sample, 1.2, fault, 0.002) == sample


def test_faults_compose_in_order_and_removal_wins():
    step = FaultConfig(kind="gps_step", start=10.0, end=20.0, offset=[3.0, 0.0, 0.0])
    outlier = FaultConfig(kind="gps_outlier", time=12.0, offset=[0.0, 10.0, 0.0])
    outage = FaultConfig(kind="gps_outage", start=14.0, end=15.0)
    chain = (step, outlier, outage)
    assert faults.apply_faults(chain, gps(12.0), 12.0, GPS_PERIOD) == pytest.approx(
        gps(12.0, p=(4.0, 12.0, -3.0)), abs=1e-12
    )
    assert faults.apply_faults(chain, gps(13.0), 13.0, GPS_PERIOD) == pytest.approx(
        gps(13.0, p=(4.0, 2.0, -3.0)), abs=1e-12
    )
    assert is_removed(faults.apply_faults(chain, gps(14.5), 14.5, GPS_PERIOD))
    assert is_removed(faults.apply_faults((outage, step), gps(14.5), 14.5, GPS_PERIOD))
    assert faults.apply_faults(chain, gps(25.0), 25.0, GPS_PERIOD) == gps(25.0)


def test_no_sample_yet_passes_through_untouched():
    step = FaultConfig(kind="gps_step", start=0.0, end=20.0, offset=[3.0, 0.0, 0.0])
    before_first = [0.0] * 6 + [NO_SAMPLE_STAMP]
    assert faults.apply_faults((step,), before_first, NO_SAMPLE_STAMP, GPS_PERIOD) == before_first


def test_sample_faults_pick_one_sensor_and_leave_out_the_delay():
    fault_list = [
        FaultConfig(kind="gps_delay", delay=0.2),
        FaultConfig(kind="mag_bias", start=1.0, end=2.0, offset=[0.1]),
        FaultConfig(kind="gps_outage", start=1.0, end=2.0),
    ]
    assert [f.kind for f in faults.sample_faults(fault_list, "gps")] == ["gps_outage"]
    assert [f.kind for f in faults.sample_faults(fault_list, "mag")] == ["mag_bias"]
    assert faults.sample_faults(fault_list, "imu") == ()
    assert faults.gps_delay_of(fault_list) == 0.2
    assert faults.gps_delay_of(fault_list[1:]) == 0.0


def test_release_due_keeps_order_and_stamps():
    pending = [gps(1.0), gps(1.1), gps(1.2)]
    due, rest = faults.release_due(pending, 1.25, 0.2)
    assert due == [gps(1.0)] and rest == [gps(1.1), gps(1.2)]
    due, rest = faults.release_due(rest, 11 * 0.1 + 0.2, 0.2)  # due exactly now, up to rounding
    assert due == [gps(1.1)] and rest == [gps(1.2)]
    due, rest = faults.release_due(rest, 1.39, 0.2)
    assert due == [] and rest == [gps(1.2)]
    assert faults.release_due([gps(1.0), gps(1.1)], 5.0, 0.2) == ([gps(1.0), gps(1.1)], [])


def _step(pending, sample, last_stamp, now, capacity=4, sample_faults=()):
    return faults.delay_queue_step(pending, sample, last_stamp, now, 0.2, capacity, sample_faults, GPS_PERIOD)


def test_delay_queue_takes_in_a_stamp_once_and_skips_no_sample():
    due, pending, last = _step([], gps(1.0), NO_SAMPLE_STAMP, 1.0)
    assert (due, pending, last) == ([], [gps(1.0)], 1.0)
    held = gps(1.0, p=(9.0, 9.0, 9.0))  # the same stamp again (a sample held between ticks)
    assert _step(pending, held, last, 1.002) == ([], [gps(1.0)], 1.0)
    nothing = faults.removed(gps(0.0))
    assert _step(pending, nothing, last, 1.004) == ([], [gps(1.0)], 1.0)
    assert _step([], nothing, NO_SAMPLE_STAMP, 1.004) == ([], [], NO_SAMPLE_STAMP)
    assert pending == [gps(1.0)]  # the argument is not modified


def test_delay_queue_releases_in_order_at_stamp_plus_delay_stamps_kept():
    stamps = [k * 0.05 for k in range(20, 24)]  # 1.0 .. 1.15 s
    pending, last = [], NO_SAMPLE_STAMP
    for stamp in stamps:
        due, pending, last = _step(pending, gps(stamp), last, stamp)
        assert due == []
    assert pending == [gps(s) for s in stamps] and last == stamps[-1]
    # due exactly now up to rounding: 1.0 + 0.2 vs 12 * 0.1; the current sample is not new
    due, rest, _ = _step(pending, gps(stamps[-1]), last, 12 * GPS_PERIOD)
    assert due == [gps(stamps[0])] and rest == [gps(s) for s in stamps[1:]]
    due, rest, _ = _step(rest, gps(stamps[-1]), last, 1.3)
    assert due == [gps(stamps[1]), gps(stamps[2])] and rest == [gps(stamps[3])]
    due, rest, last = _step(rest, gps(1.4), last, 10.0)  # a new sample is queued before release
    assert due == [gps(stamps[3]), gps(1.4)] and rest == [] and last == 1.4


def test_delay_queue_applies_the_faults_at_the_stamp_and_drops_removed_samples():
    outage = FaultConfig(kind="gps_outage", start=1.0, end=1.1)
    step = FaultConfig(kind="gps_step", start=1.1, end=2.0, offset=[1.0, 0.0, 0.0])
    due, pending, last = _step([gps(0.9)], gps(1.0), 0.9, 1.05, sample_faults=(outage, step))
    assert (due, pending, last) == ([], [gps(0.9)], 1.0)  # removed, but its stamp taken in
    due, pending, last = _step(pending, gps(1.1), last, 1.1, sample_faults=(outage, step))
    assert (due, pending, last) == ([gps(0.9)], [gps(1.1, p=(2.0, 2.0, -3.0))], 1.1)


def test_delay_queue_overflow_raises_past_capacity_after_the_release():
    pending = [gps(1.0), gps(1.1)]
    assert _step(pending, gps(1.15), 1.1, 1.15, capacity=3) == ([], [*pending, gps(1.15)], 1.15)
    with pytest.raises(RuntimeError, match=r"^gps_delay queue overflow at t = 1.15 s \(3 samples\)$"):
        _step(pending, gps(1.15), 1.1, 1.15, capacity=2)
    # at 1.2 s the sample of 1.0 s leaves first: two stay, which fit
    assert _step(pending, gps(1.2), 1.1, 1.2, capacity=2) == ([gps(1.0)], [gps(1.1), gps(1.2)], 1.2)


# ----- configuration -------------------------------------------------------------

SCENARIO = """
end_time: 2
vehicles:
  - name: Quad
    sensors: {imu: {}, gps: {}, mag: {}}
"""


@pytest.mark.parametrize(
    "faults_yaml, expected",
    [
        (
            "[{kind: gps_blackout, start: 1, end: 2}]",
            "vehicles.0.faults.0.kind: 'gps_blackout' is not one of",
        ),
        ("[{kind: gps_outage, start: 5, end: 5}]", "vehicles.0.faults.0.end: must be > start (5.0), got 5.0"),
        ("[{kind: gps_outage, start: 5}]", "vehicles.0.faults.0.end: must be > start"),
        (
            "[{kind: gps_step, start: 1, end: 2, offset: [1, 2]}]",
            "faults.0.offset: gps_step takes 3 values, got 2",
        ),
        ("[{kind: gps_outlier, time: 3}]", "faults.0.offset: gps_outlier takes 3 values, got 0"),
        (
            "[{kind: mag_bias, start: 1, end: 2, offset: [0.1, 0.2]}]",
            "offset: mag_bias takes 1 values, got 2",
        ),
        ("[{kind: gps_outage, start: 1, end: 2, offset: [1]}]", "offset: gps_outage takes 0 values, got 1"),
        ("[{kind: gps_delay}]", "faults.0.delay: must be a positive multiple of 0.002 s, got 0.0"),
        ("[{kind: gps_delay, delay: 0.201}]", "faults.0.delay: must be a positive multiple of 0.002 s"),
        ("[{kind: gps_delay, delay: 0.2}, {kind: gps_delay, delay: 0.1}]", "faults: at most one gps_delay"),
        ("[{kind: gps_outage, start: -1, end: 2}]", "vehicles.0.faults.0.start: must be >= 0"),
        ("[{kind: gps_outage, begin: 1, end: 2}]", "vehicles.0.faults.0.begin: unknown key"),
        ("{kind: gps_outage, start: 1, end: 2}", "vehicles.0.faults: expected a list"),
    ],
)
def test_bad_faults_are_one_line_naming_the_field(tmp_path, faults_yaml, expected):
    from quad_drake.config.errors import ConfigError
    from quad_drake.config.loader import load_scenario

    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    with pytest.raises(ConfigError) as info:
        load_scenario(path, [f"vehicles.0.faults={faults_yaml}"])
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(path))
    assert expected in message


def test_a_fault_needs_its_sensor(tmp_path):
    from quad_drake.config.errors import ConfigError
    from quad_drake.config.loader import load_scenario

    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    with pytest.raises(
        ConfigError, match="vehicles.0.faults.0.kind: mag_bias needs a mag sensor on the vehicle"
    ):
        load_scenario(
            path,
            [
                "vehicles.0.sensors.mag=null",
                "vehicles.0.faults=[{kind: mag_bias, start: 1, end: 2, offset: [1]}]",
            ],
        )


def test_faults_load_in_order_and_round_trip(tmp_path):
    from pydrake.common.yaml import yaml_load_typed

    from quad_drake.config.loader import dump_scenario, load_scenario
    from quad_drake.config.schema import ScenarioConfig

    path = tmp_path / "s.yaml"
    path.write_text(SCENARIO)
    faults_yaml = "[{kind: gps_delay, delay: 0.2}, {kind: gps_outlier, time: 3, offset: [50, 0, 0]}]"
    scenario = load_scenario(path, [f"vehicles.0.faults={faults_yaml}"])
    got = scenario.vehicles[0].faults
    assert [f.kind for f in got] == ["gps_delay", "gps_outlier"]
    assert got[0].delay == 0.2 and got[1].offset == [50.0, 0.0, 0.0] and got[1].time == 3.0
    assert yaml_load_typed(schema=ScenarioConfig, data=dump_scenario(scenario)) == scenario
