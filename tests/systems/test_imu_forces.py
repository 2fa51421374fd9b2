"""The IMU that feels every force: the plant's body-frame delta-velocity read by a delta-velocity
IMU (``ImuParams.delta_velocity``) on a vehicle resting on the floor, touching down at 3 m/s, in
free fall and in a steady wind; the old last-step IMU beside it where they differ."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from quad_drake.config.schema import ImuParams, PhysicsParams
from quad_drake.conventions import GRAVITY, ONBOARD_PERIOD
from quad_drake.models.rotations import quat_from_euler
from quad_drake.systems.plant import QuadrotorPlant
from quad_drake.systems.sensors import Imu

G16 = 16 * GRAVITY
QUIET = {"accel_std": [0.0] * 3, "gyro_std": [0.0] * 3}
MASS = 0.5
HOVER = MASS * GRAVITY / 4


def fly(position, velocity, thrust, imu_params, physics=None, wind=None, ticks=5, euler=(0.0, 0.0, 0.0)):
    """(delta-velocity IMU samples, last-step IMU samples, saturation counts) at ticks 1..`ticks`
    of a plant with `thrust` N per motor, motor noise 0, the air at `wind` (3, m/s)."""
    physics = physics or PhysicsParams(motor_noise=0.0, min_motor_thrust=0.0)
    x0 = np.concatenate([position, quat_from_euler(*euler), velocity, np.zeros(3)])
    builder = DiagramBuilder()
    plant = builder.AddSystem(QuadrotorPlant(physics, x0))
    averaged = builder.AddSystem(Imu(ImuParams(delta_velocity=True, **QUIET, **imu_params)))
    last_step = builder.AddSystem(Imu(ImuParams(**QUIET, **imu_params)))
    for imu, motion in ((averaged, "delta_velocity"), (last_step, "acceleration")):
        builder.Connect(plant.GetOutputPort("state"), imu.GetInputPort("state"))
        builder.Connect(plant.GetOutputPort(motion), imu.GetInputPort(motion))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    for system in (plant, averaged, last_step):
        sub = system.GetMyMutableContextFromRoot(context)
        for i in range(system.num_input_ports()):
            port = system.get_input_port(i)
            if port.get_name() == "motor_thrusts":
                port.FixValue(sub, [thrust] * 4)
            elif port.get_name() == "motor_noise":
                port.FixValue(sub, [0.5] * 8)
            elif port.get_name() == "wind":
                port.FixValue(sub, wind)
            elif port.get_name() == "noise":
                port.FixValue(sub, np.zeros(6))
    rows = []
    for tick in range(1, ticks + 1):
        # the IMU samples at t_k; read just after it, before the plant's steps of the tick
        simulator.AdvanceTo(tick * ONBOARD_PERIOD + 1e-7)
        rows.append(
            [
                imu.GetOutputPort(name).Eval(imu.GetMyContextFromRoot(context)).copy()
                for imu in (averaged, last_step)
                for name in ("imu", "imu_saturation")
            ]
        )
    return rows


def test_resting_on_the_floor_reads_the_support_force():
    rows = fly([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], 0.1, {"accel_limit": G16}, ticks=20)
    for averaged, saturated, last_step, _ in rows:
        np.testing.assert_allclose(averaged, [0, 0, -GRAVITY, 0, 0, 0], atol=1e-12)
        np.testing.assert_allclose(last_step, [0, 0, -GRAVITY, 0, 0, 0], atol=1e-12)
        assert saturated.tolist() == [0.0, 0.0]


def test_a_3_m_per_s_touchdown_shows_and_saturates():
    """2 mm above the floor at 3 m/s with the motors at 0: the floor stops the vehicle in the
    tick's first 1 ms step. The delta-velocity IMU reads the whole impulse, -3 m/s over 2 ms
    (-1510 m/s^2, beyond 16 g: clipped and counted); the last-step IMU reads only the step after
    it, on the floor (-g): the impulse is unseen."""
    wide = {"accel_limit": 1e4}
    first = fly([0.0, 0.0, -0.002], [0.0, 0.0, 3.0], 0.0, wide, ticks=1)[0]
    averaged, _, last_step, _ = first
    impulse = (0.0 - 3.0 - GRAVITY * ONBOARD_PERIOD) / ONBOARD_PERIOD  # delta-v / dt, body z
    assert averaged[2] == pytest.approx(impulse, rel=1e-9)
    assert last_step[2] == pytest.approx(-GRAVITY, abs=1e-9)
    clipped = fly([0.0, 0.0, -0.002], [0.0, 0.0, 3.0], 0.0, {"accel_limit": G16}, ticks=3)
    averaged, saturated, last_step, last_saturated = clipped[0]
    assert averaged[2] == -G16 and saturated.tolist() == [1.0, 0.0]
    assert last_saturated.tolist() == [0.0, 0.0]
    # then it rests: the support force, and the count stays at 1
    averaged, saturated, _, _ = clipped[-1]
    assert averaged[2] == pytest.approx(-GRAVITY, abs=1e-9) and saturated.tolist() == [1.0, 0.0]


def test_free_fall_reads_zero():
    for averaged, _, last_step, _ in fly([0.0, 0.0, -20.0], [0.0, 0.0, 0.0], 0.0, {}, ticks=10)[1:]:
        np.testing.assert_allclose(averaged[:3], 0.0, atol=1e-9)
        np.testing.assert_allclose(last_step[:3], 0.0, atol=1e-9)


@pytest.mark.parametrize("euler", [(0.0, 0.0, 0.0), (0.2, -0.1, 0.7)])
def test_steady_wind_reads_the_drag(euler):
    """A vehicle at rest in a 5 m/s wind from the south (blowing north): the accelerometer reads
    thrust and drag, F/m in body axes: the drag (k + c |v|) 5 m/s / m along the wind (turned into
    the body) and -T/m on body z."""
    physics = PhysicsParams(
        motor_noise=0.0,
        min_motor_thrust=0.0,
        rotor_drag=[0.22, 0.22, 0.44],
        parasitic_drag=[0.005, 0.005, 0.01],
    )
    wind = np.array([5.0, 0.0, 0.0])
    rows = fly([0.0, 0.0, -10.0], [0.0, 0.0, 0.0], HOVER, {}, physics, wind, ticks=1, euler=euler)
    averaged, _, last_step, _ = rows[0]
    from quad_drake.models.rotations import rotation_from_quat

    R = rotation_from_quat(quat_from_euler(*euler))
    v_rel_B = R.T @ (-wind)
    k, c = np.array(physics.rotor_drag), np.array(physics.parasitic_drag)
    drag_B = -(k + c * np.linalg.norm(v_rel_B)) * v_rel_B
    expected = (drag_B + [0.0, 0.0, -4 * HOVER]) / MASS
    # the vehicle starts to move with the air within the 2 ms: the drag falls by ~0.4 %
    np.testing.assert_allclose(averaged[:3], expected, rtol=0, atol=0.02)
    np.testing.assert_allclose(last_step[:3], expected, rtol=0, atol=0.02)
    assert averaged[0] * np.sign(expected[0]) > 0.1
