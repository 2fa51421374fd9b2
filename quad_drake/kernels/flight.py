"""Batched kernels: the array form of the scalar pure functions, leading axis N (vehicles).

Each function here is the array form of the scalar function it names (``dynamics``,
``sensor_models``, ``control.cascade``), which stays the reference implementation;
``tests/test_kernels.py`` checks every one against it on seeded random inputs to
1e-12. The per-tick steps (plant, IMU, magnetometer, cascade controller) are the scalar
functions' own code compiled by numba (cached on disk, ``kernels.jit.njit_cached``: the JIT cost,
about 2 s, is paid once per machine) and run per vehicle, reading and writing the fleet
systems' port and state arrays in place (no allocation per tick); the 10 Hz GPS and the IMU
bias walk, plain arithmetic, run the scalar helper as is on rows of the transposed arrays.

Shapes: ``state`` (N, 13) in the ``conventions`` layout (p_NB m NED, q_NB wxyz, v_NB m/s,
w_NB_B rad/s); motor forces (N, 4) N; IMU samples (N, 6); references (N, 10). Parameters
are one set for the whole fleet: the compiled kernels take the :func:`frozen` form of the
scalar dataclasses, the numpy ones the dataclasses. Pure: no RNG, no pydrake."""

import collections
import dataclasses

import numpy as np

from quad_drake.config.schema import ControllerParams, GpsParams, ImuParams, MagParams, PhysicsParams
from quad_drake.control import cascade
from quad_drake.kernels.jit import compiled, njit_cached
from quad_drake.models import dynamics, rotations, sensor_models, wind
from quad_drake.models.fidelity import Fidelity

# ----- parameters ------------------------------------------------------------


ControllerTuple = collections.namedtuple(
    "ControllerTuple", [f.name for f in dataclasses.fields(ControllerParams)]
)
PhysicsTuple = collections.namedtuple("PhysicsTuple", [f.name for f in dataclasses.fields(PhysicsParams)])
ImuTuple = collections.namedtuple("ImuTuple", [f.name for f in dataclasses.fields(ImuParams)])
MagTuple = collections.namedtuple("MagTuple", [f.name for f in dataclasses.fields(MagParams)])
GpsTuple = collections.namedtuple("GpsTuple", [f.name for f in dataclasses.fields(GpsParams)])
FidelityTuple = collections.namedtuple("FidelityTuple", [f.name for f in dataclasses.fields(Fidelity)])


def _plain(value):
    if isinstance(value, bool):
        return value
    if isinstance(value, (list, tuple)):
        return tuple(float(v) for v in value)
    return float(value)


def frozen(params) -> tuple:
    """The ControllerParams, PhysicsParams, ImuParams, MagParams, GpsParams or Fidelity `params` as a plain
    tuple of its fields in order (numbers as floats, lists as tuples of floats), typed the same for
    every config so that numba's on-disk cache is reused. A compiled kernel makes it the namedtuple
    of its type above (``PhysicsTuple(*params)``), which the scalar functions read: numba's
    dispatcher types a plain tuple in C, about 3.6 us faster per call than a namedtuple."""
    return tuple(_plain(getattr(params, f.name)) for f in dataclasses.fields(params))


# ----- dynamics ---------------------------------------------------------------


_to_float32_compiled = compiled(dynamics.to_float32)
_rates_compiled = compiled(dynamics._rates)
_coefficients_compiled = compiled(dynamics._coefficients)
_drag_compiled = compiled(dynamics.drag_acceleration, drag_force_body=compiled(dynamics.drag_force_body))
_plant_compiled = compiled(
    dynamics.plant_step,
    has_drag=compiled(dynamics.has_drag),
    drag_acceleration=_drag_compiled,
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
    float32_rounded=compiled(dynamics.float32_rounded, to_float32=_to_float32_compiled),
)


