"""The no-aiding failsafe (``control.failsafe``, ``kernels.failsafe``, ``systems.failsafe``): its
aiding book and phases on hand-made inputs, the compiled kernel against the scalar function, its
config rules, and its phases in a short closed-loop flight (a GPS outage on the ESKF with a
barometer)."""

import math

import numpy as np
import pytest

from quad_drake.config.errors import ConfigError
from quad_drake.config.schema import FailsafeConfig
from quad_drake.config.validation import check_scenario
from quad_drake.control import failsafe
from quad_drake.control.failsafe import DESCENDING, LANDED, NOMINAL, failsafe_step, initial_memory
from quad_drake.kernels import failsafe as kernels
from quad_drake.kernels.flight import frozen
from quad_drake.running import catalog
from quad_drake.running.simulation import run

DT = 0.002
HOVER = (0.0, 0.0, -1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
DEFAULTS = FailsafeConfig()
TRAJECTORY = (1.0, 2.0, -1.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3)


def _fly(memory, times, gps, estimate=HOVER, params=DEFAULTS):
    """Step the scalar supervisor at `times` with gps(t) -> (stamp, gated, resets); the last outputs."""
    for t in times:
        memory, command, status = failsafe_step(memory, t, DT, *gps(t), estimate, TRAJECTORY, params)
    return memory, command, status


def test_a_fused_or_reset_sample_aids_and_a_gated_one_does_not():
    memory, command, status = _fly(initial_memory(), [1.0], lambda t: (0.9, 0.0, 0.0))
    assert memory[1] == 0.9 and status == (1.0, pytest.approx(0.1), NOMINAL) and command == TRAJECTORY
    gated, _, status = failsafe_step(memory, 1.1, DT, 1.0, 1.0, 0.0, HOVER, TRAJECTORY, FailsafeConfig())
    assert gated[1] == 0.9 and status[1] == pytest.approx(0.2)  # rejected by the gate: not aided
    reset, _, _ = failsafe_step(gated, 1.2, DT, 1.1, 2.0, 1.0, HOVER, TRAJECTORY, FailsafeConfig())
    assert reset[1] == 1.1  # rejected but reset to: aided
    same, _, _ = failsafe_step(reset, 1.3, DT, 1.1, 2.0, 1.0, HOVER, TRAJECTORY, FailsafeConfig())
    assert same[1] == 1.1  # no fresh sample


def test_the_phases_descend_land_and_idle():
    params = FailsafeConfig(no_aiding_timeout=1.0, descent_rate=0.5)
    times = np.arange(0.0, 1.0, DT)
    memory, command, status = _fly(initial_memory(), times, lambda t: (-1.0, 0.0, 0.0), params=params)
    assert status[2] == NOMINAL and command == TRAJECTORY
    memory, command, status = _fly(memory, [1.01], lambda t: (-1.0, 0.0, 0.0), params=params)
    assert status[:1] == (0.0,) and status[2] == DESCENDING
    # the horizontal loop holds the estimate's position at zero velocity, the height descends
    assert command[:2] == HOVER[:2] and command[3:5] == (0.0, 0.0) and command[5] == 0.5
    assert command[2] == HOVER[2] and command[6:9] == (0.0, 0.0, 0.0) and command[9] == 0.0
    # the vehicle stays at -1 m (on a table): the set-point runs landed_lag below it, then landed_time
    below = 1.01 + params.landed_lag / params.descent_rate
    memory, command, status = _fly(
        memory, np.arange(1.01 + DT, below + 0.99, DT), lambda t: (-1.0, 0, 0), params=params
    )
    assert status[2] == DESCENDING
    memory, command, status = _fly(
        memory, np.arange(below + 1.0, below + 1.1, DT), lambda t: (-1.0, 0, 0), params=params
    )
    assert status[2] == LANDED and command[5] == 0.0
    # landed stays landed, even when the GPS comes back
    memory, command, status = _fly(memory, [20.0], lambda t: (19.9, 0.0, 0.0), params=params)
    assert status[0] == 1.0 and status[2] == LANDED


@pytest.mark.parametrize("resume", [True, False])
def test_regained_aiding_resumes_the_mission_or_keeps_landing(resume):
    params = FailsafeConfig(no_aiding_timeout=1.0, resume_on_aiding=resume, brake=False)
    descending = (-0.3, 0.2, -1.0, 1.0, 0.0, 0.0, 0.0, 0.4, -0.2, 0.5, 0.0, 0.0, 0.0)
    memory, command, _ = _fly(initial_memory(), [1.5], lambda t: (-1.0, 0.0, 0.0), descending, params)
    assert memory[0] == DESCENDING and command[3:5] == (0.4, -0.2)  # no brake: zero acceleration
    memory, command, status = _fly(memory, [1.6], lambda t: (1.55, 0.0, 0.0), descending, params)
    assert status[0] == 1.0
    assert (status[2], command == TRAJECTORY) == ((NOMINAL, True) if resume else (DESCENDING, False))


def test_the_kernel_is_the_scalar_step():
    rng = np.random.default_rng(40)
    n, ticks = 7, 400
    params = FailsafeConfig(no_aiding_timeout=0.3, landed_time=0.05, landed_lag=0.02)
    memory = np.tile(initial_memory(), (n, 1))
    scalar = [initial_memory()] * n
    stamps = np.full(n, -1.0)
    gated, resets = np.zeros(n), np.zeros(n)
    for k in range(ticks):
        t = k * DT
        fresh = (rng.random(n) < 0.05) & (
            (k < 100) | ((k > 300) & (np.arange(n) % 3 == 0))
        )  # lost, some regain
        stamps = np.where(fresh, t, stamps)
        gated += fresh & (rng.random(n) < 0.3)
        resets += fresh & (rng.random(n) < 0.1)
        estimate = rng.normal(size=(n, 13))
        estimate[:, 2] = -1.0 + 0.001 * k * (np.arange(n) % 2)  # half of them do not descend
        reference = rng.normal(size=(n, 10))
        command, status = np.empty((n, 10)), np.empty((n, failsafe.STATUS_SIZE))
        diagnostics = np.column_stack((np.full(n, np.nan), stamps, gated, resets))  # read at (1, 2, 3)
        kernels.failsafe_steps(
            memory, t, DT, diagnostics, (1, 2, 3), estimate, reference, frozen(params), command, status
        )
        for i in range(n):
            scalar[i], ref, flags = failsafe_step(
                scalar[i],
                t,
                DT,
                stamps[i],
                gated[i],
                resets[i],
                tuple(estimate[i]),
                tuple(reference[i]),
                params,
            )
            np.testing.assert_allclose(command[i], ref, rtol=0, atol=1e-12)
            np.testing.assert_allclose(status[i], flags, rtol=0, atol=1e-12)
            np.testing.assert_allclose(memory[i], scalar[i], rtol=0, atol=1e-12, equal_nan=True)
    assert set(memory[:, 0]) == {NOMINAL, DESCENDING, LANDED}  # the inputs reach every phase


def test_a_failsafe_needs_a_vehicle_flying_on_its_estimate():
    scenario = catalog.load("29_gps_outage_failsafe")
    check_scenario(scenario)
    scenario.vehicles[0].flies_on = "truth"
    with pytest.raises(ConfigError, match="vehicles.0.failsafe"):
        check_scenario(scenario)
    with pytest.raises(ConfigError, match="descent_rate: must be > 0"):
        catalog.load("29_gps_outage_failsafe", overrides=["vehicles.0.failsafe.descent_rate=0"])


SHORT = [
    "end_time=10.0",
    "vehicles.0.trajectory={kind: point, point: [0, 0, -1]}",
    "vehicles.0.failsafe.no_aiding_timeout=1.0",
    "safety.landing_time=2.5",
    "criteria=[]",
]


@pytest.mark.slow
def test_a_short_outage_lands_and_idles_the_motors():
    """GPS lost at 2 s: the position is invalid from about 2.9 s (last sample 1.9 s + 1 s), the
    vehicle descends at 0.5 m/s from 1 m, touches down below 1 m/s, is detected on the ground and
    idles (about 2 s after the touchdown); the GPS returning at 9 s does not lift it again (seed 0;
    the same checks hold on fleet seeds 1-20)."""
    result = run(
        catalog.load(
            "29_gps_outage_failsafe",
            overrides=SHORT + ["vehicles.0.faults=[{kind: gps_outage, start: 2, end: 9}]"],
        )
    )
    assert result.passed, [r.line for r in result.criteria if not r.passed]
    t = result.times
    phase = result.signals["Quad.Failsafe.Phase"].values
    valid = result.signals["Quad.Failsafe.PositionValid"].values
    assert set(np.unique(phase)) == {NOMINAL, DESCENDING, LANDED}
    entered = t[np.argmax(phase == DESCENDING)]
    assert 2.85 < entered < 3.0 and valid[t < entered].all() and not valid[(t > entered) & (t < 9.0)].any()
    landed = t[np.argmax(phase == LANDED)]
    touchdown = t[np.argmax(result.signals["Quad.FloorTouchdowns"].values > 0)]
    assert entered + 1.0 < touchdown < landed < 9.0 and (phase[t >= landed] == LANDED).all()
    assert valid[-1] == 1.0  # the GPS is back, the vehicle stays down
    assert result.signals["Quad.TouchdownSpeed"].values.max() < 1.0
    forces = [result.signals[f"Quad.Thrust.{m}"].values[-1] for m in "ABCD"]
    assert max(forces) < 0.2  # idle: min_motor_thrust 0.1 N and the motor noise


@pytest.mark.slow
def test_aiding_regained_in_flight_resumes_the_mission():
    result = run(
        catalog.load(
            "29_gps_outage_failsafe",
            overrides=SHORT + ["vehicles.0.faults=[{kind: gps_outage, start: 2, end: 4}]"],
        )
    )
    phase = result.signals["Quad.Failsafe.Phase"].values
    t = result.times
    assert DESCENDING in phase and LANDED not in phase and (phase[t > 4.5] == NOMINAL).all()
    assert result.signals["Quad.FloorTouchdowns"].values[-1] == 0
    assert abs(result.signals["Quad.Pos.Z"].values[-1] + 1.0) < 0.3  # back at its 1 m hover
    assert not math.isnan(result.signals["Quad.Failsafe.NoAidTime"].values[-1])
