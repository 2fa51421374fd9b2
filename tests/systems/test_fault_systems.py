"""SensorFaults: fixed inputs, the schedule it fires on, the delay queue, and its latency in a vehicle."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from quad_drake import conventions as c
from quad_drake.config.schema import FaultConfig
from quad_drake.running import catalog
from quad_drake.running.simulation import run
from quad_drake.systems.faults import SensorFaults

GPS_PERIOD = 0.1
GPS_FIRST = GPS_PERIOD + c.SLOW_SENSOR_OFFSET


def gps(stamp):
    return np.array([1.0, 2.0, -3.0, 0.5, -0.5, 0.1, stamp])


class Fixture:
    def __init__(self, dut, sensor):
        self.dut, self.sensor = dut, sensor
        self.simulator = Simulator(dut)
        self.context = self.simulator.get_mutable_context()
        self.simulator.Initialize()

    def fix(self, value):
        self.dut.GetInputPort(self.sensor).FixValue(self.context, value)

    def advance(self, t):
        self.simulator.AdvanceTo(t)
        return self.dut.GetOutputPort(self.sensor).Eval(self.context)


def test_ports_and_initial_output_say_no_sample_yet():
    dut = SensorFaults(
        "gps", c.GPS_SIZE, [FaultConfig(kind="gps_outage", start=1, end=2)], GPS_PERIOD, GPS_FIRST
    )
    assert dut.num_input_ports() == 1 and dut.num_output_ports() == 1
    assert dut.GetInputPort("gps").size() == dut.GetOutputPort("gps").size() == c.GPS_SIZE
    assert not dut.HasAnyDirectFeedthrough()
    output = dut.GetOutputPort("gps").Eval(dut.CreateDefaultContext())
    assert output[-1] == c.NO_SAMPLE_STAMP


def test_gps_outage_fires_just_after_each_sensor_sample_and_judges_by_the_stamp():
    fixture = Fixture(
        SensorFaults(
            "gps", c.GPS_SIZE, [FaultConfig(kind="gps_outage", start=1.0, end=1.5)], GPS_PERIOD, GPS_FIRST
        ),
        "gps",
    )
    fixture.fix(gps(c.NO_SAMPLE_STAMP))
    fixture.advance(0.85)
    fixture.fix(gps(0.9))
    # the system fires at 0.9 + SLOW_SENSOR_OFFSET + FAULT_LAG, before the EKF offset
    assert fixture.advance(0.9 + c.SLOW_SENSOR_OFFSET)[-1] == c.NO_SAMPLE_STAMP
    np.testing.assert_array_equal(fixture.advance(0.9 + c.EKF_OFFSET), gps(0.9))
    fixture.fix(gps(1.0))
    out = fixture.advance(1.0 + c.EKF_OFFSET)
    assert out[-1] == c.NO_SAMPLE_STAMP and np.isnan(out[:-1]).all()
    fixture.fix(gps(1.5))
    np.testing.assert_array_equal(fixture.advance(1.5 + c.EKF_OFFSET), gps(1.5))


def test_imu_dropout_uses_the_sampling_time_and_fires_before_the_attitude_filter():
    faults = [FaultConfig(kind="imu_dropout", start=1.0, end=1.2)]
    fixture = Fixture(SensorFaults("imu", c.IMU_SIZE, faults, c.ONBOARD_PERIOD, c.SENSOR_OFFSET), "imu")
    sample = np.array([0.1, 0.2, -9.8, 0.01, 0.02, 0.03])
    fixture.fix(sample)
    np.testing.assert_array_equal(fixture.advance(1.0 - c.ONBOARD_PERIOD + c.ATTITUDE_FILTER_OFFSET), sample)
    assert np.isnan(fixture.advance(1.0 + c.ATTITUDE_FILTER_OFFSET)).all()
    assert np.isnan(fixture.advance(1.2 - c.ONBOARD_PERIOD + c.ATTITUDE_FILTER_OFFSET)).all()
    np.testing.assert_array_equal(fixture.advance(1.2 + c.ATTITUDE_FILTER_OFFSET), sample)


def test_gps_delay_releases_each_sample_at_stamp_plus_delay_with_its_stamp():
    delay = 0.25
    faults = [
        FaultConfig(kind="gps_delay", delay=delay),
        FaultConfig(kind="gps_step", start=0, end=9, offset=[1, 0, 0]),
    ]
    fixture = Fixture(SensorFaults("gps", c.GPS_SIZE, faults, GPS_PERIOD, GPS_FIRST), "gps")
    released = {}
    t = 0.0
    for k in range(1, 8):  # samples 0.1 ... 0.7, each held for one period as a sensor would
        stamp = k * GPS_PERIOD
        fixture.fix(gps(stamp))
        while t < stamp + GPS_PERIOD - 1e-9:
            t += c.ONBOARD_PERIOD
            out = fixture.advance(t + c.EKF_OFFSET)
            released.setdefault(out[-1], (t, out.copy()))
    for k in range(1, 6):
        stamp = k * GPS_PERIOD
        first_seen, out = released[stamp]
        assert first_seen == pytest.approx(stamp + delay, abs=1e-9)
        np.testing.assert_allclose(out, gps(stamp) + [1, 0, 0, 0, 0, 0, 0], atol=1e-12)


# ----- in a vehicle: no extra tick of latency, a delay of exactly D, an outage of exactly its window ----

NEVER = 100.0  # s, a fault window after the end of the run


def _run(*overrides, end_time=2.0):
    return run(catalog.load("11_gps_update", 0, [f"end_time={end_time}", *overrides]))


def test_fault_systems_that_do_nothing_leave_every_log_bit_identical():
    plain = _run()
    faulted = _run(
        "vehicles.0.faults=["
        f"{{kind: gps_outage, start: {NEVER}, end: {NEVER + 1}}},"
        f"{{kind: mag_bias, start: {NEVER}, end: {NEVER + 1}, offset: [1.0]}},"
        f"{{kind: imu_dropout, start: {NEVER}, end: {NEVER + 1}}}]"
    )
    for name, data in plain.logs["Quad"].items():
        np.testing.assert_array_equal(data, faulted.logs["Quad"][name], err_msg=name)


def test_gps_delay_reaches_the_ekf_exactly_delay_late():
    delay = 0.2
    plain = _run()
    delayed = _run(f"vehicles.0.faults=[{{kind: gps_delay, delay: {delay}}}]")
    shift = round(delay / c.LOG_PERIOD)
    stamp_plain = plain.logs["Quad"]["diagnostics"][:, 1]  # stamp of the last fused GPS sample
    stamp_delayed = delayed.logs["Quad"]["diagnostics"][:, 1]
    np.testing.assert_array_equal(stamp_delayed[shift:], stamp_plain[:-shift])
    assert (stamp_delayed[:shift] == c.NO_SAMPLE_STAMP).all()


@pytest.mark.slow
def test_a_five_second_gps_outage_leaves_no_fresh_gps_sample_in_its_window():
    result = _run("vehicles.0.faults=[{kind: gps_outage, start: 1.0, end: 6.0}]", end_time=7.0)
    times, fresh = result.times, result.signals["Quad.GPS.X"].fresh
    fused = result.logs["Quad"]["diagnostics"][:, 1]
    inside = (times > 1.0 + c.EKF_OFFSET) & (times <= 6.0)
    assert not fresh[inside].any()
    assert fresh[(times > 6.0) & (times <= 6.1)].sum() == 1  # the 6.0 s sample, first after the window
    assert fresh[times <= 1.0].sum() == 9  # 0.1 ... 0.9; the 1.0 s sample is the first one removed
    assert set(fused[inside]) == {0.9}  # the EKF's last fused sample stays the one before the outage
    assert math.isclose(fused[-1], 6.9, abs_tol=1e-9)
