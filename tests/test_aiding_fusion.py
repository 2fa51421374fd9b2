"""Pure barometer and 3-axis magnetometer fusion maths (estimation/baro.py, estimation/mag3.py):
Jacobians against central differences, the running forms against the dense oracles, NIS
statistics, the bias filter's consistency."""

import math

import numpy as np
import pytest
from scipy.stats import chi2

from quad_drake.estimation import baro, ekf, eskf, mag3
from quad_drake.models import sensor_models
from quad_drake.models.rotations import euler_from_quat, quat_from_euler, rotation_from_quat, wrap_to_pi

M_N = sensor_models.world_field(0.5, 0.2, 1.1)


def random_spd(rng, n, scale=1.0):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + 0.1 * np.eye(n))


def random_nominal(rng):
    q = quat_from_euler(*rng.uniform(-0.5, 0.5, 2), rng.uniform(-math.pi, math.pi))
    return eskf.initial_nominal(
        rng.normal(size=3), rng.normal(size=3), q, rng.normal(0, 0.1, 3), rng.normal(0, 0.02, 3)
    )


def perturbed_quaternion(q, dtheta):
    """q of R = Exp(dtheta) R(q) (eskf.py's error convention)."""
    return np.array(eskf.quat_mul(eskf.quat_exp(dtheta), tuple(q)))


# ----- barometer ------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(5))
def test_height_correction_equals_the_dense_ekf7_update(seed):
    rng = np.random.default_rng(seed)
    x, P = rng.normal(size=7), random_spd(rng, 7)
    height, bias, bias_var, height_var = 1.3, 0.2, 0.05, 0.01
    expected_x, expected_P, expected_nis = baro.ekf7_baro_update(x, P, height, bias, height_var + bias_var)
    nu, S = baro.height_innovation(x[2], P, height, bias, height_var + bias_var)
    dx, P_new, nis = baro.height_correction(P, nu, S)
    np.testing.assert_allclose(x + dx, expected_x, atol=1e-12)
    np.testing.assert_allclose(P_new, expected_P, atol=1e-12)
    assert nis == pytest.approx(expected_nis, rel=1e-12)
    assert P_new[2, 2] < P[2, 2]  # the height variance shrinks


@pytest.mark.parametrize("n", [16, 10])
def test_bias_state_correction_injected_equals_the_eskf_oracle_and_the_jacobian(n):
    rng = np.random.default_rng(n)
    x, P = np.append(random_nominal(rng), 0.1), random_spd(rng, n, 0.01)
    height, height_var = -x[2] + 0.3, 0.01
    expected_x, expected_P, expected_nis = baro.eskf_baro_update(x, P, height, height_var)
    nu, S = baro.bias_state_innovation(x[2], x[eskf.BARO_BIAS_NOMINAL], P, height, height_var)
    dx, P_new, nis = baro.bias_state_correction(P, nu, S)
    x_new, P_new = eskf.inject(x, P_new, dx)
    np.testing.assert_allclose(x_new, expected_x, atol=1e-12)
    np.testing.assert_allclose(P_new, expected_P, atol=1e-12)
    assert nis == pytest.approx(expected_nis, rel=1e-12)
    assert x_new[eskf.BARO_BIAS_NOMINAL] != x[eskf.BARO_BIAS_NOMINAL]  # the bias is corrected too
    # H = -e_2 + e_(n-1) against central differences of h(x (+) dx) = -(p_z + dp_z) + (b + db)
    H = baro.height_jacobian(n)
    H[0, n - 1] = 1.0
    for j in range(n):
        d = np.zeros(n)
        d[j] = 1e-6
        plus = baro.predicted_height(x[2] + d[2]) + x[eskf.BARO_BIAS_NOMINAL] + d[n - 1]
        minus = baro.predicted_height(x[2] - d[2]) + x[eskf.BARO_BIAS_NOMINAL] - d[n - 1]
        assert (plus - minus) / 2e-6 == pytest.approx(H[0, j], abs=1e-9)


def test_bias_state_reset_correlates_the_new_bias_with_the_height():
    rng = np.random.default_rng(1)
    P = random_spd(rng, 10, 0.01)
    P_new = baro.bias_state_reset(P, 0.01)
    np.testing.assert_array_equal(P_new[9, :9], P[2, :9])
    np.testing.assert_array_equal(P_new[:9, 9], P[2, :9])
    assert P_new[9, 9] == pytest.approx(P[2, 2] + 0.01)
    np.testing.assert_array_equal(P_new[:9, :9], P[:9, :9])
    assert np.linalg.eigvalsh(P_new).min() > 0.0  # e_b = dp_z - n_baro: a valid covariance


