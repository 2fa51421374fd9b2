"""The EKF-GSF yaw estimator: the compiled bank (``kernels/gsf.py``) against the matrix-form
oracles of ``estimation/gsf.py`` on seeded random inputs (1e-12), the reset rule, its config
errors, and a short closed-loop in-air alignment without a magnetometer."""

import math

import numpy as np
import pytest

from quad_drake.config.errors import ConfigError
from quad_drake.estimation import gsf
from quad_drake.estimation.vocabulary import DIAG, DIAGNOSTICS_SIZE
from quad_drake.kernels import fusion
from quad_drake.kernels import gsf as gsf_kernel
from quad_drake.models.rotations import euler_from_quat, quat_from_euler_tuple, wrap_angles
from quad_drake.running import catalog
from quad_drake.running.simulation import run

TOL = 1e-12
M = 5


def random_books(rng, n, models=M):
    """n GSF books with random banks (positive-definite P, normalised weights) and their oracles' banks."""
    books, banks = [], []
    for _ in range(n):
        X, P, w = gsf.initial_bank(models, rng.normal(size=2), rng.uniform(0.1, 1.0))
        X[:, 0:2] += rng.normal(size=(models, 2))
        X[:, 2] = wrap_angles(X[:, 2] + rng.normal(scale=0.3, size=models))
        A = rng.normal(scale=0.3, size=(models, 3, 3))
        P = P + A @ np.swapaxes(A, 1, 2)
        w = rng.uniform(0.01, 1.0, size=models)
        w /= w.sum()
        book = gsf_kernel.initial_book(models)
        book[gsf_kernel.STARTED] = 1.0
        H = gsf_kernel.HEADER
        book[H : H + 3 * models], book[H + 3 * models : H + 12 * models] = X.ravel(), P.ravel()
        book[H + 12 * models : H + 13 * models] = w
        books.append(book)
        banks.append((X, P, w))
    return np.array(books), banks


def assert_bank_equal(book_row, X, P, w):
    Xk, Pk, wk = gsf_kernel.bank_of(book_row, M)
    yaw_difference = wrap_angles(Xk[:, 2] - X[:, 2])
    assert np.abs(yaw_difference).max() <= TOL
    np.testing.assert_allclose(Xk[:, 0:2], X[:, 0:2], rtol=TOL, atol=TOL)
    np.testing.assert_allclose(Pk, P, rtol=TOL, atol=TOL)
    np.testing.assert_allclose(wk, w, rtol=TOL, atol=TOL)
    yaw, var = gsf.gaussian_sum_yaw(X, P, w)
    assert abs(wrap_angles(book_row[gsf_kernel.YAW] - yaw)) <= TOL
    assert book_row[gsf_kernel.YAW_VAR] == pytest.approx(var, rel=TOL, abs=TOL)


@pytest.mark.parametrize("seed", range(3))
def test_the_compiled_prediction_equals_the_oracle(seed):
    rng = np.random.default_rng(seed)
    n, params = 8, gsf.GsfParams()
    books, banks = random_books(rng, n)
    roll, pitch = rng.normal(scale=0.3, size=n), rng.normal(scale=0.3, size=n)
    f_B = rng.normal(size=(n, 3)) + (0.0, 0.0, -9.81)
    w_B = rng.normal(size=(n, 3))
    out = gsf_kernel.predict(books, M, roll, pitch, f_B, w_B, 0.002, params)
    for i, (X, P, w) in enumerate(banks):
        X_new, P_new = gsf.predict_bank(X, P, roll[i], pitch[i], f_B[i], w_B[i], 0.002, params)
        assert_bank_equal(out[i], X_new, P_new, w)


@pytest.mark.parametrize("seed", range(3))
def test_the_compiled_velocity_update_equals_the_oracle(seed):
    rng = np.random.default_rng(10 + seed)
    books, banks = random_books(rng, 8)
    v_NE = rng.normal(scale=3.0, size=(8, 2))  # some innovations beyond the 5 sigma clip
    out = gsf_kernel.fuse_velocity(books, M, v_NE, 0.25)
    for i, (X, P, w) in enumerate(banks):
        assert_bank_equal(out[i], *gsf.fuse_velocity_bank(X, P, w, v_NE[i], 0.25))


