"""Pure plant physics: motors, mixer, rigid body, integrator, room limits (no Drake)."""

import dataclasses
import math

import numpy as np
import pytest

from quad_drake.config.schema import PhysicsParams
from quad_drake.conventions import GRAVITY, PHYSICS_PERIOD
from quad_drake.models.dynamics import (
    apply_room_constraints,
    clamped_noisy_commands,
    count_contacts,
    motor_lag_step,
    plant_step,
    rigid_body_derivatives,
    rigid_body_step,
    thrusts_from_wrench,
    wrench_from_thrusts,
)
from quad_drake.models.rotations import quat_from_euler, rotation_from_quat, skew

DT = PHYSICS_PERIOD
PARAMS = PhysicsParams()
HOVER = PARAMS.mass * GRAVITY / 4.0
NO_NOISE = [0.5] * 4  # u = 0.5 maps to zero force noise


def make_state(p=(0.0, 0.0, -1.0), ypr=(0.0, 0.0, 0.0), v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)):
    q = quat_from_euler(ypr[2], ypr[1], ypr[0])
    return [*map(float, p), *q.tolist(), *map(float, v), *map(float, w)]


def rk4_reference(state, thrust, moment, mass, inertia, dt, steps):
    """Generic numpy RK4 on rigid_body_derivatives, renormalising q each step."""
    x = np.array(state, dtype=float)

    def f(y):
        return np.array(rigid_body_derivatives(y, thrust, moment, mass, inertia))

    for _ in range(steps):
        k1 = f(x)
        k2 = f(x + 0.5 * dt * k1)
        k3 = f(x + 0.5 * dt * k2)
        k4 = f(x + dt * k3)
        x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        x[3:7] /= np.linalg.norm(x[3:7])
    return x


# ----- motors -----------------------------------------------------------------


def test_commands_are_clamped_then_noised():
    out = clamped_noisy_commands([-1.0, 1.0, 6.0, 2.0], [1.0, 1.0, 1.0, 0.0], 0.1, 4.5, 0.25)
    np.testing.assert_allclose(out, [0.35, 1.25, 4.75, 1.75], atol=1e-15)
    np.testing.assert_allclose(clamped_noisy_commands([1.0] * 4, NO_NOISE, 0.1, 4.5, 0.25), [1.0] * 4)


def test_motor_lag_rising_reaches_63_percent_near_tau_up():
    tau_up, tau_down = 0.01, 0.02
    forces = [0.0] * 4
    history = []
    for _ in range(40):
        forces = motor_lag_step(forces, [1.0] * 4, DT, tau_up, tau_down)
        history.append(forces[0])
    # backward Euler: F_n = 1 - (tau/(tau+dt))^n
    np.testing.assert_allclose(history, [1 - (tau_up / (tau_up + DT)) ** n for n in range(1, 41)], rtol=1e-12)
    first = next(n for n, f in enumerate(history, start=1) if f >= 1 - math.exp(-1))
    assert first == 11  # 63.2 % after 11 ms, tau_up = 10 ms
    assert history[9] == pytest.approx(1 - (1 / 1.1) ** 10, abs=1e-12)


def test_motor_lag_falling_uses_tau_down_per_motor():
    tau_up, tau_down = 0.01, 0.02
    forces = [1.0, 0.0, 1.0, 0.0]
    cmd = [0.0, 1.0, 0.0, 1.0]
    out = motor_lag_step(forces, cmd, DT, tau_up, tau_down)
    np.testing.assert_allclose(out, [tau_down / (tau_down + DT), DT / (tau_up + DT)] * 2, rtol=1e-14)
    drop = [1.0]
    while drop[-1] > math.exp(-1):
        drop.append(motor_lag_step([drop[-1]] * 4, [0.0] * 4, DT, tau_up, tau_down)[0])
    assert len(drop) - 1 == 21  # 63.2 % of the fall after 21 ms, tau_down = 20 ms


# ----- mixer ------------------------------------------------------------------


def test_single_motor_moments_follow_the_x_layout():
    arm = PARAMS.arm_length / math.sqrt(2)
    k = PARAMS.kappa
    expected = {  # motor: (Mx, My, Mz) per newton
        0: (arm, arm, -k),  # front-left: rolls right, pitches up, yaws left
        1: (-arm, arm, k),  # front-right
        2: (arm, -arm, k),  # rear-left
        3: (-arm, -arm, -k),  # rear-right
    }
    for i, moments in expected.items():
        forces = [0.0] * 4
        forces[i] = 2.0
        t, mx, my, mz = wrench_from_thrusts(forces, PARAMS.arm_length, k)
        assert t == 2.0
        np.testing.assert_allclose((mx, my, mz), 2.0 * np.array(moments), rtol=1e-14)


