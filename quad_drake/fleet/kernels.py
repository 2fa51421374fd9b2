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

from quad_drake import dynamics, rotations, sensor_models
from quad_drake.config import ControllerParams, ImuParams, PhysicsParams
from quad_drake.control import cascade
from quad_drake.fidelity import PHYSICAL, Fidelity
from quad_drake.rotations import euler_from_quats, wrap_angles
from quad_drake.sensor_models import gps_measurement

# ----- dynamics ---------------------------------------------------------------


def compiled(function, **callees):
    """The scalar `function`'s own code compiled by numba (nopython, cached on disk), with the
    module globals it calls replaced by their compiled forms `callees`."""
    namespace = dict(function.__globals__, **callees)
    return numba.njit(types.FunctionType(function.__code__, namespace, function.__name__), cache=True)


_rates_compiled = compiled(dynamics._rates)
_coefficients_compiled = compiled(dynamics._coefficients)
_plant_compiled = compiled(
    dynamics.plant_step,
    clamped_noisy_commands=compiled(dynamics.clamped_noisy_commands),
    motor_lag_step=compiled(dynamics.motor_lag_step),
    wrench_from_thrusts=compiled(dynamics.wrench_from_thrusts),
    rigid_body_step=compiled(
        dynamics.rigid_body_step, _rates=_rates_compiled, _coefficients=_coefficients_compiled
    ),
    rigid_body_step_semi_implicit=compiled(
        dynamics.rigid_body_step_semi_implicit, _rates=_rates_compiled, _coefficients=_coefficients_compiled
    ),
    outside_room=compiled(dynamics.outside_room),
    apply_room_constraints=compiled(dynamics.apply_room_constraints),
    float32_rounded=compiled(dynamics.float32_rounded, _float32=compiled(dynamics._float32)),
)


@numba.njit(cache=True)
def _plant_steps(state, forces_old, commands, noise_unit, params, dt, fidelity, new, accel, forces, hit_wall):
    """Per vehicle i, the scalar plant step of row i of the inputs into row i of the outputs."""
    for i in range(state.shape[0]):
        s, f, u, m = state[i], forces_old[i], noise_unit[i], commands[i]
        x = (s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8], s[9], s[10], s[11], s[12])
        lagged_before, command = (f[0], f[1], f[2], f[3]), (m[0], m[1], m[2], m[3])
        noise = (u[0], u[1], u[2], u[3])
        out, a, lagged, hit_wall[i] = _plant_compiled(x, lagged_before, command, noise, params, dt, fidelity)
        for k in range(13):
            new[i, k] = out[k]
        accel[i, 0], accel[i, 1], accel[i, 2] = a
        for k in range(4):
            forces[i, k] = lagged[k]


def on_floor(state, params):
    """(N,) bool of :func:`quad_drake.dynamics.on_floor`."""
    return state[:, 2] >= params.z_bounds[1]


def plant_step(state, forces_old, commands, noise_unit, params, dt, fidelity=PHYSICAL):
    """(state_new (N, 13), a_NB (N, 3), forces (N, 4), hit_wall (N,) bool) of
    :func:`quad_drake.dynamics.plant_step`, whose code numba compiles and runs per vehicle;
    noise_unit (N, 4) uniforms in [0, 1]. params, fidelity: PhysicsParams and Fidelity, or
    their :func:`frozen` forms (faster)."""
    params = frozen(params) if dataclasses.is_dataclass(params) else params
    fidelity = frozen(fidelity) if dataclasses.is_dataclass(fidelity) else fidelity
    n = state.shape[0]
    new, accel, forces, hit_wall = np.empty((n, 13)), np.empty((n, 3)), np.empty((n, 4)), np.empty(n, bool)
    _plant_steps(
        *(np.ascontiguousarray(a, dtype=float) for a in (state, forces_old, commands, noise_unit)),
        params,
        float(dt),
        fidelity,
        new,
        accel,
        forces,
        hit_wall,
    )
    return new, accel, forces, hit_wall


# ----- sensors ----------------------------------------------------------------


