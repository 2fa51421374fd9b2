"""Innovation gates, reset timing and covariance repair; a 50 m GPS outlier against the gated EKF7."""

import math

import numpy as np
import pytest
from scipy.stats import binom, chi2

from quad_drake.config import EkfParams
from quad_drake.conventions import GRAVITY
from quad_drake.estimation import ekf, gating

DT = 0.002


def test_gate_threshold_matches_the_scalar_sigma_test():
    # 1 dof: nis <= g^2 is exactly |nu| <= g sqrt(S).
    for g in (1.0, 3.0, 5.0):
        assert gating.gate_threshold(1, g) == pytest.approx(g * g, rel=1e-9)
    assert gating.false_alarm_probability(5.0) == pytest.approx(5.733e-7, rel=1e-3)
    # 6 dof: same false-alarm probability as the scalar 5-sigma test.
    assert chi2.sf(gating.gate_threshold(6, 5.0), 6) == pytest.approx(
        gating.false_alarm_probability(5.0), rel=1e-6
    )
    assert gating.gate_threshold(6, 0.0) == math.inf
    assert gating.gate_accepts(1e9, math.inf)
    assert not gating.gate_accepts(math.nan, math.inf)
    assert gating.gate_ratio(12.5, 25.0) == 0.5
    with pytest.raises(ValueError):
        gating.gate_threshold(0, 5.0)


def test_rejection_clock_and_reset_timing():
    start = math.nan
    for stamp in (1.0, 1.1, 1.2):
        start = gating.rejection_start(start, False, stamp)
    assert start == 1.0
    assert not gating.reset_due(start, 1.2, 0.5)
    assert gating.reset_due(start, 1.5, 0.5)
    assert not gating.reset_due(start, 100.0, 0.0)  # timeout 0: never
    assert math.isnan(gating.rejection_start(start, True, 1.6))
    assert not gating.reset_due(math.nan, 100.0, 0.5)


def test_reset_states_sets_values_and_drops_cross_covariance():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(7, 7))
    P = A @ A.T
    x, P_new = gating.reset_states(np.arange(7.0), P, [0, 1, 2], [9.0, 8.0, 7.0], np.diag([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(x, [9, 8, 7, 3, 4, 5, 6])
    np.testing.assert_array_equal(P_new[0:3, 0:3], np.diag([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(P_new[0:3, 3:], 0.0)
    np.testing.assert_array_equal(P_new[3:, 3:], P[3:, 3:])


def test_repaired_covariance_outcomes():
    good = np.diag([1.0, 2.0])
    P, outcome = gating.repaired_covariance(good, np.eye(2))
    assert outcome == gating.COVARIANCE_OK
    np.testing.assert_array_equal(P, good)
    indefinite = np.array([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3, -1
    P, outcome = gating.repaired_covariance(indefinite, np.eye(2))
    assert outcome == gating.COVARIANCE_REPAIRED
    assert np.linalg.eigvalsh(P).min() >= -1e-12
    np.testing.assert_allclose(P, [[1.5, 1.5], [1.5, 1.5]], atol=1e-12)
    P, outcome = gating.repaired_covariance(np.array([[np.nan, 0.0], [0.0, 1.0]]), 3 * np.eye(2))
    assert outcome == gating.COVARIANCE_RESET
    np.testing.assert_array_equal(P, 3 * np.eye(2))
    assert gating.covariance_looks_healthy(good)
    assert not gating.covariance_looks_healthy(np.diag([1.0, -1.0]))
    assert not gating.covariance_looks_healthy(np.diag([1.0, math.inf]))


CONSISTENT = dict(
    q_pos_xy_std=0.0, q_pos_z_std=0.0, q_vel_xy_std=0.5 * math.sqrt(DT), q_vel_z_std=1.5 * math.sqrt(DT),
    q_yaw_std=0.0, gps_pos_xy_std=0.7, gps_pos_z_std=2.0, gps_vel_xy_std=0.1, gps_vel_z_std=0.3,
)  # fmt: skip
"""EKF7 noise equal to the synthetic truth's: accelerometer 0.5 / 1.5 m/s^2 per 2 ms sample."""
SCENARIO_11 = dict(
    q_pos_xy_std=0.05,
    q_vel_xy_std=0.35,
    q_vel_z_std=0.2,
    q_yaw_std=0.06,
    gps_pos_xy_std=0.7,
    gps_pos_z_std=2.0,
)
"""11_gps_update's EKF7 tuning (where one 50 m outlier failed 10/10 closed-loop runs)."""


def _hover_run(seed, outlier_at=None, gate_sigma=5.0, seconds=30.0, tuning=CONSISTENT):
    """Pure EKF7 at hover on synthetic data: truth at rest, noisy IMU and 10 Hz GPS.

    Returns (max position error after 2 s (m), gated GPS samples, GPS samples).
    """
    rng = np.random.default_rng(seed)
    params = EkfParams(**tuning)
    Q, R = ekf.process_noise(params), ekf.gps_noise(params)
    threshold = gating.gate_threshold(6, gate_sigma)
    x, P = ekf.initial_state(params), np.diag([0.01] * 6 + [1e-6])
    truth = np.array([0.0, 0.0, -1.0, 0.0, 0.0, 0.0])
    accel_std = np.array([0.5, 0.5, 1.5])
    gps_std = np.array([0.7, 0.7, 2.0, 0.1, 0.1, 0.3])
    worst, gated, samples = 0.0, 0, 0
    for k in range(1, int(seconds / DT) + 1):
        f_B = np.array([0.0, 0.0, -GRAVITY]) + accel_std * rng.normal(size=3)
        x, P = ekf.predict(x, P, 0.0, 0.0, f_B, DT, Q)
        if k % 50 == 0:
            z = truth + gps_std * rng.normal(size=6)
            if outlier_at is not None and k == outlier_at:
                z[0] += 50.0
            x_new, P_new, nis = ekf.gps_update(x, P, z, R)
            samples += 1
            if gating.gate_accepts(nis, threshold):
                x, P = x_new, P_new
            else:
                gated += 1
        if k * DT > 2.0:
            worst = max(worst, float(np.linalg.norm(x[0:3] - truth[0:3])))
    return worst, gated, samples


def test_gate_rejects_no_more_consistent_samples_than_its_false_alarm_rate():
    gated = samples = 0
    for seed in range(3):
        _, g, n = _hover_run(100 + seed, seconds=20.0)
        gated, samples = gated + g, samples + n
    # 99.9 % upper quantile of Binomial(samples, P_fa): 0 at 5 sigma for 600 samples.
    assert gated <= binom.ppf(0.999, samples, gating.false_alarm_probability(5.0))
    # A 2-sigma gate does reject (the test can fail): P_fa = 4.6 % per sample.
    _, g, n = _hover_run(200, gate_sigma=2.0, seconds=20.0)
    assert binom.ppf(0.001, n, 0.0455) <= g <= binom.ppf(0.999, n, 0.0455)


def test_a_single_50_m_gps_outlier_no_longer_fails_the_1_m_criterion():
    outlier = int(15.0 / DT)
    ungated, _, _ = _hover_run(7, outlier_at=outlier, gate_sigma=0.0, tuning=SCENARIO_11)
    assert ungated > 1.0  # without the gate the outlier drags the estimate metres away
    gated_worst, gated, _ = _hover_run(7, outlier_at=outlier, gate_sigma=5.0, tuning=SCENARIO_11)
    assert gated == 1
    assert gated_worst < 1.0
