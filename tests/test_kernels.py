"""The batched kernels against the scalar reference functions on seeded random inputs.

Tolerance: 1e-12 absolute on every output (the values are O(1)-O(100); in practice the
kernels agree bit for bit or to a few ulp).
"""

import dataclasses

import numpy as np
import pytest

from quad_drake.config.schema import ControllerParams, GpsParams, ImuParams, MagParams, PhysicsParams
from quad_drake.control import cascade
from quad_drake.kernels import flight as kernels
from quad_drake.models import dynamics, sensor_models
from quad_drake.models.fidelity import PHYSICAL, REFERENCE

N = 200
TOL = 1e-12
RTOL_BOUND = (
    1e-12  # relative: the bound is propagated in covariance form (measured 1.4e-14 over 2000 samples)
)
FIDELITIES = pytest.mark.parametrize("fidelity", [PHYSICAL, REFERENCE], ids=["physical", "reference"])


def random_states(rng, n=N, spread=1.0):
    """(n, 13) states: positions over and beyond a small room, unit quaternions, fast rates."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.concatenate(
        [
            rng.uniform(-3, 1, size=(n, 3)) * spread,
            q,
            rng.normal(size=(n, 3)) * 3,
            rng.normal(size=(n, 3)) * 5,
        ],
        axis=1,
    )


def small_room():
    """A room whose walls, ceiling and floor the random states cross."""
    return PhysicsParams(
        x_bounds=[-2.0, 0.5], y_bounds=[-2.5, 0.8], z_bounds=[-2.0, 0.2], com_offset=[0.01, -0.02]
    )


def close(batched, scalar_rows):
    np.testing.assert_allclose(
        np.asarray(batched, dtype=float), np.asarray(scalar_rows, dtype=float), rtol=0, atol=TOL
    )


DRAG = {"rotor_drag": [0.22, 0.25, 0.44], "parasitic_drag": [0.005, 0.006, 0.01]}


@FIDELITIES
@pytest.mark.parametrize("column", [0, 4])
@pytest.mark.parametrize("drag", [False, True], ids=["still", "drag"])
def test_plant_steps_match_scalar(fidelity, column, drag):
    rng = np.random.default_rng(1201)
    params = small_room()
    if drag:
        params = PhysicsParams(**{**params.__dict__, **DRAG})
    state = random_states(rng)
    forces_old = rng.uniform(0, 5, size=(N, 4))
    commands = rng.uniform(-1, 6, size=(N, 4))  # below and above the motor limits
    noise = rng.uniform(size=(N, 8))
    wind = rng.normal(size=(N, 3)) * 5
    contacts = np.column_stack([rng.integers(0, 2, N), rng.integers(0, 5, size=(N, 2))]).astype(float)
    new, forces, accel, counted = state.copy(), forces_old.copy(), np.empty((N, 3)), contacts.copy()
    delta_v = rng.normal(size=(N, 3))
    delta_v_before = delta_v.copy()
    kernels.plant_steps(
        new, forces, commands, noise, column, kernels.frozen(params), 0.001, kernels.frozen(fidelity),
        accel, counted, wind, delta_v,
    )  # fmt: skip
    rows = [
        dynamics.plant_step(
            state[i].tolist(),
            forces_old[i].tolist(),
            commands[i].tolist(),
            noise[i, column : column + 4].tolist(),
            params,
            0.001,
            fidelity,
            wind[i].tolist(),
        )
        for i in range(N)
    ]
    close(new, [r[0] for r in rows])
    close(accel, [r[1] for r in rows])
    close(forces, [r[2] for r in rows])
    steps = [
        sensor_models.delta_velocity_step(state[i, 3:7], r[0][3:7], r[1], 0.001) for i, r in enumerate(rows)
    ]
    close(delta_v, np.asarray(steps) + (delta_v_before if column else 0.0))
    if drag:  # the wind acted
        first = (state[0].tolist(), forces_old[0].tolist(), commands[0].tolist())
        still = dynamics.plant_step(*first, noise[0, column : column + 4].tolist(), params, 0.001, fidelity)
        assert still[0] != rows[0][0]
    before = contacts.tolist()
    expected = [dynamics.count_contacts(before[i], r[0], r[3], params) for i, r in enumerate(rows)]
    assert counted.tolist() == [list(c) for c in expected]
    assert 0 < sum(r[3] for r in rows) < N  # the walls were exercised
    floor = kernels.on_floor(new, params)
    assert floor.tolist() == [dynamics.on_floor(r[0], params) for r in rows]
    assert 0 < floor.sum() < N
    assert 0 < (counted[:, 1] - contacts[:, 1]).sum() < N  # touchdowns were counted


@FIDELITIES
def test_plant_steps_match_scalar_over_many_steps(fidelity):
    rng = np.random.default_rng(1202)
    params = PhysicsParams()
    state = random_states(rng)
    commands = rng.uniform(0.5, 4.0, size=(N, 4))
    batched, forces = state.copy(), rng.uniform(0, 5, size=(N, 4))
    accel, contacts = np.empty((N, 3)), np.zeros((N, 3))
    scalar = [(s.tolist(), f.tolist(), (0.0, 0.0, 0.0)) for s, f in zip(state, forces, strict=True)]
    frozen_params, frozen_fidelity = kernels.frozen(params), kernels.frozen(fidelity)
    for _ in range(50):
        noise = rng.uniform(size=(N, 4))
        kernels.plant_steps(
            batched, forces, commands, noise, 0, frozen_params, 0.001, frozen_fidelity, accel, contacts,
            np.zeros((N, 3)), np.zeros((N, 3)),
        )  # fmt: skip
        stepped = [
            dynamics.plant_step(s, f, commands[i].tolist(), noise[i].tolist(), params, 0.001, fidelity)
            for i, (s, f, _) in enumerate(scalar)
        ]
        scalar = [
            (new, lagged, dynamics.count_contacts(c, new, hit_wall, params))
            for (new, _, lagged, hit_wall), (_, _, c) in zip(stepped, scalar, strict=True)
        ]
    close(batched, [s for s, _, _ in scalar])
    close(forces, [f for _, f, _ in scalar])
    assert contacts.tolist() == [list(c) for _, _, c in scalar]
    assert contacts[:, 1].sum() > 0  # touchdowns were counted


@FIDELITIES
@pytest.mark.parametrize("gyro_limit", [0.0, 4.0])
def test_imu_matches_scalar(fidelity, gyro_limit):
    rng = np.random.default_rng(1203)
    params = ImuParams(
        accel_limit=12.0,
        accel_bias=[0.1, -0.2, 0.3],
        gyro_bias_walk_std=[0.01, 0.02, 0.03],
        gyro_limit=gyro_limit,
    )
    state = random_states(rng)
    accel = rng.normal(size=(N, 3)) * 8  # some beyond the saturation
    noise = rng.normal(size=(N, 6))
    bias = rng.normal(size=(N, 6)) * 0.1
    out = np.full((N, 6), np.nan)
    saturation = np.zeros((N, 2))
    kernels.imu_samples(
        state,
        accel,
        noise,
        kernels.frozen(params),
        kernels.frozen(fidelity),
        bias,
        out,
        accel,
        0.002,
        saturation,
    )
    expected = [sensor_models.imu_saturated(row, params) for row in out.tolist()]
    assert saturation.tolist() == [list(e) for e in expected]
    assert 0 < saturation[:, 0].sum() < N
    assert (0 < saturation[:, 1].sum() < N) == (gyro_limit > 0)
    rows = [
        sensor_models.imu_measurement(
            state[i, 3:7].tolist(),
            state[i, 10:13].tolist(),
            accel[i].tolist(),
            noise[i].tolist(),
            params,
            fidelity,
            bias[i].tolist(),
        )
        for i in range(N)
    ]
    close(out, rows)
    if fidelity is PHYSICAL:  # the delta-velocity accelerometer: the mean specific force dv / dt
        delta = dataclasses.replace(params, delta_velocity=True)
        dv = rng.normal(size=(N, 3)) * 0.02
        kernels.imu_samples(
            state,
            accel,
            noise,
            kernels.frozen(delta),
            kernels.frozen(fidelity),
            bias,
            out,
            dv,
            0.002,
            saturation,
        )
        rows = [
            sensor_models.imu_from_specific_force(
                (dv[i] / 0.002).tolist(),
                state[i, 10:13].tolist(),
                noise[i].tolist(),
                delta,
                fidelity,
                bias[i].tolist(),
            )
            for i in range(N)
        ]
        close(out, rows)
    stepped = kernels.imu_bias_step(bias, noise, params)
    close(
        stepped, [sensor_models.imu_bias_step(bias[i].tolist(), noise[i].tolist(), params) for i in range(N)]
    )


@FIDELITIES
def test_gps_and_magnetometer_match_scalar(fidelity):
    rng = np.random.default_rng(1204)
    gps = GpsParams(pos_random_walk_std=[0.1, 0.2, 0.3])
    mag = MagParams(yaw_std=0.3)
    state = random_states(rng)
    walk = rng.normal(size=(N, 3))
    noise = rng.normal(size=(N, 9))
    new_walk, out = walk.copy(), np.full((N, 7), np.nan)
    kernels.gps_samples(state, new_walk, noise, kernels.frozen(gps), kernels.frozen(fidelity), 0.3, out)
    rows = [
        sensor_models.gps_measurement(
            state[i, 0:3].tolist(),
            state[i, 7:10].tolist(),
            walk[i].tolist(),
            noise[i].tolist(),
            gps,
            fidelity,
        )
        for i in range(N)
    ]
    close(out, [r[0] + r[1] + [0.3] for r in rows])
    close(new_walk, [r[2] for r in rows])
    yaw_noise = rng.normal(size=(N, 1)) * 5
    out = np.full((N, 2), np.nan)
    kernels.magnetometer_samples(state, yaw_noise, kernels.frozen(mag), kernels.frozen(fidelity), 0.25, out)
    close(
        out,
        [
            [sensor_models.magnetometer_yaw(state[i, 3:7].tolist(), yaw_noise[i, 0], mag, fidelity), 0.25]
            for i in range(N)
        ],
    )


@FIDELITIES
@pytest.mark.parametrize("spread", [0.2, 5.0], ids=["near", "far"])
def test_cascade_step_matches_scalar(fidelity, spread):
    """Near the set-point no limit is active; far from it the speed, acceleration, tilt and
    thrust limits are."""
    rng = np.random.default_rng(1205)
    params = ControllerParams()
    state = random_states(rng, spread=spread)
    q = rng.normal(size=(N, 4)) * [1.0, 0.2, 0.2, 0.6] + [3.0, 0, 0, 0]
    state[:, 3:7] = q  # near-level, not unit (the controller normalises)
    reference = np.concatenate([rng.normal(size=(N, 9)) * spread, rng.uniform(-4, 4, size=(N, 1))], axis=1)
    integral = rng.normal(size=N) * 0.1
    forces, new_integral = np.full((N, 4), np.nan), integral.copy()
    kernels.cascade_steps(
        state, reference, new_integral, 0.002, kernels.frozen(params), kernels.frozen(fidelity), forces
    )
    rows = [
        cascade.cascade_step(state[i].tolist(), reference[i].tolist(), integral[i], 0.002, params, fidelity)
        for i in range(N)
    ]
    close(forces, [r[0] for r in rows])
    close(new_integral, [r[1] for r in rows])


def test_posterior_crbs_match_the_scalar_bound():
    from quad_drake.config.schema import SensorsConfig
    from quad_drake.kernels.bounds import posterior_crbs
    from quad_drake.models.accuracy_bound import posterior_crb

    rng = np.random.default_rng(1206)
    n, runs = 1000, 4
    states = np.stack([random_states(rng, n) for _ in range(runs)], axis=1)
    states[:, :, 7:10] = np.cumsum(rng.normal(size=(n, runs, 3)) * 0.05, axis=0)  # smooth velocities
    gps = rng.random((n, runs)) < 0.05
    mag = rng.random((n, runs)) < 0.2
    sensors = SensorsConfig(imu=ImuParams(), gps=GpsParams(), mag=MagParams())
    batched = posterior_crbs(states, gps, mag, sensors)
    for j in range(runs):
        scalar = posterior_crb(states[:, j], gps[:, j], mag[:, j], sensors)
        for name, values in scalar.items():
            np.testing.assert_allclose(batched[name][:, j], values, rtol=RTOL_BOUND, atol=0)
