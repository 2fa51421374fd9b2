"""Every system sized by ``n``: a system of n vehicles flies each of them exactly as a one-vehicle
system fed that vehicle's inputs (its rows of the vehicle-major ports), bit for bit, with the
noise on (the fleet's noiseless Diagram tests in ``tests/test_fleet.py`` cannot see a noise
column read from the wrong vehicle)."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from quad_drake import conventions as c
from quad_drake.config.schema import (
    BaroParams,
    ControllerParams,
    GpsParams,
    GustConfig,
    ImuParams,
    MagParams,
    PhysicsParams,
    WindConfig,
)
from quad_drake.models.rotations import quat_from_euler
from quad_drake.models.trajectories import figure_eight
from quad_drake.systems.controller import CascadeController
from quad_drake.systems.plant import QuadrotorPlant
from quad_drake.systems.sensors import Barometer, Gps, Imu, Magnetometer
from quad_drake.systems.trajectory import TrajectorySource
from quad_drake.systems.wind import Wind

N = 3


def _state(rng):
    """A random 13-vector state: p m, a unit quaternion, v m/s, w rad/s."""
    roll, pitch, yaw = rng.uniform(-0.5, 0.5, 3)
    return np.concatenate([rng.normal(0, 2, 3), quat_from_euler(roll, pitch, yaw), rng.normal(0, 1, 6)])


def _input(port, rng):
    """A random value of the one-vehicle input `port`."""
    size = port.size()
    if port.get_name() == "state":
        return _state(rng)
    if port.get_name() == "motor_noise":
        return rng.uniform(0, 1, size)
    if port.get_name() == "motor_thrusts":
        return rng.uniform(1, 4, size)
    return rng.normal(0, 1, size)


MAKERS = {
    "plant": lambda n: QuadrotorPlant(PhysicsParams(), np.r_[0, 0, -1, 1, 0, 0, 0, np.zeros(6)], n=n),
    "imu with a bias walk": lambda n: Imu(
        ImuParams(accel_bias_walk_std=[0.01, 0.02, 0.03], gyro_bias_walk_std=[0.001, 0.002, 0.003]), n=n
    ),
    "plant with drag in wind": lambda n: QuadrotorPlant(
        PhysicsParams(rotor_drag=[0.2, 0.3, 0.4], parasitic_drag=[0.01, 0.02, 0.03]),
        np.r_[0, 0, -1, 1, 0, 0, 0, np.zeros(6)],
        n=n,
    ),
    "delta-velocity imu with range limits": lambda n: Imu(
        ImuParams(delta_velocity=True, accel_limit=1.5, gyro_limit=1.0), n=n
    ),
    "wind": lambda n: Wind(
        WindConfig(
            mean=[2.0, 1.0, 0.0],
            gusts=[GustConfig(start=0.05, duration=0.1, amplitude=3.0)],
            turbulence="severe",
        ),
        n=n,
    ),
    "gps": lambda n: Gps(GpsParams(), n=n),
    "magnetometer": lambda n: Magnetometer(MagParams(), n=n),
    "3-axis magnetometer": lambda n: Magnetometer(
        MagParams(three_axis=True, hard_iron=[0.05, -0.02, 0.01], field_std=[0.01, 0.02, 0.03]), n=n
    ),
    "barometer with a bias walk and ground effect": lambda n: Barometer(
        BaroParams(bias=0.3, bias_walk_std=0.01, ground_effect_height=3.0, ground_effect_error=-0.2),
        floor_z=0.5,
        n=n,
    ),
    "controller": lambda n: CascadeController(ControllerParams(), n=n),
    "trajectory": lambda n: TrajectorySource(figure_eight(), n=n),
}


@pytest.mark.parametrize("kind", MAKERS)
def test_n_vehicles_fly_as_n_one_vehicle_systems(kind):
    rng = np.random.default_rng(28)
    builder = DiagramBuilder()
    many = builder.AddSystem(MAKERS[kind](N))
    ones = [builder.AddSystem(MAKERS[kind](1)) for _ in range(N)]
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    differ = False  # whether the vehicles' outputs differ at all
    for tick in range(1, 111):  # 220 ms: two GPS samples, 22 magnetometer samples
        for i in range(many.num_input_ports()):
            rows = [_input(one.get_input_port(i), rng) for one in ones]
            many.get_input_port(i).FixValue(many.GetMyMutableContextFromRoot(context), np.concatenate(rows))
            for one, row in zip(ones, rows, strict=True):
                one.get_input_port(i).FixValue(one.GetMyMutableContextFromRoot(context), row)
        simulator.AdvanceTo(tick * c.ONBOARD_PERIOD)
        for k in range(many.num_output_ports()):
            value = many.get_output_port(k).Eval(many.GetMyContextFromRoot(context)).reshape(N, -1)
            assert value.shape[1] == ones[0].get_output_port(k).size()
            differ = differ or len({tuple(v) for v in value}) == N
            for j, one in enumerate(ones):
                expected = one.get_output_port(k).Eval(one.GetMyContextFromRoot(context))
                np.testing.assert_array_equal(value[j], expected, err_msg=f"{kind} vehicle {j}, tick {tick}")
    assert differ or kind == "trajectory"  # (its one sample is every vehicle's)
