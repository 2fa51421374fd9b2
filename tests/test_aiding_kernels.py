"""kernels/aiding.py: the compiled barometer, field and heading fusion of N filters against the
pure functions they compile (estimation/baro.py, estimation/mag3.py) and their dense oracles,
to 1e-12; the gates, the bias filter's GPS updates and resets, non-finite samples."""

import dataclasses
import math

import numpy as np
import pytest
from conftest import as_flight_input

from quad_drake.estimation import baro, ekf, eskf, gating, mag3
from quad_drake.estimation.vocabulary import DIAG, initial_diagnostics
from quad_drake.kernels import aiding, ekf7
from quad_drake.models import sensor_models
from quad_drake.models.rotations import quat_from_euler, wrap_to_pi

N = 4
PARAMS = baro.BaroFusionParams(
    height_std=0.1, bias_init=0.2, bias_init_std=0.5, bias_walk_std=0.01, reset_timeout=0.1
)
THRESHOLD = gating.gate_threshold(1, 5.0)


def spd(rng, n, scale):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + 0.1 * np.eye(n))


def nominal(rng):
    q = quat_from_euler(*rng.uniform(-0.4, 0.4, 2), rng.uniform(-math.pi, math.pi))
    return eskf.initial_nominal(rng.normal(size=3) - [0, 0, 2], rng.normal(size=3), q)


def fresh_books(count):
    return np.tile(baro.initial_book(PARAMS), (count, 1)), np.tile(initial_diagnostics(), (count, 1))


def baro_rows(x, P, samples, gps, *rest):
    """aiding.baro_rows with the barometer and GPS samples as a flight passes them."""
    aiding.baro_rows(x, P, as_flight_input(samples), as_flight_input(gps), *rest)


def field_rows(x, P, mag, *rest):
    """aiding.field_rows with the magnetometer sample as a flight passes it."""
    aiding.field_rows(x, P, as_flight_input(mag), *rest)


def heading_rows(x, P, mag, attitude, *rest):
    """aiding.heading_rows with the magnetometer sample and the attitude as a flight passes them."""
    aiding.heading_rows(x, P, as_flight_input(mag), as_flight_input(attitude), *rest)


def test_baro_rows_fuse_as_the_pure_update_and_gate_the_outlier():
    rng = np.random.default_rng(0)
    x = np.stack([nominal(rng) for _ in range(N)])
    P = np.stack([spd(rng, 7, 0.01) for _ in range(N)])  # the EKF7's: its bias in the book
    P_before = P.copy()
    book, diagnostics = fresh_books(N)
    book[:, baro.LAST_STAMP] = 0.98  # the previous sample
    book[:, baro.DATUM_SET] = 1.0
    heights = -x[:, 2] + 0.2 + np.array([0.05, -0.1, 0.0, 30.0])  # vehicle 3: a 30 m outlier
    heights[2] = math.nan  # vehicle 2: a non-finite sample
    samples = np.column_stack((heights, np.full(N, 1.0)))
    gps = np.tile([0.0] * 6 + [-1.0], (N, 1))  # no GPS
    model = aiding.baro_model(PARAMS, 2.0, THRESHOLD, 0.02)
    dx, fused = np.zeros((N, 7)), np.zeros(N, dtype=bool)
    baro_rows(x, P, samples, gps, book, diagnostics, model, dx, fused)
    assert fused.tolist() == [True, True, False, False]
    bias_var = 0.5**2 + 0.01**2 * 0.02  # grown over the 20 ms since the previous sample
    for i in (0, 1):
        nu, S = baro.height_innovation(x[i, 2], P_before[i], heights[i], 0.2, 0.01)
        expected_dx, expected_P, nis = baro.height_correction(P_before[i], nu, S)
        assert expected_P[2, 2] < bias_var  # the floor binds: P[2, 2] is raised to the bias variance
        expected_P[2, 2] = bias_var
        np.testing.assert_allclose(dx[i], expected_dx, rtol=0, atol=1e-12)
        np.testing.assert_allclose(P[i], expected_P, rtol=0, atol=1e-12)
        assert diagnostics[i, DIAG["baro_nis"]] == pytest.approx(nis, rel=1e-12)
        # added (the EKF7's correction), the dense oracle's posterior, floored
        x_oracle, P_oracle, _ = baro.ekf7_baro_update(x[i, :7], P_before[i], heights[i], 0.2, 0.01)
        P_oracle[2, 2] = bias_var
        np.testing.assert_allclose(x[i, :7] + dx[i], x_oracle, atol=1e-12)
        np.testing.assert_allclose(P[i], P_oracle, atol=1e-12)
    np.testing.assert_array_equal(P[2:], P_before[2:])  # skipped and gated keep P
    assert diagnostics[2, DIAG["nonfinite_samples"]] == 1 and diagnostics[3, DIAG["baro_gated"]] == 1
    assert book[3, baro.REJECTED_SINCE] == 1.0 and math.isnan(book[0, baro.REJECTED_SINCE])
    np.testing.assert_allclose(diagnostics[:, DIAG["baro_bias_std"]], math.sqrt(bias_var))
    # the same stamp again is not fresh: nothing moves
    P_after = P.copy()
    baro_rows(x, P, samples, gps, book, diagnostics, model, dx, fused)
    assert not fused.any()
    np.testing.assert_array_equal(P, P_after)


