"""Compiled kernels below the systems: the pure modules' functions in (n, ...) array form, run by
the LeafSystems of ``quad_drake.systems`` for one vehicle and for a fleet alike.

- ``flight``: the plant step, the IMU and magnetometer samples and the cascade controller, the
  pure functions' own code compiled by numba (and ``compiled``, ``frozen``: how to compile one).
- ``rotations``: ``quad_drake.rotations``' formulas compiled once for the estimator kernels.
- ``imu_hold``: the estimators' running mean of the IMU, dead-reckoned on over a dropout.
- ``attitude``: the complementary attitude filter.
- ``ekf7``, ``eskf``: the two estimators' ticks; each module's docstring carries its equations.
- ``fusion``: what both estimators share: freshness, books, the mag gate, the GPS Joseph update
  and gated policy, covariance health and repair.
- ``sensors``: the 3-axis magnetometer's samples (compiled) and the barometer's (on the columns).
- ``aiding``: both estimators' barometer and 3-axis magnetometer fusion (``estimation/baro.py``,
  ``estimation/mag3.py`` compiled): the gates, the baro bias filter, the field and the heading.

They import the pure modules and numba only (no pydrake, no systems: ``tests/test_packaging.py``);
no kernel re-types a pure formula: the scalar ones are compiled from their own code, and the
matrix forms that stay in ``estimation/`` are named reference oracles the kernels are tested against.
"""
