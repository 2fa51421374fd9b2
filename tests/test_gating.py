"""Innovation gates, the GPS gate-and-reset policy, covariance repair; a 50 m GPS outlier on the EKF7."""

import math

import numpy as np
import pytest
from scipy.stats import binom, chi2

from quad_drake.conventions import GRAVITY
from quad_drake.estimation import ekf, gating
from quad_drake.estimation.registry import Ekf7EstimatorConfig
from quad_drake.estimation.vocabulary import DIAG, initial_diagnostics
from quad_drake.kernels import ekf7, fusion

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
    with pytest.raises(ValueError):
        gating.gate_threshold(0, 5.0)


GATES = gating.GpsGates(
    thresholds=tuple(gating.gate_threshold(len(c), 5.0) for c in gating.GPS_GROUP_COMPONENTS),
    reset_timeouts=(5.0, 1.0, 0.5),
    regain_time=1.0,
)


def fresh_books(m):
    return np.tile(gating.initial_gps_book(), (m, 1))


def test_each_gps_group_is_gated_against_its_own_marginal():
    # A 5 m/s velocity error (a graze the IMU missed) with a good position: the velocity group
    # fails, the horizontal position and the height pass (the joint 6-dof gate refused all three).
    S = np.diag([0.5, 0.5, 4.0, 0.01, 0.01, 0.09])[None]
    nu = np.array([[0.3, -0.2, 1.0, 5.0, 0.0, 0.0]])
    nis = gating.gps_group_nis(nu, S)
    np.testing.assert_allclose(nis, [[0.26, 0.25, 2500.0]], rtol=1e-12)
    assert gating.innovation_nis(nu, S)[0] > gating.gate_threshold(6, 5.0)
    accepted, reset = gating.gps_gate_decisions(nis, [0.1], fresh_books(1), GATES)
    assert accepted.tolist() == [[True, True, False]] and not reset.any()
    assert gating.component_mask(accepted).tolist() == [[True] * 3 + [False] * 3]


def test_a_rejected_group_is_reset_after_its_own_timeout_and_only_that_group():
    book = fresh_books(1)
    bad_velocity = np.array([[1.0, 1.0, 1e4]])
    for k, stamp in enumerate((0.1, 0.2, 0.3, 0.4, 0.5)):
        accepted, reset = gating.gps_gate_decisions(bad_velocity, [stamp], book, GATES)
        assert accepted.tolist() == [[True, True, False]]
        assert not reset.any(), k
        assert book[0, gating.GPS_REJECTED_SINCE][2] == 0.1
    accepted, reset = gating.gps_gate_decisions(bad_velocity, [0.6], book, GATES)  # 0.5 s of rejection
    assert reset.tolist() == [[False, False, True]]
    assert np.isnan(book[0, gating.GPS_REJECTED_SINCE]).all()
    # A timeout of 0 never resets; an accepted sample ends the run.
    never = gating.GpsGates(GATES.thresholds, (0.0, 0.0, 0.0), 0.0)
    book = fresh_books(1)
    for stamp in np.arange(1, 100) * 0.1:
        _, reset = gating.gps_gate_decisions(bad_velocity, [stamp], book, never)
        assert not reset.any()
    gating.gps_gate_decisions(np.ones((1, 3)), [10.0], book, never)
    assert np.isnan(book[0, gating.GPS_REJECTED_SINCE]).all()


def test_a_sample_after_an_outage_is_fused_or_reset_never_gated():
    book = fresh_books(2)
    nis = np.array([[1.0, 1.0, 1.0], [1e4, 1.0, 1e4]])
    gating.gps_gate_decisions(np.ones((2, 3)), [5.0, 5.0], book, GATES)
    # 0.9 s later: no outage, gated as usual
    accepted, reset = gating.gps_gate_decisions(nis, [5.9, 5.9], book, GATES)
    assert accepted.tolist() == [[True] * 3, [False, True, False]] and not reset.any()
    # then 1.1 s without a sample: the rejected groups are reset at once, the others fused
    accepted, reset = gating.gps_gate_decisions(nis, [7.0, 7.0], book, GATES)
    assert accepted.tolist() == [[True] * 3, [False, True, False]]
    assert reset.tolist() == [[False] * 3, [True, False, True]]
    off = gating.GpsGates(GATES.thresholds, GATES.reset_timeouts, 0.0)
    _, reset = gating.gps_gate_decisions(nis, [20.0, 20.0], fresh_books(2), off)
    assert not reset.any()


