"""Fidelity modes: the physical default, or the reference binary's numerics (README "Fidelity").

A scenario's ``fidelity`` field picks a mode; :func:`fidelity_from_mode` turns it into a
frozen :class:`Fidelity` that the pure modules and the systems take as an argument.

``physical`` (the default, what a user should trust): an RK4 rigid body, the physical
accelerometer f_B = R_NB^T (a_NB - g_N), the lateral acceleration command limited by its
horizontal norm, the trajectory looked up at the exact simulation time.

``reference`` reproduces the FCND E-sim binary (SPEC §2, §3, §5 step 4, §0.2): its
semi-implicit Euler body step, its float32 vehicle state, its accelerometer R_NB^T (a_NB + g_N)
(and the estimators read it as the reference's do), its 3-D norm limit of the lateral acceleration command
(z entry -kp_vel_xy vz), its float32 clock advanced by 0.001f per physics step, its sensors
and estimator stored in float32, its estimator without innovation gates, resets or covariance
repair, its altitude integral without anti-windup, its logged errors taken at the last
onboard tick, and its number of log samples (5,001 in 25 s).
"""

from dataclasses import dataclass

FIDELITY_MODES = ("physical", "reference")
"""Allowed values of ``ScenarioConfig.fidelity``."""


@dataclass(frozen=True)
class Fidelity:
    """Which of the reference's numerics are switched on (all off: the physical default).

    semi_implicit_euler: plant body step of SPEC §3 steps 4-6 instead of RK4.
    float32_state: the plant state is rounded to float32 after every step, as the reference
        stores it (V3F, Quaternion<float>). It matters: at 3 m from the origin a float32
        position cannot move by less than 2.4e-7 m per step, so the reference's 08 vehicle
        comes to rest 3.1e-5 m off its set-point with a residual 6e-5 m/s velocity.
    reference_accelerometer: the IMU reads R_NB^T (a_NB + g_N) (SPEC §2; (0, 0, +9.81) level
        at rest) instead of the specific force; the attitude filter and the EKF read it with
        the reference's formulas (tilt atan2(ay, az), atan2(-ax, g); a_N = R f - g_N).
    lateral_limit_3d: the lateral acceleration command is rescaled by the norm of
        (ax, ay, -kp_vel_xy vz) (SPEC §5 step 4) instead of the norm of (ax, ay).
    float32_clock: the trajectory is looked up at the reference's float32 simulation time,
        0.001f added once per physics step (SPEC §0.2), instead of the exact time.
    float32_estimator: the sensors' samples (IMU, GPS with its random walk, magnetometer), the
        attitude filter's angles and body rate and the EKF7's state and covariance are rounded
        to float32 after every sample and every 500 Hz tick, as the reference stores them
        (V3F, float, Eigen's VectorXf/MatrixXf). Rounded where stored, not after every
        operation as the binary's float arithmetic is. It matters: a float32 position stops
        moving when the per-tick increment is below half its resolution (6e-8 m at |z| = 1 m),
        and a constant velocity's increments round the same way tick after tick. The ESKF is
        not the reference's estimator and is not rounded.
    errors_at_onboard_tick: the logged ``Est.E.*`` errors, ``PosFollowErr`` and ``Ref.*`` are
        the binary's (SPEC §7, §0.2): computed at the last onboard (2 ms) tick before each 5 ms
        sample, against that tick's true state and reference (1 or 2 ms before the sample),
        instead of the estimate held at the sample against the truth and the reference at the
        sample time (``signals``). The truth signals (``Pos.*``, ``Roll`` ...) are the sample's
        in both definitions, as the binary's are.
    reference_estimator: the estimators fuse every sample as the reference's EKF does: no
        innovation gates, no resets to the GPS, no covariance repair (``estimation/gating.py``).
    reference_log_samples: the log holds the binary's samples: it samples every 5 ms until its
        float32 clock (``float32_clock``) has reached end_time at the start of a 5 ms frame, so
        a 25 s run logs 5,001 samples (t = 0.005 ... 25.005 s; its clock reads 25.0029 at the
        last) where the physical default logs 5,000 (0.005 ... 25.000 s). With it a "value at
        the last sample" is the binary's (SPEC §0.2's table; the golden traces' row counts).
    altitude_integral_windup: the altitude-error integral keeps integrating while the collective
        thrust is clamped, as the reference's controller does; the physical default holds it
        there (anti-windup), so a large height error after a GPS regain or a floor strike does
        not wind it up into a divergent vertical oscillation (``control.cascade.cascade_step``).
    """

    semi_implicit_euler: bool = False
    float32_state: bool = False
    reference_accelerometer: bool = False
    lateral_limit_3d: bool = False
    float32_clock: bool = False
    float32_estimator: bool = False
    errors_at_onboard_tick: bool = False
    reference_estimator: bool = False
    altitude_integral_windup: bool = False
    reference_log_samples: bool = False


PHYSICAL = Fidelity()
REFERENCE = Fidelity(
    semi_implicit_euler=True,
    float32_state=True,
    reference_accelerometer=True,
    lateral_limit_3d=True,
    float32_clock=True,
    float32_estimator=True,
    errors_at_onboard_tick=True,
    reference_estimator=True,
    altitude_integral_windup=True,
    reference_log_samples=True,
)


def fidelity_from_mode(mode) -> Fidelity:
    """The :class:`Fidelity` of a mode name in :data:`FIDELITY_MODES`."""
    if mode == "physical":
        return PHYSICAL
    if mode == "reference":
        return REFERENCE
    raise ValueError(f"unknown fidelity mode {mode!r}; expected one of {', '.join(FIDELITY_MODES)}")
