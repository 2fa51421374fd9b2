"""Flight-safety criteria: derivation from a scenario, the analyzers, the plant's contact
counts, and verdicts of whole runs (a crash must fail)."""

import dataclasses
import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from quad_drake.config.errors import ConfigError
from quad_drake.config.loader import load_scenario
from quad_drake.config.schema import (
    CriterionConfig,
    FaultConfig,
    PhysicsParams,
    ScenarioConfig,
    VehicleConfig,
)
from quad_drake.conventions import GRAVITY
from quad_drake.judging.evaluation import (
    evaluate_criterion,
    floor_touchdowns,
    judged_criteria,
    room_contacts,
    state_finite,
    tracking_bound,
)
from quad_drake.judging.safety import (
    dead_reckoning_windows,
    is_closed_loop,
    labelled_safety_criteria,
    safety_criteria,
)
from quad_drake.judging.signals import vehicle_signals
from quad_drake.models.dynamics import on_floor, outside_room
from quad_drake.models.rotations import quat_from_euler
from quad_drake.systems.plant import QuadrotorPlant

TIMES = 0.005 * np.arange(1, 201)  # 1 s of 5 ms samples


def scenario(**safety):
    open_loop = VehicleConfig(name="Open")
    open_loop.controller.kp_pos_xy = 0.0
    s = ScenarioConfig(vehicles=[VehicleConfig(name="Quad"), open_loop])
    s.safety = dataclasses.replace(s.safety, **safety)
    return s


def test_every_vehicle_gets_floor_room_finite_and_closed_loop_ones_tracking():
    criteria = safety_criteria(scenario())
    assert [(c.kind, c.signal) for c in criteria] == [
        ("floor", "Quad.FloorTouchdowns"),
        ("room", "Quad.WallContactSteps"),
        ("finite", "Quad.StateFinite"),
        ("tracking", "Quad.PosFollowErr"),
        ("attitude", "Quad.Tilt"),
        ("floor", "Open.FloorTouchdowns"),
        ("room", "Open.WallContactSteps"),
        ("finite", "Open.StateFinite"),
        ("attitude", "Open.Tilt"),
    ]
    assert criteria[3].threshold == 6.0
    assert is_closed_loop(VehicleConfig()) and not is_closed_loop(scenario().vehicles[1])
    s = scenario()
    assert judged_criteria(s) == list(s.criteria) + criteria


def test_safety_switches_off_as_a_whole_or_check_by_check():
    assert safety_criteria(scenario(enabled=False)) == []
    kinds = {c.kind for c in safety_criteria(scenario(tracking=False, room=False, attitude=False))}
    assert kinds == {"floor", "finite"}
    bounded = safety_criteria(scenario(tracking_bound=2.5, landing_time=12.0))
    assert [c.threshold for c in bounded if c.kind == "tracking"] == [2.5]
    assert {c.landing_time for c in bounded if c.kind == "floor"} == {12.0}


def outage_scenario(*outages, flies_on="estimate", end_time=25.0, **safety):
    """One closed-loop vehicle flying on `flies_on` with a gps_outage fault per (start, end) s."""
    vehicle = VehicleConfig(name="Quad", flies_on=flies_on)
    vehicle.faults = [FaultConfig(kind="gps_outage", start=a, end=b) for a, b in outages]
    vehicle.faults.append(FaultConfig(kind="mag_outage", start=0.0, end=25.0))  # not the GPS: ignored
    s = ScenarioConfig(end_time=end_time, vehicles=[vehicle])
    s.safety = dataclasses.replace(s.safety, **safety)
    return s


def tracking_of(scenario):
    return [c for c in safety_criteria(scenario) if c.signal == "Quad.PosFollowErr"]


