"""Cascade controller loops (SPEC §5): hand-computed numbers with default ControllerParams."""

import math

import numpy as np
import pytest

from quad_drake.config.schema import ControllerParams
from quad_drake.control.cascade import (
    altitude_control,
    body_rate_control,
    cascade_step,
    clamp_collective_thrust,
    collective_thrust_limits,
    lateral_position_control,
    roll_pitch_control,
    yaw_control,
)
from quad_drake.models.dynamics import thrusts_from_wrench, wrench_from_thrusts
from quad_drake.models.fidelity import REFERENCE
from quad_drake.models.rotations import (
    euler_from_quat,
    quat_from_euler,
    rotation_from_euler,
    rotation_from_quat,
    skew,
)

P = ControllerParams()
HOVER_THRUST = 0.5 * 9.81  # N, mass g
TOL = 1e-12


# ----- altitude -----------------------------------------------------------------


def test_altitude_hover_level_gives_weight():
    thrust, integral = altitude_control(-1.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0, 0.002, P)
    assert thrust == pytest.approx(4.905, abs=TOL)
    assert integral == 0.0


def test_altitude_hover_tilted_divides_by_r22():
    thrust, _ = altitude_control(-1.0, 0.0, 0.0, -1.0, 0.0, math.cos(0.3), 0.0, 0.002, P)
    assert thrust == pytest.approx(4.905 / math.cos(0.3), abs=TOL)


def test_altitude_integral_accumulates_error_before_use():
    # e = -1 - (-0.5) = -0.5; integral 0.01 - 0.5 * 0.002 = 0.009; vz_cmd = 2 * -0.5 = -1
    # a_z = 8 (-1 - 0.2) + 50 * 0.009 - 9.81 = -18.96; T = 18.96 * 0.5
    thrust, integral = altitude_control(-1.0, 0.0, 0.0, -0.5, 0.2, 1.0, 0.01, 0.002, P)
    assert integral == pytest.approx(0.009, abs=TOL)
    assert thrust == pytest.approx(9.48, abs=1e-12)


def test_altitude_feedforward_velocity_and_acceleration():
    # vz_cmd = 1; a_z = 8 (1 - 0.5) - 2 - 9.81 = -7.81; T = 3.905
    thrust, _ = altitude_control(-1.0, 1.0, -2.0, -1.0, 0.5, 1.0, 0.0, 0.002, P)
    assert thrust == pytest.approx(3.905, abs=1e-12)


def test_altitude_ascent_rate_clamp():
    # e = -10 -> vz_cmd -20 clamped to -5; integral -0.02
    # a_z = 8 (-5) + 50 (-0.02) - 9.81 = -50.81; T = 25.405
    thrust, integral = altitude_control(-10.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.002, P)
    assert integral == pytest.approx(-0.02, abs=TOL)
    assert thrust == pytest.approx(25.405, abs=1e-12)
    # the clamp also applies to a feed-forward velocity beyond the limit
    thrust_ff, _ = altitude_control(-1.0, -7.0, 0.0, -1.0, 0.0, 1.0, 0.0, 0.002, P)
    assert thrust_ff == pytest.approx(-(8 * -5.0 - 9.81) * 0.5, abs=1e-12)


def test_altitude_descent_rate_clamp():
    # e = +10 -> vz_cmd 20 clamped to +2; dt = 0 keeps the integral at 0
    # a_z = 8 * 2 - 9.81 = 6.19; T = -3.095 (returned unclamped)
    thrust, integral = altitude_control(0.0, 0.0, 0.0, -10.0, 0.0, 1.0, 0.0, 0.0, P)
    assert integral == 0.0
    assert thrust == pytest.approx(-3.095, abs=1e-12)


# ----- collective-thrust clamp ----------------------------------------------------


def test_collective_thrust_limits_defaults():
    low, high = collective_thrust_limits(P)
    assert low == pytest.approx(2.16, abs=1e-12)
    assert high == pytest.approx(16.24, abs=1e-12)


@pytest.mark.parametrize("thrust, expected", [(-3.0, 2.16), (1.0, 2.16), (5.0, 5.0), (25.405, 16.24)])
def test_clamp_collective_thrust(thrust, expected):
    assert clamp_collective_thrust(thrust, P) == pytest.approx(expected, abs=1e-12)


# ----- lateral position ---------------------------------------------------------


def test_lateral_zero_error_returns_feedforward():
    a = lateral_position_control((1.0, 2.0), (0.5, -0.5), (0.3, -0.7), (1.0, 2.0), (0.5, -0.5), P)
    assert a == pytest.approx((0.3, -0.7), abs=TOL)