def test_where_the_gps_is_the_height_reference_a_sample_after_a_gap_resets_the_height():
    # PX4 stops its GNSS height fusion after GPS_HEIGHT_TIMEOUT without a sample and restarts it
    # at the next with a height reset; tested once per 10 ms update, so a 1 Hz receiver's
    # 1.008 s spacing restarts nothing. Accepted or not; never where the barometer is the reference.
    no_regain = gating.GpsGates(GATES.thresholds, GATES.reset_timeouts, 0.0)
    nis = np.array([[1.0, 1.0, 1.0], [1.0, 1e4, 1.0], [1.0, 1.0, 1.0]])
    reference = np.array([True, True, False])
    book = fresh_books(3)
    assert gating.height_restarts([5.0] * 3, book, reference).tolist() == [True, True, False]  # the first
    gating.gps_gate_decisions(np.ones((3, 3)), [5.0] * 3, book, no_regain)
    for stamp in (6.0, 7.008):  # 1.0 and 1.008 s later
        restarted = gating.height_restarts([stamp] * 3, book, reference)
        accepted, reset = gating.gps_gate_decisions(np.ones((3, 3)), [stamp] * 3, book, no_regain, restarted)
        assert not restarted.any() and accepted.all() and not reset.any()
    restarted = gating.height_restarts([8.1] * 3, book, reference)  # 1.092 s later
    assert restarted.tolist() == [True, True, False]
    accepted, reset = gating.gps_gate_decisions(nis, [8.1] * 3, book, no_regain, restarted)
    assert accepted.tolist() == [[True] * 3, [True, False, True], [True] * 3]
    assert reset.tolist() == [[False, True, False], [False, True, False], [False] * 3]
    _, reset = gating.gps_gate_decisions(nis, [10.1] * 3, book, no_regain)  # None: no filter restarts
    assert not reset.any()


def test_a_consistently_over_confident_filter_widens_its_gate_and_an_outlier_never_does():
    adaptive = gating.GpsGates(GATES.thresholds, GATES.reset_timeouts, GATES.regain_time, 0.1)
    threshold = GATES.thresholds[0]
    book = fresh_books(1)
    # innovations 6 times the variance the filter claims (NIS/dof = 6), all within the gate
    for k in range(1, 40):
        gating.gps_gate_decisions(np.full((1, 3), 6.0 * np.array([2, 1, 3])), [0.1 * k], book, adaptive)
    np.testing.assert_allclose(book[0, gating.GPS_NIS_MEAN], 6.0, rtol=0.02)
    # a sample twice the fixed gate now passes; an outlier 100 times it still fails
    accepted, _ = gating.gps_gate_decisions(np.array([[2 * threshold, 1.0, 1.0]]), [4.0], book, adaptive)
    assert accepted[0, 0]
    mean = book[0, gating.GPS_NIS_MEAN].copy()
    accepted, _ = gating.gps_gate_decisions(np.array([[100 * threshold, 1.0, 1.0]]), [4.1], book, adaptive)
    assert not accepted[0, 0]
    assert book[0, gating.GPS_NIS_MEAN][0] == mean[0]  # rejected samples never move the mean
    # a consistent filter's gate stays the chi^2 gate: the mean is floored at 1
    book = fresh_books(1)
    gating.gps_gate_decisions(np.full((1, 3), 0.01), [0.1], book, adaptive)
    accepted, _ = gating.gps_gate_decisions(np.array([[1.01 * threshold, 1.0, 1.0]]), [0.2], book, adaptive)
    assert not accepted[0, 0]


def test_gates_off_accept_everything_and_never_reset():
    off = gating.GpsGates.from_params(Ekf7EstimatorConfig(), enabled=False)
    book = fresh_books(1)
    accepted, reset = gating.gps_gate_decisions(np.full((1, 3), 1e12), [30.0], book, off)
    assert accepted.all() and not reset.any()
    assert gating.GpsGates.from_params(Ekf7EstimatorConfig(gps_gate_sigma=0.0)).thresholds == (math.inf,) * 3


