"""Compiled kernels below the systems: the pure modules' functions in (n, ...) array form, run by
the LeafSystems of ``quad_drake.systems`` for one vehicle and for a fleet alike.

- ``flight``: the plant step, the IMU and magnetometer samples and the cascade controller, the
  pure functions' own code compiled by numba (and ``compiled``, ``frozen``: how to compile one).
- ``rotations``: ``quad_drake.models.rotations``' formulas compiled once for the estimator kernels.
- ``imu_hold``: the estimators' running mean of the IMU, dead-reckoned on over a dropout.
- ``attitude``: the complementary attitude filter.
- ``ekf7``, ``eskf``: the two estimators' ticks; each module's docstring carries its equations.
- ``fusion``: what both estimators share: freshness, books, the mag gate, the GPS Joseph update
  and gated policy (the correction applied by the estimator's ``correct``), covariance health
  and repair.
- ``sensors``: the 3-axis magnetometer's samples (compiled) and the barometer's (on the columns).
- ``aiding``: both estimators' barometer and 3-axis magnetometer fusion (``estimation/baro.py``,
  ``estimation/mag3.py`` compiled): the gates, the baro bias filter, the field and the heading.

They import the pure modules and numba only (no pydrake, no systems: ``tests/test_packaging.py``).

The rule for what lives here, and in what form:

1. A kernel exists only for a speed reason. Maths that runs once a tick as numpy over all the
   vehicles' rows needs none: the pure function itself takes (N, ...) arrays (e.g.
   ``estimation/delay_compensation.py``, called by ``systems.faults`` directly).
2. No kernel re-types a pure formula: a scalar formula is compiled from its own code
   (``flight.compiled``), with its callees replaced by their compiled forms.
3. What runs every tick for every vehicle (the predictions, the covariance health check, the
   quiet-tick yaw update folded into the EKF7's tick) may be hand-unrolled over the few
   nonzeros; its matrix form stays in ``estimation/`` as a named reference oracle, tested against
   the kernel at 1e-12 (``tests/test_estimator_kernels.py``) and never flown
   (``tests/test_oracles.py``).
4. What runs only when a sample is fused (the magnetometer updates, the ESKF injection, the
   aiding updates) is the oracle's own code compiled, unless ``benchmarks/bench_fleet_estimators.py``
   (N = 1000, paired against the row form, CPU time) shows the compiled oracle costing 3 % or more;
   then the hand-written row form stays, with its oracle tested against it at 1e-12 and never
   flown, as in rule 3. Measured for the yaw magnetometer updates and the ESKF injection (the
   dense oracles allocate their outer products and call BLAS for every fused vehicle): the
   compiled ``ekf.mag_update`` cost the EKF7 +13 % per vehicle-tick and the compiled
   ``eskf.mag_update`` and ``eskf.inject`` cost the ESKF +43 % (median of 8 paired rounds; per
   fused vehicle 0.45 us against 0.13 us, 2.7 against 0.36 and, the injection, 0.94 against
   0.13), so ``ekf7._mag_update_row``, ``eskf._mag_update_row`` and ``eskf._inject_row`` stay.
   The aiding updates are ``estimation/baro.py`` and ``estimation/mag3.py`` compiled.
5. How a correction is applied is the estimator's (``ekf7.correct``: added; ``eskf.correct``:
   injected); the measurement kernels write the correction dx and the fused flags, and
   ``systems/updates.py`` hands them to it.
"""
