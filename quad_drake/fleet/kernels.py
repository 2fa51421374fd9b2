"""Batched kernels: the array form of the scalar pure functions, leading axis N (vehicles).

Each function here is the array form of the scalar function it names (``dynamics``,
``sensor_models``, ``control.cascade``), which stays the reference implementation;
``tests/test_fleet_kernels.py`` checks every one against it on seeded random inputs to
1e-12. One kernel per concept: where a scalar helper is plain arithmetic it is called as
is on rows of the transposed arrays; the rigid-body steps, the plant's hot spot, are the
scalar functions' own code compiled by numba (``cache=True``: the JIT cost, about 2 s, is
paid once per machine) and run per vehicle; the parts written with branches are re-written
here with numpy (``np.where``, ``np.clip``).

Shapes: ``state`` (N, 13) in the ``conventions`` layout (p_NB m NED, q_NB wxyz, v_NB m/s,
w_NB_B rad/s); motor forces (N, 4) N; IMU samples (N, 6); references (N, 10). Parameters
are the scalar dataclasses (one set for the whole fleet). Pure: no RNG, no pydrake.
"""

import collections
import dataclasses
import types

import numba
import numpy as np

from quad_drake import dynamics, rotations
from quad_drake.config import ControllerParams
from quad_drake.control import cascade
from quad_drake.conventions import SQRT2
from quad_drake.fidelity import PHYSICAL, Fidelity
from quad_drake.rotations import euler_from_quats, wrap_angles
from quad_drake.sensor_models import gps_measurement, reference_accelerometer, specific_force

# ----- dynamics ---------------------------------------------------------------


def clamped_noisy_commands(commands, noise_unit, min_thrust, max_thrust, noise_half_width):
    """(N, 4) of :func:`quad_drake.dynamics.clamped_noisy_commands`."""
    return np.clip(commands, min_thrust, max_thrust) + noise_half_width * (2.0 * noise_unit - 1.0)


def motor_lag_step(forces_old, forces_cmd, dt, tau_up, tau_down):
    """(N, 4) of :func:`quad_drake.dynamics.motor_lag_step`."""
    tau = np.where(forces_cmd >= forces_old, tau_up, tau_down)
    return (forces_cmd * dt + forces_old * tau) / (dt + tau)


def wrench_from_thrusts(forces, arm_length, kappa, com_offset=(0.0, 0.0)):
    """(T, Mx, My, Mz), each (N,), of :func:`quad_drake.dynamics.wrench_from_thrusts`."""
    f0, f1, f2, f3 = forces.T
    arm = arm_length / SQRT2
    thrust = f0 + f1 + f2 + f3
    return (
        thrust,
        arm * (f0 - f1 + f2 - f3) + com_offset[1] * thrust,
        arm * (f0 + f1 - f2 - f3) - com_offset[0] * thrust,
        kappa * (-f0 + f1 + f2 - f3),
    )


def _compiled(function, **callees):
    """The scalar `function`'s own code compiled by numba (nopython, cached on disk), with the
    module globals it calls replaced by their compiled forms `callees`."""
    namespace = dict(function.__globals__, **callees)
    return numba.njit(types.FunctionType(function.__code__, namespace, function.__name__), cache=True)


_rates_compiled = _compiled(dynamics._rates)
_coefficients_compiled = _compiled(dynamics._coefficients)
_rk4_compiled = _compiled(
    dynamics.rigid_body_step, _rates=_rates_compiled, _coefficients=_coefficients_compiled
)
_semi_implicit_compiled = _compiled(
    dynamics.rigid_body_step_semi_implicit, _rates=_rates_compiled, _coefficients=_coefficients_compiled
)


@numba.njit(cache=True)
def _body_steps(semi_implicit, state, thrust, mx, my, mz, mass, inertia, dt, new, accel):
    """Per vehicle i, the scalar body step of state[i] into new[i], accel[i]."""
    for i in range(state.shape[0]):
        s = state[i]
        x = (s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8], s[9], s[10], s[11], s[12])
        moment = (mx[i], my[i], mz[i])
        if semi_implicit:
            out, a = _semi_implicit_compiled(x, thrust[i], moment, mass, inertia, dt)
        else:
            out, a = _rk4_compiled(x, thrust[i], moment, mass, inertia, dt)
        for k in range(13):
            new[i, k] = out[k]
        accel[i, 0], accel[i, 1], accel[i, 2] = a


