"""Complementary attitude filter: accelerometer tilt (physical sign), gyro integration, blending, wrap."""

import math

import numpy as np
import pytest

from quad_drake.conventions import GRAVITY
from quad_drake.estimation.complementary import (
    accel_roll_pitch,
    complementary_update,
    integrate_euler_exact,
)
from quad_drake.models.rotations import (
    euler_from_quat,
    quat_from_euler,
    quat_integrate_body_rate,
    rotation_from_euler,
    wrap_to_pi,
)

DT = 0.002
NO_ACCEL = 1e15  # tau, s: the accelerometer weight dt / (tau + dt) is ~1e-18


def specific_force_at_rest(roll, pitch, yaw=0.0):
    """f_B = R_NB^T (0 - g_N) of a vehicle at rest."""
    return rotation_from_euler(roll, pitch, yaw).T @ np.array([0.0, 0.0, -GRAVITY])


def run(variant, start, w_B, steps, tau=NO_ACCEL, f_B=(0.0, 0.0, -GRAVITY)):
    roll, pitch, yaw = start
    for _ in range(steps):
        roll, pitch, yaw = complementary_update(roll, pitch, yaw, f_B, w_B, DT, tau, variant)
    return np.array([roll, pitch, yaw])


def test_accel_tilt_sign_is_physical():
    # Right wing down by 0.2 rad at rest: gravity pulls along +y_B, the accelerometer reads -y_B.
    f_B = specific_force_at_rest(0.2, 0.0)
    assert f_B[1] == pytest.approx(-GRAVITY * math.sin(0.2), abs=1e-12)
    assert accel_roll_pitch(f_B) == pytest.approx((0.2, 0.0), abs=1e-12)
    # Nose up by 0.3 rad: the accelerometer reads +x_B.
    f_B = specific_force_at_rest(0.0, 0.3)
    assert f_B[0] == pytest.approx(GRAVITY * math.sin(0.3), abs=1e-12)
    assert accel_roll_pitch(f_B) == pytest.approx((0.0, 0.3), abs=1e-12)
    assert accel_roll_pitch((0.0, 0.0, -GRAVITY)) == (0.0, 0.0)


def test_accel_tilt_is_exact_at_rest_for_any_attitude():
    rng = np.random.default_rng(1)
    for _ in range(200):
        roll, pitch, yaw = rng.uniform(-3.0, 3.0), rng.uniform(-1.5, 1.5), rng.uniform(-3.0, 3.0)
        f_B = specific_force_at_rest(roll, pitch, yaw)
        assert accel_roll_pitch(f_B) == pytest.approx((roll, pitch), abs=1e-12)


def test_exact_step_matches_rotations_quaternion_integration():
    rng = np.random.default_rng(2)
    for _ in range(100):
        roll, pitch, yaw = rng.uniform(-1.0, 1.0, 3) * (3.0, 1.4, 3.0)
        w_B = rng.normal(0.0, 3.0, 3)
        q = quat_integrate_body_rate(quat_from_euler(roll, pitch, yaw), w_B, DT)
        got = integrate_euler_exact(roll, pitch, yaw, w_B, DT)
        assert got == pytest.approx(euler_from_quat(q), abs=1e-12)
    got = integrate_euler_exact(0.1, 0.2, 0.3, (0.0, 0.0, 0.0), DT)
    assert got == pytest.approx((0.1, 0.2, 0.3), abs=1e-15)


def test_nonlinear_variant_matches_exact_integration_of_a_constant_rate():
    start, w_B, steps = (0.1, -0.2, 0.3), np.array([0.3, -0.5, 0.8]), 500
    q_exact = quat_integrate_body_rate(quat_from_euler(*start), w_B, steps * DT)
    expected = euler_from_quat(q_exact)
    got = run("nonlinear", start, w_B, steps)
    np.testing.assert_allclose(got, expected, atol=1e-10)
    assert np.abs(got - start).max() > 0.3  # it did move


def test_small_angle_variant_is_wrong_for_yaw_rate_at_a_tilt():
    # Rolled by 0.5 rad, spinning about body z at 1 rad/s for 1 s: the pitch changes at
    # -r sin(roll) ~ -0.48 rad/s, which the small-angle integration ignores.
    start, w_B, steps = (0.5, 0.0, 0.0), np.array([0.0, 0.0, 1.0]), 500
    exact = euler_from_quat(quat_integrate_body_rate(quat_from_euler(*start), w_B, steps * DT))
    nonlinear = run("nonlinear", start, w_B, steps)
    small = run("small_angle", start, w_B, steps)
    np.testing.assert_allclose(nonlinear, exact, atol=1e-10)
    np.testing.assert_allclose(small, (0.5, 0.0, 1.0), atol=1e-12)
    assert abs(small[1] - exact[1]) > 0.3
    assert exact[1] < -0.3


def test_variants_agree_for_a_single_axis_rate_from_level():
    for w_B in ([0.7, 0.0, 0.0], [0.0, -0.4, 0.0], [0.0, 0.0, 1.3]):
        np.testing.assert_allclose(
            run("nonlinear", (0.0, 0.0, 0.0), w_B, 250),
            run("small_angle", (0.0, 0.0, 0.0), w_B, 250),
            atol=1e-10,
        )


@pytest.mark.parametrize("variant", ["nonlinear", "small_angle"])
def test_accel_only_convergence_to_the_physical_tilt(variant):
    f_B = specific_force_at_rest(0.3, -0.2, 1.0)
    got = run(variant, (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), 1000, tau=0.05, f_B=f_B)
    np.testing.assert_allclose(got, (0.3, -0.2, 1.0), atol=1e-6)


@pytest.mark.parametrize("variant", ["nonlinear", "small_angle"])
def test_one_step_blend_weights(variant):
    f_B = specific_force_at_rest(0.4, 0.1)
    tau = 1.0
    roll, pitch, yaw = complementary_update(0.0, 0.0, 0.2, f_B, (0.0, 0.0, 0.0), DT, tau, variant)
    assert roll == pytest.approx(DT / (tau + DT) * 0.4, abs=1e-15)
    assert pitch == pytest.approx(DT / (tau + DT) * 0.1, abs=1e-15)
    assert yaw == pytest.approx(0.2, abs=1e-15)  # yaw is not blended


@pytest.mark.parametrize("variant", ["nonlinear", "small_angle"])
def test_yaw_wraps_across_pi(variant):
    yaw = complementary_update(
        0.0, 0.0, math.pi - 0.001, (0.0, 0.0, -GRAVITY), (0.0, 0.0, 1.0), DT, 100.0, variant
    )[2]
    assert yaw == pytest.approx(-math.pi + 0.001, abs=1e-12)
    yaw = complementary_update(
        0.0, 0.0, -math.pi + 0.001, (0.0, 0.0, -GRAVITY), (0.0, 0.0, -1.0), DT, 100.0, variant
    )[2]
    assert yaw == pytest.approx(math.pi - 0.001, abs=1e-12)
    many = run(variant, (0.0, 0.0, 0.0), (0.0, 0.0, 5.0), 2000)[2]  # 20 rad of turning
    assert -math.pi <= many < math.pi
    assert many == pytest.approx(wrap_to_pi(20.0), abs=1e-9)


def test_unknown_variant_raises():
    with pytest.raises(ValueError, match="variant"):
        complementary_update(0.0, 0.0, 0.0, (0.0, 0.0, -GRAVITY), (0.0, 0.0, 0.0), DT, 1.0, "linear")
