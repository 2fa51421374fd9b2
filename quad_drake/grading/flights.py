"""Fly the course's scenarios 06-11 with a student's module for N seeds at once (fleet mode),
and read the signals the grading criteria judge.

Each scenario is the bundled one at ``fidelity: reference`` (the course's accelerometer
convention, which the student's formulas are written for: (0, 0, +9.81) level at rest, SPEC §2)
with every vehicle's estimator ``{kind: course, module: <the student's file>}``; 06 judges the
sensors alone and flies no estimator. The N runs of a scenario are one fleet
(``fleet.simulation.run_fleet``), so each of the student's functions is called once per
500 Hz tick for all N runs.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from quad_drake.campaigns.fleet.diagram import run_fleet
from quad_drake.config.schema import ScenarioConfig
from quad_drake.estimation.registry import vehicle_vocabulary
from quad_drake.grading.course import load_student_module, tuning_of
from quad_drake.judging.signals import vehicle_signals
from quad_drake.running import catalog

COURSE_SCENARIOS = (
    "06_sensor_noise",
    "07_attitude_estimation",
    "08_predict_state",
    "09_predict_covariance",
    "10_mag_update",
    "11_gps_update",
)
"""The course's estimation scenarios, in the order a student meets them."""

INIT_STD = {"09_predict_covariance": ", init_std: [0.001, 0.001, 0.001, 0.001, 0.001, 0.001, 0.05]"}
"""Estimator overrides per scenario: 09 judges how the predicted covariance grows with the
spread of errors that start at 0 (every estimate starts at the truth), so its position and
velocity sigmas start at 1 mm and 1 mm/s instead of the student's INIT_STD_DEVS."""


def graded_scenario(name, module) -> ScenarioConfig:
    """The ScenarioConfig of bundled scenario `name` as the grader flies it with the student's
    module (path): reference numerics, every vehicle on the course estimator (06: none, and its
    own two criteria judge the student's sigmas, as the reference's 06 does)."""
    base = catalog.load(name)
    estimator = f"{{kind: course, module: '{Path(module).resolve()}'{INIT_STD.get(name, '')}}}"
    overrides = ["fidelity=reference"]
    if name.startswith("06"):
        estimator = "{kind: truth}"
        tuning = tuning_of(load_student_module(str(module)))
        overrides += [f"criteria.0.sigma={tuning.gps_sigma!r}", f"criteria.1.sigma={tuning.accel_sigma!r}"]
    overrides += [f"vehicles.{i}.estimator={estimator}" for i in range(len(base.vehicles))]
    return catalog.load(name, overrides=overrides)


@dataclass
class Flight:
    """N runs of one graded scenario: ``times`` (samples,) s; ``signals[vehicle]`` the vehicle's
    named signals (``signals.vehicle_signals``: values and fresh masks (samples, N)); ``seeds``
    (N,); ``scenario`` as flown."""

    scenario: object
    seeds: tuple
    times: np.ndarray
    signals: dict

    def values(self, name) -> np.ndarray:
        """(samples, N) values of ``Vehicle.Signal`` `name`."""
        return self.signals[name.split(".", 1)[0]][name].values

    def fresh(self, name) -> np.ndarray:
        """(samples, N) fresh mask of `name`."""
        return np.asarray(self.signals[name.split(".", 1)[0]][name].fresh, dtype=bool)


def fly(name, module, seeds) -> Flight:
    """The :class:`Flight` of scenario `name` flown with the student's module for `seeds`.
    A student's exception ends it with ``course.StudentProblem`` (one line)."""
    scenario = graded_scenario(name, module)
    times, logs, _ = run_fleet(scenario, seeds)
    signals = {
        vehicle.name: vehicle_signals(vehicle.name, logs[vehicle.name], vehicle_vocabulary(vehicle))
        for vehicle in scenario.vehicles
    }
    return Flight(scenario, tuple(int(s) for s in seeds), times, signals)