def test_reset_states_sets_values_and_drops_cross_covariance():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(2, 7, 7))
    P = A @ A.transpose(0, 2, 1)
    values = np.array([[9.0, 8.0, 7.0], [6.0, 5.0, 4.0]])
    x, P_new = gating.reset_states(
        np.arange(14.0).reshape(2, 7), P, [0, 1, 2], values, np.diag([1.0, 2.0, 3.0])
    )
    np.testing.assert_array_equal(x, [[9, 8, 7, 3, 4, 5, 6], [6, 5, 4, 10, 11, 12, 13]])
    for i in range(2):
        np.testing.assert_array_equal(P_new[i, 0:3, 0:3], np.diag([1.0, 2.0, 3.0]))
        np.testing.assert_array_equal(P_new[i, 0:3, 3:], 0.0)
        np.testing.assert_array_equal(P_new[i, 3:, 3:], P[i, 3:, 3:])


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
    """Pure EKF7 at hover on synthetic data, fused through the estimators' GPS policy
    (``kernels.fusion.fuse_gps``, fixed gates): truth at rest, noisy IMU and 10 Hz GPS.

    Returns (max position error after 2 s (m), GPS samples with a gated group, GPS samples).
    """
    rng = np.random.default_rng(seed)
    params = Ekf7EstimatorConfig(**tuning, gps_gate_sigma=gate_sigma, gps_gate_adaptation=0.0)
    Q, R = ekf.process_noise(params), ekf.gps_noise(params)
    gates = gating.GpsGates.from_params(params)
    x, P = ekf.initial_state(params)[None], np.diag([0.01] * 6 + [1e-6])[None]
    diagnostics, book = initial_diagnostics()[None], fusion.initial_book()[None]
    truth = np.array([0.0, 0.0, -1.0, 0.0, 0.0, 0.0])
    accel_std = np.array([0.5, 0.5, 1.5])
    gps_std = np.array([0.7, 0.7, 2.0, 0.1, 0.1, 0.3])
    worst, samples = 0.0, 0
    for k in range(1, int(seconds / DT) + 1):
        f_B = np.array([0.0, 0.0, -GRAVITY]) + accel_std * rng.normal(size=3)
        x0, P0 = ekf.predict(x[0], P[0], 0.0, 0.0, f_B, DT, Q)
        x[0], P[0] = x0, P0
        if k % 50 == 0:
            z = truth + gps_std * rng.normal(size=6)
            if outlier_at is not None and k == outlier_at:
                z[0] += 50.0
            filters = fusion.Filters(x, P, diagnostics, book, hold=None)
            fusion.fuse_gps(filters, np.r_[z, k * DT][None], slice(None), ekf7.correct_gps, R, gates)
            samples += 1
        if k * DT > 2.0:
            worst = max(worst, float(np.linalg.norm(x[0, 0:3] - truth[0:3])))
    return worst, int(diagnostics[0, DIAG["gps_gated"]]), samples


def test_gate_rejects_no_more_consistent_samples_than_its_false_alarm_rate():
    gated = samples = 0
    for seed in range(3):
        _, g, n = _hover_run(100 + seed, seconds=20.0)
        gated, samples = gated + g, samples + n
    # 99.9 % upper quantile of Binomial(samples, P_fa): 0 at 5 sigma for 600 samples.
    assert gated <= binom.ppf(0.999, samples, gating.false_alarm_probability(5.0))
    # A 2-sigma gate does reject (the test can fail): P_fa = 4.6 % per group, three groups.
    _, g, n = _hover_run(200, gate_sigma=2.0, seconds=20.0)
    p = 1.0 - (1.0 - gating.false_alarm_probability(2.0)) ** len(gating.GPS_GROUPS)
    assert binom.ppf(0.001, n, p) <= g <= binom.ppf(0.999, n, p)