def test_mixer_round_trip_is_identity():
    rng = np.random.default_rng(7)
    for _ in range(50):
        forces = rng.uniform(0.1, 4.5, 4)
        wrench = wrench_from_thrusts(forces, PARAMS.arm_length, PARAMS.kappa)
        np.testing.assert_allclose(
            thrusts_from_wrench(*wrench, PARAMS.arm_length, PARAMS.kappa), forces, rtol=1e-12, atol=1e-12
        )
        wrench = (rng.uniform(0, 18), *rng.uniform(-0.5, 0.5, 2), rng.uniform(-0.1, 0.1))
        back = wrench_from_thrusts(
            thrusts_from_wrench(*wrench, PARAMS.arm_length, PARAMS.kappa), PARAMS.arm_length, PARAMS.kappa
        )
        np.testing.assert_allclose(back, wrench, rtol=1e-12, atol=1e-12)


def test_com_offset_adds_moments_proportional_to_thrust():
    forces = [HOVER] * 4
    t, mx, my, mz = wrench_from_thrusts(forces, PARAMS.arm_length, PARAMS.kappa, (0.0, -0.05))
    assert (t, my, mz) == (pytest.approx(4 * HOVER), pytest.approx(0.0), pytest.approx(0.0))
    assert mx == pytest.approx(-0.05 * 4 * HOVER, rel=1e-14)
    _, mx, my, _ = wrench_from_thrusts(forces, PARAMS.arm_length, PARAMS.kappa, (0.03, 0.0))
    assert mx == pytest.approx(0.0, abs=1e-15)
    assert my == pytest.approx(-0.03 * 4 * HOVER, rel=1e-14)
    # through the full step: equal forces with cy = -0.05 give w_dot_x = cy T / Ixx
    params = dataclasses.replace(PARAMS, com_offset=[0.0, -0.05])
    new, _, _, _ = plant_step(make_state(), [HOVER] * 4, [HOVER] * 4, NO_NOISE, params, DT)
    assert new[10] / DT == pytest.approx(-0.05 * 4 * HOVER / PARAMS.inertia[0], rel=1e-9)


# ----- rigid body -------------------------------------------------------------


def test_torque_gives_inverse_inertia_times_moment():
    inertia = [0.0023, 0.0031, 0.0046]
    moment = (0.01, -0.02, 0.005)
    d = rigid_body_derivatives(make_state(ypr=(0.4, 0.2, -0.3)), 4.0, moment, 0.5, inertia)
    np.testing.assert_allclose(d[10:13], np.array(moment) / inertia, rtol=1e-14)
    rng = np.random.default_rng(3)
    for _ in range(10):
        w = rng.uniform(-5, 5, 3)
        d = rigid_body_derivatives(make_state(w=w), 4.0, moment, 0.5, inertia)
        iw = np.array(inertia) * w
        np.testing.assert_allclose(d[10:13], (np.array(moment) - np.cross(w, iw)) / inertia, rtol=1e-12)


def test_derivatives_translation_and_quaternion_kinematics():
    rng = np.random.default_rng(11)
    for _ in range(10):
        ypr = rng.uniform(-1.5, 1.5, 3)
        w = rng.uniform(-4, 4, 3)
        x = make_state(p=rng.uniform(-5, 5, 3), ypr=ypr, v=rng.uniform(-3, 3, 3), w=w)
        d = np.array(rigid_body_derivatives(x, 7.0, (0.0, 0.0, 0.0), 0.5, PARAMS.inertia))
        q = np.array(x[3:7])
        r = rotation_from_quat(q)
        np.testing.assert_allclose(d[0:3], x[7:10], rtol=0, atol=0)
        np.testing.assert_allclose(d[7:10], r @ [0, 0, -7.0 / 0.5] + [0, 0, GRAVITY], atol=1e-12)
        # R_dot = R [w]x for a body-frame rate
        eps = 1e-7
        r_dot = (rotation_from_quat(q + eps * d[3:7]) - rotation_from_quat(q - eps * d[3:7])) / (2 * eps)
        np.testing.assert_allclose(r_dot, r @ skew(w), atol=1e-7)


