"""Error-state EKF: Jacobians against central differences, injection/reset, seeded consistency, PSD."""

import math

import numpy as np
import pytest
from scipy.stats import chi2

from quad_drake.conventions import GRAVITY
from quad_drake.estimation import eskf
from quad_drake.estimation.registry import EskfEstimatorConfig
from quad_drake.models.rotations import quat_from_euler, rotation_from_quat

DT = 0.002


def boxplus(x, dx):
    """Truth = nominal (+) error, as in the module docstring."""
    x = np.array(x, dtype=float)
    x[0:6] += dx[0:6]
    x[6:10] = eskf.quat_mul(eskf.quat_exp(dx[6:9]), tuple(x[6:10]))
    if dx.size == 15:
        x[10:16] += dx[9:15]
    return x


def boxminus(x_true, x_hat, n):
    """Error dx with x_true = x_hat (+) dx."""
    dx = np.zeros(n)
    dx[0:6] = x_true[0:6] - x_hat[0:6]
    dx[6:9] = eskf.rotation_log(rotation_from_quat(x_true[6:10]) @ rotation_from_quat(x_hat[6:10]).T)
    if n == 15:
        dx[9:15] = x_true[10:16] - x_hat[10:16]
    return dx


def random_nominal(rng):
    q = quat_from_euler(*rng.uniform(-0.5, 0.5, 2), rng.uniform(-math.pi, math.pi))
    return eskf.initial_nominal(
        rng.normal(size=3), rng.normal(size=3), q, rng.normal(0, 0.1, 3), rng.normal(0, 0.02, 3)
    )


@pytest.mark.parametrize("n", [15, 9])
def test_transition_matches_central_differences_of_the_nominal_model(n):
    rng = np.random.default_rng(3)
    for _ in range(5):
        x = random_nominal(rng)
        f_B = rng.normal([0.0, 0.0, -GRAVITY], 2.0)
        w_B = rng.normal(size=3)
        x_next, R, R_next, u_N = eskf.predict_nominal(x, f_B, w_B, DT)
        F = eskf.transition(R, R_next, u_N, DT, n)
        numeric = np.zeros((n, n))
        h = 1e-6
        for j in range(n):
            e = np.zeros(n)
            e[j] = h
            plus = boxminus(
                np.array(eskf.predict_nominal(boxplus(x, e), f_B, w_B, DT)[0]), np.array(x_next), n
            )
            minus = boxminus(
                np.array(eskf.predict_nominal(boxplus(x, -e), f_B, w_B, DT)[0]), np.array(x_next), n
            )
            numeric[:, j] = (plus - minus) / (2 * h)
        # First-order model: the gyro-bias block ignores the O(|w| dt^2) right Jacobian.
        np.testing.assert_allclose(F, numeric, atol=5e-6, rtol=0)


def test_reset_jacobian_and_mag_jacobian_match_central_differences():
    rng = np.random.default_rng(4)
    d_hat = rng.normal(0, 0.02, 3)
    h = 1e-6

    def new_error(d):  # Log(Exp(d) Exp(-d_hat))
        left, right = rotation_from_quat(eskf.quat_exp(d)), rotation_from_quat(eskf.quat_exp(-d_hat))
        return eskf.rotation_log(left @ right)

    numeric = np.column_stack(
        [(new_error(d_hat + h * e) - new_error(d_hat - h * e)) / (2 * h) for e in np.eye(3)]
    )
    # First order: the neglected terms are O(|d_hat|^2).
    G = eskf.reset_jacobian(d_hat, 9)[6:9, 6:9]
    np.testing.assert_allclose(G, numeric, atol=0.5 * float(d_hat @ d_hat))
    assert np.abs(G - np.eye(3)).max() > 10 * np.abs(G - numeric).max()  # the skew term matters
    for _ in range(5):
        q = random_nominal(rng)[6:10]
        yaw, H = eskf.yaw_and_jacobian(q)

        def yaw_of(d, q=q):
            return math.atan2(*(rotation_from_quat(eskf.quat_mul(eskf.quat_exp(d), tuple(q)))[[1, 0], 0]))

        numeric = [(yaw_of(h * e) - yaw_of(-h * e)) / (2 * h) for e in np.eye(3)]
        np.testing.assert_allclose(H, numeric, atol=1e-7)
        assert yaw == pytest.approx(yaw_of(np.zeros(3)), abs=1e-12)


