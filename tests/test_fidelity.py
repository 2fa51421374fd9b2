"""The pieces of ``fidelity: reference`` one by one (the whole is tests/test_golden.py)."""

import dataclasses
import math

import numpy as np
import pytest

from quad_drake.config import ConfigError, ControllerParams, ImuParams, PhysicsParams, load_scenario
from quad_drake.control.cascade import cascade_step, lateral_position_control
from quad_drake.conventions import GRAVITY, PHYSICS_PERIOD
from quad_drake.dynamics import plant_step, rigid_body_step, rigid_body_step_semi_implicit
from quad_drake.estimation import ekf
from quad_drake.estimation.complementary import accel_roll_pitch
from quad_drake.fidelity import FIDELITY_MODES, PHYSICAL, REFERENCE, Fidelity, fidelity_from_mode
from quad_drake.rotations import quat_from_euler
from quad_drake.sensor_models import imu_measurement, reference_accelerometer, specific_force
from quad_drake.trajectories import Trajectory, float32_clock, lookup_time

DT = PHYSICS_PERIOD
INERTIA = (0.0023, 0.0023, 0.0046)


def state(p=(0.0, 0.0, -1.0), rpy=(0.0, 0.0, 0.0), v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)):
    return [*p, *quat_from_euler(*rpy).tolist(), *v, *w]


def test_modes_map_to_all_off_and_all_on():
    assert FIDELITY_MODES == ("physical", "reference")
    assert fidelity_from_mode("physical") == PHYSICAL == Fidelity()
    assert fidelity_from_mode("reference") == REFERENCE
    assert all(dataclasses.astuple(REFERENCE)) and not any(dataclasses.astuple(PHYSICAL))
    with pytest.raises(ValueError, match="unknown fidelity mode 'exact'"):
        fidelity_from_mode("exact")


