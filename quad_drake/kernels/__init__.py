"""Compiled kernels below the systems: the pure modules' functions in (n, ...) array form, run by
the LeafSystems of ``quad_drake.systems`` for one vehicle and for a fleet alike.

- ``flight``: the plant step, the IMU and magnetometer samples and the cascade controller, the
  pure functions' own code compiled by numba.
- ``estimation``: the attitude filter, EKF7 and ESKF steps, the gated GPS fusion and covariance
  health, the delay compensation's odometry.

They import the pure modules and numba only (no pydrake, no systems: ``tests/test_packaging.py``).
"""
