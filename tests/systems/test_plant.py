"""QuadrotorPlant: ports, timing, motor start-up and noise, and a cross-check of the
rigid-body model against Drake's MultibodyPlant."""

import dataclasses

import numpy as np
import pytest
from pydrake.common import RandomDistribution, RandomGenerator
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.math import SpatialForce, SpatialVelocity
from pydrake.multibody.plant import ExternallyAppliedSpatialForce, MultibodyPlant
from pydrake.multibody.tree import RotationalInertia, SpatialInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import AddRandomInputs, ConstantVectorSource, RandomSource

from quad_drake.config.schema import PhysicsParams
from quad_drake.conventions import GRAVITY, ONBOARD_PERIOD, PHYSICS_PERIOD, PLANT_OFFSET
from quad_drake.models.dynamics import plant_step, rigid_body_derivatives
from quad_drake.models.rotations import quat_from_euler, rotation_from_quat
from quad_drake.systems.plant import QuadrotorPlant

PARAMS = PhysicsParams()
HOVER = PARAMS.mass * GRAVITY / 4.0
DT = PHYSICS_PERIOD


def make_state(p=(0.0, 0.0, -1.0), ypr=(0.0, 0.0, 0.0), v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)):
    return np.concatenate([p, quat_from_euler(ypr[2], ypr[1], ypr[0]), v, w]).astype(float)


def fixed_plant(commands, noise=(0.5,) * 8, x0=None, params=PARAMS):
    dut = QuadrotorPlant(params, make_state() if x0 is None else x0)
    context = dut.CreateDefaultContext()
    dut.GetInputPort("motor_thrusts").FixValue(context, np.asarray(commands, dtype=float))
    dut.GetInputPort("motor_noise").FixValue(context, np.asarray(noise, dtype=float))
    return dut, context, Simulator(dut, context)


def outputs(dut, context):
    return {
        name: dut.GetOutputPort(name).Eval(context).copy()
        for name in ("state", "acceleration", "motor_forces")
    }


def test_ports_are_declared_with_sizes_and_noise_type():
    dut = QuadrotorPlant(PARAMS, make_state())
    assert dut.GetInputPort("motor_thrusts").size() == 4
    assert dut.GetInputPort("motor_noise").size() == 8
    assert (dut.noise_size, dut.noise_period) == (8, ONBOARD_PERIOD)
    sizes = {name: dut.GetOutputPort(name).size() for name in ("state", "acceleration", "motor_forces")}
    assert sizes == {"state": 13, "acceleration": 3, "motor_forces": 4}
    for i in range(dut.num_input_ports()):
        for j in range(dut.num_output_ports()):
            assert not dut.HasDirectFeedthrough(i, j)
    with pytest.raises(ValueError, match="13 values"):
        QuadrotorPlant(PARAMS, np.zeros(12))


def test_only_motor_noise_is_a_random_uniform_input():
    builder = DiagramBuilder()
    plant = builder.AddSystem(QuadrotorPlant(PARAMS, make_state()))
    source = builder.AddSystem(ConstantVectorSource(np.full(4, HOVER)))
    builder.Connect(source.get_output_port(), plant.GetInputPort("motor_thrusts"))
    assert AddRandomInputs(PHYSICS_PERIOD, builder) == 1
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyContextFromRoot(context)
    samples = []
    for seed in range(50):
        diagram.SetRandomContext(context, RandomGenerator(seed))
        samples.append(plant.GetInputPort("motor_noise").Eval(plant_context).copy())
    samples = np.array(samples)
    assert samples.min() >= 0.0 and samples.max() <= 1.0  # uniform on [0, 1], not Gaussian
    assert abs(samples.mean() - 0.5) < 0.1


