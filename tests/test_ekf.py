"""7-state EKF: noise matrices, prediction and its Jacobian, Joseph-form updates, consistency (NEES)."""

import math
from statistics import NormalDist

import numpy as np
import pytest
from scipy.stats import chi2

from quad_drake.conventions import GRAVITY
from quad_drake.estimation import ekf
from quad_drake.estimation.registry import AttitudeFilterParams, Ekf7EstimatorConfig
from quad_drake.models.rotations import wrap_to_pi

DT = 0.002
HOVER_F_B = np.array([0.0, 0.0, -GRAVITY])


def random_spd(rng, n, scale=1.0):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + 0.1 * np.eye(n))


def random_inputs(rng):
    x = rng.normal(size=7)
    x[6] = rng.uniform(-math.pi, math.pi)
    return x, rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.normal([0.0, 0.0, -GRAVITY], 3.0)


def test_noise_matrices_and_initial_covariance_from_spec_defaults():
    p = Ekf7EstimatorConfig()
    np.testing.assert_allclose(ekf.process_noise(p), np.diag([5e-6] * 5 + [2e-5, 5e-6]), rtol=1e-12, atol=0)
    np.testing.assert_allclose(
        ekf.gps_noise(p), np.diag([1.0, 1.0, 9.0, 0.01, 0.01, 0.09]), rtol=1e-12, atol=0
    )
    np.testing.assert_allclose(ekf.mag_noise(p), [[0.01]], rtol=1e-12)
    np.testing.assert_allclose(
        ekf.initial_covariance(p), np.diag([0.01, 0.01, 0.09, 0.01, 0.01, 0.09, 0.0025]), rtol=1e-12, atol=0
    )
    np.testing.assert_array_equal(ekf.initial_state(p), [0, 0, -1, 0, 0, 0, 0])
    q = ekf.process_noise(Ekf7EstimatorConfig(q_yaw_std=0.2, dt_imu=0.01))
    assert q[6, 6] == pytest.approx(0.04 * 0.01, rel=1e-12)


def test_level_hover_keeps_velocity_and_integrates_position():
    for yaw in (0.0, 1.0, -2.5):
        x = np.array([1.0, 2.0, -3.0, 0.5, -0.25, 0.1, yaw])
        got = ekf.predict_state(x, 0.0, 0.0, HOVER_F_B, DT)
        np.testing.assert_allclose(got, [1.001, 1.9995, -2.9998, 0.5, -0.25, 0.1, yaw], atol=1e-14)


def test_tilted_hover_accelerates_the_physical_way():
    # Rolled right by 0.2 rad with thrust/mass = g / cos(roll): a_N = (0, g tan(roll), 0) when
    # heading north, (-g tan(roll), 0, 0) when heading east (right wing points south).
    roll = 0.2
    f_B = np.array([0.0, 0.0, -GRAVITY / math.cos(roll)])
    for yaw, a_expected in (
        (0.0, (0.0, GRAVITY * math.tan(roll), 0.0)),
        (math.pi / 2, (-GRAVITY * math.tan(roll), 0.0, 0.0)),
    ):
        got = ekf.predict_state(np.array([0, 0, 0, 0, 0, 0, yaw], dtype=float), roll, 0.0, f_B, 1.0)
        np.testing.assert_allclose(got[3:6], a_expected, atol=1e-12)
        np.testing.assert_allclose(got[0:3], 0.0, atol=0)


@pytest.mark.parametrize("dt", [DT, 0.1])
def test_predict_jacobian_equals_central_differences(dt):
    rng = np.random.default_rng(3)
    h = 1e-6
    for _ in range(20):
        x, roll, pitch, f_B = random_inputs(rng)
        G = ekf.predict_jacobian(x, roll, pitch, f_B, dt)
        numeric = np.empty((7, 7))
        for j in range(7):
            e = np.zeros(7)
            e[j] = h
            numeric[:, j] = (
                ekf.predict_state(x + e, roll, pitch, f_B, dt)
                - ekf.predict_state(x - e, roll, pitch, f_B, dt)
            ) / (2 * h)
        np.testing.assert_allclose(G, numeric, atol=1e-8 * max(1.0, dt * 10), rtol=0)
        assert abs(G[3:5, 6]).max() > 1e-4 * dt  # the yaw column is exercised