def test_hover_equilibrium_holds_still_for_two_seconds():
    x0 = make_state(p=(1.0, -2.0, -3.0), ypr=(0.7, 0.0, 0.0))
    x, forces = x0, [HOVER] * 4
    for _ in range(2000):
        x, accel, forces, _ = plant_step(x, forces, [HOVER] * 4, NO_NOISE, PARAMS, DT)
    np.testing.assert_allclose(x, x0, atol=1e-12)
    np.testing.assert_allclose(accel, 0.0, atol=1e-9)
    np.testing.assert_allclose(forces, HOVER, rtol=1e-15)


def test_free_fall_at_min_thrust_matches_closed_form():
    x0 = make_state(p=(0.0, 0.0, -30.0), v=(0.5, -0.25, 0.0))
    x, forces = x0, [PARAMS.min_motor_thrust] * 4
    accel_z = GRAVITY - 4 * PARAMS.min_motor_thrust / PARAMS.mass
    for _ in range(2000):
        x, accel, forces, _ = plant_step(x, forces, [0.0] * 4, NO_NOISE, PARAMS, DT)
    t = 2.0
    np.testing.assert_allclose(x[0:3], [0.5 * t, -0.25 * t, -30.0 + 0.5 * accel_z * t * t], atol=1e-9)
    np.testing.assert_allclose(x[7:10], [0.5, -0.25, accel_z * t], atol=1e-9)
    np.testing.assert_allclose(accel, [0.0, 0.0, accel_z], atol=1e-6)
    assert accel_z == pytest.approx(9.01)


def test_step_acceleration_is_mean_velocity_change():
    x = make_state(ypr=(0.3, 0.4, -0.2), v=(1.0, 2.0, -1.0), w=(3.0, -2.0, 1.0))
    new, accel = rigid_body_step(x, 6.0, (0.02, -0.01, 0.005), 0.5, PARAMS.inertia, DT)
    np.testing.assert_allclose(accel, (np.array(new[7:10]) - x[7:10]) / DT, rtol=1e-9)
    start = np.array(rigid_body_derivatives(x, 6.0, (0.02, -0.01, 0.005), 0.5, PARAMS.inertia))[7:10]
    np.testing.assert_allclose(accel, start, atol=0.05)  # attitude moves little in 1 ms
    assert not np.allclose(accel, start, atol=1e-6)


def test_integrator_accuracy_over_two_seconds_against_fine_rk4():
    x0 = make_state(p=(0.0, 0.0, -20.0), ypr=(0.2, 0.1, -0.1), v=(1.0, -0.5, 0.2), w=(2.0, -1.0, 0.5))
    thrust, moment = 6.0, (0.004, -0.003, 0.002)
    x = x0
    for _ in range(2000):
        x, _ = rigid_body_step(x, thrust, moment, PARAMS.mass, PARAMS.inertia, DT)
    ref = rk4_reference(x0, thrust, moment, PARAMS.mass, PARAMS.inertia, DT / 20, 40000)
    assert np.linalg.norm(ref[10:13]) > 3.0  # really tumbling
    assert np.linalg.norm(np.array(x[0:3]) - ref[0:3]) < 1e-9  # explicit Euler: 2 cm
    assert np.linalg.norm(np.array(x[7:10]) - ref[7:10]) < 1e-9
    assert np.linalg.norm(np.array(x[3:7]) - ref[3:7]) < 1e-10
    assert np.linalg.norm(np.array(x[10:13]) - ref[10:13]) < 1e-10


def test_quaternion_norm_and_momentum_over_60_s_of_torque_free_tumbling():
    inertia = [0.0023, 0.0031, 0.0046]  # asymmetric: a genuinely tumbling body
    x = make_state(ypr=(0.5, -0.3, 0.2), w=(1.0, 6.0, 0.3))  # near the unstable middle axis

    def momentum(s):
        return rotation_from_quat(s[3:7]) @ (np.array(inertia) * s[10:13])

    h0 = momentum(x)
    worst = 0.0
    for _ in range(60000):
        x, _ = rigid_body_step(x, 0.0, (0.0, 0.0, 0.0), PARAMS.mass, inertia, DT)
        worst = max(worst, abs(math.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2 + x[6] ** 2) - 1.0))
    assert worst < 1e-9
    np.testing.assert_allclose(momentum(x), h0, rtol=0, atol=1e-9 * np.linalg.norm(h0))
    assert abs(x[10]) > 1.0 or abs(x[12]) > 1.0  # the rate did move between axes