def test_default_context_holds_the_initial_state_and_nothing_moves_before_the_first_step():
    x0 = make_state(p=(1.0, 2.0, -3.0), ypr=(0.5, 0.1, -0.2), v=(1.0, 0.0, 0.0))
    dut, context, sim = fixed_plant([HOVER] * 4, x0=x0)
    out = outputs(dut, context)
    np.testing.assert_array_equal(out["state"], x0)
    np.testing.assert_array_equal(out["acceleration"], 0.0)
    np.testing.assert_array_equal(out["motor_forces"], 0.0)
    sim.AdvanceTo(PLANT_OFFSET - 1e-9)
    np.testing.assert_array_equal(dut.GetOutputPort("state").Eval(context), x0)
    sim.AdvanceTo(PLANT_OFFSET + 1e-9)  # the first step fires at t = PLANT_OFFSET
    expected, accel, forces, _ = plant_step(x0.tolist(), [HOVER] * 4, [HOVER] * 4, [0.5] * 4, PARAMS, DT)
    out = outputs(dut, context)
    np.testing.assert_array_equal(out["state"], expected)
    np.testing.assert_array_equal(out["acceleration"], accel)
    np.testing.assert_array_equal(out["motor_forces"], forces)
    assert out["state"][0] == pytest.approx(1.0 + DT, abs=1e-6)


def test_each_tick_steps_twice_with_its_own_half_of_the_noise():
    noise = [0.0] * 4 + [1.0] * 4  # first step: -0.25 N per motor, second step: +0.25 N
    dut, context, sim = fixed_plant([HOVER] * 4, noise=noise)
    x = make_state()
    sim.AdvanceTo(PHYSICS_PERIOD + PLANT_OFFSET - 1e-9)
    x1, _, f1, _ = plant_step(x.tolist(), [HOVER] * 4, [HOVER] * 4, [0.0] * 4, PARAMS, DT)
    np.testing.assert_array_equal(outputs(dut, context)["state"], x1)  # held until t_k + 1 ms + offset
    sim.AdvanceTo(PHYSICS_PERIOD + PLANT_OFFSET + 1e-9)
    x2, _, f2, _ = plant_step(x1, f1, [HOVER] * 4, [1.0] * 4, PARAMS, DT)
    np.testing.assert_array_equal(outputs(dut, context)["state"], x2)
    np.testing.assert_array_equal(outputs(dut, context)["motor_forces"], f2)
    assert f1[0] < HOVER < f2[0]
    sim.AdvanceTo(ONBOARD_PERIOD + PLANT_OFFSET - 1e-9)
    np.testing.assert_array_equal(outputs(dut, context)["state"], x2)


def test_hover_is_an_equilibrium_for_two_seconds():
    x0 = make_state(p=(0.5, -1.0, -2.0), ypr=(1.0, 0.0, 0.0))
    dut, context, sim = fixed_plant([HOVER] * 4, x0=x0)
    sim.AdvanceTo(2.0)
    out = outputs(dut, context)
    np.testing.assert_allclose(out["state"], x0, atol=1e-12)
    np.testing.assert_allclose(out["acceleration"], 0.0, atol=1e-9)
    np.testing.assert_allclose(out["motor_forces"], HOVER, rtol=1e-15)


def test_free_fall_steps_at_the_physics_rate_and_matches_the_closed_form():
    x0 = make_state(p=(0.0, 0.0, -20.0))
    dut, context, sim = fixed_plant([PARAMS.min_motor_thrust] * 4, x0=x0)
    accel_z = GRAVITY - 4 * PARAMS.min_motor_thrust / PARAMS.mass
    sim.AdvanceTo(0.0101)  # steps at 4e-6, 1.004e-3, ..., 10.004e-3: 11 of them
    t = 11 * DT
    state = dut.GetOutputPort("state").Eval(context)
    assert state[2] == pytest.approx(-20.0 + 0.5 * accel_z * t * t, abs=1e-12)
    sim.AdvanceTo(1.5)
    t = 1500 * DT
    out = outputs(dut, context)
    assert out["state"][2] == pytest.approx(-20.0 + 0.5 * accel_z * t * t, abs=1e-9)
    assert out["state"][9] == pytest.approx(accel_z * t, abs=1e-9)
    np.testing.assert_allclose(out["acceleration"], [0.0, 0.0, accel_z], atol=1e-6)