def test_attitude_errors_invert_exp():
    rng = np.random.default_rng(5)
    q_true = np.array([random_nominal(rng)[6:10] for _ in range(6)])
    d = rng.normal(0, 0.3, (6, 3))
    q_hat = np.array([eskf.quat_mul(eskf.quat_exp(di), tuple(qi)) for di, qi in zip(d, q_true, strict=True)])
    np.testing.assert_allclose(eskf.attitude_errors(q_hat, q_true), d, atol=1e-12)
    np.testing.assert_allclose(eskf.attitude_errors(-q_hat, q_true), d, atol=1e-12)  # sign of q irrelevant


def test_injection_moves_the_nominal_and_zeroes_nothing_else():
    rng = np.random.default_rng(6)
    x = random_nominal(rng)
    dx = rng.normal(0, 0.01, 15)
    x_new, P_new = eskf.inject(x, np.eye(15), dx)
    np.testing.assert_allclose(boxminus(x_new, x, 15), dx, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(x_new[6:10]), 1.0, atol=1e-15)
    np.testing.assert_allclose(P_new, P_new.T, atol=0)


def simulate(seed, params, seconds, truth_std=None, P0_scale=1.0):
    """Pure ESKF against a synthetic truth flown with the filter's own discrete model.

    The truth turns and accelerates (sinusoidal body rates and thrust); the IMU adds white
    noise of ``truth_std`` (default: what the filter assumes); GPS at 10 Hz, mag at 100 Hz.
    Returns (per-step NEES of p, v, theta at the GPS samples, min eigenvalue of P seen).
    """
    rng = np.random.default_rng(seed)
    accel_std = np.asarray(truth_std or params.accel_std, dtype=float)
    gyro_std = np.asarray(params.gyro_std, dtype=float)
    x_true = eskf.initial_nominal([0, 0, -1.0], [0, 0, 0], [1.0, 0, 0, 0])
    x = x_true.copy()
    P = eskf.initial_covariance(params) * P0_scale
    n = P.shape[0]
    R_gps, R_mag = eskf.gps_noise(params), eskf.mag_noise(params)
    noise = eskf.NoiseModel.from_params(params)
    gps_std = np.sqrt(np.diag(R_gps))
    nees, min_eig = [], math.inf
    for k in range(int(seconds / DT)):
        t = k * DT
        w_true = np.array([0.3 * math.sin(1.1 * t), 0.3 * math.cos(0.7 * t), 0.2])
        f_true = np.array([0.5 * math.sin(0.5 * t), 0.0, -GRAVITY + math.sin(0.9 * t)])
        f_meas = f_true + accel_std * rng.normal(size=3)
        w_meas = w_true + gyro_std * rng.normal(size=3)
        x_true = np.array(eskf.predict_nominal(x_true, f_true, w_true, DT)[0])
        x, P = eskf.predict(x, P, f_meas, w_meas, DT, noise)
        if (k + 1) % 5 == 0:
            yaw_true = eskf.yaw_and_jacobian(x_true[6:10])[0]
            x, P, _ = eskf.mag_update(x, P, yaw_true + params.mag_yaw_std * rng.normal(), R_mag)
        if (k + 1) % 50 == 0:
            z = np.concatenate([x_true[0:3], x_true[3:6]]) + gps_std * rng.normal(size=6)
            x, P, _ = eskf.gps_update(x, P, z, R_gps)
            e = boxminus(x_true, x, n)[0:9]
            nees.append(float(e @ np.linalg.solve(P[0:9, 0:9], e)))
            min_eig = min(min_eig, float(np.linalg.eigvalsh(P).min()))
    return np.array(nees), min_eig


@pytest.mark.parametrize("biases", [True, False])
def test_seeded_run_is_consistent(biases):
    params = EskfEstimatorConfig(estimate_biases=biases, accel_bias_rw_std=0.0, gyro_bias_rw_std=0.0)
    nees, min_eig = simulate(11, params, 40.0)
    steady = nees[50:]  # after 5 s
    # 350 samples of a chi^2(9) variable; strongly correlated in time, so a wide +-25 % band.
    assert 0.75 * 9 < steady.mean() < 1.25 * 9
    assert np.mean(steady <= chi2.ppf(0.95, 9)) > 0.85
    assert min_eig > 0.0