def test_tracking_is_judged_around_a_gps_outage_not_during_it():
    pos = "Quad.PosFollowErr"
    assert tracking_of(outage_scenario((10.0, 15.0))) == [
        CriterionConfig(kind="bound", signal=pos, threshold=6.0, start=0.0, end=10.0),
        CriterionConfig(kind="recovery", signal=pos, threshold=6.0, start=15.0, window=3.0),
    ]
    # a vehicle flying on the truth does not dead-reckon: the whole flight, as without an outage
    assert tracking_of(outage_scenario((10.0, 15.0), flies_on="truth")) == [
        CriterionConfig(kind="tracking", signal=pos, threshold=6.0)
    ]
    assert tracking_of(outage_scenario()) == [CriterionConfig(kind="tracking", signal=pos, threshold=6.0)]
    # two outages: judged between them from `recovery` s after the first; the bound and time move
    two = tracking_of(
        outage_scenario((12.0, 14.0), (4.0, 6.0), tracking_bound=4.0, tracking_recovery_time=2.0)
    )
    assert [(c.kind, c.start, c.end, c.window, c.threshold) for c in two] == [
        ("bound", 0.0, 4.0, 1.0, 4.0),
        ("bound", 8.0, 12.0, 1.0, 4.0),
        ("recovery", 14.0, 0.0, 2.0, 4.0),
    ]
    # outages closer than the recovery time merge; one at take-off has no window before it
    assert dead_reckoning_windows(outage_scenario((0.0, 2.0), (4.0, 6.0)).vehicles[0], 3.0) == [(0.0, 6.0)]
    assert [c.kind for c in tracking_of(outage_scenario((0.0, 2.0), (4.0, 6.0)))] == ["recovery"]
    # the GPS back too late to judge a recovery (flight ends within 3 s): only the bound before
    assert [c.kind for c in tracking_of(outage_scenario((10.0, 23.0)))] == ["bound"]
    assert tracking_of(outage_scenario((10.0, 15.0), tracking=False)) == []
    # a campaign table counts the split pair as the tracking it stands for
    labelled = labelled_safety_criteria(outage_scenario((10.0, 15.0), landing_time=20.0))
    assert [kind for kind, _ in labelled] == [
        "floor",
        "room",
        "finite",
        "tracking",
        "tracking",
        "landing",
        "attitude",
    ]
    assert [c for _, c in labelled] == safety_criteria(outage_scenario((10.0, 15.0), landing_time=20.0))


def test_a_dead_reckoned_excursion_passes_and_a_flyaway_fails():
    """The old rule (|PosFollowErr| <= 6 m over the whole flight) failed a vehicle whose estimate
    drifted 9 m during the outage and came back; the split rule passes it and still fails one that
    is still lost 3 s after the GPS returned."""
    times = 0.005 * np.arange(1, 5001)  # 25 s
    outage = (times >= 10.0) & (times < 15.0)
    drifted = np.where(outage, 9.0, 3.0)
    flyaway = np.where(times >= 10.0, 9.0, 3.0)
    flyaway[times >= 19.0] = 3.0  # back only 4 s after the GPS returned

    def verdicts(error):
        return [
            evaluate_criterion(c, times, lambda name: (error, None)).passed
            for c in tracking_of(outage_scenario((10.0, 15.0)))
        ]

    assert verdicts(drifted) == [True, True]
    assert not tracking_bound(times, drifted, 6.0).passed  # what the whole-flight bound said
    assert verdicts(flyaway) == [True, False]