def test_a_single_50_m_gps_outlier_no_longer_fails_the_1_m_criterion():
    outlier = int(15.0 / DT)
    ungated, _, _ = _hover_run(7, outlier_at=outlier, gate_sigma=0.0, tuning=SCENARIO_11)
    assert ungated > 1.0  # without the gate the outlier drags the estimate metres away
    gated_worst, gated, _ = _hover_run(7, outlier_at=outlier, gate_sigma=5.0, tuning=SCENARIO_11)
    assert gated == 1
    assert gated_worst < 1.0


def test_a_withheld_gps_height_is_neither_fused_nor_reset_to():
    # two EKF7s with the same prior and a GPS sample 3 m high: the one whose GPS height is withheld
    # (its barometer disagrees, BaroUpdate.withholds_gps_height) keeps its height through a fused
    # sample and through the 1 s height reset timeout; the other takes the height
    params = Ekf7EstimatorConfig(gps_gate_adaptation=0.0)
    R, gates = ekf.gps_noise(params), gating.GpsGates.from_params(params)
    x = np.tile(ekf.initial_state(params), (2, 1))
    P = np.tile(np.diag([0.01] * 6 + [1e-6]), (2, 1, 1))
    diagnostics, book = np.tile(initial_diagnostics(), (2, 1)), np.tile(fusion.initial_book(), (2, 1))
    withheld = np.array([True, False])
    for k in range(1, 21):  # 2 s at 10 Hz: a 0.1 m offset is fused, then a 30 m one is rejected
        offset = 0.1 if k < 5 else 30.0
        gps = np.tile(np.r_[0.0, 0.0, -1.0 - offset, 0.0, 0.0, 0.0, 0.1 * k], (2, 1))
        filters = fusion.Filters(x, P, diagnostics, book, hold=None)
        fusion.fuse_gps(filters, gps, slice(None), ekf7.correct_gps, R, gates, withheld)
    assert x[0, 2] == -1.0 and P[0, 2, 2] == 0.01  # the withheld height: untouched
    assert x[1, 2] == pytest.approx(-31.0, abs=0.1)  # the other: reset to the GPS height after 1 s
    assert diagnostics[1, DIAG["gps_resets"]] >= 1 and diagnostics[0, DIAG["gps_resets"]] == 0


def test_a_restart_moves_the_baro_bias_and_a_reset_to_a_rejected_height_does_not():
    # the EKF7 (its baro bias in the barometer's book: fuse_gps returns the steps it must follow),
    # its GPS the height reference: a 30 m GPS height step is rejected and reset to after the 1 s
    # timeout with no step returned (the barometer stays the independent check, estimation/baro.py);
    # a sample 2 m lower after a 2 s gap restarts the height, and its step is returned
    params = Ekf7EstimatorConfig(gps_gate_adaptation=0.0)
    R, gates = ekf.gps_noise(params), gating.GpsGates.from_params(params)
    x, P = ekf.initial_state(params)[None].copy(), np.diag([0.01] * 6 + [1e-6])[None].copy()
    diagnostics, book = initial_diagnostics()[None], fusion.initial_book()[None]
    steps = []
    for stamp in [0.1 * k for k in range(1, 21)] + [4.0]:  # 2 s at 10 Hz, then one after a 2 s gap
        height = -1.0 if stamp < 0.5 else -31.0 if stamp < 4.0 else -29.0
        filters = fusion.Filters(x, P, diagnostics, book, hold=None)
        prior = x[0, 2]
        step = fusion.fuse_gps(filters, np.r_[0.0, 0.0, height, 0.0, 0.0, 0.0, stamp][None], slice(None),
                               ekf7.correct_gps, R, gates, height_restart=np.array([True]))  # fmt: skip
        steps.append((stamp, prior, step[0]))
    assert diagnostics[0, DIAG["gps_resets"]] >= 1  # the rejected height was reset to
    assert all(math.isnan(step) for stamp, _, step in steps if stamp < 4.0)  # never moving the bias
    assert diagnostics[0, DIAG["gps_height_restarts"]] == 1  # the sample after the gap
    stamp, prior, step = steps[-1]
    assert prior == pytest.approx(-31.0, abs=0.1) and step == pytest.approx(-29.0 - prior, abs=1e-12)
    assert x[0, 2] == -29.0
