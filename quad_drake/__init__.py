"""quad_drake: quadrotor state-estimation and control simulator on Drake.

Conventions (stated once, used everywhere):

- World frame N is NED (x north, y east, z down); body frame B is FRD
  (x forward, y right, z down). Thrust acts along -Bz. Gravity is
  ``GRAVITY_N = (0, 0, +9.81)`` m/s^2; an altitude of 1 m is z = -1.
- Quaternions are wxyz (Drake order), Hamilton, and map body to world.
  Euler angles are ZYX: ``R_NB = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
  Every yaw difference goes through :func:`quad_drake.models.rotations.wrap_to_pi`.
- Names follow Drake's monogram notation: ``p_NB`` (position of B in N,
  expressed in N), ``v_NB``, ``R_NB``, ``w_NB_B`` (angular velocity of B in N,
  expressed in B).
- The accelerometer measures the physical specific force
  ``f_B = R_NB^T (a_NB - g_N)``, i.e. (0, 0, -9.81) when level at rest. This
  deliberately differs from the reference simulator's formula.
- SI units and radians throughout. Noise fields named ``*_std`` are the
  standard deviation of one sample.
- Truth parameters (what the simulator injects) are separate from what the
  controller and the estimators assume; any mismatch is explicit in config.

Architecture, floor by floor (a module imports its own floor or lower ones; no file circle;
``tests/test_packaging.py`` checks both on every module's import closure):

- ``conventions``: the shared constants;
- pure (numpy, scipy; no pydrake but the YAML of ``config.loader``): ``config`` (errors, fields,
  schema, validation, saved, loader), ``models`` (rotations, dynamics, sensor models, trajectories,
  wind, faults, fidelity, random streams, accuracy bounds), ``estimation``, ``control`` and the
  reading of flight logs (``flightlogs.reader``, ``flightlogs.schedule``);
- ``kernels``: the pure functions compiled by numba (``kernels.jit``), in (n, ...) array form;
- ``judging``: named signals, the reference's analyzers, verdicts, consistency statistics;
- ``systems``: the Drake LeafSystems, thin glue over the floors below, each sized by n;
- ``output``: run folders, results, plots, reports, CSV export, the Meshcat animation;
- ``running``: the scenario catalog, cost limits, the Diagram and its run (``simulation``);
- ``campaigns`` (with ``campaigns.fleet``), ``tuning``, ``flightlogs`` (replay): many runs;
- ``cli``: the front end (nothing in the package imports it).
"""

__version__ = "0.3.0.dev0"