_contacts_compiled = compiled(dynamics.count_contacts, on_floor=compiled(dynamics.on_floor))
_rotate_to_body_compiled = compiled(sensor_models._rotate_to_body)
_delta_velocity_compiled = compiled(
    sensor_models.delta_velocity_step, _rotate_to_body=_rotate_to_body_compiled
)


@njit_cached
def _state_row(state, i):
    """Row i of an (N, 13) state array as a 13-tuple, entry by entry: a row view per vehicle
    costs numba about 20 ns."""
    return (
        state[i, 0], state[i, 1], state[i, 2], state[i, 3], state[i, 4], state[i, 5], state[i, 6],
        state[i, 7], state[i, 8], state[i, 9], state[i, 10], state[i, 11], state[i, 12],
    )  # fmt: skip


@njit_cached
def plant_steps(
    state, forces, commands, noise_unit, column, params, dt, fidelity, accel, contacts, wind, delta_v
) -> None:
    """One :func:`quad_drake.models.dynamics.plant_step` of N vehicles IN PLACE, the scalar function's
    code compiled and run per vehicle, with ``systems.plant.QuadrotorPlant``'s contact counts and
    body-frame delta-velocity.

    state (N, 13) and forces (N, 4) N (the lagged motor forces before the step): replaced by
    their values after dt s; commands (N, 4) N; noise_unit (N, >= column + 4): the step's four
    uniforms in [0, 1] are columns column..column + 3 (the plant's two steps per tick share one
    (N, 8) draw); accel (N, 3): a_NB m/s^2 of the step, written; contacts (N, 3): (on the floor
    0/1, floor touchdowns, wall hits), updated by :func:`quad_drake.models.dynamics.count_contacts` (its
    code compiled). wind (N, 3): the air's velocity, m/s, NED (acts through the drag only);
    delta_v (N, 3): the body-frame delta-velocity (m/s, FRD) of the onboard tick so far, set to
    this step's :func:`quad_drake.models.sensor_models.delta_velocity_step` when column is 0 (the
    tick's first step) and added to otherwise. params, fidelity: the :func:`frozen`
    PhysicsParams and Fidelity; dt: a float.
    """
    physics, fidelity_tuple = PhysicsTuple(*params), FidelityTuple(*fidelity)
    for i in range(state.shape[0]):  # entries indexed in place (see _state_row)
        x = _state_row(state, i)
        lagged_before = (forces[i, 0], forces[i, 1], forces[i, 2], forces[i, 3])
        command = (commands[i, 0], commands[i, 1], commands[i, 2], commands[i, 3])
        c = column
        noise = (noise_unit[i, c], noise_unit[i, c + 1], noise_unit[i, c + 2], noise_unit[i, c + 3])
        air = (wind[i, 0], wind[i, 1], wind[i, 2])
        out, a, lagged, hit_wall = _plant_compiled(
            x, lagged_before, command, noise, physics, dt, fidelity_tuple, air
        )
        dv = _delta_velocity_compiled((x[3], x[4], x[5], x[6]), (out[3], out[4], out[5], out[6]), a, dt)
        if column == 0:
            delta_v[i, 0], delta_v[i, 1], delta_v[i, 2] = dv
        else:
            delta_v[i, 0] += dv[0]
            delta_v[i, 1] += dv[1]
            delta_v[i, 2] += dv[2]
        for k in range(13):
            state[i, k] = out[k]
        accel[i, 0], accel[i, 1], accel[i, 2] = a
        for k in range(4):
            forces[i, k] = lagged[k]
        contacts[i, 0], contacts[i, 1], contacts[i, 2] = _contacts_compiled(
            (contacts[i, 0], contacts[i, 1], contacts[i, 2]), out, hit_wall, physics
        )


def on_floor(state, params) -> np.ndarray:
    """(N,) bool of :func:`quad_drake.models.dynamics.on_floor`."""
    return state[:, 2] >= params.z_bounds[1]