def test_the_weights_follow_the_likelihood_and_a_clear_motion_picks_the_true_yaw():
    """Accelerating north at a true yaw of 1 rad: the model nearest 1 rad wins the weight."""
    params = gsf.GsfParams()
    X, P, w = gsf.initial_bank(M, (0.0, 0.0), 0.25)
    true_yaw, dt = 1.0, 0.002
    velocity = np.zeros(2)
    # 1 m/s^2 north: in the body frame of yaw 1 rad (level), f_B = Rz(-1) (1, 0, 0) + (0, 0, -g)
    f_B = (math.cos(true_yaw), -math.sin(true_yaw), -9.81)
    for k in range(1, 1001):
        X, P = gsf.predict_bank(X, P, 0.0, 0.0, f_B, (0.0, 0.0, 0.0), dt, params)
        velocity[0] += dt
        if k % 50 == 0:
            X, P, w = gsf.fuse_velocity_bank(X, P, w, velocity, 0.25)
    yaw, var = gsf.gaussian_sum_yaw(X, P, w)
    assert abs(wrap_angles(yaw - true_yaw)) < math.radians(5) and math.sqrt(var) < math.radians(15)
    assert w.sum() == pytest.approx(1.0) and w.argmax() == np.argmin(np.abs(wrap_angles(X[:, 2] - true_yaw)))


def test_the_yaw_reset_keeps_roll_and_pitch():
    q = quat_from_euler_tuple(0.2, -0.3, 2.0)
    roll, pitch, yaw = euler_from_quat(gsf.yaw_reset_quaternion(*q, -2.5))
    assert (roll, pitch, yaw) == pytest.approx((0.2, -0.3, -2.5), abs=1e-12)


def test_the_reset_rule():
    limits = dict(max_yaw_var=0.01, disagreement_time=1.0, max_resets=3)
    reason = lambda t, since, var, aligned, resets: gsf.reset_reason(  # noqa: E731
        t,
        since,
        var,
        aligned,
        resets,
        limits["max_yaw_var"],
        limits["disagreement_time"],
        limits["max_resets"],
    )
    assert reason(5.0, math.nan, 0.02, False, 0) == gsf.NO_RESET  # not confident yet
    assert reason(5.0, math.nan, 0.005, False, 0) == gsf.ALIGN  # no magnetometer has aligned the yaw
    assert reason(5.0, math.nan, 0.005, True, 0) == gsf.NO_RESET  # aligned and agreeing
    assert reason(5.0, 4.5, 0.005, True, 0) == gsf.NO_RESET  # disagreeing for 0.5 s only
    assert reason(5.0, 4.0, 0.005, True, 0) == gsf.DISAGREE
    assert reason(5.0, 4.0, 0.005, True, 3) == gsf.NO_RESET  # out of resets
    start = gsf.disagreement_start
    assert start(math.nan, 2.0, 0.0, 0.005, 0.5, 0.01, 0.436) == 2.0
    assert start(1.0, 2.0, 0.0, 0.005, 0.5, 0.01, 0.436) == 1.0
    assert math.isnan(start(1.0, 2.0, 0.0, 0.005, 0.3, 0.01, 0.436))  # within 25 deg
    assert math.isnan(start(1.0, 2.0, 0.0, 0.02, 0.5, 0.01, 0.436))  # GSF not confident