def test_predict_equals_its_parts_and_reuses_the_work_buffer():
    rng = np.random.default_rng(4)
    Q = ekf.process_noise(Ekf7EstimatorConfig())
    G_work = ekf.predict_jacobian(np.zeros(7), 0.0, 0.0, HOVER_F_B, DT)
    for _ in range(20):
        x, roll, pitch, f_B = random_inputs(rng)
        P = random_spd(rng, 7, 0.1)
        x_new, P_new = ekf.predict(x, P, roll, pitch, f_B, DT, Q, G_work)
        G = ekf.predict_jacobian(x, roll, pitch, f_B, DT)
        np.testing.assert_allclose(x_new, ekf.predict_state(x, roll, pitch, f_B, DT), atol=1e-15)
        np.testing.assert_allclose(P_new, G @ P @ G.T + Q, rtol=1e-13, atol=1e-16)
        np.testing.assert_array_equal(G_work, G)
        np.testing.assert_array_equal(P_new, P_new.T)
        x_alloc, P_alloc = ekf.predict(x, P, roll, pitch, f_B, DT, Q)
        np.testing.assert_array_equal(x_alloc, x_new)
        np.testing.assert_array_equal(P_alloc, P_new)


def test_predict_with_yaw_is_predict_after_taking_the_attitude_yaw():
    rng = np.random.default_rng(5)
    Q = ekf.process_noise(Ekf7EstimatorConfig())
    G_work = ekf.predict_jacobian(np.zeros(7), 0.0, 0.0, HOVER_F_B, DT)
    for _ in range(20):
        x, roll, pitch, f_B = random_inputs(rng)
        yaw = rng.uniform(-math.pi, math.pi)
        P = random_spd(rng, 7, 0.1)
        x_new, P_new = ekf.predict_with_yaw(x.tolist(), P, (roll, pitch, yaw), f_B.tolist(), DT, Q, G_work)
        assert isinstance(x_new, list)
        x_yaw = x.copy()
        x_yaw[6] = yaw
        x_ref, P_ref = ekf.predict(x_yaw, P, roll, pitch, f_B, DT, Q)
        np.testing.assert_array_equal(x_new, x_ref)
        np.testing.assert_array_equal(P_new, P_ref)
        np.testing.assert_array_equal(G_work, ekf.predict_jacobian(x_yaw, roll, pitch, f_B, DT))


def test_joseph_update_equals_standard_form_for_optimal_gain():
    rng = np.random.default_rng(5)
    for m in (1, 3, 6):
        x, P = rng.normal(size=7), random_spd(rng, 7)
        H, R = rng.normal(size=(m, 7)), random_spd(rng, m, 0.5)
        z, z_hat = rng.normal(size=m), rng.normal(size=m)
        x_new, P_new, nis = ekf.kalman_update(x, P, z, H, R, z_hat)
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        nu = z - z_hat
        np.testing.assert_allclose(x_new, x + K @ nu, rtol=1e-11, atol=1e-12)
        np.testing.assert_allclose(P_new, (np.eye(7) - K @ H) @ P, rtol=1e-10, atol=1e-12)
        assert nis == pytest.approx(nu @ np.linalg.inv(S) @ nu, rel=1e-11)


def test_updates_keep_covariance_symmetric_and_positive_definite():
    rng = np.random.default_rng(6)
    p = Ekf7EstimatorConfig()
    Q, R_gps, R_mag = ekf.process_noise(p), ekf.gps_noise(p), ekf.mag_noise(p)
    x, P = ekf.initial_state(p), ekf.initial_covariance(p)
    for k in range(3000):
        _, roll, pitch, f_B = random_inputs(rng)
        x, P = ekf.predict(x, P, roll, pitch, f_B, DT, Q)
        if k % 5 == 0:
            x, P, _ = ekf.mag_update(x, P, rng.uniform(-math.pi, math.pi), R_mag)
        if k % 50 == 0:
            x, P, _ = ekf.gps_update(x, P, rng.normal(size=6) * 10.0, R_gps)
        np.testing.assert_array_equal(P, P.T)
        assert np.linalg.eigvalsh(P).min() > 0.0
    assert -math.pi <= x[6] < math.pi