def test_covariance_stays_symmetric_psd_over_a_long_adversarial_run():
    # IMU truth noise 4x what the filter assumes and a 100x initial covariance: the filter is
    # badly over-confident, the Joseph form still keeps P symmetric positive definite.
    params = EskfEstimatorConfig()
    nees, min_eig = simulate(12, params, 60.0, truth_std=[2.0, 2.0, 6.0], P0_scale=100.0)
    assert min_eig > 0.0
    assert nees.mean() > 9 * 2  # over-confident, as it should be with the wrong noise


def test_write_estimate_puts_p_q_v_in_the_state_layout_and_keeps_the_body_rate():
    x = eskf.initial_nominal((1.0, 2.0, 3.0), (4.0, 5.0, 6.0), (0.5, 0.5, 0.5, 0.5), (7.0, 7.0, 7.0))
    estimate = np.full(13, -1.0)
    eskf.write_estimate(x, estimate)
    np.testing.assert_array_equal(estimate, [1, 2, 3, 0.5, 0.5, 0.5, 0.5, 4, 5, 6, -1, -1, -1])
    rng = np.random.default_rng(3)
    batch_x, batch = rng.normal(size=(5, 16)), rng.normal(size=(5, 13))
    expected = batch.copy()
    for row_x, row in zip(batch_x, expected, strict=True):
        eskf.write_estimate(row_x, row)
    eskf.write_estimate(batch_x, batch)
    np.testing.assert_array_equal(batch, expected)  # the batched form is the scalar one row by row


def test_a_level_axis_accelerometer_bias_is_not_learned_as_px4s():
    """PX4's accelerometer-bias inhibition (``eskf.uncorrelate_unobservable_accel_bias``): on a
    level vehicle the x and y biases lose every correlation (no update can move them), z keeps
    its (the kept block unchanged); pitched 90° nose up, x is the vertical axis."""
    from quad_drake.estimation.eskf import uncorrelate_unobservable_accel_bias

    rng = np.random.default_rng(3)
    A = rng.normal(size=(2, 15, 15))
    P = A @ A.transpose(0, 2, 1) + 15 * np.eye(15)
    x = np.zeros((2, 16))
    x[0, 6] = 1.0  # level
    x[1, 6:10] = (math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0)  # pitched up 90°
    before = P.copy()
    uncorrelate_unobservable_accel_bias(x, P, math.radians(15.0))
    for i, inhibited in enumerate(((9, 10), (10, 11))):
        for k in inhibited:
            assert np.count_nonzero(P[i, k]) == 1 and P[i, k, k] == before[i, k, k]
            assert np.count_nonzero(P[i, :, k]) == 1
        others = [j for j in range(15) if j not in inhibited]
        np.testing.assert_array_equal(P[i][np.ix_(others, others)], before[i][np.ix_(others, others)])


def test_no_accelerometer_bias_is_learned_while_the_vehicle_manoeuvres_hard():
    """PX4's manoeuvre levels (``eskf.manoeuvre_levels``: on the IMU summed over PX4's 10 ms
    update, peak-held, decaying with EKF2_ABL_TAU): a 5 rad/s spin inhibits every axis of a
    vertical-axis-up vehicle once a 10 ms period is summed (not before), and 0.5 s of quiet later
    (50 periods, decayed below EKF2_ABL_GYRLIM 3 rad/s: 5 x 0.98^50 = 1.82) only the level axes
    stay inhibited."""
    from quad_drake.estimation.eskf import (
        MANOEUVRE_SIZE,
        manoeuvre_levels,
        uncorrelate_unobservable_accel_bias,
    )

    x = np.zeros((1, 16))
    x[0, 6] = 1.0
    state = np.zeros((1, MANOEUVRE_SIZE))
    spin = np.array([[0.0, 0.0, -GRAVITY, 5.0, 0.0, 0.0]])
    for _ in range(5):  # 10 ms of 2 ms ticks
        assert state[0, 0] == 0.0
        manoeuvre_levels(state, spin, 0.002)
    assert state[0, 0] == pytest.approx(5.0) and state[0, 1] == pytest.approx(GRAVITY)
    P = np.ones((1, 15, 15)) + np.eye(15)
    uncorrelate_unobservable_accel_bias(x, P, math.radians(15.0), state[:, 0:2])
    assert all(np.count_nonzero(P[0, k]) == 1 for k in (9, 10, 11))
    for _ in range(250):  # 0.5 s at rest
        manoeuvre_levels(state, np.array([[0.0, 0.0, -GRAVITY, 0.0, 0.0, 0.0]]), 0.002)
    assert state[0, 0] == pytest.approx(5.0 * (1.0 - 0.010 / 0.5) ** 50) and state[0, 0] < 3.0
    P = np.ones((1, 15, 15)) + np.eye(15)
    uncorrelate_unobservable_accel_bias(x, P, math.radians(15.0), state[:, 0:2])
    assert [np.count_nonzero(P[0, k]) == 1 for k in (9, 10, 11)] == [True, True, False]