def test_the_tick_resets_the_eskf_yaw_as_the_oracle_and_blocks_a_lying_magnetometer():
    """A confident bank whose yaw disagrees with the ESKF's for longer than disagreement_time: the
    ESKF's x, P become ``gsf.eskf_yaw_reset``'s and the magnetometer is no longer fused."""
    rng = np.random.default_rng(7)
    params = gsf.GsfParams(enabled=True)
    model = gsf_kernel.model(params, 0.002, 0.1, (DIAG["mag_stamp"], DIAG["mag_gated"]))
    X, P, w = gsf.initial_bank(M, (0.0, 0.0), 0.25)
    X[:, 2], P[:, 2, 2], w = 1.0, 1e-4, np.full(M, 1.0 / M)  # every model at 1 rad, sure of it
    book = gsf_kernel.initial_book(M)
    H = gsf_kernel.HEADER
    book[H : H + 3 * M], book[H + 3 * M : H + 12 * M], book[H + 12 * M :] = X.ravel(), P.ravel(), w
    book[gsf_kernel.STARTED] = book[gsf_kernel.ALIGNED] = 1.0
    book[gsf_kernel.GPS_STAMP] = 0.1  # no fresh GPS sample: prediction only
    book[gsf_kernel.DISAGREE_SINCE] = 0.0
    x = np.zeros((1, 16))
    x[0, 6:10] = quat_from_euler_tuple(0.1, 0.05, 0.0)
    A = rng.normal(size=(15, 15))
    P_main = (A @ A.T)[None]
    filters = fusion.Filters(x, P_main, np.zeros((1, DIAGNOSTICS_SIZE)), None, None)
    imu = np.array([[0.0, 0.0, -9.81, 0.0, 0.0, 0.0]])
    gps = np.array([[0.0] * 6 + [0.1]])
    blocked = np.zeros(1, dtype=bool)
    x_before, P_before = x[0].copy(), P_main[0].copy()
    log = np.full((1, 3 + M), np.nan)
    gsf_kernel.tick(filters, book[None], log, imu, gps, 2.0, model, blocked)
    yaw, var = book[gsf_kernel.YAW], book[gsf_kernel.YAW_VAR]
    weights = book[gsf_kernel.HEADER + 12 * M :]
    np.testing.assert_array_equal(log[0], np.r_[yaw, np.sqrt(var), 1.0, weights])  # the tick's log row
    x_expected, P_expected = gsf.eskf_yaw_reset(x_before, P_before, yaw, var)
    np.testing.assert_allclose(x[0], x_expected, atol=TOL)
    np.testing.assert_allclose(P_main[0], P_expected, atol=TOL)
    assert book[gsf_kernel.RESETS] == 1.0 and blocked[0]
    assert euler_from_quat(x[0, 6:10])[2] == pytest.approx(yaw, abs=1e-12)


@pytest.mark.parametrize(
    "override, message",
    [
        ("vehicles.0.estimator.gsf.models=1", "vehicles.0.estimator.gsf.models"),
        ("vehicles.0.estimator.gsf.reset_max_yaw_std=-0.1", "vehicles.0.estimator.gsf.reset_max_yaw_std"),
        ("vehicles.0.sensors.gps=null", "vehicles.0.estimator.gsf: enabled needs a gps sensor"),
        ("vehicles.0.estimator.gsf.enabled=false", "or, without a magnetometer, the estimator's gsf enabled"),
    ],
)
def test_gsf_config_errors_are_one_line(override, message):
    with pytest.raises(ConfigError) as info:
        catalog.load("26_gsf_yaw_alignment", None, ["vehicles.0.flies_on=estimate", override])
    text = str(info.value)
    assert message in text and "\n" not in text


def aligned_in_the_air(seed):
    """26 (no magnetometer, true heading 2.5 rad from the ESKF's belief) flown 8 s at `seed`:
    (aligned as its criteria judge it, the first yaw error, the resets)."""
    result = run(catalog.load("26_gsf_yaw_alignment", seed, ["end_time=8"]))
    yaw_error = np.abs(result.signals["Quad.Est.E.Yaw"].values)
    at_check = np.searchsorted(result.times, 7.0)
    aligned = yaw_error[at_check] < math.radians(5) and yaw_error[at_check:].max() < math.radians(15)
    return aligned, yaw_error[0], result.signals["Quad.Est.GsfResets"].values[-1]


@pytest.mark.slow
def test_a_vehicle_without_a_magnetometer_aligns_its_yaw_in_the_air():
    """26's check (PX4's inAirYawAlignment): |yaw error| < 5 deg at 7 s, below 15 deg after, from
    143 deg off; the GSF reset the ESKF's yaw. Seed 0 pinned after seeds 0-19 all passed
    (``aligned_in_the_air`` at each, 2026-12-06)."""
    aligned, first_error, resets = aligned_in_the_air(0)
    assert first_error > 2.0 and aligned and resets >= 1.0
