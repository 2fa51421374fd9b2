"""Grade a student's module: fly 06-11 over N seeds each, judge every run on the grading
criteria (``criteria.py``) and on the scenario's own (the reference's) criteria, and say which
function a failing scenario isolates.

``grade(module, runs, first_seed)`` returns a :class:`Grade`; ``grade_lines(grade)`` its text.
Each scenario's N runs fly as one fleet, so the student's functions are called once per tick
for all N (``flights.py``).
"""

import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

import numpy as np

from quad_drake.grading import statistics
from quad_drake.grading.course import load_student_module, tuning_of
from quad_drake.grading.criteria import CRITERIA, ISOLATES, PASS_SHARE
from quad_drake.grading.flights import COURSE_SCENARIOS, fly
from quad_drake.judging.consistency import binomial_interval
from quad_drake.judging.evaluation import CriterionStream

DEFAULT_RUNS = 50
"""Seeds per scenario of a default grade (``quad-drake grade``): a grade within a minute on the
2-core machine (docs/measurements/grading.md); the 95 % interval of 50/50 is [92.9, 100] %."""
DEFAULT_FIRST_SEED = 0

STATISTICS = {
    "07_attitude_estimation": statistics.attitude,
    "08_predict_state": statistics.dead_reckoning,
    "09_predict_covariance": statistics.covariance,
    "10_mag_update": statistics.magnetometer,
    "11_gps_update": statistics.gps,
}


@dataclass
class ScenarioGrade:
    """One scenario's N runs: ``values`` {statistic: (N,)}, ``failed`` {statistic: (N,) bool},
    ``passed`` (N,) bool (all grading criteria), ``reference_passed`` (N,) bool (the scenario's
    own criteria, the reference's single-seed test, run at each seed), ``cpu_time`` s."""

    name: str
    seeds: tuple
    values: dict
    failed: dict
    passed: np.ndarray
    reference_passed: np.ndarray
    cpu_time: float

    @property
    def runs(self) -> int:
        return len(self.seeds)

    @property
    def passes(self) -> int:
        return int(self.passed.sum())

    @property
    def verdict(self) -> bool:
        """True when more than PASS_SHARE of the runs pass."""
        return self.passes > PASS_SHARE * self.runs

    def interval(self) -> tuple[float, float]:
        """(low, high) 95 % Clopper-Pearson interval of the pass rate, fractions."""
        return binomial_interval(self.passes, self.runs)


@dataclass
class Grade:
    """A student module's grade: its name and the graded scenarios (each with a ``verdict``)."""

    module: str
    scenarios: list

    @property
    def passed(self) -> bool:
        return all(s.verdict for s in self.scenarios)


def scenario_statistics(name, flight, tuning) -> dict[str, np.ndarray]:
    """{statistic: (N,)} of one scenario's flight."""
    if name == "06_sensor_noise":
        return statistics.sensor_noise(flight, tuning.gps_sigma, tuning.accel_sigma)
    return STATISTICS[name](flight)


def reference_verdicts(flight) -> np.ndarray:
    """(N,) bool: each run judged on the scenario's own criteria (all of them passed)."""
    vehicles = [v.name for v in flight.scenario.vehicles]
    runs = len(flight.seeds)

    def signal(name):
        return flight.values(name), flight.fresh(name)

    passed = np.ones(runs, dtype=bool)
    for criterion in flight.scenario.criteria:
        stream = CriterionStream(criterion, runs, vehicles)
        stream.update(flight.times, signal)
        passed &= np.array([stream.result(j).passed for j in range(runs)])
    return passed


def grade_scenario(name, module, seeds) -> ScenarioGrade:
    """The ScenarioGrade of scenario `name` flown with the student's module for `seeds`."""
    tuning = tuning_of(load_student_module(str(module)))
    start = time.process_time()
    flight = fly(name, module, seeds)
    values = scenario_statistics(name, flight, tuning)
    failed = {c.statistic: ~c.passed(values[c.statistic]) for c in CRITERIA[name]}
    passed = ~np.any(list(failed.values()), axis=0)
    return ScenarioGrade(
        name, flight.seeds, values, failed, passed, reference_verdicts(flight), time.process_time() - start
    )


def grade(
    module,
    runs=DEFAULT_RUNS,
    first_seed=DEFAULT_FIRST_SEED,
    scenarios=COURSE_SCENARIOS,
    progress=None,
    jobs=1,
) -> Grade:
    """The Grade of the student's module (path): each scenario flown for seeds first_seed ..
    first_seed + runs - 1, on `jobs` worker processes (1: in this process; else the longest
    scenarios first). ``progress(ScenarioGrade)`` after each scenario, in the order they
    finish. StudentProblem (one line) when the module cannot be graded or raises in flight."""
    tuning_of(load_student_module(str(module)))  # every bad-input problem before anything flies
    seeds = tuple(range(first_seed, first_seed + runs))
    graded = {}

    def done(scenario_grade):
        graded[scenario_grade.name] = scenario_grade
        if progress is not None:
            progress(scenario_grade)

    if jobs <= 1:
        for name in scenarios:
            done(grade_scenario(name, module, seeds))
    else:
        longest_first = sorted(scenarios, key=lambda name: -FLIGHT_SECONDS[name])
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=jobs, mp_context=context) as pool:
            futures = [pool.submit(grade_scenario, name, str(module), seeds) for name in longest_first]
            for future in as_completed(futures):
                done(future.result())
    return Grade(str(module), [graded[name] for name in scenarios])


FLIGHT_SECONDS = {
    "06_sensor_noise": 10.0,
    "07_attitude_estimation": 4.0,
    "08_predict_state": 40.0,
    "09_predict_covariance": 10.0,  # 1 s of ten vehicles
    "10_mag_update": 20.0,
    "11_gps_update": 25.0,
}
"""Simulated vehicle-seconds of one run of each scenario: the order a pool grades them in."""


def scenario_lines(s) -> list[str]:
    """The text of one ScenarioGrade: its verdict and pass rate, each criterion's failures, and
    the function to look at when it fails."""
    low, high = s.interval()
    word = "PASS" if s.verdict else "FAIL"
    lines = [
        f"{word} {s.name}: {s.passes}/{s.runs} seeds pass = {100 * s.passes / s.runs:.0f} % "
        f"[{100 * low:.1f}, {100 * high:.1f}] (95 % CI); the reference's criteria: "
        f"{int(s.reference_passed.sum())}/{s.runs}"
    ]
    for c in CRITERIA[s.name]:
        values = s.values[c.statistic]
        lines.append(
            f"    {c.text} {c.bounds_text}: failed {int(s.failed[c.statistic].sum())}/{s.runs} "
            f"(median {np.median(values):.3g}, range {np.min(values):.3g} .. {np.max(values):.3g})"
        )
    if not s.verdict:
        lines.append(f"    -> look at {ISOLATES[s.name]}")
    return lines


def grade_lines(grade_result) -> list[str]:
    """Every line of a Grade's text, then the overall verdict."""
    lines = []
    for s in grade_result.scenarios:
        lines += scenario_lines(s)
    failing = [s.name for s in grade_result.scenarios if not s.verdict]
    lines.append("GRADE: PASS (every scenario)" if not failing else f"GRADE: FAIL ({', '.join(failing)})")
    return lines
