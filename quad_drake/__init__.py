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

Architecture: pure math modules (``rotations``, ``dynamics``, ``sensor_models``,
``estimation``, ``control``, ``trajectories``, ``evaluation``) under thin Drake
glue in ``systems``; ``simulation`` wires the Diagram, ``catalog`` finds and loads
scenarios, ``cli`` is the front end (nothing in the package imports it).
"""

__version__ = "0.3.0.dev0"