def test_first_step_starts_the_motor_lag_from_the_raw_command():
    # command 0 is below min thrust: lag starts at 0 (pre-clamp) and rises towards 0.1
    dut, context, sim = fixed_plant([0.0] * 4)
    sim.AdvanceTo(DT)  # AdvanceTo(n DT) runs exactly n steps
    w_up = DT / (DT + PARAMS.motor_tau_up)
    np.testing.assert_allclose(dut.GetOutputPort("motor_forces").Eval(context), 0.1 * w_up, rtol=1e-12)
    sim.AdvanceTo(2 * DT)
    expected = 0.1 * w_up + 0.1 * w_up * (1 - w_up)
    np.testing.assert_allclose(dut.GetOutputPort("motor_forces").Eval(context), expected, rtol=1e-12)
    # set_initial_state re-arms it: a new raw command starts the lag again
    dut.set_initial_state(context, make_state(p=(0.0, 0.0, -5.0)))
    dut.GetInputPort("motor_thrusts").FixValue(context, [2.0, 2.0, 2.0, 2.0])
    sim.AdvanceTo(3 * DT)
    np.testing.assert_allclose(dut.GetOutputPort("motor_forces").Eval(context), 2.0, rtol=1e-14)
    assert dut.GetOutputPort("state").Eval(context)[2] < -5.0 + 1e-4


def test_unit_noise_one_adds_a_quarter_newton_after_the_clamp():
    commands = [1.0, 3.0, 6.0, -1.0]
    dut, context, sim = fixed_plant(commands, noise=[1.0] * 8, x0=make_state(p=(0, 0, -35.0)))
    sim.AdvanceTo(DT)
    # lag from the raw command: up for motors 0, 1, 3 (tau_up), down for motor 2 (6 -> 4.75)
    w = np.array(
        [
            DT / (DT + tau)
            for tau in [PARAMS.motor_tau_up] * 2 + [PARAMS.motor_tau_down] + [PARAMS.motor_tau_up]
        ]
    )
    target = np.array([1.25, 3.25, 4.75, 0.35])
    np.testing.assert_allclose(
        dut.GetOutputPort("motor_forces").Eval(context), w * target + (1 - w) * np.array(commands), rtol=1e-12
    )
    dut.GetInputPort("motor_noise").FixValue(context, [0.0] * 8)
    sim.AdvanceTo(1.0)  # 50 time constants: forces settle at clamp(cmd) - 0.25
    np.testing.assert_allclose(
        dut.GetOutputPort("motor_forces").Eval(context), [0.75, 2.75, 4.25, -0.15], rtol=1e-9
    )


def test_com_offset_rolls_the_vehicle():
    params = dataclasses.replace(PARAMS, com_offset=[0.0, -0.05])
    dut, context, sim = fixed_plant([HOVER] * 4, params=params)
    sim.AdvanceTo(0.01)
    w = dut.GetOutputPort("state").Eval(context)[10:13]
    expected_rate = -0.05 * 4 * HOVER / PARAMS.inertia[0] * 10 * DT
    np.testing.assert_allclose(w, [expected_rate, 0.0, 0.0], rtol=1e-9, atol=1e-12)


def test_sticky_floor_in_the_simulator():
    dut, context, sim = fixed_plant(
        [PARAMS.min_motor_thrust] * 4, x0=make_state(p=(1.0, 1.0, -0.02), v=(2.0, 0.0, 0.0))
    )
    sim.AdvanceTo(0.5)
    out = outputs(dut, context)
    assert out["state"][2] == 0.0
    np.testing.assert_array_equal(out["state"][7:13], 0.0)
    np.testing.assert_array_equal(out["acceleration"], 0.0)
    assert 1.0 < out["state"][0] < 1.2  # slid for ~60 ms before touching down, then stuck


