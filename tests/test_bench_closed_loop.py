"""benchmarks/bench_closed_loop.py: the handler breakdown, the layout floor, the baseline process."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest
from pydrake.systems.framework import Diagram

from quad_drake.running import catalog
from quad_drake.systems.plant import QuadrotorPlant

SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "bench_closed_loop.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_closed_loop", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_breakdown_times_every_ticking_system_and_restores_the_handlers(bench):
    step = QuadrotorPlant.__dict__["_first_step"]
    scenario = catalog.load("11_gps_update", None, ["end_time=0.2"])
    lines = bench.breakdown(scenario)
    names = [line.split()[0] for line in lines[1:-1]]
    for name in ("QuadrotorPlant._first_step", "QuadrotorPlant._second_step", "Ekf._update", "Imu._sample"):
        assert name in names
    per_tick = {line.split()[0]: float(line.split()[1].removesuffix("/tick")) for line in lines[1:-1]}
    assert per_tick["Ekf._update"] == pytest.approx(1.0, abs=0.01)  # 100 ticks in 0.2 s
    assert QuadrotorPlant.__dict__["_first_step"] is step


def test_the_baseline_runs_as_a_process_of_its_own():
    done = subprocess.run([sys.executable, str(SCRIPT), "--baseline-process", "0.5"], capture_output=True)
    assert done.returncode == 0, done.stderr


def _leaf_systems(diagram, kind):
    for system in diagram.GetSystems():
        if isinstance(system, Diagram):
            yield from _leaf_systems(system, kind)
        elif isinstance(system, kind):
            yield system


def test_the_layout_floor_runs_the_diagram_with_every_handler_emptied(bench):
    scenario = catalog.load("11_gps_update", None, ["end_time=0.1"])
    step = QuadrotorPlant.__dict__["_first_step"]
    with bench.replaced_handlers(bench._system_modules(), bench.empty):
        simulator = bench.scenario_simulator(scenario)
        simulator.AdvanceTo(scenario.end_time)
        diagram, context = simulator.get_system(), simulator.get_context()
        plant = next(_leaf_systems(diagram, QuadrotorPlant))
        state = plant.GetOutputPort("state").Eval(plant.GetMyContextFromRoot(context))
        initial = plant.GetOutputPort("state").Eval(plant.CreateDefaultContext())
        assert (state == initial).all()  # 50 ticks, and the plant never stepped
    assert QuadrotorPlant.__dict__["_first_step"] is step
    assert bench.layout_floor(scenario) > 0.0