def test_scenario_field_defaults_to_physical_and_rejects_other_words(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("end_time: 1.0\n")
    assert load_scenario(path).fidelity == "physical"
    assert load_scenario(path, ["fidelity=reference"]).fidelity == "reference"
    with pytest.raises(ConfigError, match=r"s\.yaml: fidelity: 'ideal' is not one of physical, reference"):
        load_scenario(path, ["fidelity=ideal"])


def test_semi_implicit_step_is_the_reference_order():
    # Free fall: v = g dt, then p moves with the new velocity (RK4: p += g dt^2 / 2).
    x0 = state(v=(1.0, 0.0, 0.0))
    new, accel = rigid_body_step_semi_implicit(x0, 0.0, (0.0, 0.0, 0.0), 0.5, INERTIA, DT)
    assert accel == pytest.approx((0.0, 0.0, GRAVITY), abs=1e-15)
    assert new[9] == pytest.approx(GRAVITY * DT, abs=1e-15)
    assert new[2] == pytest.approx(-1.0 + GRAVITY * DT * DT, abs=1e-15)
    assert new[0] == pytest.approx(DT, abs=1e-15)
    rk4, _ = rigid_body_step(x0, 0.0, (0.0, 0.0, 0.0), 0.5, INERTIA, DT)
    assert rk4[2] == pytest.approx(-1.0 + 0.5 * GRAVITY * DT * DT, abs=1e-15)


def test_semi_implicit_attitude_uses_the_rate_at_the_start_of_the_step():
    # A roll moment changes w, but q advances with the old w: q + q (x) (0, w_old) dt / 2.
    w_old = 30.0
    x0 = state(w=(w_old, 0.0, 0.0))
    new, _ = rigid_body_step_semi_implicit(x0, 4.905, (0.1, 0.0, 0.0), 0.5, INERTIA, DT)
    half = 0.5 * w_old * DT
    expected = np.array([1.0, half, 0.0, 0.0]) / math.hypot(1.0, half)
    np.testing.assert_allclose(new[3:7], expected, atol=1e-15)
    assert new[10] == pytest.approx(w_old + 0.1 / INERTIA[0] * DT, abs=1e-12)


def test_plant_step_picks_the_body_step_and_rounds_to_float32():
    params = dataclasses.replace(PhysicsParams(), motor_noise=0.0)
    x0 = state(p=(3.0, -3.0, -1.0), v=(6e-5, -6e-5, 0.0), w=(0.3, -0.2, 0.1))
    commands = [1.3, 1.2, 1.25, 1.21]
    physical, euler, reference = (
        plant_step(x0, commands, commands, [0.5] * 4, params, DT, fidelity)[0]
        for fidelity in (PHYSICAL, Fidelity(semi_implicit_euler=True), REFERENCE)
    )
    assert np.max(np.abs(np.subtract(physical, euler))) > 1e-9
    np.testing.assert_allclose(reference, euler, atol=3e-7)
    assert list(reference) == np.array(reference, dtype=np.float32).astype(float).tolist()
    # The float32 position cannot take a 6e-8 m step at 3 m (half an ULP is 1.2e-7 m): the
    # stagnation that holds the binary's 08 vehicle 3.1e-5 m off its set-point.
    assert reference[0] == 3.0 and euler[0] != 3.0


def test_reference_accelerometer_reads_plus_g_level_and_minus_2g_sin_pitch_in_level_flight():
    level = quat_from_euler(0.0, 0.0, 0.3)
    assert reference_accelerometer(level, (0.0, 0.0, 0.0)) == pytest.approx([0.0, 0.0, GRAVITY])
    assert specific_force(level, (0.0, 0.0, 0.0)) == pytest.approx([0.0, 0.0, -GRAVITY])
    # SPEC §2: constant altitude at pitch 0.2 rad (a = (-g tan 0.2, 0, 0)) reads ax = -3.90.
    pitched = quat_from_euler(0.0, 0.2, 0.0)
    a = (-GRAVITY * math.tan(0.2), 0.0, 0.0)
    assert reference_accelerometer(pitched, a)[0] == pytest.approx(-3.90, abs=5e-3)
    assert specific_force(pitched, a)[0] == pytest.approx(0.0, abs=1e-12)  # along body z only
    params = ImuParams(accel_std=[0.0] * 3, gyro_std=[0.0] * 3)
    sample = imu_measurement(pitched, (0.1, 0.2, 0.3), a, [0.0] * 6, params, REFERENCE)
    assert sample == pytest.approx(list(reference_accelerometer(pitched, a)) + [0.1, 0.2, 0.3])


def test_estimators_read_the_reference_accelerometer_with_the_reference_formulas():
    roll, pitch = 0.1, -0.05
    q = quat_from_euler(roll, pitch, 0.0)
    at_rest = reference_accelerometer(q, (0.0, 0.0, 0.0))
    fy, fz = at_rest[1], at_rest[2]
    assert accel_roll_pitch(at_rest, True) == pytest.approx(
        (math.atan2(fy, fz), math.atan2(-at_rest[0], GRAVITY)), abs=1e-15
    )
    assert accel_roll_pitch(at_rest, True)[0] == pytest.approx(roll, abs=1e-12)
    # EKF: a_N = R f - g_N is zero at rest; the physical reading of it would be 2 g.
    x = [0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0]
    P, Q, G = np.eye(7), np.zeros((7, 7)), np.eye(7)
    moved, _ = ekf.predict_with_yaw(x, P, (roll, pitch, 0.0), at_rest, 0.002, Q, G, True)
    np.testing.assert_allclose(moved[3:6], 0.0, atol=1e-15)
    wrong, _ = ekf.predict_with_yaw(x, P, (roll, pitch, 0.0), at_rest, 0.002, Q, G)
    assert wrong[5] == pytest.approx(2 * GRAVITY * 0.002, rel=1e-12)


def test_lateral_limit_3d_counts_the_vertical_speed():
    params = ControllerParams()  # kp_vel_xy 8, max_horiz_accel 12
    args = ((0.6, 0.0), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0), params)
    horizontal = lateral_position_control(*args, vz=1.0)
    assert horizontal == pytest.approx((9.6, 0.0))  # 8 * 2 * 0.6 m: under 12
    ax, ay = lateral_position_control(*args, vz=1.0, fidelity=REFERENCE)
    assert ax == pytest.approx(9.6 * 12.0 / math.hypot(9.6, 8.0))  # |(9.6, 0, -8)| = 12.5 > 12
    assert ay == 0.0
    assert lateral_position_control(*args, vz=0.0, fidelity=REFERENCE) == pytest.approx(horizontal)
    x = state(v=(0.0, 0.0, 1.0))
    reference = [1.0, 0.0, -1.0, 0, 0, 0, 0, 0, 0, 0]
    assert (
        cascade_step(x, reference, 0.0, 0.002, params)[0]
        != cascade_step(x, reference, 0.0, 0.002, params, REFERENCE)[0]
    )


def test_float32_clock_and_lookup_time():
    assert float32_clock(0) == 0.0
    assert float32_clock(1) == float(np.float32(0.001))
    assert float32_clock(8000) - 8.0 == pytest.approx(-0.000397, abs=1e-6)  # SPEC §5: -0.40 ms
    assert float32_clock(10000) - 10.0 == pytest.approx(0.000411, abs=1e-6)  # +0.41 ms
    assert lookup_time(8.0, PHYSICAL) == 8.0
    assert lookup_time(8.0 + 3e-6, REFERENCE) == float32_clock(8000)
    ramp = Trajectory([0.0, 20.0], [[0.0, 0.0, 0.0], [20.0, 0.0, 0.0]])
    assert ramp.sample(lookup_time(8.0, REFERENCE))[0] == pytest.approx(8.0 - 0.000397, abs=1e-6)