def test_safety_config_from_yaml_and_its_errors(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("end_time: 1.0\nsafety: {tracking_bound: 3.0, floor: false}\n")
    loaded = load_scenario(path)
    assert (loaded.safety.tracking_bound, loaded.safety.floor, loaded.safety.enabled) == (3.0, False, True)
    assert load_scenario(path, ["safety.enabled=false"]).safety.enabled is False
    with pytest.raises(ConfigError, match=r"s\.yaml: safety\.tracking_bound: must be > 0, got -1"):
        load_scenario(path, ["safety.tracking_bound=-1"])
    with pytest.raises(ConfigError, match=r"s\.yaml: safety\.tracking_recovery_time: must be > 0, got 0"):
        load_scenario(path, ["safety.tracking_recovery_time=0"])
    with pytest.raises(ConfigError, match=r"s\.yaml: safety\.landing_time: must be >= 0, got -2"):
        load_scenario(path, ["safety.landing_time=-2.0"])
    with pytest.raises(ConfigError, match=r"safety\.ceiling: unknown key"):
        load_scenario(path, ["safety.ceiling=true"])


def test_floor_verdicts():
    airborne = np.zeros(TIMES.size)
    clean = floor_touchdowns(TIMES, np.zeros(TIMES.size), airborne, "Quad")
    assert clean.passed and clean.line == "PASS: Quad never touched the floor after take-off"
    counts = np.zeros(TIMES.size)
    counts[TIMES >= 0.345] = 1
    counts[TIMES >= 0.5] = 2
    counts[TIMES >= 0.9] = 3
    crash = floor_touchdowns(TIMES, counts, airborne, "Quad")
    assert not crash.passed and crash.measured == 3.0
    assert crash.line == "FAIL: Quad touched the floor 3 times (first at 0.345 s)"
    once = floor_touchdowns(TIMES, np.minimum(counts, 1), airborne, "Quad")
    assert once.line == "FAIL: Quad touched the floor 1 time (first at 0.345 s)"
    # A documented landing: touchdowns counted from landing_time on pass.
    landed = np.where(TIMES >= 0.8, 1.0, 0.0)
    assert floor_touchdowns(TIMES, landed, airborne, "Quad", landing_time=0.8).passed
    early = floor_touchdowns(TIMES, counts, airborne, "Quad", landing_time=0.8)
    assert not early.passed and early.measured == 2.0
    assert early.line == "FAIL: Quad touched the floor 2 times before its landing at 0.8 s (first at 0.345 s)"
    grounded = floor_touchdowns(TIMES, np.zeros(TIMES.size), np.ones(TIMES.size), "Quad")
    assert not grounded.passed
    assert grounded.line == "FAIL: Quad never took off (on the floor at every sample)"


def test_room_finite_and_tracking_verdicts():
    assert room_contacts(TIMES, np.zeros(TIMES.size), "Quad").line == "PASS: Quad stayed inside the room"
    steps = np.where(TIMES >= 0.25, 350.0, 0.0)
    wall = room_contacts(TIMES, steps, "Quad")
    assert not wall.passed and wall.measured == pytest.approx(0.35)
    assert wall.line == "FAIL: Quad was stopped by a wall or the ceiling for 0.350 s (first at 0.250 s)"

    finite = np.ones(TIMES.size)
    assert state_finite(TIMES, finite, "Quad").line == "PASS: the true state of Quad stayed finite"
    finite[TIMES >= 0.5] = 0.0
    broken = state_finite(TIMES, finite, "Quad")
    assert not broken.passed and broken.line == "FAIL: the true state of Quad became non-finite at 0.500 s"

    error = 2.0 * np.sin(np.pi * TIMES)  # max 2 at 0.5 s
    ok = tracking_bound(TIMES, error, 2.5, "Quad.PosFollowErr")
    assert ok.passed and ok.measured == pytest.approx(2.0)
    assert ok.line == "PASS: ABS(Quad.PosFollowErr) stayed below 2.500000 (max 2.000 at 0.500 s)"
    assert (ok.measured_text, ok.required_text) == ("max 2 m at 0.500 s", "max <= 2.5 m")
    assert ok.measured_unit == "m"
    lost = tracking_bound(TIMES, error, 1.5, "Quad.PosFollowErr")
    assert not lost.passed
    assert lost.line.startswith("FAIL: ABS(Quad.PosFollowErr) reached 1.5")
    assert lost.line.endswith("above 1.500000")
    error[50] = math.nan
    diverged = tracking_bound(TIMES, error, 2.5, "Quad.PosFollowErr")
    assert not diverged.passed and diverged.measured == math.inf


def test_evaluate_criterion_dispatches_the_safety_kinds():
    signals = {
        "Quad.FloorTouchdowns": np.where(TIMES >= 0.6, 1.0, 0.0),
        "Quad.FloorContact": np.zeros(TIMES.size),
        "Quad.WallContactSteps": np.zeros(TIMES.size),
        "Quad.StateFinite": np.ones(TIMES.size),
        "Quad.PosFollowErr": np.full(TIMES.size, 6.5),
        "Quad.Tilt": np.full(TIMES.size, 0.2),
    }
    verdicts = {
        c.kind: evaluate_criterion(c, TIMES, lambda name: (signals[name], None))
        for c in safety_criteria(scenario())
        if c.signal.startswith("Quad.")
    }
    assert {k: v.passed for k, v in verdicts.items()} == {
        "floor": False,
        "room": True,
        "finite": True,
        "tracking": False,
        "attitude": True,
    }
    assert verdicts["floor"].line == "FAIL: Quad touched the floor 1 time (first at 0.600 s)"


QUIET = PhysicsParams(motor_noise=0.0)


def _plant(x0, commands, params=QUIET):
    dut = QuadrotorPlant(params, np.asarray(x0, dtype=float))
    context = dut.CreateDefaultContext()
    dut.GetInputPort("motor_thrusts").FixValue(context, np.asarray(commands, dtype=float))
    dut.GetInputPort("motor_noise").FixValue(context, np.full(8, 0.5))
    return dut, context, Simulator(dut, context)


def _state(p, v=(0.0, 0.0, 0.0)):
    return np.concatenate([p, quat_from_euler(0.0, 0.0, 0.0), v, np.zeros(3)])


def test_plant_counts_a_touchdown_after_a_fall_but_not_a_take_off():
    dut, context, simulator = _plant(_state((0.0, 0.0, -0.05)), [0.1] * 4)  # falls 5 cm
    assert dut.GetOutputPort("contacts").Eval(context).tolist() == [0.0, 0.0, 0.0]
    simulator.AdvanceTo(0.5)
    assert dut.GetOutputPort("contacts").Eval(context).tolist() == [1.0, 1.0, 0.0]
    lift = 0.5 * PhysicsParams().mass * GRAVITY  # 2 g thrust: leaves the floor at once
    dut, context, simulator = _plant(_state((0.0, 0.0, 0.0)), [lift] * 4)
    assert dut.GetOutputPort("contacts").Eval(context).tolist() == [1.0, 0.0, 0.0]
    simulator.AdvanceTo(0.2)
    assert dut.GetOutputPort("contacts").Eval(context).tolist() == [0.0, 0.0, 0.0]


def test_plant_counts_the_steps_stopped_at_a_wall():
    room = PhysicsParams(motor_noise=0.0, x_bounds=[-1.0, 1.0])
    hover = room.mass * GRAVITY / 4
    dut, context, simulator = _plant(_state((0.99, 0.0, -1.0), v=(1.0, 0.0, 0.0)), [hover] * 4, room)
    simulator.AdvanceTo(0.1)
    floor, touchdowns, wall_steps = dut.GetOutputPort("contacts").Eval(context).tolist()
    assert (floor, touchdowns) == (0.0, 0.0)
    assert wall_steps == 1.0  # 0.99 + 0.011 m leaves the room once; the velocity is then 0


@pytest.mark.slow
def test_a_vehicle_that_cannot_lift_off_fails_11(constant_q_ekf7, quad_drake_cli):
    # README "Flight-safety criteria": 11 with a 2 kg vehicle sits on the floor. The EKF7 misses
    # the touchdown (stopped within one 1 ms plant step, between two IMU samples, and beyond the
    # accelerometer's range), so it predicts a fall the GPS keeps correcting. With 11's earlier
    # constant-Q EKF7 (a velocity Q wide enough to follow the GPS) and the GPS gate off (the
    # 5-sigma gate rejects the GPS after the touchdown until its 5 s reset), the estimate still
    # passes: the estimation criterion alone passes a crashed flight. (The CLI in this process,
    # without plots: the verdict lines are what is checked.)
    command = ["run", "11_gps_update", "--no-plots"]
    heavy = ["--set", "vehicles.0.physics.mass=2.0"]
    sets = [arg for s in ["vehicles.0.estimator.gps_gate_sigma=0", *constant_q_ekf7] for arg in ("--set", s)]
    done = quad_drake_cli(*command, *heavy, *sets)
    assert done.returncode == 1, done.stderr
    assert "PASS: ABS(Quad.Est.E.Pos) was less than 1.000000 for at least 20.000000 seconds" in done.stdout
    assert "FAIL: Quad touched the floor 1 time (first at 0.700 s)" in done.stdout
    # As bundled (the tilt-aware EKF7 trusts its IMU more) the estimate fails too; so does the floor.
    bundled = quad_drake_cli(*command, *heavy)
    assert bundled.returncode == 1, bundled.stderr
    assert "FAIL: Quad touched the floor 1 time" in bundled.stdout
    assert "FAIL: ABS(Quad.Est.E.Pos)" in bundled.stdout
    assert "FAIL: Quad touched the floor" not in quad_drake_cli(*command, "--set", "end_time=2").stdout


def test_room_predicates_on_the_floor_at_a_wall_and_for_a_non_finite_state():
    params = PhysicsParams()
    assert on_floor(_state((0.0, 0.0, 0.0)), params) and not on_floor(_state((0.0, 0.0, -1e-9)), params)
    assert outside_room(_state((30.01, 0.0, -1.0)), params)
    assert outside_room(_state((0.0, 0.0, -40.1)), params)
    assert not outside_room(_state((29.99, -29.99, -39.99)), params)
    nan = _state((math.nan, math.nan, math.nan))
    assert not on_floor(nan, params) and not outside_room(nan, params)


def test_the_attitude_criterion_fails_a_planted_tilt():
    """The true tilt may not pass what the cascade commands (asin(sqrt 2 max_tilt), 81.9 deg for
    0.7) plus safety.tilt_margin (0.1 rad): 85 deg passes, a roll to 95 deg fails, on one sample."""
    s = scenario()
    (criterion,) = [c for c in safety_criteria(s) if c.signal == "Quad.Tilt"]
    assert criterion.threshold == pytest.approx(math.asin(math.sqrt(2.0) * 0.7) + 0.1)
    assert [c.signal for c in safety_criteria(scenario(attitude=False)) if c.signal.endswith("Tilt")] == []

    def verdict(roll_deg, pitch_deg=0.0):
        state = np.zeros((TIMES.size, 13))
        state[:, 3] = 1.0
        state[100, 3:7] = quat_from_euler(math.radians(roll_deg), math.radians(pitch_deg), 0.7)
        logs = {"state": state}
        signals = vehicle_signals("Quad", logs)
        tilt = signals["Quad.Tilt"].values
        assert tilt[0] == 0.0 and tilt[100] == pytest.approx(math.radians(abs(roll_deg) + abs(pitch_deg)))
        return evaluate_criterion(criterion, TIMES, lambda name: (signals[name].values, None)).passed

    assert verdict(85.0) is True
    assert verdict(95.0) is False
    assert verdict(-95.0) is False
    assert verdict(0.0, 120.0) is False