# ----- room -------------------------------------------------------------------


def test_sticky_floor_stops_a_falling_vehicle():
    old = make_state(p=(1.0, 2.0, -0.001), ypr=(0.3, 0.1, 0.0), v=(1.0, 1.0, 3.0), w=(1.0, 2.0, 3.0))
    new, accel, _, _ = plant_step(old, [0.1] * 4, [0.1] * 4, NO_NOISE, PARAMS, DT)
    assert new[0:3] == (1.0, 2.0, 0.0)
    assert new[7:13] == tuple([0.0] * 6)
    np.testing.assert_allclose(accel, np.array([-1.0, -1.0, -3.0]) / DT)
    # resting on the floor at low thrust: no motion, zero kinematic acceleration
    x = new
    for _ in range(100):
        x, accel, _, _ = plant_step(x, [0.1] * 4, [0.1] * 4, NO_NOISE, PARAMS, DT)
    assert x[0:3] == (1.0, 2.0, 0.0)
    assert accel == (0.0, 0.0, 0.0)


def test_floor_keeps_upward_velocity_and_allows_take_off():
    on_floor = make_state(p=(0.0, 0.0, 0.0))
    constrained = apply_room_constraints(
        make_state(p=(0.5, 0.5, 0.01), v=(1, 1, -2), w=(1, 1, 1)), on_floor, PARAMS
    )
    assert constrained[0:3] == (0.0, 0.0, 0.0)
    assert constrained[7:13] == (0.0, 0.0, -2.0, 0.0, 0.0, 0.0)
    x, forces = on_floor, [3.0] * 4
    for _ in range(100):
        x, _, forces, _ = plant_step(x, forces, [3.0] * 4, NO_NOISE, PARAMS, DT)
    assert x[2] < -0.05 and x[9] < -1.0


def test_room_bounds_revert_only_the_offending_coordinate():
    old = make_state(p=(29.9999, -29.9999, -39.9999), v=(0.5, -0.5, -0.5))
    new, accel, _, _ = plant_step(old, [HOVER] * 4, [HOVER] * 4, NO_NOISE, PARAMS, DT)
    assert new[0:3] == tuple(old[0:3])
    assert new[7:10] == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(accel, [-500.0, 500.0, 500.0])
    # x out of bounds only: y and z keep integrating
    old = make_state(p=(-29.9999, 1.0, -5.0), v=(-0.5, 0.5, 0.5))
    new, _, _, _ = plant_step(old, [HOVER] * 4, [HOVER] * 4, NO_NOISE, PARAMS, DT)
    assert (new[0], new[7]) == (old[0], 0.0)
    np.testing.assert_allclose(new[1:3], [1.0005, -4.9995], atol=1e-12)
    np.testing.assert_allclose(new[8:10], [0.5, 0.5], atol=1e-12)
    # inputs are not modified
    assert old[7] == -0.5


def test_contact_counts_follow_touchdowns_take_offs_and_wall_hits():
    floor, air = make_state(p=(0.0, 0.0, 0.0)), make_state(p=(0.0, 0.0, -1.0))
    assert count_contacts((0.0, 2.0, 5.0), floor, False, PARAMS) == (1.0, 3.0, 5.0)  # touchdown
    assert count_contacts((1.0, 3.0, 5.0), floor, False, PARAMS) == (1.0, 3.0, 5.0)  # resting
    assert count_contacts((1.0, 3.0, 5.0), air, False, PARAMS) == (0.0, 3.0, 5.0)  # take-off
    assert count_contacts((0.0, 3.0, 5.0), air, True, PARAMS) == (0.0, 3.0, 6.0)  # wall hit
    assert count_contacts((0.0, 3.0, 6.0), floor, True, PARAMS) == (1.0, 4.0, 7.0)  # both


NARROW_ROOM = dataclasses.replace(
    PARAMS,
    com_offset=[0.02, -0.03],
    motor_noise=0.4,
    x_bounds=[-1.0, 1.0],
    y_bounds=[-1.0, 1.0],
    z_bounds=[-3.0, 0.0],
)
