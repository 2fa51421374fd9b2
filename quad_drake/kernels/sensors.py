"""Compiled kernels of the aiding sensors (issue 32): the 3-axis magnetometer at 100 Hz, the
scalar ``sensor_models.magnetometer_field``'s own code compiled by numba and run per vehicle (as
``kernels.flight`` does for the IMU and the yaw magnetometer), and the 50 Hz barometer, plain
arithmetic run as is on a fleet's columns (as the GPS).

Shapes: ``state`` (N, 13) in the ``conventions`` layout (p_NB m NED, q_NB wxyz, v_NB m/s,
w_NB_B rad/s). Pure: no RNG, no pydrake."""

import numpy as np

from quad_drake.kernels.flight import _rotate_to_body_compiled
from quad_drake.kernels.jit import compiled, njit_cached
from quad_drake.models import sensor_models

_magnetometer_field_compiled = compiled(
    sensor_models.magnetometer_field, _rotate_to_body=_rotate_to_body_compiled
)


@njit_cached
def magnetometer_field_samples(state, noise, m_N, hard_iron, field_std, stamp, out) -> None:
    """N 3-axis :class:`~quad_drake.systems.sensors.Magnetometer` samples into out (N, 4): m_B of
    :func:`quad_drake.models.sensor_models.magnetometer_field` (gauss, body FRD; its code compiled, run
    per vehicle) of q_NB in state (N, 13) and the unit normal noise (N, 3), and `stamp` s.
    m_N, hard_iron, field_std: 3-tuples of floats (gauss)."""
    for i in range(state.shape[0]):
        quaternion = (state[i, 3], state[i, 4], state[i, 5], state[i, 6])
        sample = _magnetometer_field_compiled(
            quaternion, m_N, hard_iron, (noise[i, 0], noise[i, 1], noise[i, 2]), field_std
        )
        out[i, 0], out[i, 1], out[i, 2] = sample
        out[i, 3] = stamp


def baro_measurements(z_NB, bias, noise, params, floor_z=0.0) -> tuple[np.ndarray, np.ndarray]:
    """(height (N,), bias (N,)) of :func:`quad_drake.models.sensor_models.baro_measurement` (which runs
    here on the columns): z_NB (N,) m NED, bias (N,) m, noise (N, 2) unit normals."""
    return sensor_models.baro_measurement(z_NB, bias, noise.T, params, floor_z)
