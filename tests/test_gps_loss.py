"""A GPS lost in flight is aided as PX4 aids it: dead-reckoning for EKF2_NOAID_TOUT (5 s), then
the last fix's horizontal position held: on the no-aiding input with PX4's σ (EKF2_NOAID_NOISE in
flight; at rest its rest σ and a zero velocity) for every kind that fuses it, merged into the GPS
(zero horizontal velocity, the barometer's height) only for the others; the GPS switched back in
as a regain (``flightlogs.replay.aiding_gps``)."""

import dataclasses
import math

import numpy as np
import pytest

from quad_drake.estimation.vocabulary import DIAG
from quad_drake.flightlogs.reader import FlightLog, Samples, read_flight_log
from quad_drake.flightlogs.replay import aiding_gps, replay
from quad_drake.flightlogs.settings import LOG_DIR, load_replay

SITL = LOG_DIR / "sitl_takeoff_land_gps.ulg"


def _synthetic_log(with_baro):
    """30 s at 100 Hz IMU, GPS at 5 Hz from 0.2 s moving north at 1 m/s with a 3 s gap at 5 s and a
    12 s loss from 10 s to 22 s; the IMU at rest but for a turn at 0.5 rad/s from 16 s to 18 s; a
    barometer at 20 Hz climbing 0.5 m/s from 12 s on."""
    imu_times = np.arange(0.0, 30.0, 0.01)
    imu = np.tile([0.0, 0.0, -9.81, 0.0, 0.0, 0.0], (len(imu_times), 1))
    imu[(imu_times >= 16.0) & (imu_times < 18.0), 5] = 0.5
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
    return FlightLog("synthetic", Samples(imu_times, imu), gps=Samples(gps_times, gps_values), baro=baro)


@pytest.mark.parametrize("with_baro", [False, True])
def test_a_loss_is_held_on_the_no_aid_input_with_px4s_std_and_no_gps_sample(with_baro):
    log = _synthetic_log(with_baro)
    config = load_replay(SITL, "{kind: eskf}")  # EKF2_NOAID_NOISE 10 m, rest 0.01 m and 0.2 m/s, every 0.2 s
    gps, no_aid, fake, late_fix, losses = aiding_gps(log, config, separate=True)
    # the 3 s gap is dead-reckoned; a fix at 0.2 s is not late; no GPS sample in the loss, so the
    # returning GPS ends an outage of the whole loss (a regain)
    assert gps is log.gps and (fake, late_fix, losses) == (False, None, [(10.0, 22.0)])
    np.testing.assert_allclose(no_aid.times, np.arange(15.0, 21.8 + 1e-9, 0.2))  # to the regain - 0.2 s
    np.testing.assert_array_equal(no_aid.values[:, 0:6], np.tile([10.0, 0.0, 0.0, 0.0, 0.0, 0.0], (35, 1)))
    turning = (no_aid.times > 16.1) & (no_aid.times < 18.9)  # from the turn to 1 s after it
    std = no_aid.values[:, 6:12]
    np.testing.assert_array_equal(std[:, 0:2], np.where(turning, 10.0, 0.01)[:, None] * np.ones(2))
    np.testing.assert_array_equal(std[:, 2], math.inf if with_baro else 10.0)  # the baro's height, not fused
    np.testing.assert_array_equal(std[:, 3:6], np.where(turning, math.inf, 0.2)[:, None] * np.ones(3))


@pytest.mark.parametrize("with_baro", [False, True])
def test_a_kind_without_no_aid_gets_the_held_position_in_its_gps(with_baro):
    log = _synthetic_log(with_baro)
    config = load_replay(SITL, "{kind: eskf}")
    gps, no_aid, fake, late_fix, losses = aiding_gps(log, config, separate=False)
    assert (no_aid, fake, late_fix, losses) == (None, False, None, [(10.0, 22.0)])
    held = ~np.isin(gps.times, log.gps.times)
    np.testing.assert_allclose(gps.times[held], np.arange(15.0, 21.8 + 1e-9, 0.2))
    np.testing.assert_array_equal(gps.values[held][:, [0, 1, 3, 4]], np.tile([10.0, 0.0, 0.0, 0.0], (35, 1)))
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
    """The bundled SITL flight (fix at 9.2 s, take-off at 19 s) with its GPS cut from 14 s to 24 s
    and, from the regain on, 30 m north of where it was (a jump the gate rejects)."""
    log = read_flight_log(SITL)
    keep = (log.gps.times < 14.0) | (log.gps.times >= 24.0)
    values = log.gps.values[keep].copy()
    values[log.gps.times[keep] >= 24.0, 0] += JUMP
    return log, dataclasses.replace(log, gps=Samples(log.gps.times[keep], values))


JUMP = 30.0  # m north: the GPS after the regain


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
def test_a_loss_holds_the_horizontal_estimate_and_the_returning_gps_is_a_regain(lost_gps_log, kind):
    log, lost = lost_gps_log
    # the GPS as logged (not measured the log's 110 ms EKF2_GPS_DELAY before): the cut's times
    config = load_replay(SITL, f"{{kind: {kind}}}", ["gps_delay=0"])
    aided = replay(config, lost)
    assert aided.aiding.gps_losses == [(pytest.approx(13.96), pytest.approx(24.048))]
    note = next(n for n in aided.notes() if n.startswith("The GPS was lost from 14.0 s to 24.0 s"))
    assert "horizontal position with σ = 10 m (EKF2_NOAID_NOISE" in note and "on its no-aiding input" in note
    rms = _loss_rms(aided, log)
    # measured: ESKF x, y 0.093, 0.104 m, vx, vy 0.036, 0.033 m/s, z 0.066 m, vz 0.021 m/s; EKF7
    # 0.025, 0.047, 0.009, 0.011, 0.039, 0.029 (dead-reckoned: ESKF x, y 0.189, 0.317 m; EKF7
    # 0.020, 0.050 m); the log's land detector says in the air from 16.7 s: no rest σ in the climb
    assert np.all(rms[0:2] < 0.12) and np.all(rms[3:5] < 0.05) and rms[2] < 0.1 and rms[5] < 0.05
    # the jump after the loss is an outage's end: reset to at once, not gated for gps_reset_timeout
    t, state = aided.times, aided.logs["estimated_state"]
    resets = aided.logs["diagnostics"][:, DIAG["gps_resets"]]
    assert resets[t < 24.0].max() == 0 and resets[t < 24.3].max() >= 1
    after = (t >= 24.3) & (t < 25.0)
    px4_north = np.interp(t[after], log.reference_position.times, log.reference_position.values[:, 0])
    assert np.all(np.abs(state[after, 0] - (px4_north + JUMP)) < 0.5)
    assert np.all(np.isfinite(state[t >= 25.0]))