# ----- wind -------------------------------------------------------------------


turbulence_filter_rows = compiled(wind.filter_rows)
""":func:`quad_drake.models.wind.filter_rows` compiled: the Dryden filters of N vehicles, in place."""
turbulence_velocity_rows = compiled(wind.velocity_rows)
""":func:`quad_drake.models.wind.velocity_rows` compiled: (N, 3) NED turbulence of the filter states."""
wind_rows = compiled(
    wind.wind_rows, filter_rows=turbulence_filter_rows, velocity_rows=turbulence_velocity_rows
)
""":func:`quad_drake.models.wind.wind_rows` compiled: one tick of ``systems.wind.Wind`` for N vehicles."""


# ----- sensors ----------------------------------------------------------------


_from_specific_force_compiled = compiled(
    sensor_models.imu_from_specific_force,
    _clamp=compiled(sensor_models._clamp),
    to_float32=_to_float32_compiled,
)
_imu_compiled = compiled(
    sensor_models.imu_measurement,
    reference_accelerometer=compiled(
        sensor_models.reference_accelerometer, _rotate_to_body=_rotate_to_body_compiled
    ),
    specific_force=compiled(sensor_models.specific_force, _rotate_to_body=_rotate_to_body_compiled),
    imu_from_specific_force=_from_specific_force_compiled,
)
_saturated_compiled = compiled(sensor_models.imu_saturated)


@njit_cached
def imu_samples(state, a_NB, noise, params, fidelity, bias, out, delta_v, interval, saturation) -> None:
    """:func:`quad_drake.models.sensor_models.imu_measurement` of N vehicles into out (N, 6), the scalar
    function's code compiled and run per vehicle: q_NB and w_NB_B from state (N, 13), a_NB (N, 3),
    noise (N, 6) unit normals, bias (N, 6). With ImuParams.delta_velocity the accelerometer reads
    instead the mean specific force delta_v / interval (delta_v (N, 3) m/s, body FRD, over the
    `interval` s before the sample) through :func:`quad_drake.models.sensor_models.imu_from_specific_force`.
    saturation (N, 2): the saturated samples so far (accelerometer, gyro), counted by
    :func:`quad_drake.models.sensor_models.imu_saturated`. params, fidelity: the :func:`frozen` ImuParams
    and Fidelity."""
    imu, fidelity_tuple = ImuTuple(*params), FidelityTuple(*fidelity)
    for i in range(state.shape[0]):  # entries indexed in place (see _state_row)
        w = (state[i, 10], state[i, 11], state[i, 12])
        n = (noise[i, 0], noise[i, 1], noise[i, 2], noise[i, 3], noise[i, 4], noise[i, 5])
        b = (bias[i, 0], bias[i, 1], bias[i, 2], bias[i, 3], bias[i, 4], bias[i, 5])
        if imu.delta_velocity:
            f = (delta_v[i, 0] / interval, delta_v[i, 1] / interval, delta_v[i, 2] / interval)
            sample = _from_specific_force_compiled(f, w, n, imu, fidelity_tuple, b)
        else:
            q = (state[i, 3], state[i, 4], state[i, 5], state[i, 6])
            a = (a_NB[i, 0], a_NB[i, 1], a_NB[i, 2])
            sample = _imu_compiled(q, w, a, n, imu, fidelity_tuple, b)
        for k in range(6):
            out[i, k] = sample[k]
        accel_saturated, gyro_saturated = _saturated_compiled(sample, imu)
        saturation[i, 0] += accel_saturated
        saturation[i, 1] += gyro_saturated


def imu_bias_step(bias, noise, params) -> np.ndarray:
    """(N, 6) of :func:`quad_drake.models.sensor_models.imu_bias_step`."""
    walk = np.asarray(list(params.accel_bias_walk_std) + list(params.gyro_bias_walk_std))
    return bias + walk * noise