def test_the_manoeuvre_levels_see_the_mean_of_a_period_not_each_sample():
    """PX4 sums its IMU over its 10 ms update before the levels see it: a vibration of +-3 m/s^2
    about gravity that alternates sample by sample leaves the level of |f_B| at g (within the
    0.9-1.1 g band of the gravity fusion), where the peak of single samples would be g + 3."""
    state = np.zeros((1, eskf.MANOEUVRE_SIZE))
    for tick in range(50):
        f_z = -GRAVITY + (3.0 if tick % 2 else -3.0)
        eskf.manoeuvre_levels(state, np.array([[0.0, 0.0, f_z, 0.0, 0.0, 0.0]]), 0.002)
    assert state[0, 1] < GRAVITY + 3.0 * 0.2 + 1e-9
    low, high = eskf.GRAVITY_ACCEL_BAND
    assert low < state[0, 1] < high


def test_the_gravity_vectors_jacobian_matches_central_differences():
    """``eskf.predicted_gravity``: h = R^T (0, 0, -1) and its H against the attitude error
    (R = Exp(dtheta) R_hat), by central differences at random attitudes; no yaw column."""
    rng = np.random.default_rng(11)
    for _ in range(5):
        x = random_nominal(rng)
        h, H = eskf.predicted_gravity(x[None], 15)
        np.testing.assert_allclose(h[0], rotation_from_quat(x[6:10]).T @ [0.0, 0.0, -1.0], atol=1e-14)
        step = 1e-6
        for j in range(15):
            dx = np.zeros(15)
            dx[j] = step
            up = eskf.predicted_gravity(boxplus(x, dx)[None], 15)[0][0]
            down = eskf.predicted_gravity(boxplus(x, -dx)[None], 15)[0][0]
            np.testing.assert_allclose(H[0, :, j], (up - down) / (2 * step), atol=1e-8)
        assert not H[0, :, 8].any()


def test_the_gravity_vector_pulls_the_tilt_to_the_accelerometers_and_gates_a_far_one():
    """``eskf.gravity_update`` (PX4's gravity fusion): a level estimate and the accelerometer of a
    vehicle rolled 50 mrad: the roll error moves toward +50 mrad and the yaw not (an uncorrelated
    P), the covariance shrinks; the same estimate and a reading 30° off is rejected whole (beyond
    the 0.25 sigma gate) and keeps x and P; a filter without the bias states reads f_B as it is."""
    x = np.tile(eskf.initial_nominal(np.zeros(3), np.zeros(3), [1.0, 0.0, 0.0, 0.0]), (2, 1))
    P = np.tile(np.diag([1.0] * 6 + [0.01] * 3 + [1e-4] * 6), (2, 1, 1))
    rolled = rotation_from_quat(quat_from_euler(0.05, 0.0, 0.0)).T @ [0.0, 0.0, -GRAVITY]
    far = rotation_from_quat(quat_from_euler(math.radians(30.0), 0.0, 0.0)).T @ [0.0, 0.0, -GRAVITY]
    dx, P_new, fused = eskf.gravity_update(x, P, np.stack([rolled, far]), 1.0, 1.0)
    assert fused.tolist() == [True, False]
    assert 0.0 < dx[0, 6] < 0.05 and abs(dx[0, 7]) < 1e-12 and dx[0, 8] == 0.0
    assert P_new[0, 6, 6] < P[0, 6, 6] and P_new[0, 8, 8] == P[0, 8, 8]
    assert not dx[1].any()
    np.testing.assert_array_equal(P_new[1], P[1])
    dx9, _, _ = eskf.gravity_update(x[:1], P[:1, :9, :9], rolled[None], 1.0, 1.0)
    np.testing.assert_allclose(dx9[0, 6:9], dx[0, 6:9], rtol=1e-6)
