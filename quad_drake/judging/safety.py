"""Flight-safety criteria every scenario is judged on by default
(``evaluation.judged_criteria`` adds them).

The reference judges only what its analyzers name, so a vehicle that sits on the floor can
pass (11 with a 2 kg vehicle: 97 % of the run on the floor, PASS). From a
:class:`~quad_drake.config.ScenarioConfig` this module derives, per vehicle, criteria on the
*true* flight, evaluated like the others (``evaluation.evaluate_criterion``):

- ``floor``: no touchdown after take-off (``V.FloorTouchdowns`` stays 0), unless the scenario
  documents a landing (``safety.landing_time``: touchdowns from then on pass), and the vehicle
  leaves the floor at all;
- with a landing (``safety.landing_time``), a landing is told from a crash by its speed: every
  touchdown's descent speed ``V.TouchdownSpeed`` stays below ``safety.max_touchdown_speed``
  (1 m/s by default: a controlled descent meets the floor at about 0.3-0.5 m/s, a fall from
  1 m at 4.4 m/s);
- ``room``: never stopped by a wall or the ceiling (``V.WallContactSteps`` stays 0);
- ``finite``: the true state stays finite (``V.StateFinite``);
- ``attitude``: the true tilt ``V.Tilt`` stays below the largest tilt the cascade commands
  (asin(sqrt 2 max_tilt), 81.9 deg for the default max_tilt 0.7) plus ``safety.tilt_margin``
  (0.1 rad: the bank loop's overshoot; the bundled scenarios at their seeds tilt at most 78.7 deg,
  05's Quad1); a vehicle that rolled over (beyond 90 deg) fails it;
- ``tracking``, for closed-loop flights (position loops closed: kp_pos_xy > 0 and
  kp_pos_z > 0): the true tracking error |``V.PosFollowErr``| stays <= ``safety.tracking_bound``,
  except while the position dead-reckons through a GPS outage (below).

The default bound, 6 m, is 1.45 times the largest tracking error measured on the bundled
scenarios (11 over seeds 0-19: at most 4.13 m, seed 12; 3.58 m at its default seed; 2.98 m
in 08 and 10 on truth): Square.txt asks for 6 m legs in 1 s while the controller caps the
speed at 5 m/s, so a healthy vehicle lags its reference by 3-4 m at every corner. 6 m, one
full leg, is what a vehicle that has lost its reference exceeds.
**Tracking is not judged while the position dead-reckons through a GPS outage.** A vehicle that
flies on its estimate (``flies_on: estimate``) through a ``gps_outage`` fault follows an estimate
that drifts on the IMU alone; any bound during the outage only says how lost it may get, and the
drift is the sensors', not a defect of the flight. Measured on 23_gps_outage_baro (ESKF with a
barometer, GPS out 10-20 s, fleet seeds 2000-2199, ``benchmarks/failsafe_checks.py tracking``):
the largest true tracking error per run is at most 3.31 m before the outage, median 7.3 m (p99
15.7, max 16.8) during it and up to 17.1 m in the 3 s after it, while the vehicle flies back to
its reference once the GPS resets the estimate; from 3 s after the outage on at most 4.49 m. On
``benchmarks/scenarios/mag3_disturbance_outage.yaml`` (5 s outage, seeds 3000-3099,
``benchmarks/outage_tracking.py``): at most 3.29 m before, up to 7.36 m during and 7.37 m in the
3 s after, at most 3.31 m from 3 s after. So around each outage (:func:`tracking_criteria`) the
bound is judged before it (a ``bound`` on [0, start) s), nothing during it, and back under the
bound within ``safety.tracking_recovery_time`` (3 s) after the GPS returns (a ``recovery``): a
vehicle that has flown off (a wall, or still lost 3 s after its GPS returned) fails, a vehicle
whose estimate drifted does not. A vehicle that flies on the truth is judged over the whole flight.

A scenario switches all of them off with ``safety: {enabled: false}`` or one by one
(``safety: {tracking: false}``); pure: config in, CriterionConfig list out.
"""

from quad_drake.config.schema import CriterionConfig
from quad_drake.control.cascade import max_commanded_tilt


def is_closed_loop(vehicle) -> bool:
    """True when the vehicle's controller tracks its trajectory's position (both position gains > 0)."""
    return vehicle.controller.kp_pos_xy > 0.0 and vehicle.controller.kp_pos_z > 0.0


SAFETY_SIGNALS = {
    "floor": "FloorTouchdowns",
    "room": "WallContactSteps",
    "finite": "StateFinite",
    "tracking": "PosFollowErr",
    "attitude": "Tilt",
}
"""The per-vehicle signal (``V.<name>``) each safety criterion judges."""


def safety_criteria(scenario) -> list[CriterionConfig]:
    """The flight-safety CriterionConfigs of `scenario`, vehicle by vehicle ([] when disabled)."""
    return [criterion for _, criterion in labelled_safety_criteria(scenario)]