def test_baro_rows_with_the_bias_in_the_state_equal_the_eskf_oracle():
    # the ESKF carries the bias (nominal x[:, 16], its error last in P): every tick of
    # baro_rows, injected, is the dense oracle's update of H = -e_2 + e_last, to 1e-12; the first
    # finite sample sets the datum (b = h + p_z, the height not moved), an outlier is gated, a
    # non-finite sample skipped
    rng = np.random.default_rng(5)
    n = 16
    x = np.stack([np.append(nominal(rng), 0.2) for _ in range(N)])
    P = np.stack([spd(rng, n, 0.01) for _ in range(N)])
    book, diagnostics = fresh_books(N)
    book[1:, baro.LAST_STAMP] = 0.98  # vehicles 1-3 had their datum
    book[1:, baro.DATUM_SET] = 1.0
    heights = -x[:, 2] + np.array([25.0, 0.25, 0.0, 30.0])  # vehicle 0: a far datum, 3: an outlier
    heights[2] = math.nan
    samples = np.column_stack((heights, np.full(N, 1.0)))
    gps = np.tile([0.0] * 6 + [-1.0], (N, 1))
    model = aiding.baro_model(PARAMS, 2.0, THRESHOLD, 0.02, bias_in_state=True)
    x_before, P_before, book_before = x.copy(), P.copy(), book.copy()
    dx, fused = np.zeros((N, n)), np.zeros(N, dtype=bool)
    baro_rows(x, P, samples, gps, book, diagnostics, model, dx, fused)
    assert fused.tolist() == [False, True, False, False]
    # vehicle 0: the datum, 25 m off: the bias takes it, the height stays
    assert x[0, eskf.BARO_BIAS_NOMINAL] == pytest.approx(25.0, abs=1e-12) and book[0, baro.DATUM_SET] == 1
    np.testing.assert_array_equal(x[0, :16], x_before[0, :16])
    np.testing.assert_allclose(P[0], baro.bias_state_reset(P_before[0], 0.01), rtol=0, atol=1e-12)
    # vehicle 1: fused (the caller injects)
    np.testing.assert_array_equal(x[1], x_before[1])
    x_oracle, P_oracle, nis = baro.eskf_baro_update(x_before[1], P_before[1], heights[1], 0.01)
    x_new, P_new = eskf.inject(x[1], P[1], dx[1])
    np.testing.assert_allclose(x_new, x_oracle, rtol=0, atol=1e-12)
    np.testing.assert_allclose(P_new, P_oracle, rtol=0, atol=1e-12)
    assert diagnostics[1, DIAG["baro_nis"]] == pytest.approx(nis, rel=1e-12)
    assert x_new[eskf.BARO_BIAS_NOMINAL] != 0.2  # the bias is corrected with the height
    for i in (0, 1):
        assert diagnostics[i, DIAG["baro_bias_std"]] == pytest.approx(math.sqrt(P[i, n - 1, n - 1]))
    np.testing.assert_array_equal(book[:, baro.BIAS_VAR], book_before[:, baro.BIAS_VAR])  # not the book's
    np.testing.assert_array_equal(P[2:], P_before[2:])
    assert diagnostics[2, DIAG["nonfinite_samples"]] == 1 and diagnostics[3, DIAG["baro_gated"]] == 1