def test_lateral_pd_within_limits():
    # v_c = (0 + 2 * 0.5, 0.1 + 2 * -0.25) = (1.0, -0.4)
    # a_c = (0.3 + 8 (1.0 - 0.1), -0.2 + 8 (-0.4 - 0.2)) = (7.5, -5.0), |a_c| = 9.01 < 12
    a = lateral_position_control((0.5, -0.25), (0.0, 0.1), (0.3, -0.2), (0.0, 0.0), (0.1, 0.2), P)
    assert a == pytest.approx((7.5, -5.0), abs=1e-12)


def test_lateral_speed_limit_rescales_keeping_direction():
    # v_c = 2 (3, 4) = (6, 8), |v_c| = 10 > 5 -> (3, 4); a_c = 8 ((3, 4) - (2.5, 3.5)) = (4, 4)
    a = lateral_position_control((3.0, 4.0), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), (2.5, 3.5), P)
    assert a == pytest.approx((4.0, 4.0), abs=1e-12)


def test_lateral_accel_limit_rescales_keeping_direction():
    # a_c = 8 (0 - (-1.5, 2)) = (12, -16), |a_c| = 20 > 12 -> (7.2, -9.6)
    a = lateral_position_control((0.0, 0.0), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), (-1.5, 2.0), P)
    assert a == pytest.approx((7.2, -9.6), abs=1e-12)


# ----- roll / pitch ---------------------------------------------------------------


def test_roll_pitch_level_zero_accel_gives_zero_rates():
    assert roll_pitch_control((0.0, 0.0), HOVER_THRUST, np.eye(3), P) == (0.0, 0.0)


def test_roll_pitch_forward_accel_pitches_nose_down():
    # c = 5 / 0.5 = 10; R02 target -0.1; q = kp_bank (-0.1 - 0) = -1.2
    p, q = roll_pitch_control((1.0, 0.0), 5.0, np.eye(3), P)
    assert p == pytest.approx(0.0, abs=TOL)
    assert q == pytest.approx(-1.2, abs=1e-12)


def test_roll_pitch_right_accel_rolls_right():
    # R12 target -0.2; p = -R00 kp_bank (-0.2) = 2.4
    p, q = roll_pitch_control((0.0, 2.0), 5.0, np.eye(3), P)
    assert p == pytest.approx(2.4, abs=1e-12)
    assert q == pytest.approx(0.0, abs=TOL)


def test_roll_pitch_tilt_clamp():
    # a / c = 20 / 10 = 2 -> clamped to 0.7; q = 12 (-0.7) = -8.4; likewise -y -> roll left
    p, q = roll_pitch_control((20.0, -30.0), 5.0, np.eye(3), P)
    assert q == pytest.approx(-8.4, abs=1e-12)
    assert p == pytest.approx(-8.4, abs=1e-12)


@pytest.mark.parametrize("thrust", [5.0, -1.0])
def test_roll_pitch_drives_r02_r12_toward_targets(thrust):
    # Independent check: with body rates (p, q, 0), R_dot = R [w]x must give
    # R02_dot = kp_bank (b_x - R02), R12_dot = kp_bank (b_y - R12).
    rng = np.random.default_rng(3)
    R = rotation_from_euler(*rng.uniform(-0.4, 0.4, 2), rng.uniform(-3, 3))
    a = (0.8, -1.3)
    p, q = roll_pitch_control(a, thrust, R, P)
    R_dot = R @ skew((p, q, 0.0))
    if thrust > 0:
        bx, by = -a[0] / (thrust / P.mass), -a[1] / (thrust / P.mass)
    else:
        bx = by = 0.0
    assert R_dot[0, 2] == pytest.approx(P.kp_bank * (bx - R[0, 2]), abs=1e-12)
    assert R_dot[1, 2] == pytest.approx(P.kp_bank * (by - R[1, 2]), abs=1e-12)


# ----- yaw and body rates -----------------------------------------------------------


def test_yaw_control_plain_error():
    assert yaw_control(0.5, 0.2, P) == pytest.approx(0.9, abs=1e-12)


def test_yaw_control_wraps_the_short_way():
    # 3.1 - (-3.1) = 6.2 = 2 pi - 0.0831853: the short way is negative yaw
    assert yaw_control(3.1, -3.1, P) == pytest.approx(3.0 * (6.2 - 2.0 * math.pi), abs=1e-12)
    assert yaw_control(3.1, -3.1, P) == pytest.approx(-0.24955592, abs=1e-8)
    assert yaw_control(-3.1, 3.1, P) == pytest.approx(0.24955592, abs=1e-8)


def test_body_rate_control():
    # I kp (cmd - w): 0.0023*70*0.5, 0.0023*70*(-2), 0.0046*15*(-0.5)
    m = body_rate_control((1.0, -2.0, 0.5), (0.5, 0.0, 1.0), P)
    assert m == pytest.approx((0.0805, -0.322, -0.0345), abs=1e-12)