def test_non_finite_baro_height_is_skipped_by_the_oracles():
    P = np.eye(7)
    x = np.zeros(7)
    assert math.isnan(baro.ekf7_baro_update(x, P, math.nan, 0.0, 0.01)[2])
    x17, P10 = np.append(eskf.initial_nominal([0, 0, -1], [0, 0, 0], [1, 0, 0, 0]), 0.0), np.eye(10)
    assert math.isnan(baro.eskf_baro_update(x17, P10, math.nan, 0.01)[2])


def test_baro_nis_is_chi2_one_dof_when_consistent():
    rng = np.random.default_rng(3)
    n, runs, height_var, bias_var = 9, 4000, 0.01, 0.004
    P = random_spd(rng, n, 0.05)
    L = np.linalg.cholesky(P)
    nis = np.empty(runs)
    for k in range(runs):
        error = L @ rng.normal(size=n)  # truth = estimate + error
        p_z_true = -1.0 + error[2]
        bias_true = 0.3 + math.sqrt(bias_var) * rng.normal()
        height = -p_z_true + bias_true + math.sqrt(height_var) * rng.normal()
        nu, S = baro.height_innovation(-1.0, P, height, 0.3, height_var + bias_var)
        nis[k] = baro.height_correction(P, nu, S)[2]
    # mean of chi^2(1) over `runs` samples: 1 +- 4 sqrt(2 / runs)
    assert abs(nis.mean() - 1.0) < 4 * math.sqrt(2.0 / runs)
    assert np.mean(nis > chi2.ppf(0.95, 1)) == pytest.approx(0.05, abs=0.015)


def test_bias_filter_learns_a_constant_bias_from_gps_and_is_consistent():
    params = baro.BaroFusionParams(height_std=0.1, bias_init_std=1.0, bias_walk_std=0.0)
    errors, variances = [], []
    for seed in range(200):
        rng = np.random.default_rng(seed)
        true_bias = rng.normal(0.0, 1.0)  # drawn from the filter's prior
        book = baro.initial_book(params)
        b, var = book[baro.BIAS], book[baro.BIAS_VAR]
        for _ in range(50):  # 5 s of 10 Hz GPS
            z_true = -1.0 + 0.1 * rng.normal()
            height = -z_true + true_bias + 0.1 * rng.normal()
            gps_z = z_true + 2.0 * rng.normal()
            var = baro.bias_predict(var, 0.1, params.bias_walk_std)
            b, var = baro.bias_update(b, var, baro.bias_from_gps(height, gps_z), 0.1**2 + 2.0**2)
        errors.append(b - true_bias)
        variances.append(var)
    errors, variances = np.array(errors), np.array(variances)
    # NEES of the scalar bias: chi^2(1) mean over 200 runs within 4 standard errors
    nees = errors**2 / variances
    assert abs(nees.mean() - 1.0) < 4 * math.sqrt(2.0 / 200)
    assert math.sqrt(variances.mean()) < 0.3  # 50 GPS heights of 2 m: 2 / sqrt(50) = 0.28 m


def test_height_variance_is_floored_at_the_bias_variance():
    assert baro.floored_height_variance(0.001, 0.01) == 0.01
    assert baro.floored_height_variance(0.04, 0.01) == 0.04


def test_bias_reset_takes_the_filter_height():
    b, var = baro.bias_reset(height=3.5, p_z=-1.0, height_var=0.01, p_z_var=0.04)
    assert b == pytest.approx(2.5)
    assert var == pytest.approx(0.05)
    assert baro.bias_predict(0.01, 2.0, 0.1) == pytest.approx(0.03)


# ----- 3-axis magnetometer: the ESKF's field --------------------------------------------------


@pytest.mark.parametrize("seed", range(5))
def test_field_jacobian_matches_central_differences_of_the_error_state(seed):
    rng = np.random.default_rng(seed)
    q = random_nominal(rng)[6:10]
    J = mag3.field_attitude_jacobian(*q, *M_N)
    step = 1e-6
    for j in range(3):
        d = np.zeros(3)
        d[j] = step
        plus = np.array(mag3.predicted_field(*perturbed_quaternion(q, d), *M_N))
        minus = np.array(mag3.predicted_field(*perturbed_quaternion(q, -d), *M_N))
        np.testing.assert_allclose((plus - minus) / (2 * step), J[:, j], atol=1e-8)
    # h(x) = R^T m_N
    np.testing.assert_allclose(mag3.predicted_field(*q, *M_N), rotation_from_quat(q).T @ M_N, atol=1e-15)
    # the sensor model's noise-free field is the filter's h(x)
    np.testing.assert_allclose(
        sensor_models.magnetometer_field(q, M_N, (0, 0, 0), (0, 0, 0), (0, 0, 0)),
        mag3.predicted_field(*q, *M_N),
        atol=1e-15,
    )


