"""The pure rotation formulas of ``quad_drake.models.rotations`` compiled once (their own code, numba),
for the estimator kernels and the fleet's PCRB: nothing here is re-typed. Pure: no pydrake."""

from collections.abc import Callable

from quad_drake.kernels.jit import compiled, njit_cached
from quad_drake.models import rotations

wrap_to_pi: Callable = compiled(rotations.wrap_to_pi)
quat_from_euler: Callable = compiled(rotations.quat_from_euler_tuple)
euler_from_quat: Callable = compiled(rotations.euler_from_quat)
quat_product: Callable = compiled(rotations.quat_product)
rotation_entries: Callable = compiled(rotations.rotation_entries)


@njit_cached
def rotation_into(qw, qx, qy, qz, R) -> None:
    """Write R_NB of a unit wxyz quaternion into R (3, 3) (``rotations.rotation_entries``)."""
    r = rotation_entries(qw, qx, qy, qz)
    R[0, 0], R[0, 1], R[0, 2] = r[0], r[1], r[2]
    R[1, 0], R[1, 1], R[1, 2] = r[3], r[4], r[5]
    R[2, 0], R[2, 1], R[2, 2] = r[6], r[7], r[8]