def test_gps_update_is_kalman_update_with_position_velocity_rows():
    rng = np.random.default_rng(7)
    x, P = rng.normal(size=7), random_spd(rng, 7)
    z, R = rng.normal(size=6), ekf.gps_noise(Ekf7EstimatorConfig())
    H = np.hstack([np.eye(6), np.zeros((6, 1))])
    got = ekf.gps_update(x, P, z, R)
    want = ekf.kalman_update(x, P, z, H, R, H @ x)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert got[2] == want[2]
    assert abs(got[0][6] - x[6]) > 1e-3  # yaw moves through its correlation with p, v


def test_mag_update_scalar_form_equals_kalman_update():
    rng = np.random.default_rng(8)
    R = ekf.mag_noise(Ekf7EstimatorConfig())
    for _ in range(50):
        x, P = rng.normal(size=7), random_spd(rng, 7)
        x[6] = rng.uniform(-1.0, 1.0)
        z = x[6] + rng.normal(0.0, 0.5)
        x_new, P_new, nis = ekf.mag_update(x, P, z, R)
        x_ref, P_ref, nis_ref = ekf.kalman_update(x, P, [z], ekf.H_MAG, R, x[6:7])
        x_ref[6] = wrap_to_pi(x_ref[6])
        np.testing.assert_allclose(x_new, x_ref, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(P_new, P_ref, rtol=1e-11, atol=1e-13)
        np.testing.assert_array_equal(P_new, P_new.T)
        assert nis == pytest.approx(nis_ref, rel=1e-12)


def test_mag_residual_goes_the_short_way_across_pi():
    p = Ekf7EstimatorConfig()
    x, P = ekf.initial_state(p), ekf.initial_covariance(p)  # P66 = 0.0025, R = 0.01
    x[6] = -3.1
    x_new, _, nis = ekf.mag_update(x, P, 3.1, ekf.mag_noise(p))
    nu = 6.2 - 2 * math.pi  # -0.0832: go down through -pi
    assert x_new[6] == pytest.approx(-3.1 + 0.2 * nu, abs=1e-12)
    assert nis == pytest.approx(nu * nu / 0.0125, rel=1e-12)
    # A confident magnetometer pulls the estimate across -pi; the result is wrapped.
    P[6, 6] = 1.0
    x_new, P_new, _ = ekf.mag_update(x, P, 3.1, np.array([[1e-6]]))
    assert x_new[6] == pytest.approx(3.1, abs=1e-5)
    assert P_new[6, 6] == pytest.approx(1e-6, rel=1e-5)


def test_non_finite_measurements_are_skipped():
    p = Ekf7EstimatorConfig()
    x, P = ekf.initial_state(p), ekf.initial_covariance(p)
    for z in ([math.nan, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, math.inf]):
        x_new, P_new, nis = ekf.gps_update(x, P, z, ekf.gps_noise(p))
        assert x_new is x and P_new is P and math.isnan(nis)
    for yaw in (math.nan, -math.inf):
        x_new, P_new, nis = ekf.mag_update(x, P, yaw, ekf.mag_noise(p))
        assert x_new is x and P_new is P and math.isnan(nis)


FALSE_FAIL = 0.001
"""Probability that a statistical test below fails on a consistent filter, whatever its seed."""


def run_nees(params_truth, params_filter, seed, runs=200, steps=1000, check_every=25):
    """(runs, steps // check_every) NEES of a seeded Monte Carlo simulation, at every
    `check_every`-th step of every run.

    The truth follows the EKF's own model with process noise Q_truth; GPS every 50 steps and
    the magnetometer every 5 steps measure it with the truth noise; the filter assumes params_filter.
    """
    rng = np.random.default_rng(seed)
    roll, pitch, f_B = 0.05, -0.03, np.array([1.0, -0.5, -GRAVITY])
    Q_std = np.sqrt(np.diag(ekf.process_noise(params_truth)))
    gps_std = np.sqrt(np.diag(ekf.gps_noise(params_truth)))
    mag_std = math.sqrt(ekf.mag_noise(params_truth)[0, 0])
    P0_std = np.sqrt(np.diag(ekf.initial_covariance(params_truth)))
    Q, R_gps = ekf.process_noise(params_filter), ekf.gps_noise(params_filter)
    R_mag = ekf.mag_noise(params_filter)
    nees = np.zeros((runs, steps // check_every))
    for run in range(runs):
        x_hat, P = ekf.initial_state(params_filter), ekf.initial_covariance(params_filter)
        x = x_hat + P0_std * rng.normal(size=7)
        for k in range(steps):
            x = ekf.predict_state(x, roll, pitch, f_B, DT) + Q_std * rng.normal(size=7)
            x_hat, P = ekf.predict(x_hat, P, roll, pitch, f_B, DT, Q)
            if k % 5 == 4:
                x_hat, P, _ = ekf.mag_update(x_hat, P, wrap_to_pi(x[6] + mag_std * rng.normal()), R_mag)
            if k % 50 == 49:
                x_hat, P, _ = ekf.gps_update(x_hat, P, x[:6] + gps_std * rng.normal(size=6), R_gps)
            if k % check_every == check_every - 1:
                e = x - x_hat
                e[6] = wrap_to_pi(e[6])
                nees[run, k // check_every] = e @ np.linalg.solve(P, e)
    return nees


@pytest.mark.parametrize("seed", [11])
def test_nees_of_a_matched_filter_lies_in_the_chi2_band(seed):
    """A matched filter's NEES is chi-square with 7 dof at every check, so the run-average of R
    runs is chi2(7 R) / R. Both tests hold at any seed but with probability FALSE_FAIL: each
    check's band is the chi-square quantiles at FALSE_FAIL / 2 shared over the checks (Bonferroni);
    the mean over runs and checks lies within the two-sided FALSE_FAIL normal quantile of 7 times
    its standard error, estimated from the spread of the runs' own means (the checks of one run
    are correlated, so their count does not shrink it: 0.56 to 0.71 at 200 runs, measured at 20 seeds).
    The old fixed band 6.6-7.4 at 40 runs failed 5 of 20 other seeds; these hold at seeds 100-119
    (issue 28)."""
    nees = run_nees(Ekf7EstimatorConfig(), Ekf7EstimatorConfig(), seed=seed)
    runs, checks = nees.shape
    tail = FALSE_FAIL / 2 / checks
    low, high = chi2.ppf(tail, 7 * runs) / runs, chi2.ppf(1 - tail, 7 * runs) / runs
    mean_nees = nees.mean(axis=0)
    assert np.all((mean_nees > low) & (mean_nees < high)), (low, high, mean_nees)
    standard_error = nees.mean(axis=1).std(ddof=1) / math.sqrt(runs)
    allowed = NormalDist().inv_cdf(1 - FALSE_FAIL / 2) * standard_error
    assert abs(nees.mean() - 7.0) < allowed, (nees.mean(), allowed)


def test_nees_of_an_overconfident_filter_leaves_the_band():
    truth = Ekf7EstimatorConfig()
    overconfident = Ekf7EstimatorConfig(
        q_pos_xy_std=0.005,
        q_pos_z_std=0.005,
        q_vel_xy_std=0.005,
        q_vel_z_std=0.01,
        q_yaw_std=0.005,
        gps_pos_xy_std=0.1,
        gps_pos_z_std=0.3,
        gps_vel_xy_std=0.01,
        gps_vel_z_std=0.03,
        mag_yaw_std=0.01,
    )
    mean_nees = run_nees(truth, overconfident, seed=12, runs=10).mean(axis=0)
    assert mean_nees[-10:].min() > 20.0


# ----- tilt-aware process noise ---------------------------------------------------------------


def test_tilt_variance_is_the_complementary_filter_error_recursion():
    gyro_std, tau = 0.5, 2.0
    a = tau / (tau + DT)
    variance = 0.0
    for k in range(1, 2001):
        variance = a * a * (variance + (gyro_std * DT) ** 2)
        if k in (1, 10, 2000):
            assert ekf.tilt_variance(k * DT, gyro_std, tau, DT) == pytest.approx(variance, rel=1e-9)
    assert ekf.tilt_variance(0.0, gyro_std, tau, DT) == 0.0
    # a long tau is the plain gyro random walk, (gyro_std dt)^2 per step
    assert ekf.tilt_variance(25.0, 0.5, 1e9, DT) == pytest.approx(0.25 * DT * 25.0, rel=1e-6)


def test_tilt_variance_follows_the_simulated_filter_error():
    # The complementary filter's own update, level and still, fed gyro noise only: the spread of
    # its roll over 400 seeded runs matches the predicted variance (chi-square 99.9 % band).
    from quad_drake.estimation.complementary import complementary_update

    rng = np.random.default_rng(3)
    runs, steps, gyro_std, tau = 400, 250, 0.5, 1.0
    rolls = np.zeros(runs)
    for j in range(runs):
        roll = pitch = yaw = 0.0
        for w in rng.normal(0.0, gyro_std, size=(steps, 3)):
            roll, pitch, yaw = complementary_update(roll, pitch, yaw, HOVER_F_B, w, DT, tau, "nonlinear")
        rolls[j] = roll
    ratio = np.mean(rolls**2) / ekf.tilt_variance(steps * DT, gyro_std, tau, DT)
    low, high = chi2.ppf([0.0005, 0.9995], runs) / runs
    assert low < ratio < high


@pytest.mark.parametrize("seed", range(5))
def test_tilt_jacobian_matches_central_differences(seed):
    rng = np.random.default_rng(seed)
    roll, pitch, yaw = rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), rng.uniform(-math.pi, math.pi)
    f_B, w_B = rng.normal([0.0, 0.0, -GRAVITY], 3.0), rng.normal(0.0, 2.0, 3)

    def outputs(r, p):
        a_N = ekf.predict_state(np.array([0, 0, 0, 0, 0, 0, yaw], dtype=float), r, p, f_B, 1.0)[3:6]
        return np.append(a_N, (w_B[1] * math.sin(r) + w_B[2] * math.cos(r)) / math.cos(p))

    h = 1e-6
    d_roll, d_pitch = ekf.tilt_jacobian(roll, pitch, yaw, *f_B, w_B[1], w_B[2])
    np.testing.assert_allclose(
        d_roll, (outputs(roll + h, pitch) - outputs(roll - h, pitch)) / (2 * h), atol=1e-7
    )
    np.testing.assert_allclose(
        d_pitch, (outputs(roll, pitch + h) - outputs(roll, pitch - h)) / (2 * h), atol=1e-7
    )


def test_tilt_process_noise_at_hover_is_g_squared_tilt_variance_on_the_horizontal_velocity():
    variance, velocity_time, yaw_time = 0.01, 0.25, 0.15
    Q = ekf.tilt_process_noise(
        (0.0, 0.0, 0.3), HOVER_F_B, (0.0, 0.0, 0.0), variance, velocity_time, yaw_time, DT
    )
    horizontal = GRAVITY**2 * variance * velocity_time * DT
    np.testing.assert_allclose(np.diag(Q), [horizontal, horizontal, 0.0, 0.0], rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(Q, Q.T, atol=0)
    assert np.linalg.eigvalsh(Q).min() > -1e-18
    # yawing while banked: roll errors leak into the integrated yaw
    Q = ekf.tilt_process_noise(
        (0.3, 0.0, 0.0), HOVER_F_B, (0.0, 0.0, 1.0), variance, velocity_time, yaw_time, DT
    )
    assert Q[3, 3] == pytest.approx(variance * DT * yaw_time * math.sin(0.3) ** 2, rel=1e-12)


def test_tilt_noise_from_params_is_off_by_default_and_adds_to_q():
    assert ekf.TiltNoise.from_params(Ekf7EstimatorConfig(), AttitudeFilterParams(), DT) is None
    params = Ekf7EstimatorConfig(tilt_gyro_std=0.5)
    tilt = ekf.TiltNoise.from_params(params, AttitudeFilterParams(tau=50.0), DT)
    assert tilt.variance(3.0) == ekf.tilt_variance(3.0, 0.5, 50.0, DT)
    Q = ekf.process_noise(params)
    total = tilt.process_noise(3.0, Q, (0.1, -0.2, 1.0), HOVER_F_B, (0.3, 0.2, 0.1))
    extra = ekf.tilt_process_noise(
        (0.1, -0.2, 1.0), HOVER_F_B, (0.3, 0.2, 0.1), tilt.variance(3.0), 0.25, 0.15, DT
    )
    np.testing.assert_allclose(total[3:7, 3:7] - Q[3:7, 3:7], extra, rtol=1e-12, atol=1e-20)
    np.testing.assert_array_equal(total[:3], Q[:3])
    assert Q[3, 3] == ekf.process_noise(params)[3, 3]  # Q itself untouched