@pytest.mark.parametrize("unknown", [(math.nan, 0.0, 0.0), (0.0, 0.0, math.inf), (math.nan,) * 3])
def test_body_rate_control_commands_no_moment_without_a_measured_rate(unknown):
    # an IMU dropout: the estimators report the rate as NaN; no feedback, no moment
    assert body_rate_control((1.0, -2.0, 0.5), unknown, P) == (0.0, 0.0, 0.0)


def test_cascade_without_a_measured_rate_gives_the_collective_thrust_alone():
    state = hover_state()
    state[10:13] = [math.nan] * 3
    forces, _ = cascade_step(state, hover_reference(0.4), 0.0, 0.002, P)  # a yaw error, no moment
    assert forces == pytest.approx((1.22625,) * 4, abs=1e-12)


# ----- whole cascade ---------------------------------------------------------------


def hover_state(yaw=0.0):
    return [0.0, 0.0, -1.0, *quat_from_euler(0.0, 0.0, yaw).tolist(), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]


def hover_reference(yaw=0.0):
    return [0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, yaw]


@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5])
def test_cascade_hover_gives_four_equal_hover_forces(yaw):
    forces, integral = cascade_step(hover_state(yaw), hover_reference(yaw), 0.0, 0.002, P)
    assert forces == pytest.approx((1.22625,) * 4, abs=1e-12)
    assert integral == 0.0


def test_cascade_yaw_error_spins_motors_differentially():
    # r_cmd = 3 * 0.1 = 0.3; Mz = 0.0046 * 15 * 0.3 = 0.0207; dz = 0.0207 / (4 * 0.016)
    forces, _ = cascade_step(hover_state(), hover_reference(0.1), 0.0, 0.002, P)
    dz = 0.0207 / 0.064
    assert forces == pytest.approx((1.22625 - dz, 1.22625 + dz, 1.22625 + dz, 1.22625 - dz), abs=1e-12)


def test_cascade_clamps_collective_thrust():
    state = hover_state()
    state[2] = -20.0  # far above the reference: wants negative thrust
    forces, _ = cascade_step(state, hover_reference(), 0.0, 0.002, P)
    assert forces == pytest.approx((2.16 / 4,) * 4, abs=1e-12)


def test_the_altitude_integral_is_held_while_the_collective_thrust_is_clamped():
    state = hover_state()
    state[2] = -20.0  # far above the reference: the thrust clamps at its minimum
    _, integral = cascade_step(state, hover_reference(), 0.25, 0.002, P)
    assert integral == 0.25  # anti-windup
    _, integral = cascade_step(state, hover_reference(), 0.25, 0.002, P, REFERENCE)
    assert integral == pytest.approx(0.25 + 19.0 * 0.002, abs=1e-15)  # the reference winds up
    state[2] = -1.1  # within reach: integrates
    _, integral = cascade_step(state, hover_reference(), 0.0, 0.002, P)
    assert integral == pytest.approx(0.1 * 0.002, abs=1e-15)


def test_cascade_matches_composition_of_loops():
    rng = np.random.default_rng(7)
    for _ in range(20):
        q = quat_from_euler(*rng.uniform(-0.5, 0.5, 2), rng.uniform(-3, 3))
        p, v, w = rng.normal(0, 1, 3), rng.normal(0, 1, 3), rng.normal(0, 1, 3)
        ref = rng.normal(0, 1, 10)
        integral = rng.normal(0, 0.05)
        state = np.concatenate([p, q, v, w])
        # a non-unit quaternion must act like its normalised self
        scaled = state.copy()
        scaled[3:7] *= 1.7
        forces, new_integral = cascade_step(scaled.tolist(), ref.tolist(), integral, 0.002, P)

        R = rotation_from_quat(q)
        unclamped, integrated = altitude_control(
            ref[2], ref[5], ref[8], p[2], v[2], R[2, 2], integral, 0.002, P
        )
        thrust = clamp_collective_thrust(unclamped, P)
        expected_integral = integrated if thrust == unclamped else integral  # anti-windup
        a = lateral_position_control(ref[0:2], ref[3:5], ref[6:8], p[0:2], v[0:2], P)
        pq = roll_pitch_control(a, thrust, R, P)
        r = yaw_control(ref[9], euler_from_quat(q)[2], P)
        m = body_rate_control((*pq, r), w, P)
        expected = thrusts_from_wrench(thrust, *m, P.arm_length, P.kappa)
        assert new_integral == pytest.approx(expected_integral, abs=1e-14)
        assert forces == pytest.approx(expected, abs=1e-9)
        assert wrench_from_thrusts(forces, P.arm_length, P.kappa)[0] == pytest.approx(thrust, abs=1e-12)