def _body_step(semi_implicit, state, thrust, moment, mass, inertia, dt):
    state = np.ascontiguousarray(state, dtype=float)
    new, accel = np.empty_like(state), np.empty((state.shape[0], 3))
    mx, my, mz = (np.ascontiguousarray(np.broadcast_to(m, thrust.shape), dtype=float) for m in moment)
    inertia = (float(inertia[0]), float(inertia[1]), float(inertia[2]))
    _body_steps(
        semi_implicit,
        state,
        np.ascontiguousarray(thrust, dtype=float),
        mx,
        my,
        mz,
        float(mass),
        inertia,
        dt,
        new,
        accel,
    )
    return new, accel


def rigid_body_step(state, thrust, moment, mass, inertia, dt):
    """((N, 13), a_NB (N, 3)) of :func:`quad_drake.dynamics.rigid_body_step` (RK4): the scalar
    function's code compiled by numba, run per vehicle."""
    return _body_step(False, state, thrust, moment, mass, inertia, dt)


def rigid_body_step_semi_implicit(state, thrust, moment, mass, inertia, dt):
    """((N, 13), a_NB (N, 3)) of :func:`quad_drake.dynamics.rigid_body_step_semi_implicit`
    (compiled as :func:`rigid_body_step`)."""
    return _body_step(True, state, thrust, moment, mass, inertia, dt)


def apply_room_constraints(state_new, state_old, params):
    """(N, 13) of :func:`quad_drake.dynamics.apply_room_constraints` (inputs not modified)."""
    s = state_new.copy()
    z_min, z_max = params.z_bounds
    floor = s[:, 2] >= z_max
    if floor.any():
        s[floor, 0:2] = state_old[floor, 0:2]
        s[floor, 2] = z_max
        s[floor, 7:9] = 0.0
        s[floor, 9] = np.minimum(0.0, s[floor, 9])
        s[floor, 10:13] = 0.0
    x_min, x_max = params.x_bounds
    wall_x = (s[:, 0] < x_min) | (s[:, 0] > x_max)
    s[wall_x, 0], s[wall_x, 7] = state_old[wall_x, 0], 0.0
    y_min, y_max = params.y_bounds
    wall_y = (s[:, 1] < y_min) | (s[:, 1] > y_max)
    s[wall_y, 1], s[wall_y, 8] = state_old[wall_y, 1], 0.0
    ceiling = s[:, 2] < z_min
    s[ceiling, 2], s[ceiling, 9] = state_old[ceiling, 2], 0.0
    return s


def on_floor(state, params):
    """(N,) bool of :func:`quad_drake.dynamics.on_floor`."""
    return state[:, 2] >= params.z_bounds[1]


def outside_room(state, params):
    """(N,) bool of :func:`quad_drake.dynamics.outside_room`."""
    x_min, x_max = params.x_bounds
    y_min, y_max = params.y_bounds
    x, y = state[:, 0], state[:, 1]
    return (x < x_min) | (x > x_max) | (y < y_min) | (y > y_max) | (state[:, 2] < params.z_bounds[0])


def plant_step(state, forces_old, commands, noise_unit, params, dt, fidelity=PHYSICAL):
    """(state_new (N, 13), a_NB (N, 3), forces (N, 4), hit_wall (N,) bool) of
    :func:`quad_drake.dynamics.plant_step`; noise_unit (N, 4) uniforms in [0, 1]."""
    targets = clamped_noisy_commands(
        commands, noise_unit, params.min_motor_thrust, params.max_motor_thrust, params.motor_noise
    )
    forces = motor_lag_step(forces_old, targets, dt, params.motor_tau_up, params.motor_tau_down)
    thrust, mx, my, mz = wrench_from_thrusts(forces, params.arm_length, params.kappa, params.com_offset)
    body_step = rigid_body_step_semi_implicit if fidelity.semi_implicit_euler else rigid_body_step
    new, _ = body_step(state, thrust, (mx, my, mz), params.mass, params.inertia, dt)
    hit_wall = outside_room(new, params)
    new = apply_room_constraints(new, state, params)
    accel = (new[:, 7:10] - state[:, 7:10]) / dt
    if fidelity.float32_state:
        new = new.astype(np.float32).astype(float)
    return new, accel, forces, hit_wall


# ----- sensors ----------------------------------------------------------------


def imu_measurement(q_NB, w_NB_B, a_NB, noise, params, fidelity=PHYSICAL, bias=None):
    """(N, 6) of :func:`quad_drake.sensor_models.imu_measurement`; q_NB (N, 4), w_NB_B (N, 3),
    a_NB (N, 3), noise (N, 6), bias (N, 6) or None (zero)."""
    accelerometer = reference_accelerometer if fidelity.reference_accelerometer else specific_force
    f = np.stack(accelerometer(q_NB.T, a_NB.T), axis=1)
    sa, sg = np.asarray(params.accel_std), np.asarray(params.gyro_std)
    bias = np.zeros((q_NB.shape[0], 6)) if bias is None else bias
    accel = f + bias[:, 0:3] + sa * noise[:, 0:3]
    gyro = w_NB_B + bias[:, 3:6] + sg * noise[:, 3:6]
    limit = params.accel_limit
    return np.concatenate([np.clip(accel, -limit, limit), gyro], axis=1)