def test_a_bias_state_reset_takes_the_height_and_the_gps_feeds_only_the_check():
    n = 10
    x = np.append(eskf.initial_nominal([0, 0, -1], [0, 0, 0], [1, 0, 0, 0]), 0.2)[None, :]
    P = (np.eye(n) * 1e-4)[None]
    P[0, 2, 9] = P[0, 9, 2] = 5e-5
    book, diagnostics = fresh_books(1)
    book[0, baro.LAST_STAMP], book[0, baro.DATUM_SET] = 0.0, 1.0
    model = aiding.baro_model(PARAMS, 2.0, THRESHOLD, 0.02, bias_in_state=True)
    dx, fused = np.zeros((1, n)), np.zeros(1, dtype=bool)
    no_gps = np.array([[0.0] * 6 + [-1.0]])
    for k in range(1, 7):  # a 5 m step, rejected for 0.1 s (reset_timeout), then reset
        sample = np.array([[1.0 + 0.2 + 5.0, 0.02 * k]])
        baro_rows(x, P, sample, no_gps, book, diagnostics, model, dx, fused)
        assert not fused[0]
    assert diagnostics[0, DIAG["baro_resets"]] == 1
    assert x[0, eskf.BARO_BIAS_NOMINAL] == pytest.approx(5.2, abs=1e-12)  # b = h + p_z
    np.testing.assert_array_equal(P[0, 9, :9], P[0, 2, :9])
    assert P[0, 9, 9] == pytest.approx(1e-4 + 0.01)
    # a GPS height stamped with the baro sample: it feeds the check alone, the bias is not fed
    book[0, baro.GPS_STAMP] = 0.02
    gps = np.array([[0.0, 0.0, -1.5, 0.0, 0.0, 0.0, 0.14]])
    baro_rows(x, P, np.array([[6.2, 0.14]]), gps, book, diagnostics, model, dx, fused)
    assert fused[0]  # the baro sample (the bias reset made it agree again)
    np.testing.assert_array_equal(dx[0], 0.0)  # a zero innovation; the GPS height feeds no bias here
    assert book[0, baro.BIAS] == PARAMS.bias_init and book[0, baro.GPS_STAMP] == 0.14
    # ... the check takes the bias state's innovation (here 0: no evidence), and books no bias to restore
    assert book[0, baro.EVIDENCE_HIGH] == book[0, baro.EVIDENCE_LOW] == 0.0
    assert book[0, baro.RUN_BIAS_HIGH] == book[0, baro.RUN_BIAS_LOW] == 0.0


def test_the_first_baro_sample_sets_the_datum_and_a_step_past_the_timeout_resets_the_bias():
    x, P = np.array([[0.0, 0.0, -1.0] + [0.0] * 4]), np.eye(7)[None] * 0.04
    book, diagnostics = fresh_books(1)
    model = aiding.baro_model(PARAMS, 2.0, THRESHOLD, 0.02)
    gps = np.array([[0.0] * 6 + [-1.0]])
    dx, fused = np.zeros((1, 7)), np.zeros(1, dtype=bool)
    baro_rows(x, P, np.array([[math.nan, 0.0]]), gps, book, diagnostics, model, dx, fused)
    assert not fused[0] and diagnostics[0, DIAG["nonfinite_samples"]] == 1  # a non-finite sample: no datum
    assert book[0, baro.DATUM_SET] == 0.0 and book[0, baro.BIAS] == 0.2
    baro_rows(x, P, np.array([[1.5, 0.02]]), gps, book, diagnostics, model, dx, fused)
    assert not fused[0]  # the first finite sample is the datum: b against the filter's height, not fused
    expected = baro.bias_update(0.2, 0.25 + 0.01**2 * 0.02, 1.5 + -1.0, 0.01 + 0.04)
    assert (book[0, baro.BIAS], book[0, baro.BIAS_VAR]) == pytest.approx(expected, rel=1e-12)
    datum = book[0, baro.BIAS]
    # a 5 m step from 0.04 s: rejected from 0.04 s, the bias reset at 0.14 s (reset_timeout 0.1 s)
    for k in range(2, 9):
        sample = np.array([[1.0 + datum + 5.0, 0.02 * k]])
        baro_rows(x, P, sample, gps, book, diagnostics, model, dx, fused)
        assert fused[0] == (k == 8), k
    assert diagnostics[0, DIAG["baro_resets"]] == 1
    assert diagnostics[0, DIAG["baro_gated"]] == 6  # 0.04 .. 0.14 s
    assert book[0, baro.BIAS] == pytest.approx(datum + 5.0, abs=1e-9)  # b = h + p_z at the reset