_gps_compiled = compiled(
    sensor_models.gps_measurement, _float32_entries=compiled(sensor_models._float32_entries)
)


@njit_cached
def gps_samples(state, walk, noise, params, fidelity, stamp, out) -> None:
    """N :class:`~quad_drake.systems.sensors.Gps` samples into out (N, 7): p_N m, v_N m/s of
    :func:`quad_drake.models.sensor_models.gps_measurement` (its code compiled, run per vehicle) of
    p_NB, v_NB in state (N, 13), the random-walk bias walk (N, 3) m (stepped IN PLACE) and the
    unit normal noise (N, 9: 3 walk, 3 position, 3 velocity), and `stamp` s. params, fidelity:
    the :func:`frozen` GpsParams and Fidelity."""
    gps, fidelity_tuple = GpsTuple(*params), FidelityTuple(*fidelity)
    for i in range(state.shape[0]):
        position, velocity, new_walk = _gps_compiled(
            (state[i, 0], state[i, 1], state[i, 2]),
            (state[i, 7], state[i, 8], state[i, 9]),
            (walk[i, 0], walk[i, 1], walk[i, 2]),
            (noise[i, 0], noise[i, 1], noise[i, 2], noise[i, 3], noise[i, 4], noise[i, 5], noise[i, 6],
             noise[i, 7], noise[i, 8]),
            gps,
            fidelity_tuple,
        )  # fmt: skip
        for k in range(3):
            out[i, k], out[i, 3 + k], walk[i, k] = position[k], velocity[k], new_walk[k]
        out[i, 6] = stamp


_wrap_compiled = compiled(rotations.wrap_to_pi)
_magnetometer_compiled = compiled(
    sensor_models.magnetometer_yaw,
    euler_from_quat=compiled(rotations.euler_from_quat),
    wrap_to_pi=_wrap_compiled,
    to_float32=_to_float32_compiled,
)


@njit_cached
def magnetometer_samples(state, noise, params, fidelity, stamp, out) -> None:
    """N :class:`~quad_drake.systems.sensors.Magnetometer` samples into out (N, 2): the yaw of
    :func:`quad_drake.models.sensor_models.magnetometer_yaw` (its code compiled, run per vehicle) of
    q_NB in state (N, 13) and the unit normal noise (N, 1), rad; and `stamp` s. params, fidelity:
    the :func:`frozen` MagParams and Fidelity."""
    mag, fidelity_tuple = MagTuple(*params), FidelityTuple(*fidelity)
    for i in range(state.shape[0]):
        quaternion = (state[i, 3], state[i, 4], state[i, 5], state[i, 6])
        out[i, 0] = _magnetometer_compiled(quaternion, noise[i, 0], mag, fidelity_tuple)
        out[i, 1] = stamp


# ----- cascade controller -----------------------------------------------------


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


@njit_cached
def cascade_steps(state, reference, integral, dt, params, fidelity, forces) -> None:
    """:func:`quad_drake.control.cascade.cascade_step` of N vehicles, the scalar function's code
    compiled and run per vehicle: state (N, 13), reference (N, 10), integral (N,) m s (replaced by
    the new integral), dt s (a float); forces (N, 4) N, written. params, fidelity: the
    :func:`frozen` ControllerParams and Fidelity."""
    controller, fidelity_tuple = ControllerTuple(*params), FidelityTuple(*fidelity)
    for i in range(state.shape[0]):  # entries indexed in place (see _state_row)
        x = _state_row(state, i)
        ref = (
            reference[i, 0], reference[i, 1], reference[i, 2], reference[i, 3], reference[i, 4],
            reference[i, 5], reference[i, 6], reference[i, 7], reference[i, 8], reference[i, 9],
        )  # fmt: skip
        out, integral[i] = _cascade_compiled(x, ref, integral[i], dt, controller, fidelity_tuple)
        forces[i, 0], forces[i, 1], forces[i, 2], forces[i, 3] = out
