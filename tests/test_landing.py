"""A landing is not a crash: ``V.TouchdownSpeed`` (``signals.touchdown_speeds``) and the safety
criterion a documented landing adds (``safety.landing_criterion``); scenario 21 lands, the same
vehicle falling onto the floor fails."""

import numpy as np
import pytest

from quad_drake.config.schema import SafetyConfig, ScenarioConfig
from quad_drake.judging.safety import safety_criteria
from quad_drake.judging.signals import touchdown_speeds
from quad_drake.running import catalog
from quad_drake.running.simulation import run


def test_touchdown_speed_is_the_descent_speed_of_the_sample_before():
    touchdowns = np.array([0, 0, 0, 1, 1, 1, 2, 2], dtype=float)
    vz = np.array([0.3, 0.4, 0.5, 0.0, -0.1, 0.2, 0.0, 0.0])
    np.testing.assert_array_equal(touchdown_speeds(touchdowns, vz), [0, 0, 0, 0.5, 0, 0, 0.2, 0])
    # a fleet batch: (n, N)
    both = touchdown_speeds(np.stack([touchdowns, touchdowns], 1), np.stack([vz, 2 * vz], 1))
    np.testing.assert_array_equal(both[:, 1], [0, 0, 0, 1.0, 0, 0, 0.4, 0])


def test_the_landing_criterion_comes_with_a_landing_only():
    plain = ScenarioConfig(name="x")
    assert not any(c.signal.endswith("TouchdownSpeed") for c in safety_criteria(plain))
    landing = ScenarioConfig(name="x", end_time=5.0, safety=SafetyConfig(landing_time=2.0))
    (criterion,) = [c for c in safety_criteria(landing) if c.signal.endswith("TouchdownSpeed")]
    assert criterion.kind == "bound" and criterion.threshold == 1.0
    assert criterion.start == 0.0 and criterion.end > landing.end_time
    off = ScenarioConfig(name="x", safety=SafetyConfig(landing_time=2.0, max_touchdown_speed=0.0))
    assert not any(c.signal.endswith("TouchdownSpeed") for c in safety_criteria(off))


@pytest.mark.slow
def test_a_landing_passes_and_a_fall_fails():
    landed = run(catalog.load("21_landing"))
    assert landed.passed, [r.line for r in landed.criteria if not r.passed]
    speeds = landed.signals["Quad.TouchdownSpeed"].values
    assert 0.2 < speeds.max() < 1.0
    assert landed.signals["Quad.IMU.AccelSaturated"].values[-1] >= 1  # the floor's impulse, clipped at 16 g
    # The same vehicle sent straight to a set-point below the floor: its altitude integral winds the
    # thrust down and it falls, touching down at 1.5-1.8 m/s after the landing time: a crash.
    fall = run(
        catalog.load(
            "21_landing",
            overrides=["vehicles.0.trajectory={kind: point, point: [0, 0, 0.3]}", "safety.landing_time=0.5"],
        )
    )
    verdicts = {r.name: r.passed for r in fall.criteria}
    assert verdicts["Quad.TouchdownSpeed"] is False
    floor = [r for r in fall.criteria if r.kind == "floor"]
    assert floor and all(r.passed for r in floor)  # its touchdowns come after the landing time
    assert fall.signals["Quad.TouchdownSpeed"].values.max() > 1.2  # 1.51-1.77 m/s over seeds 0-20
