"""A GPS lost in flight is aided as PX4 aids it: dead-reckoning for EKF2_NOAID_TOUT (5 s), then
the last fix's horizontal position held with zero horizontal velocity (the barometer's height
and vertical velocity where the log has one), fed to every kind on its GPS input, and the GPS
switched back in as a regain (``flightlogs.replay.aiding_gps``)."""

import dataclasses

import numpy as np
import pytest

from quad_drake.flightlogs.reader import FlightLog, Samples, read_flight_log
from quad_drake.flightlogs.replay import aiding_gps, replay
from quad_drake.flightlogs.settings import LOG_DIR, load_replay

SITL = LOG_DIR / "sitl_takeoff_land_gps.ulg"


def _synthetic_log(with_baro):
    """30 s at 100 Hz IMU, GPS at 5 Hz from 0.2 s moving north at 1 m/s with a 3 s gap at 5 s and a
    12 s loss from 10 s to 22 s; a barometer at 20 Hz climbing 0.5 m/s from 12 s on."""
    imu_times = np.arange(0.0, 30.0, 0.01)
    imu = Samples(imu_times, np.tile([0.0, 0.0, -9.81, 0.0, 0.0, 0.0], (len(imu_times), 1)))
    gps_times = np.round(np.arange(0.2, 30.0, 0.2), 9)
    gap = (gps_times > 5.0) & (gps_times < 8.0)
    loss = (gps_times > 10.0) & (gps_times < 22.0)
    gps_times = gps_times[~(gap | loss)]
    gps_values = np.zeros((len(gps_times), 6))
    gps_values[:, 0], gps_values[:, 3] = gps_times, 1.0
    baro = None
    if with_baro:
        baro_times = np.arange(0.0, 30.0, 0.05)
        baro = Samples(baro_times, (100.0 + 0.5 * np.maximum(baro_times - 12.0, 0.0))[:, None])
    return FlightLog("synthetic", imu, gps=Samples(gps_times, gps_values), baro=baro)


@pytest.mark.parametrize("with_baro", [False, True])
def test_a_loss_longer_than_px4s_timeout_is_held_until_a_regain(with_baro):
    log = _synthetic_log(with_baro)
    config = load_replay(SITL, "{kind: eskf}")  # gps_regain_time 1 s, fake_position_period 0.2 s
    gps, no_aid, fake, late_fix, losses = aiding_gps(log, config, separate=True)
    # the 3 s gap is dead-reckoned; a fix at 0.2 s is not late: no no-aiding samples
    assert (no_aid, fake, late_fix, losses) == (None, False, None, [(10.0, 22.0)])
    held = ~np.isin(gps.times, log.gps.times)
    np.testing.assert_allclose(gps.times[held], np.arange(15.0, 20.8 + 1e-9, 0.2))  # to regain - 1 s - 0.2
    np.testing.assert_array_equal(gps.values[held][:, [0, 1, 3, 4]], np.tile([10.0, 0.0, 0.0, 0.0], (30, 1)))
    if with_baro:  # climbing 0.5 m/s from 12 s: z from the baro's change since the loss, v_d its slope
        np.testing.assert_allclose(gps.values[held][:, 2], -0.5 * (gps.times[held] - 12.0), atol=1e-12)
        np.testing.assert_allclose(gps.values[held][:, 5], -0.5, atol=1e-9)
    else:
        np.testing.assert_array_equal(gps.values[held][:, [2, 5]], 0.0)
    assert np.all(np.diff(gps.times) > 0)


def test_no_loss_and_no_aiding_leave_the_gps_as_logged():
    log = _synthetic_log(False)
    config = load_replay(SITL, "{kind: eskf}")
    short = dataclasses.replace(log, gps=Samples(log.gps.times[log.gps.times < 10.0], log.gps.values[:49]))
    assert aiding_gps(short, config)[0] is short.gps
    off = dataclasses.replace(config, fake_position_std=0.0)
    assert aiding_gps(log, off) == (log.gps, None, False, None, [])


@pytest.fixture(scope="module")
def lost_gps_log():
    """The bundled SITL flight (fix at 9.2 s, take-off at 19 s) with its GPS cut from 14 s to 24 s."""
    log = read_flight_log(SITL)
    keep = (log.gps.times < 14.0) | (log.gps.times >= 24.0)
    return log, dataclasses.replace(log, gps=Samples(log.gps.times[keep], log.gps.values[keep]))


def _loss_rms(result, log):
    """(6,) RMS of ours - PX4's (x, y, z m, vx, vy, vz m/s) over the loss (PX4 kept its GPS)."""
    t, state = result.times, result.logs["estimated_state"]
    inside = (t >= 14.0) & (t < 24.0)
    ours = np.column_stack([state[inside][:, 0:3], state[inside][:, 7:10]])
    ref = log.reference_position
    px4 = np.column_stack([np.interp(t[inside], ref.times, ref.values[:, j]) for j in range(6)])
    return np.sqrt(np.mean((ours - px4) ** 2, axis=0))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["eskf", "ekf7"])
def test_a_held_position_keeps_the_estimate_near_px4s_through_a_loss(lost_gps_log, kind):
    log, lost = lost_gps_log
    config = load_replay(SITL, f"{{kind: {kind}}}")
    aided = replay(config, lost)
    assert aided.aiding.gps_losses == [(pytest.approx(13.96), pytest.approx(24.048))]
    assert any(note.startswith("The GPS was lost from 14.0 s to 24.0 s") for note in aided.notes())
    rms = _loss_rms(aided, log)
    # measured: ESKF x, y 0.044, 0.043 m (dead-reckoned 0.189, 0.317), z 0.073, vz 0.033 (0.020);
    # EKF7 0.030, 0.025 m (0.020, 0.050), z 0.052, vz 0.052 (0.028) while PX4 climbs to 2 m
    assert np.all(rms[0:2] < 0.05) and rms[2] < 0.1 and np.all(rms[3:5] < 0.03) and rms[5] < 0.1
    after = aided.times >= 25.0
    assert np.all(np.isfinite(aided.logs["estimated_state"][after]))