def test_random_source_wiring_is_seeded_and_bounded():
    def run(seed):
        builder = DiagramBuilder()
        plant = builder.AddSystem(QuadrotorPlant(PARAMS, make_state()))
        source = builder.AddSystem(ConstantVectorSource(np.full(4, HOVER)))
        noise = builder.AddSystem(
            RandomSource(RandomDistribution.kUniform, plant.noise_size, plant.noise_period)
        )
        builder.Connect(source.get_output_port(), plant.GetInputPort("motor_thrusts"))
        builder.Connect(noise.get_output_port(), plant.GetInputPort("motor_noise"))
        diagram = builder.Build()
        sim = Simulator(diagram)
        diagram.SetRandomContext(sim.get_mutable_context(), RandomGenerator(seed))
        forces = []
        for k in range(1, 201):
            sim.AdvanceTo(k * DT)
            ctx = plant.GetMyContextFromRoot(sim.get_context())
            forces.append(plant.GetOutputPort("motor_forces").Eval(ctx).copy())
        return np.array(forces)

    a, b, c = run(1), run(1), run(2)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    # each lagged force is a weighted mean of targets within HOVER +- 0.25
    assert np.all(np.abs(a - HOVER) <= 0.25)
    assert 0.01 < np.std(a - HOVER) < 0.06  # ~0.144 sqrt(w/(2-w)), w = 0.09
    assert len({tuple(row) for row in np.diff(a, axis=0)}) == 199  # fresh noise every step


# ----- cross-check against Drake's MultibodyPlant ------------------------------

R_WN = np.diag([1.0, -1.0, -1.0])  # NED -> Drake's z-up world (x kept, y and z flipped)
R_BD = np.diag([1.0, -1.0, -1.0])  # FRD body -> FLU body frame D of the Drake body


def drake_accelerations(x, thrust, moment, mass, inertia):
    """(a_NB in N, w_dot_B in B) of a MultibodyPlant free body with the same wrench."""
    mbp = MultibodyPlant(0.0)
    body = mbp.AddRigidBody(
        "quad", SpatialInertia.MakeFromCentralInertia(mass, np.zeros(3), RotationalInertia(*inertia))
    )  # diagonal: same in FRD and FLU
    mbp.mutable_gravity_field().set_gravity_vector([0.0, 0.0, -GRAVITY])
    mbp.Finalize()
    context = mbp.CreateDefaultContext()
    r_nb = rotation_from_quat(x[3:7])
    r_wb = R_WN @ r_nb
    mbp.SetFreeBodyPose(context, body, RigidTransform(RotationMatrix(r_wb @ R_BD), R_WN @ x[0:3]))
    mbp.SetFreeBodySpatialVelocity(context, body, SpatialVelocity(w=r_wb @ x[10:13], v=R_WN @ x[7:10]))
    force = ExternallyAppliedSpatialForce()
    force.body_index = body.index()
    force.p_BoBq_B = np.zeros(3)
    force.F_Bq_W = SpatialForce(tau=r_wb @ np.asarray(moment), f=r_wb @ [0.0, 0.0, -thrust])
    mbp.get_applied_spatial_force_input_port().FixValue(context, [force])
    accel = mbp.get_body_spatial_accelerations_output_port().Eval(context)[int(body.index())]
    return R_WN.T @ accel.translational(), r_wb.T @ accel.rotational()


def test_rigid_body_matches_multibody_plant_free_body():
    rng = np.random.default_rng(2024)
    for _ in range(12):
        mass = rng.uniform(0.3, 1.5)
        ixx, iyy = rng.uniform(0.001, 0.004, 2)
        inertia = np.array([ixx, iyy, rng.uniform(0.7, 1.0) * (ixx + iyy)])  # triangle inequality
        ypr = rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi])
        x = make_state(p=rng.uniform(-10, 10, 3), ypr=ypr, v=rng.uniform(-5, 5, 3), w=rng.uniform(-10, 10, 3))
        thrust, moment = rng.uniform(0.0, 18.0), rng.uniform(-0.5, 0.5, 3)
        d = np.array(rigid_body_derivatives(x, thrust, moment, mass, inertia))
        a_n, w_dot_b = drake_accelerations(x, thrust, moment, mass, inertia)
        np.testing.assert_allclose(d[7:10], a_n, rtol=1e-9, atol=1e-9 * np.linalg.norm(a_n))
        np.testing.assert_allclose(d[10:13], w_dot_b, rtol=1e-9, atol=1e-9 * np.linalg.norm(w_dot_b))
        assert np.linalg.norm(w_dot_b - np.asarray(moment) / inertia) > 1.0  # gyroscopic terms matter