@pytest.mark.parametrize("attitude_only", [True, False])
@pytest.mark.parametrize("n", [15, 9])
def test_sequential_field_update_equals_the_batch_oracle(n, attitude_only):
    rng = np.random.default_rng(10 + n)
    x, P = random_nominal(rng), random_spd(rng, n, 0.01)
    field_var = np.array([2e-5, 3e-5, 1e-5])
    hard_iron = np.array([0.02, -0.01, 0.03])
    m_B = np.array(mag3.predicted_field(*x[6:10], *M_N)) + hard_iron + rng.normal(0, 0.01, 3)
    expected_x, expected_P, expected_nis = mag3.eskf_field_update(
        x, P, m_B, M_N, hard_iron, field_var, attitude_only
    )
    nu, H, S, nis = mag3.field_innovation(x[6:10], P, m_B, M_N, hard_iron, field_var)
    dx, P_new = mag3.sequential_field_update(P, nu, H, field_var, attitude_only)
    if attitude_only:  # the field corrects the attitude alone
        assert not dx[:6].any() and not dx[9:].any() and dx[6:9].any()
    x_new, P_new = eskf.inject(x, P_new, dx)
    np.testing.assert_allclose(x_new, expected_x, atol=1e-12)
    np.testing.assert_allclose(P_new, expected_P, atol=1e-12)
    assert nis == pytest.approx(expected_nis, rel=1e-10)
    np.testing.assert_allclose(S, H @ P @ H.T + np.diag(field_var), atol=1e-15)


def test_inverse3_and_a_singular_innovation_covariance():
    rng = np.random.default_rng(4)
    S = random_spd(rng, 3)
    inv, det = mag3.inverse3(S)
    np.testing.assert_allclose(inv, np.linalg.inv(S), rtol=1e-12)
    assert det == pytest.approx(np.linalg.det(S), rel=1e-12)
    _, det = mag3.inverse3(np.zeros((3, 3)))
    assert det == 0.0
    P = np.zeros((9, 9))
    q = np.array([1.0, 0, 0, 0])
    assert math.isnan(mag3.field_innovation(q, P, (0.2, 0, 0.4), M_N, (0, 0, 0), (0.0, 0.0, 0.0))[3])


def test_field_nis_is_chi2_three_dof_when_consistent():
    rng = np.random.default_rng(5)
    runs = 3000
    field_var = np.array([0.005, 0.005, 0.005]) ** 2
    x = random_nominal(rng)
    P = np.diag(np.r_[np.full(6, 0.01), np.full(3, 0.02**2), np.full(6, 1e-4)])
    nis = np.empty(runs)
    for k in range(runs):
        dtheta = rng.normal(0.0, 0.02, 3)
        q_true = perturbed_quaternion(x[6:10], dtheta)
        m_B = sensor_models.magnetometer_field(
            q_true, M_N, (0.0, 0.0, 0.0), rng.normal(size=3), np.sqrt(field_var)
        )
        nis[k] = mag3.field_innovation(x[6:10], P, m_B, M_N, (0.0, 0.0, 0.0), field_var)[3]
    assert abs(nis.mean() - 3.0) < 4 * math.sqrt(6.0 / runs) + 0.05  # + linearisation at 0.02 rad
    assert np.mean(nis > chi2.ppf(0.99, 3)) < 0.02


# ----- 3-axis magnetometer: the EKF7's heading -------------------------------------------------


@pytest.mark.parametrize("seed", range(10))
def test_tilt_compensated_heading_of_a_noise_free_field_is_the_yaw(seed):
    rng = np.random.default_rng(seed)
    roll, pitch, yaw = rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-math.pi, math.pi)
    declination = rng.uniform(-0.5, 0.5)
    m_N = sensor_models.world_field(0.5, declination, rng.uniform(-1.3, 1.3))
    q = quat_from_euler(roll, pitch, yaw)
    m_B = sensor_models.magnetometer_field(q, m_N, (0, 0, 0), (0, 0, 0), (0, 0, 0))
    heading = mag3.tilt_compensated_heading(roll, pitch, *m_B, declination)
    assert wrap_to_pi(heading - yaw) == pytest.approx(0.0, abs=1e-12)
    assert -math.pi <= heading < math.pi
    lx, ly, lz = mag3.leveled_field(roll, pitch, *m_B)
    np.testing.assert_allclose(
        (lx, ly, lz), rotation_from_quat(quat_from_euler(0.0, 0.0, yaw)).T @ m_N, atol=1e-14
    )
    assert euler_from_quat(q)[2] == pytest.approx(yaw)