_rotate_to_body_compiled = compiled(sensor_models._rotate_to_body)
_imu_compiled = compiled(
    sensor_models.imu_measurement,
    reference_accelerometer=compiled(
        sensor_models.reference_accelerometer, _rotate_to_body=_rotate_to_body_compiled
    ),
    specific_force=compiled(sensor_models.specific_force, _rotate_to_body=_rotate_to_body_compiled),
    _clamp=compiled(sensor_models._clamp),
)


@numba.njit(cache=True)
def _imu_samples(q_NB, w_NB_B, a_NB, noise, params, fidelity, bias, out):
    """Per vehicle i, the scalar IMU sample of row i of the inputs into out[i]."""
    for i in range(q_NB.shape[0]):
        q, w, a, u, b = q_NB[i], w_NB_B[i], a_NB[i], noise[i], bias[i]
        sample = _imu_compiled(
            (q[0], q[1], q[2], q[3]),
            (w[0], w[1], w[2]),
            (a[0], a[1], a[2]),
            (u[0], u[1], u[2], u[3], u[4], u[5]),
            params,
            fidelity,
            (b[0], b[1], b[2], b[3], b[4], b[5]),
        )
        for k in range(6):
            out[i, k] = sample[k]


def imu_measurement(q_NB, w_NB_B, a_NB, noise, params, fidelity=PHYSICAL, bias=None):
    """(N, 6) of :func:`quad_drake.sensor_models.imu_measurement`, whose code numba compiles and
    runs per vehicle; q_NB (N, 4), w_NB_B (N, 3), a_NB (N, 3), noise (N, 6), bias (N, 6) or
    None (zero). params, fidelity: ImuParams and Fidelity, or their :func:`frozen` forms."""
    params = frozen(params) if dataclasses.is_dataclass(params) else params
    fidelity = frozen(fidelity) if dataclasses.is_dataclass(fidelity) else fidelity
    n = q_NB.shape[0]
    bias = np.zeros((n, 6)) if bias is None else bias
    out = np.empty((n, 6))
    _imu_samples(
        *(np.ascontiguousarray(x, dtype=float) for x in (q_NB, w_NB_B, a_NB, noise)),
        params,
        fidelity,
        np.ascontiguousarray(bias, dtype=float),
        out,
    )
    return out


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


_wrap_compiled = compiled(rotations.wrap_to_pi)
_thrusts_compiled = compiled(dynamics.thrusts_from_wrench)
_cascade_compiled = compiled(
    cascade.cascade_step,
    altitude_control=compiled(cascade.altitude_control),
    clamp_collective_thrust=compiled(
        cascade.clamp_collective_thrust, collective_thrust_limits=compiled(cascade.collective_thrust_limits)
    ),
    lateral_position_control=compiled(cascade.lateral_position_control),
    _roll_pitch=compiled(cascade._roll_pitch),
    yaw_control=compiled(cascade.yaw_control, wrap_to_pi=_wrap_compiled),
    body_rate_control=compiled(cascade.body_rate_control),
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
PhysicsTuple = collections.namedtuple("PhysicsTuple", [f.name for f in dataclasses.fields(PhysicsParams)])
ImuTuple = collections.namedtuple("ImuTuple", [f.name for f in dataclasses.fields(ImuParams)])
FidelityTuple = collections.namedtuple("FidelityTuple", [f.name for f in dataclasses.fields(Fidelity)])
_FROZEN = {
    ControllerParams: ControllerTuple,
    PhysicsParams: PhysicsTuple,
    ImuParams: ImuTuple,
    Fidelity: FidelityTuple,
}


def _plain(value):
    if isinstance(value, bool):
        return value
    if isinstance(value, (list, tuple)):
        return tuple(float(v) for v in value)
    return float(value)


def frozen(params):
    """The ControllerParams, PhysicsParams, ImuParams or Fidelity `params` as a module-level
    namedtuple (numbers as floats, lists as tuples of floats): what the compiled scalar
    functions read, typed the same for every config so that numba's on-disk cache is reused."""
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
