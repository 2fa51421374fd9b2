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
  kp_pos_z > 0): the true tracking error |``V.PosFollowErr``| stays <= ``safety.tracking_bound``.

The default bound, 6 m, is 1.45 times the largest tracking error measured on the bundled
scenarios (11 over seeds 0-19: at most 4.13 m, seed 12; 3.58 m at its default seed; 2.98 m
in 08 and 10 on truth): Square.txt asks for 6 m legs in 1 s while the controller caps the
speed at 5 m/s, so a healthy vehicle lags its reference by 3-4 m at every corner. 6 m, one
full leg, is what a vehicle that has lost its reference exceeds.
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
    safety = scenario.safety
    if not safety.enabled:
        return []
    criteria = []
    for vehicle in scenario.vehicles:
        wanted = (
            ("floor", safety.floor, {"landing_time": safety.landing_time}),
            ("room", safety.room, {}),
            ("finite", safety.finite, {}),
            ("tracking", safety.tracking and is_closed_loop(vehicle), {"threshold": safety.tracking_bound}),
        )
        criteria += [
            CriterionConfig(kind=kind, signal=f"{vehicle.name}.{SAFETY_SIGNALS[kind]}", **fields)
            for kind, enabled, fields in wanted
            if enabled
        ]
        if safety.floor and safety.landing_time is not None and safety.max_touchdown_speed > 0:
            criteria.append(landing_criterion(vehicle.name, safety.max_touchdown_speed, scenario.end_time))
        if safety.attitude:
            criteria.append(attitude_criterion(vehicle, safety.tilt_margin, scenario.end_time))
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