@pytest.mark.parametrize("seed", range(5))
def test_heading_jacobians_match_central_differences(seed):
    rng = np.random.default_rng(seed)
    roll, pitch = rng.uniform(-0.6, 0.6, 2)
    m_B = rng.normal(0.0, 0.3, 3) + np.array([0.3, 0.0, 0.3])
    d_field, d_tilt = mag3.heading_jacobians(roll, pitch, *m_B)
    step = 1e-7

    def heading(r, p, m):
        return mag3.tilt_compensated_heading(r, p, *m, 0.0)

    for j in range(3):
        d = np.zeros(3)
        d[j] = step
        numeric = wrap_to_pi(heading(roll, pitch, m_B + d) - heading(roll, pitch, m_B - d)) / (2 * step)
        assert numeric == pytest.approx(d_field[j], abs=1e-6)
    numeric_roll = wrap_to_pi(heading(roll + step, pitch, m_B) - heading(roll - step, pitch, m_B)) / (
        2 * step
    )
    numeric_pitch = wrap_to_pi(heading(roll, pitch + step, m_B) - heading(roll, pitch - step, m_B)) / (
        2 * step
    )
    assert numeric_roll == pytest.approx(d_tilt[0], abs=1e-6)
    assert numeric_pitch == pytest.approx(d_tilt[1], abs=1e-6)


def test_heading_variance_matches_the_spread_of_noisy_headings():
    rng = np.random.default_rng(8)
    roll, pitch, yaw = 0.2, -0.3, 1.0
    field_std = np.array([0.005, 0.008, 0.004])
    q = quat_from_euler(roll, pitch, yaw)
    headings = np.array(
        [
            mag3.tilt_compensated_heading(
                roll,
                pitch,
                *sensor_models.magnetometer_field(q, M_N, (0, 0, 0), rng.normal(size=3), field_std),
                0.2,
            )
            for _ in range(4000)
        ]
    )
    variance = mag3.heading_variance(roll, pitch, *mag3.predicted_field(*q, *M_N), field_std**2, 0.0)
    sample = np.var(wrap_to_pi(headings - yaw))
    assert sample == pytest.approx(variance, rel=4 * math.sqrt(2 / 4000) + 0.02)
    # the horizontal field is cos(1.1) * 0.5 = 0.23 gauss: about 0.005 / 0.23 = 0.02 rad
    assert 0.01 < math.sqrt(variance) < 0.05
    assert mag3.heading_variance(roll, pitch, *mag3.predicted_field(*q, *M_N), field_std**2, 1e-4) > variance


def test_ekf7_fuses_the_heading_as_its_yaw():
    # the EKF7's yaw update with the heading and its variance: a non-trivial check that the
    # heading is on the EKF7's yaw scale (rad, NED, wrapped)
    rng = np.random.default_rng(9)
    x, P = rng.normal(size=7), random_spd(rng, 7, 0.01)
    roll, pitch = 0.1, -0.05
    q = quat_from_euler(roll, pitch, x[6] + 0.05)
    m_B = sensor_models.magnetometer_field(q, M_N, (0, 0, 0), (0, 0, 0), (0, 0, 0))
    heading = mag3.tilt_compensated_heading(roll, pitch, *m_B, 0.2)
    var = mag3.heading_variance(roll, pitch, *m_B, (2.5e-5,) * 3, 0.0)
    x_new, _, nis = ekf.mag_update(x, P, heading, np.array([[var]]))
    assert wrap_to_pi(x_new[6] - x[6]) > 0.0  # pulled towards yaw + 0.05
    assert nis == pytest.approx(0.05**2 / (P[6, 6] + var), rel=1e-6)


def test_heading_variance_splits_into_a_white_field_part_and_a_tilt_part_that_floors_the_yaw():
    roll, pitch = 0.1, -0.2
    m_B = mag3.predicted_field(*quat_from_euler(roll, pitch, 0.7), *M_N)
    field_part, tilt_part = mag3.heading_variances(roll, pitch, *m_B, (2.5e-5,) * 3, 0.01)
    assert field_part + tilt_part == pytest.approx(
        mag3.heading_variance(roll, pitch, *m_B, (2.5e-5,) * 3, 0.01)
    )
    assert field_part == pytest.approx(mag3.heading_variance(roll, pitch, *m_B, (2.5e-5,) * 3, 0.0))
    # near level the heading moves by about tan(inclination) per radian of roll: |J_tilt|^2 ~ tan(I)^2
    assert tilt_part / 0.01 == pytest.approx(math.tan(1.1) ** 2, rel=0.3)
    assert mag3.floored_yaw_variance(1e-4, tilt_part) == tilt_part
    assert mag3.floored_yaw_variance(1.0, tilt_part) == 1.0
