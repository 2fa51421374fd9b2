"""LogPlayback: each sample on the first onboard tick at or after its time, with its stamp, on ports
shaped as the simulated sensors' (so an estimator takes either unchanged)."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from quad_drake.config.schema import GpsParams, ImuParams, MagParams
from quad_drake.conventions import NO_SAMPLE_STAMP, ONBOARD_PERIOD
from quad_drake.flightlogs.reader import FlightLog, Samples
from quad_drake.flightlogs.schedule import playback_streams
from quad_drake.systems.playback import LogPlayback
from quad_drake.systems.sensors import Gps, Imu, Magnetometer


def _log():
    imu_times = np.arange(0, 25) * 0.004  # 250 Hz
    imu = np.column_stack([np.zeros((25, 2)), np.full(25, -9.81), imu_times, np.zeros((25, 2))])
    gps_times = np.array([0.011, 0.05, 0.0505])  # the last two share a tick: the later wins
    gps = np.column_stack([gps_times * 100, np.zeros((3, 5))])
    field = np.tile([0.2, 0.0, 0.4], (2, 1))  # pointing north: heading 0
    return FlightLog(
        source="synthetic",
        imu=Samples(imu_times, imu),
        gps=Samples(gps_times, gps),
        mag_field=Samples(np.array([0.003, 0.021]), field),
    )


@pytest.fixture
def dut():
    return LogPlayback(playback_streams(_log()))


def _output_at(dut, t, name):
    """`name`'s output after advancing a fresh context to t (s)."""
    simulator = Simulator(dut)
    simulator.AdvanceTo(t)
    return dut.GetOutputPort(name).Eval(simulator.get_context())


def test_the_ports_are_shaped_as_the_simulated_sensors(dut):
    sensors = {"imu": Imu(ImuParams()), "gps": Gps(GpsParams()), "mag": Magnetometer(MagParams())}
    for name, sensor in sensors.items():
        assert dut.GetOutputPort(name).size() == sensor.GetOutputPort(name).size()
    assert dut.GetOutputPort("mag_field").size() == 4 and dut.GetOutputPort("baro").size() == 2
    assert dut.num_input_ports() == 0


def test_nothing_is_emitted_before_a_sensors_first_sample(dut):
    assert _output_at(dut, 0.0105, "gps")[-1] == NO_SAMPLE_STAMP  # due at the tick of 0.012 s
    assert _output_at(dut, 0.001, "baro").tolist() == [0.0, NO_SAMPLE_STAMP]  # the log has none
    assert _output_at(dut, 1e-7, "imu")[2] == -9.81  # the first IMU sample is emitted at t = 0


def test_each_sample_is_emitted_at_its_first_tick_with_its_stamp(dut):
    # The tick at 0.012 s carries the GPS sample of 0.011 s; outputs are held until the next one.
    assert _output_at(dut, 0.012 + 1e-7, "gps").tolist() == pytest.approx([1.1, 0, 0, 0, 0, 0, 0.011])
    assert _output_at(dut, 0.049, "gps")[-1] == 0.011
    # 0.05 and 0.0505 s are both due at the tick of 0.052 s: only the later one is emitted.
    assert _output_at(dut, 0.052 + 1e-7, "gps").tolist() == pytest.approx([5.05, 0, 0, 0, 0, 0, 0.0505])
    mag = _output_at(dut, 0.004 + 1e-7, "mag")
    assert mag.tolist() == pytest.approx([0.0, 0.003])  # heading north, stamped with its time
    assert _output_at(dut, 0.004 + 1e-7, "mag_field").tolist() == pytest.approx([0.2, 0.0, 0.4, 0.003])


def test_a_250_hz_imu_is_held_for_two_ticks(dut):
    for tick in range(12):
        t = tick * ONBOARD_PERIOD + 1e-7
        assert _output_at(dut, t, "imu")[3] == pytest.approx(0.004 * (tick // 2))


def test_n_flights_play_as_n_single_playbacks():
    first = playback_streams(_log())
    later = _log()
    shifted = FlightLog(  # the flight's samples 3 ms later (another schedule), shorter, no magnetometer
        source="shifted",
        imu=Samples(later.imu.times[:12] + 0.003, later.imu.values[:12] * 2.0),
        gps=Samples(later.gps.times + 0.003, later.gps.values + 1.0),
    )
    second = playback_streams(shifted)
    both = LogPlayback([first, second])
    singles = [LogPlayback(first), LogPlayback(second)]
    for t in (0.0, 0.004, 0.012, 0.03, 0.05, 0.0525, 0.09):
        for name in ("imu", "gps", "mag", "mag_field", "baro"):
            joined = _output_at(both, t, name)
            parts = np.concatenate([_output_at(single, t, name) for single in singles])
            np.testing.assert_array_equal(joined, parts)
    with pytest.raises(ValueError, match="same streams"):
        LogPlayback([first, {"imu": first["imu"]}])