def imu_bias_step(bias, noise, params):
    """(N, 6) of :func:`quad_drake.sensor_models.imu_bias_step`."""
    walk = np.asarray(list(params.accel_bias_walk_std) + list(params.gyro_bias_walk_std))
    return bias + walk * noise


def gps_measurements(p_NB, v_NB, random_walk, noise, params):
    """(position (N, 3), velocity (N, 3), random walk (N, 3)) of
    :func:`quad_drake.sensor_models.gps_measurement` (which runs here on the rows)."""
    position, velocity, walk = gps_measurement(p_NB.T, v_NB.T, random_walk.T, noise.T, params)
    return np.stack(position, axis=1), np.stack(velocity, axis=1), np.stack(walk, axis=1)


def magnetometer_yaws(q_NB, noise, params):
    """(N,) of :func:`quad_drake.sensor_models.magnetometer_yaw`; noise (N,)."""
    return wrap_angles(euler_from_quats(q_NB)[2] + params.yaw_std * noise)


# ----- cascade controller -----------------------------------------------------


_wrap_compiled = _compiled(rotations.wrap_to_pi)
_thrusts_compiled = _compiled(dynamics.thrusts_from_wrench)
_cascade_compiled = _compiled(
    cascade.cascade_step,
    altitude_control=_compiled(cascade.altitude_control),
    clamp_collective_thrust=_compiled(
        cascade.clamp_collective_thrust, collective_thrust_limits=_compiled(cascade.collective_thrust_limits)
    ),
    lateral_position_control=_compiled(cascade.lateral_position_control),
    _roll_pitch=_compiled(cascade._roll_pitch),
    yaw_control=_compiled(cascade.yaw_control, wrap_to_pi=_wrap_compiled),
    body_rate_control=_compiled(cascade.body_rate_control),
    thrusts_from_wrench=_thrusts_compiled,
)


@numba.njit(cache=True)
def _cascade_steps(state, reference, integral, dt, params, fidelity, forces, new_integral):
    """Per vehicle i, the scalar cascade step of state[i], reference[i], integral[i]."""
    for i in range(state.shape[0]):
        s, r = state[i], reference[i]
        x = (s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8], s[9], s[10], s[11], s[12])
        ref = (r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9])
        out, new_integral[i] = _cascade_compiled(x, ref, integral[i], dt, params, fidelity)
        forces[i, 0], forces[i, 1], forces[i, 2], forces[i, 3] = out


ControllerTuple = collections.namedtuple(
    "ControllerTuple", [f.name for f in dataclasses.fields(ControllerParams)]
)
FidelityTuple = collections.namedtuple("FidelityTuple", [f.name for f in dataclasses.fields(Fidelity)])
_FROZEN = {ControllerParams: ControllerTuple, Fidelity: FidelityTuple}


def _plain(value):
    if isinstance(value, bool):
        return value
    if isinstance(value, (list, tuple)):
        return tuple(float(v) for v in value)
    return float(value)


def frozen(params):
    """The ControllerParams or Fidelity `params` as a module-level namedtuple (numbers as floats,
    lists as tuples of floats): what the compiled scalar functions read, typed the same for
    every config so that numba's on-disk cache is reused."""
    return _FROZEN[type(params)](*(_plain(getattr(params, f.name)) for f in dataclasses.fields(params)))


def cascade_step(state, reference, integral, dt, params, fidelity=PHYSICAL):
    """(forces (N, 4), integral (N,)) of :func:`quad_drake.control.cascade.cascade_step`;
    state (N, 13), reference (N, 10), integral (N,) m s: the scalar function's code compiled
    by numba, run per vehicle. params, fidelity: ControllerParams and Fidelity, or their
    :func:`frozen` forms (faster)."""
    params = frozen(params) if dataclasses.is_dataclass(params) else params
    fidelity = frozen(fidelity) if dataclasses.is_dataclass(fidelity) else fidelity
    n = state.shape[0]
    forces, new_integral = np.empty((n, 4)), np.empty(n)
    _cascade_steps(
        np.ascontiguousarray(state, dtype=float),
        np.ascontiguousarray(reference, dtype=float),
        np.ascontiguousarray(integral, dtype=float),
        float(dt),
        params,
        fidelity,
        forces,
        new_integral,
    )
    return forces, new_integral