def test_a_flight_logs_datum_hundreds_of_metres_up_is_set_by_the_first_sample_and_never_gated():
    """A log's barometer reads a pressure altitude (here 300 m over the datum of the filter's
    height, PX4's 3.5 m noise, the 1 m prior): with the replay's datum_from_first_sample the first
    sample sets b = h + p_z, P_b = height_std^2 + P[2, 2] (the ESKF's rule), and every later sample
    fuses; fused against the prior the datum would move 1 / 14.3 of the way and the baro be gated
    until its reset."""
    params = baro.BaroFusionParams(height_std=3.5, datum_from_first_sample=True)
    x, P = np.array([[0.0, 0.0, -1.0] + [0.0] * 4]), np.eye(7)[None] * 0.04
    book, diagnostics = np.tile(baro.initial_book(params), (1, 1)), np.tile(initial_diagnostics(), (1, 1))
    model = aiding.baro_model(params, 1000.0, THRESHOLD, 0.02)
    gps = np.array([[0.0] * 6 + [-1.0]])
    dx, fused = np.zeros((1, 7)), np.zeros(1, dtype=bool)
    rng = np.random.default_rng(3)
    for k in range(1, 101):  # 2 s of samples at 50 Hz, the vehicle still 1 m up
        sample = np.array([[301.0 + 0.1 * rng.normal(), 0.02 * k]])
        baro_rows(x, P, sample, gps, book, diagnostics, model, dx, fused)
        if k == 1:
            expected = baro.bias_reset(sample[0, 0], -1.0, 3.5**2, 0.04)
            assert (book[0, baro.BIAS], book[0, baro.BIAS_VAR]) == expected
            assert expected == baro.first_datum(0.0, 1.0, sample[0, 0], -1.0, 3.5**2, 0.04, True)
        assert fused[0] == (k > 1), k
    assert diagnostics[0, DIAG["baro_gated"]] == 0 and diagnostics[0, DIAG["baro_resets"]] == 0


def test_baro_bias_learns_from_simultaneous_gps_heights_only():
    x, P = np.zeros((2, 7)), np.tile(np.eye(7) * 0.04, (2, 1, 1))
    x[:, 2] = -1.0
    book, diagnostics = fresh_books(2)
    book[:, baro.LAST_STAMP] = 0.08  # not the first sample
    book[:, baro.DATUM_SET] = 1.0
    model = aiding.baro_model(PARAMS, 2.0, THRESHOLD, 0.02)
    dx, fused = np.zeros((2, 7)), np.zeros(2, dtype=bool)
    samples = np.array([[1.5, 0.1], [1.5, 0.1]])
    gps = np.array([[0, 0, -1.1, 0, 0, 0, 0.1], [0, 0, -1.1, 0, 0, 0, 0.3]])  # vehicle 1: stale baro
    baro_rows(x, P, samples, gps, book, diagnostics, model, dx, fused)
    prior_var = 0.25 + 0.01**2 * 0.02
    bias, var = baro.bias_update(0.2, prior_var, baro.bias_from_gps(1.5, -1.1), 0.01 + 4.0)
    assert book[0, baro.BIAS] == pytest.approx(bias, rel=1e-12)
    assert book[0, baro.BIAS_VAR] == pytest.approx(var, rel=1e-12)
    assert book[1, baro.BIAS] == 0.2 and book[1, baro.GPS_STAMP] == 0.3
    assert diagnostics[0, DIAG["baro_bias"]] == pytest.approx(bias)


M_N = sensor_models.world_field(0.5, 0.1, 1.1)
FIELD = mag3.MagFieldFusionParams(
    declination=0.1, hard_iron=[0.02, -0.01, 0.0], field_std=[0.005, 0.006, 0.004]
)


