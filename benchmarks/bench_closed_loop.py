"""Closed-loop speed: wall time and real-time factor of whole scenarios, against a Drake C++ baseline.

Each scenario runs as ``quad-drake run`` simulates it (every sensor, filter and logger; build
and log extraction excluded), ``--runs`` times; the table shows medians. In the same process
the C++ baseline -- ``pydrake.examples.QuadrotorPlant`` under its ``StabilizingLQRController``,
integrated with fixed 1 ms RK2 steps and logged every 5 ms -- runs over the same simulated
time, so ``ratio`` = scenario wall / baseline wall is a machine-independent figure that
survives load from other processes better than the wall times themselves.

    python benchmarks/bench_closed_loop.py [--runs 5] [scenario ...]
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from pydrake.common import RandomGenerator
from pydrake.examples import QuadrotorPlant, StabilizingLQRController
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from quad_drake import catalog  # noqa: E402
from quad_drake import conventions as c  # noqa: E402
from quad_drake.simulation import build_diagram  # noqa: E402

TARGET_REAL_TIME_FACTOR = 25.0
"""Issue target for 11_gps_update on the 2-core reference machine."""


def _timed_advance(simulator, end_time):
    """(wall s, CPU s) of Initialize + AdvanceTo(end_time)."""
    wall, cpu = time.perf_counter(), time.process_time()
    simulator.Initialize()
    simulator.AdvanceTo(end_time)
    return time.perf_counter() - wall, time.process_time() - cpu


def time_scenario(scenario):
    """(wall s, CPU s, Simulator steps) of one seeded run of a ScenarioConfig."""
    diagram, _ = build_diagram(scenario)
    simulator = Simulator(diagram)
    diagram.SetRandomContext(simulator.get_mutable_context(), RandomGenerator(scenario.seed))
    wall, cpu = _timed_advance(simulator, scenario.end_time)
    return wall, cpu, simulator.get_num_steps_taken()


def time_cpp_baseline(end_time):
    """(wall s, CPU s, Simulator steps) of the C++ quadrotor + LQR loop over end_time s."""
    builder = DiagramBuilder()
    plant = builder.AddSystem(QuadrotorPlant())
    controller = builder.AddSystem(StabilizingLQRController(plant, [0.0, 0.0, 1.0]))
    builder.Connect(plant.get_output_port(0), controller.get_input_port(0))
    builder.Connect(controller.get_output_port(0), plant.get_input_port(0))
    LogVectorOutput(plant.get_output_port(0), builder, publish_period=c.LOG_PERIOD)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    ApplySimulatorConfig(
        SimulatorConfig(
            integration_scheme="runge_kutta2", max_step_size=c.PHYSICS_PERIOD, use_error_control=False
        ),
        simulator,
    )
    x0 = np.zeros(12)
    x0[0:6] = [0.5, -0.3, 1.5, 0.1, -0.1, 0.2]  # displaced and tilted: the LQR flies back to (0, 0, 1)
    plant.GetMyContextFromRoot(simulator.get_mutable_context()).SetContinuousState(x0)
    wall, cpu = _timed_advance(simulator, end_time)
    return wall, cpu, simulator.get_num_steps_taken()


def _medians(samples):
    return [statistics.median(column) for column in zip(*samples, strict=True)]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "scenarios",
        nargs="*",
        default=["11_gps_update"],
        help="bundled scenario names (default: 11_gps_update)",
    )
    parser.add_argument("--runs", type=int, default=5, help="runs per scenario, >= 1 (default 5)")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be >= 1")

    rows = []
    for name in args.scenarios:
        scenario = catalog.load(name)
        time_scenario(scenario)  # warm-up: imports, first-call caches
        wall, cpu, steps = _medians([time_scenario(scenario) for _ in range(args.runs)])
        base_wall, base_cpu, _ = _medians([time_cpp_baseline(scenario.end_time) for _ in range(args.runs)])
        rows.append((name, scenario.end_time, wall, cpu, steps, base_wall, base_cpu))

    print(f"median of {args.runs} runs; wall = Initialize + AdvanceTo; ratio = scenario wall / C++ wall")
    header = (
        f"{'scenario':<24}{'sim s':>7}{'wall s':>9}{'x real':>8}{'CPU s':>8}{'steps/ms':>10}"
        f"{'C++ wall s':>12}{'C++ x real':>12}{'ratio':>8}"
    )
    print(header)
    print("-" * len(header))
    for name, end_time, wall, cpu, steps, base_wall, _ in rows:
        print(
            f"{name:<24}{end_time:>7.1f}{wall:>9.3f}{end_time / wall:>8.1f}{cpu:>8.3f}"
            f"{steps / (end_time * 1000.0):>10.2f}{base_wall:>12.4f}{end_time / base_wall:>12.0f}"
            f"{wall / base_wall:>8.1f}"
        )
    for name, end_time, wall, *_ in rows:
        if name == "11_gps_update":
            verdict = "met" if end_time / wall >= TARGET_REAL_TIME_FACTOR else "NOT met"
            print(
                f"target {TARGET_REAL_TIME_FACTOR:g}x real time for {name}: {verdict} "
                f"({end_time / wall:.1f}x)"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