def labelled_safety_criteria(scenario) -> list[tuple[str, CriterionConfig]]:
    """(what it guards, CriterionConfig) per flight-safety criterion of `scenario`, in the order of
    :func:`safety_criteria`: ``floor``, ``room``, ``finite``, ``tracking`` (also the ``bound`` and
    ``recovery`` that judge the tracking around a GPS outage), ``landing``, ``attitude``; what a
    campaign table counts its failures by."""
    safety = scenario.safety
    if not safety.enabled:
        return []
    labelled = []
    for vehicle in scenario.vehicles:
        wanted = (
            ("floor", safety.floor, {"landing_time": safety.landing_time}),
            ("room", safety.room, {}),
            ("finite", safety.finite, {}),
        )
        labelled += [
            (kind, CriterionConfig(kind=kind, signal=f"{vehicle.name}.{SAFETY_SIGNALS[kind]}", **fields))
            for kind, enabled, fields in wanted
            if enabled
        ]
        if safety.tracking and is_closed_loop(vehicle):
            labelled += [("tracking", c) for c in tracking_criteria(vehicle, safety, scenario.end_time)]
        if safety.floor and safety.landing_time is not None and safety.max_touchdown_speed > 0:
            labelled.append(
                ("landing", landing_criterion(vehicle.name, safety.max_touchdown_speed, scenario.end_time))
            )
        if safety.attitude:
            labelled.append(("attitude", attitude_criterion(vehicle, safety.tilt_margin, scenario.end_time)))
    return labelled


def dead_reckoning_windows(vehicle, recovery_time) -> list[tuple[float, float]]:
    """The [start, end) s windows in which `vehicle`'s flown position dead-reckons: its
    ``gps_outage`` faults when it flies on its estimate (none when it flies on the truth), sorted,
    and merged where one outage starts before `recovery_time` s after another has ended (no
    judged window between them)."""
    if vehicle.flies_on != "estimate":
        return []
    outages = sorted((f.start, f.end) for f in vehicle.faults if f.kind == "gps_outage" and f.end > f.start)
    windows = []
    for start, end in outages:
        if windows and start < windows[-1][1] + recovery_time:
            windows[-1] = (windows[-1][0], max(windows[-1][1], end))
        else:
            windows.append((start, end))
    return windows


def tracking_criteria(vehicle, safety, end_time) -> list[CriterionConfig]:
    """The tracking criteria of `vehicle` (``V.PosFollowErr`` <= ``safety.tracking_bound`` m):
    one ``tracking`` over the whole flight, or, where its position dead-reckons
    (:func:`dead_reckoning_windows`), the bound where it can know where it is: a ``bound`` on
    [0, start) s before the first outage and on [end + recovery, next start) between two, and a
    ``recovery`` back under the bound within ``safety.tracking_recovery_time`` s after the last
    (not judged when the flight of `end_time` s ends before that; see the module docstring)."""
    signal = f"{vehicle.name}.{SAFETY_SIGNALS['tracking']}"
    bound, recovery = safety.tracking_bound, safety.tracking_recovery_time
    windows = dead_reckoning_windows(vehicle, recovery)
    if not windows:
        return [CriterionConfig(kind="tracking", signal=signal, threshold=bound)]
    criteria, judged_from = [], 0.0
    for start, end in windows:
        if start > judged_from:
            criteria.append(
                CriterionConfig(kind="bound", signal=signal, threshold=bound, start=judged_from, end=start)
            )
        judged_from = end + recovery
    last_end = windows[-1][1]
    if last_end + recovery <= end_time:
        criteria.append(
            CriterionConfig(kind="recovery", signal=signal, threshold=bound, start=last_end, window=recovery)
        )
    return criteria


def attitude_criterion(vehicle, margin, end_time) -> CriterionConfig:
    """A vehicle that tilts beyond what its controller allows has not passed: its true tilt
    ``V.Tilt`` (rad, the body z axis from the vertical) stays below the cascade's largest commanded
    tilt (``control.cascade.max_commanded_tilt``) plus `margin` rad over the whole flight of
    `end_time` s (judged as a ``bound``; no plot of its own)."""
    return CriterionConfig(
        kind="attitude",
        signal=f"{vehicle.name}.{SAFETY_SIGNALS['attitude']}",
        threshold=max_commanded_tilt(vehicle.controller) + margin,
        start=0.0,
        end=end_time + 1.0,
    )


def landing_criterion(vehicle_name, max_speed, end_time) -> CriterionConfig:
    """What tells a landing from a crash: every touchdown's descent speed (``V.TouchdownSpeed``,
    m/s) stays below `max_speed` over the whole flight of `end_time` s (a ``bound`` criterion)."""
    return CriterionConfig(
        kind="bound",
        signal=f"{vehicle_name}.TouchdownSpeed",
        threshold=max_speed,
        start=0.0,
        end=end_time + 1.0,
    )