@pytest.mark.parametrize("corrects_tilt", [True, False])
def test_field_rows_equal_the_batch_oracle_and_gate_a_disturbance(corrects_tilt):
    rng = np.random.default_rng(1)
    x = np.stack([nominal(rng) for _ in range(N)])
    P = np.stack([spd(rng, 15, 1e-3) for _ in range(N)])
    P_before = P.copy()
    field = dataclasses.replace(FIELD, corrects_tilt=corrects_tilt)
    model = aiding.field_model(field, gating.gate_threshold(3, 5.0))
    mag = np.empty((N, 4))
    for i in range(N):
        mag[i, :3] = (
            mag3.predicted_field(*x[i, 6:10], *M_N) + np.array(FIELD.hard_iron) + rng.normal(0, 0.005, 3)
        )
        mag[i, 3] = 0.5
    mag[3, :3] += [0.3, 0.0, 0.0]  # a disturbance
    book, diagnostics = np.full((N, 4), -1.0), np.tile(initial_diagnostics(), (N, 1))
    dx, fused = np.zeros((N, 15)), np.zeros(N, dtype=bool)
    field_rows(x, P, mag, book, 1, diagnostics, model, dx, fused)
    assert fused.tolist() == [True, True, True, False]
    assert diagnostics[3, DIAG["mag_gated"]] == 1 and (book[:, 1] == 0.5).all()
    variance = np.square(FIELD.field_std)
    for i in range(3):
        x_oracle, P_oracle, nis = mag3.eskf_field_update(
            x[i], P_before[i], mag[i, :3], M_N, FIELD.hard_iron, variance, FIELD.attitude_only, corrects_tilt
        )
        if not corrects_tilt:  # the heading alone: no correction of the tilt about N and E
            np.testing.assert_array_equal(dx[i, 6:8], 0.0)
        x_new, P_new = eskf.inject(x[i], P[i], dx[i])
        np.testing.assert_allclose(x_new, x_oracle, atol=1e-12)
        np.testing.assert_allclose(P_new, P_oracle, atol=1e-12)
        assert diagnostics[i, DIAG["field_nis"]] == pytest.approx(nis, rel=1e-10)
    np.testing.assert_array_equal(P[3], P_before[3])


def test_heading_rows_fuse_the_tilt_compensated_heading_as_the_ekf7_yaw():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(N, 7))
    P = np.stack([spd(rng, 7, 0.01) for _ in range(N)])
    P_before, x_before = P.copy(), x.copy()
    attitude = np.column_stack((rng.uniform(-0.3, 0.3, (N, 2)), x[:, 6]))
    mag = np.empty((N, 4))
    for i in range(N):
        q = quat_from_euler(attitude[i, 0], attitude[i, 1], x[i, 6] + 0.05)
        mag[i, :3] = sensor_models.magnetometer_field(q, M_N, FIELD.hard_iron, (0, 0, 0), (0, 0, 0))
        mag[i, 3] = 0.25
    mag[2, :3] = math.nan
    model = aiding.heading_model(FIELD, gating.gate_threshold(1, 5.0))
    book, diagnostics = np.full((N, 4), -1.0), np.tile(initial_diagnostics(), (N, 1))
    dx, fused = np.zeros((N, 7)), np.zeros(N, dtype=bool)
    heading_rows(x, P, mag, attitude, book, 1, diagnostics, model, dx, fused)
    assert fused.tolist() == [True, True, False, True]
    ekf7.correct(x, P, dx, fused)
    for i in (0, 1, 3):
        m = mag[i, :3] - FIELD.hard_iron
        heading = mag3.tilt_compensated_heading(attitude[i, 0], attitude[i, 1], *m, FIELD.declination)
        assert wrap_to_pi(heading - x_before[i, 6] - 0.05) == pytest.approx(0.0, abs=1e-12)
        r = mag3.heading_variance(attitude[i, 0], attitude[i, 1], *m, np.square(FIELD.field_std), 0.0)
        x_oracle, P_oracle, nis = ekf.mag_update(x_before[i], P_before[i], heading, np.array([[r]]))
        np.testing.assert_allclose(x[i], x_oracle, atol=1e-12)
        np.testing.assert_allclose(P[i], P_oracle, atol=1e-12)
        assert diagnostics[i, DIAG["mag_nis"]] == pytest.approx(nis, rel=1e-10)
    assert diagnostics[2, DIAG["nonfinite_samples"]] == 1
    np.testing.assert_array_equal(x[2], x_before[2])


