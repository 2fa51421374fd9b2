"""Pure: the no-aiding failsafe (PX4's ``EKF2_NOAID_TOUT`` and the commander's land failsafe).

A flight stack stops trusting its horizontal position when no position measurement has been
fused for a while: PX4's EKF2 declares the local position invalid after ``EKF2_NOAID_TOUT``
(5 s by default) without aiding, and the commander then switches to a failsafe that no longer
needs it (descend and land, holding the attitude level and the height on the barometer). This
module is that supervisor, one scalar tick per vehicle, between the trajectory and the cascade
controller (``systems/failsafe.py`` runs it for n vehicles, its compiled form
``kernels/failsafe.py``).

**Position aiding** is read from the estimator's ``diagnostics`` (``estimation/vocabulary.py``):
a fresh GPS sample (its stamp changed) aids the position when the estimator fused it whole
(the count of gated samples did not grow) or reset to it (the count of resets grew). The time
without aiding is ``t - last_aided`` (s; the start, t = 0, counts as aided: the vehicle starts
where it was told). The horizontal position is **valid** while that time is at most
``no_aiding_timeout``.

**Phases** (``FailsafeConfig``):

- ``NOMINAL`` (0): the trajectory's reference passes through.
- ``DESCENDING`` (1), entered when the position becomes invalid: the horizontal loop is told the
  vehicle is where its estimate says (p_ref = p_hat, so no position error acts) and, with
  ``brake``, to hold zero velocity (the estimated velocity is damped: it drifts far slower than
  the dead-reckoned position); without ``brake``, v_ref = v_hat, a zero horizontal acceleration
  command: level attitude. The height set-point starts at the estimated height (the barometer's,
  where it is fused) and moves down at ``descent_rate`` m/s (feed-forward vz_ref = descent_rate);
  the yaw is held at the estimate's yaw at entry. When the position becomes valid again in flight
  and ``resume_on_aiding`` is set, the phase returns to NOMINAL (the mission resumes).
- ``LANDED`` (2): the land detector (PX4's idea: commanded down, not descending) found the vehicle
  on the ground: the descending height set-point has run more than ``landed_lag`` m below the
  estimated height for ``landed_time`` s in a row (in the air the altitude loop follows it within
  a few cm). The estimated vertical *speed* is not used: without position aiding it drifts by up
  to 1.6 m/s while the barometer holds the height (measured on the ESKF resting on the floor). The
  motors go to idle (``systems/failsafe.py``) and the phase stays LANDED.

Memory layout per vehicle (:data:`MEMORY`), the supervisor's discrete state. Frames: p, v NED
(m, m/s), z down; the reference layout is ``conventions.REFERENCE_SIZE`` (p, v, a feed-forward, yaw).
"""

import math

NOMINAL, DESCENDING, LANDED = 0.0, 1.0, 2.0

MEMORY = (
    "phase",  # NOMINAL, DESCENDING or LANDED
    "last_aided",  # s, stamp of the last GPS sample that aided the position (0: the start)
    "gps_stamp",  # s, the last GPS stamp seen in the diagnostics (-1: none yet)
    "gps_gated",  # the estimator's count of gated GPS samples at that stamp
    "gps_resets",  # its count of resets to the GPS at that stamp
    "z_ref",  # m, NED down: the descent's height set-point
    "yaw_hold",  # rad, the yaw held while the failsafe flies
    "below_since",  # s, since when the set-point is landed_lag below the estimate (NaN: it is not)
)
MEMORY_SIZE = len(MEMORY)
STATUS = ("position_valid", "no_aiding_time", "phase")
"""The status output per vehicle: 1/0 horizontal position valid, s since the last position
aiding, the phase (NOMINAL, DESCENDING, LANDED)."""
STATUS_SIZE = len(STATUS)


def initial_memory() -> tuple:
    """One vehicle's memory before its first tick (:data:`MEMORY`): nominal, aided at t = 0."""
    return (NOMINAL, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, math.nan)


def failsafe_step(memory, t, dt, gps_stamp, gps_gated, gps_resets, estimate, reference, params) -> tuple:
    """One supervisor tick at t s (dt s since the last): (new memory, reference to fly, status).

    memory: :data:`MEMORY` tuple; gps_stamp (s, -1: none), gps_gated, gps_resets: the estimator's
    diagnostics (``gps_stamp``, ``gps_gated``, ``gps_resets``); estimate: the 13-entry estimated
    state (p m NED, q wxyz, v m/s NED, w rad/s FRD); reference: the trajectory's 10-tuple
    reference (p, v, a, yaw); params: a FailsafeConfig (or its frozen tuple). Returns the memory,
    the 10-entry reference for the controller and the :data:`STATUS` 3-tuple.
    """
    phase, last_aided, seen_stamp, seen_gated, seen_resets, z_ref, yaw_hold, below_since = memory
    if gps_stamp >= 0.0 and gps_stamp != seen_stamp:
        if gps_gated == seen_gated or gps_resets > seen_resets:
            last_aided = gps_stamp
        seen_stamp, seen_gated, seen_resets = gps_stamp, gps_gated, gps_resets
    no_aiding = t - last_aided
    valid = no_aiding <= params.no_aiding_timeout

    px, py, pz, qw, qx, qy, qz, vx, vy = estimate[0:9]
    if phase == NOMINAL and not valid:
        phase, z_ref, below_since = DESCENDING, pz, math.nan
        yaw_hold = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    elif phase == DESCENDING and valid and params.resume_on_aiding:
        phase = NOMINAL
    elif phase == DESCENDING:
        z_ref += params.descent_rate * dt
        if z_ref - pz > params.landed_lag:
            if math.isnan(below_since):
                below_since = t
            elif t - below_since >= params.landed_time:
                phase = LANDED
        else:
            below_since = math.nan

    if phase == NOMINAL:
        command = reference
    else:
        hold_vx, hold_vy = (0.0, 0.0) if params.brake else (vx, vy)
        descent = params.descent_rate if phase == DESCENDING else 0.0
        command = (px, py, z_ref, hold_vx, hold_vy, descent, 0.0, 0.0, 0.0, yaw_hold)
    memory = (phase, last_aided, seen_stamp, seen_gated, seen_resets, z_ref, yaw_hold, below_since)
    return memory, command, (1.0 if valid else 0.0, no_aiding, phase)