def _dead_reckoned(seconds, gyro_std):
    """(x (16,), P (9, 9)) of a level hovering ESKF after `seconds` s without aiding (no GPS): its
    attitude variance grown by gyro noise of gyro_std rad/s per 2 ms sample, its position and
    velocity errors correlated with the tilt through the prediction (``eskf.predict``)."""
    params = type("Params", (), {"accel_std": [0.5, 0.5, 1.5], "gyro_std": [gyro_std] * 3})
    noise = eskf.NoiseModel(
        np.square(params.accel_std), np.square(params.gyro_std), accel_bias_rate=0.0, gyro_bias_rate=0.0
    )
    x = eskf.initial_nominal((0.0, 0.0, -1.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
    P = np.eye(9) * 1e-6
    for _ in range(round(seconds / 0.002)):
        x, P = eskf.predict(x, P, (0.0, 0.0, -9.81), (0.0, 0.0, 0.0), 0.002, noise)
    return np.asarray(x), P


@pytest.mark.parametrize("attitude_only", [True, False])
def test_a_disturbed_field_the_widened_gate_accepts_moves_only_the_attitude(attitude_only):
    # 4 s without GPS at twice the simulated gyro noise: the tilt's sigma is ~0.09 rad and the
    # position's error is correlated with it, so the 3-dof gate (5 sigma) accepts a disturbance of
    # 0.03 gauss across the field (it looks like a rotation of ~0.06 rad)
    x, P = _dead_reckoned(4.0, 1.0)
    assert math.sqrt(P[6, 6]) > 0.08 and abs(P[0, 7]) / math.sqrt(P[0, 0] * P[7, 7]) > 0.5
    params = mag3.MagFieldFusionParams(attitude_only=attitude_only)
    m_N = mag3.assumed_world_field(params)
    field = np.array(mag3.predicted_field(*x[6:10], *m_N))
    across = np.cross(field, (0.0, 0.0, 1.0))
    mag = np.zeros((1, 4))
    mag[0, :3] = field + 0.03 * across / np.linalg.norm(across)
    mag[0, 3] = 0.5
    book, diagnostics = np.full((1, 4), -1.0), np.tile(initial_diagnostics(), (1, 1))
    dx, fused = np.zeros((1, 9)), np.zeros(1, dtype=bool)
    P_batch = P[None].copy()
    field_rows(
        x[None],
        P_batch,
        mag,
        book,
        1,
        diagnostics,
        aiding.field_model(params, gating.gate_threshold(3, 5.0)),
        dx,
        fused,
    )
    assert fused[0] and np.linalg.norm(dx[0, 6:9]) > 0.03  # accepted: the attitude turns
    if attitude_only:
        np.testing.assert_array_equal(dx[0, :6], 0.0)  # position and velocity keep their values
        np.testing.assert_allclose(np.diag(P_batch[0])[:6], np.diag(P)[:6], rtol=1e-12)
    else:  # the full gain carries the rotation into the position through the correlation
        assert np.linalg.norm(dx[0, :3]) > 0.5


def _learnt_bias_under_a_gps_height_step(seed, params, step=-3.0, seconds=60.0):
    """(bias m, book) of the baro bias filter (``aiding.baro_rows``) after `seconds` s of a
    barometer reading the true 1 m height (0.1 m noise, 50 Hz) and a GPS height (2 m noise, 10 Hz)
    offset by `step` m (NED) from 5 s on, and the first time (s) the check disagreed (NaN: never).
    The filter's height takes the baro corrections and its variance grows by 1e-4 m² between
    samples (a stand-in for its prediction)."""
    rng = np.random.default_rng(seed)
    x, P = np.zeros((1, 16)), np.eye(9)[None] * 0.01
    x[0, 2] = -1.0
    book, diagnostics = np.tile(baro.initial_book(params), (1, 1)), np.tile(initial_diagnostics(), (1, 1))
    model = aiding.baro_model(params, 2.0, gating.gate_threshold(1, params.gate_sigma), 0.02)
    dx, fused = np.zeros((1, 9)), np.zeros(1, dtype=bool)
    gps = np.full((1, 7), -1.0)
    caught = math.nan
    for k in range(1, round(seconds / 0.02) + 1):
        stamp = 0.02 * k
        if k % 5 == 0:
            offset = step if stamp >= 5.0 else 0.0
            gps[0, :] = (0.0, 0.0, -1.0 + offset + rng.normal(0.0, 2.0), 0.0, 0.0, 0.0, stamp)
        P[0, 2, 2] += 1e-4
        sample = np.array([[1.0 + rng.normal(0.0, 0.1), stamp]])
        baro_rows(x, P, sample, gps, book, diagnostics, model, dx, fused)
        if fused[0]:
            x[0, 2] += dx[0, 2]
        disagrees = baro.gps_height_disagrees(
            book[0, baro.EVIDENCE_HIGH], book[0, baro.EVIDENCE_LOW], params.gps_check_threshold
        )
        if disagrees and math.isnan(caught):
            caught = stamp
    return book[0, baro.BIAS], book[0], caught


def test_a_gps_height_that_disagrees_with_the_barometer_does_not_feed_the_bias():
    # the accumulated evidence catches a 3 m GPS height error within seconds and restores the bias
    # (truly 0) it had before; without the check the bias follows the GPS error and takes the
    # baro-held height with it (seed 0 pinned; over seeds 1-20: caught after 0.9-2.7 s, |bias|
    # <= 0.22 m checked, bias <= -2.0 m unchecked, |bias| <= 0.18 m and never caught without the
    # step; the earlier filtered-mean check left |bias| up to 0.42 m)
    checked = baro.BaroFusionParams()
    bias, book, caught = _learnt_bias_under_a_gps_height_step(0, checked)
    assert abs(bias) < 0.3 and 5.0 < caught < 8.0
    assert book[baro.EVIDENCE_LOW] > checked.gps_check_threshold  # the GPS reads high: low innovations
    unchecked = baro.BaroFusionParams(gps_check_offset=0.0)
    assert _learnt_bias_under_a_gps_height_step(0, unchecked)[0] < -1.5
    # a consistent GPS height keeps feeding it and is never taken for a wrong one
    bias, book, caught = _learnt_bias_under_a_gps_height_step(0, checked, step=0.0)
    assert abs(bias) < 0.2 and math.isnan(caught)


def test_the_evidence_is_pages_cusum_of_the_offset_log_likelihood():
    # under a consistent GPS each log-likelihood ratio has the mean -d²/2 and the spread d
    # (d = offset / sigma); the evidence restarts at 0 below and stops at its cap above
    rng = np.random.default_rng(0)
    ratios = baro.offset_log_likelihood(rng.normal(0.0, 2.0, 200000), 4.0, 2.0)
    assert np.mean(ratios) == pytest.approx(-0.5, abs=0.01) and np.std(ratios) == pytest.approx(1.0, rel=0.01)
    assert baro.offset_log_likelihood(3.0, 4.0, 2.0) == pytest.approx((6.0 - 2.0) / 4.0, rel=1e-12)
    assert baro.accumulated_evidence(0.5, -1.0, 28.0) == 0.0
    assert baro.accumulated_evidence(27.5, 1.0, 28.0) == 28.0
    assert baro.accumulated_evidence(3.0, 1.5, 28.0) == 4.5
    assert baro.gps_height_disagrees(14.5, 0.0, 14.0) and baro.gps_height_disagrees(0.0, 14.5, 14.0)
    assert not baro.gps_height_disagrees(14.0, 13.0, 14.0)


def test_the_eskf_check_withholds_the_gps_height_and_leaves_its_bias_state_alone():
    # the ESKF's GPS update teaches its bias state between GPS heights (stand-in: +0.05 m each);
    # the check, on the innovation against x[16] of variance P[9, 9] + R, fires on a GPS height 3 m
    # off within 10-20 samples and stays fired; it restores nothing (the bias state, P and the
    # book's scalar filter keep their values: module docstring of ``baro``)
    x, P = np.zeros((1, 17)), np.eye(10)[None] * 0.01
    x[0, 2] = -1.0
    book, diagnostics = np.tile(baro.initial_book(PARAMS), (1, 1)), np.tile(initial_diagnostics(), (1, 1))
    book[0, baro.DATUM_SET], book[0, baro.LAST_STAMP], book[0, baro.LAST_HEIGHT] = 1.0, 0.14, 1.0
    model = aiding.baro_model(PARAMS, 2.0, THRESHOLD, 0.02, bias_in_state=True)
    dx, fused = np.zeros((1, 10)), np.zeros(1, dtype=bool)
    no_baro = np.array([[1.0, 0.14]])  # the same stamp: no new baro sample, P untouched
    P_before, fired = P.copy(), []
    for k in range(40):
        gps = np.array([[0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.14 + 1e-4 * (k + 1)]])  # 3 m low
        baro_rows(x, P, no_baro, gps, book, diagnostics, model, dx, fused)
        fired.append(
            bool(baro.gps_height_disagrees(book[0, baro.EVIDENCE_HIGH], book[0, baro.EVIDENCE_LOW], 14.0))
        )
        x[0, eskf.BARO_BIAS_NOMINAL] += 0.05
    assert 10 < fired.index(True) < 20 and all(fired[fired.index(True) :])
    assert book[0, baro.EVIDENCE_HIGH] > 14.0 and book[0, baro.EVIDENCE_LOW] == 0.0  # the GPS reads low
    assert x[0, eskf.BARO_BIAS_NOMINAL] == pytest.approx(0.05 * 40, abs=1e-12)
    np.testing.assert_array_equal(P, P_before)
    assert book[0, baro.BIAS] == PARAMS.bias_init and book[0, baro.BIAS_VAR] == PARAMS.bias_init_std**2


def test_per_vehicle_settings_fuse_each_vehicle_as_its_own_model_alone():
    """One call over N vehicles, each with its own world field, hard iron, declination, GPS height
    noise and barometer period (vehicle 3 without a barometer), equals each vehicle's call alone
    with its own model, bit for bit (what a replay of N logs in one Diagram runs)."""
    rng = np.random.default_rng(5)
    fields = [
        mag3.MagFieldFusionParams(declination=0.1 * i, inclination=1.0 + 0.05 * i, hard_iron=[0.01 * i, 0, 0])
        for i in range(N)
    ]
    gps_z_std, period, carried = [0.5, 2.0, 10.0, 3.0], [0.02, 0.008, 0.04, 0.02], [True, True, True, False]
    x16 = np.stack([nominal(rng) for _ in range(N)])
    x7 = np.column_stack((x16[:, 0:6], rng.uniform(-1, 1, N)))
    P15, P7 = (
        np.stack([spd(rng, 15, 1e-3) for _ in range(N)]),
        np.stack([spd(rng, 7, 0.01) for _ in range(N)]),
    )
    mag = np.full((N, 4), 0.5)  # each vehicle's field as its own model predicts it, plus noise
    attitude = np.column_stack((rng.uniform(-0.3, 0.3, (N, 2)), x7[:, 6]))
    for i, f in enumerate(fields):
        m_N = mag3.assumed_world_field(f)
        mag[i, :3] = (
            mag3.predicted_field(*x16[i, 6:10], *m_N) + np.array(f.hard_iron) + rng.normal(0, 0.005, 3)
        )
        m = mag[i, :3] - f.hard_iron
        x7[i, 6] = mag3.tilt_compensated_heading(attitude[i, 0], attitude[i, 1], *m, f.declination) + 0.05
    attitude[:, 2] = x7[:, 6]
    heights = np.column_stack((-x16[:, 2] + rng.normal(0, 0.1, N), np.full(N, 1.0)))
    gps = np.column_stack((x16[:, 0:6] + rng.normal(0, 0.3, (N, 6)), np.full(N, 1.005)))

    def run(rows, field_model, heading_model, baro_model):
        state = [a[rows].copy() for a in (x16, P15, x7, P7)]
        count = len(state[0])
        outputs = []
        for kernel, x, P, model, args in (
            (field_rows, state[0], state[1], field_model, (mag[rows], np.full((count, 4), -1.0), 1)),
            (
                heading_rows,
                state[2],
                state[3],
                heading_model,
                (mag[rows], attitude[rows], np.full((count, 4), -1.0), 1),
            ),
            (
                baro_rows,
                state[0],
                state[1],
                baro_model,
                (heights[rows], gps[rows], fresh_books(count)[0]),
            ),
        ):
            diagnostics = np.tile(initial_diagnostics(), (count, 1))
            dx, fused = np.zeros((count, P.shape[1])), np.zeros(count, dtype=bool)
            kernel(x, P, *args, diagnostics, model, dx, fused)
            outputs += [P.copy(), dx, fused, diagnostics] + ([args[-1]] if kernel is baro_rows else [])
        return outputs

    threshold, heading_threshold = gating.gate_threshold(3, 5.0), gating.gate_threshold(1, 5.0)
    together = run(
        slice(None),
        aiding.field_model(fields, threshold),
        aiding.heading_model(fields, heading_threshold),
        aiding.baro_model(PARAMS, gps_z_std, THRESHOLD, period, carried),
    )
    for i in range(N):
        alone = run(
            slice(i, i + 1),
            aiding.field_model(fields[i], threshold),
            aiding.heading_model(fields[i], heading_threshold),
            aiding.baro_model(PARAMS, gps_z_std[i], THRESHOLD, period[i], carried[i]),
        )
        for shared, own in zip(together, alone, strict=True):
            np.testing.assert_array_equal(shared[i : i + 1], own)
    assert together[2].all() and together[6].all()  # every field and heading fused
    book = together[12]  # each barometer's first sample sets its datum; vehicle 3 has none
    assert book[:, baro.DATUM_SET].tolist() == [1.0, 1.0, 1.0, 0.0]
    np.testing.assert_array_equal(together[11][3], initial_diagnostics())  # as without an update
