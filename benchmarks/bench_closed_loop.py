"""Closed-loop speed in CPU time: ``11_gps_update`` against a Drake C++ baseline, in-process and as
whole processes, all measured in one run of this script.

Four figures (and the floor below), each the median of ``--runs`` rounds (one round runs them
in turn, so a busy machine slows all of them alike):

- **ours in-process**: CPU s (``time.process_time``) of ``Simulator.Initialize`` + ``AdvanceTo``
  of the scenario's full closed loop (every sensor, filter and logger), build excluded;
- **ours, whole process**: CPU s (user + system, ``resource.getrusage(RUSAGE_CHILDREN)``) of
  ``python -m quad_drake run 11_gps_update --no-plots`` (imports, loading, simulation, the
  verdicts and the saved run);
- **C++ baseline in-process**: ``pydrake.examples.QuadrotorPlant`` under its
  ``StabilizingLQRController``, fixed 1 ms RK2 steps, logged every 5 ms, over the same
  simulated time;
- **C++ baseline, whole process**: the same loop as a process of its own (this script with
  ``--baseline-process SECONDS``: imports of numpy and pydrake, build, simulation).

The ratios to the baseline are the machine-independent figures; the issue's targets are 35x real
time in CPU for the in-process run and a whole process within 4x the baseline's. Child processes
run with bytecode caching on (as an installed package has it), after one warm-up each.
Each round also times the **layout floor**: the same in-process run with every handler of
``quad_drake.systems`` emptied (same systems, ports, events, noise sources and loggers, no
maths), the least any handler code could cost. ``--breakdown`` adds one timed in-process run:
CPU per 2 ms tick of each system's handlers.

    python benchmarks/bench_closed_loop.py [--runs 3] [--breakdown] [scenario]
"""

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.handlers import empty, replaced_handlers  # noqa: E402

TARGET_REAL_TIME_FACTOR = 35.0
"""Issue 12 target: in-process CPU time of 11_gps_update at >= 35x real time."""
TARGET_PROCESS_RATIO = 4.0
"""Issue 12 target: the whole ``quad-drake run`` process within 4x the C++ baseline process's CPU."""
LOG_PERIOD, PHYSICS_PERIOD = 0.005, 0.001  # s, as quad_drake.conventions (not imported: see main)


def _timed_advance(simulator, end_time):
    """CPU s of Initialize + AdvanceTo(end_time)."""
    cpu = time.process_time()
    simulator.Initialize()
    simulator.AdvanceTo(end_time)
    return time.process_time() - cpu


def scenario_simulator(scenario):
    """A seeded Simulator of a ScenarioConfig's diagram, not yet initialised."""
    from pydrake.common import RandomGenerator
    from pydrake.systems.analysis import Simulator

    from quad_drake.running.simulation import build_diagram

    diagram, _ = build_diagram(scenario)
    simulator = Simulator(diagram)
    diagram.SetRandomContext(simulator.get_mutable_context(), RandomGenerator(scenario.seed))
    return simulator


def time_scenario(scenario):
    """CPU s of one seeded run of a ScenarioConfig (build excluded)."""
    return _timed_advance(scenario_simulator(scenario), scenario.end_time)


def time_cpp_baseline(end_time):
    """CPU s of the C++ quadrotor + LQR loop over end_time s (build excluded)."""
    import numpy as np
    from pydrake.examples import QuadrotorPlant, StabilizingLQRController
    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator, SimulatorConfig
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import LogVectorOutput

    builder = DiagramBuilder()
    plant = builder.AddSystem(QuadrotorPlant())
    controller = builder.AddSystem(StabilizingLQRController(plant, [0.0, 0.0, 1.0]))
    builder.Connect(plant.get_output_port(0), controller.get_input_port(0))
    builder.Connect(controller.get_output_port(0), plant.get_input_port(0))
    LogVectorOutput(plant.get_output_port(0), builder, publish_period=LOG_PERIOD)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    ApplySimulatorConfig(
        SimulatorConfig(
            integration_scheme="runge_kutta2", max_step_size=PHYSICS_PERIOD, use_error_control=False
        ),
        simulator,
    )
    x0 = np.zeros(12)
    x0[0:6] = [0.5, -0.3, 1.5, 0.1, -0.1, 0.2]  # displaced and tilted: the LQR flies back to (0, 0, 1)
    plant.GetMyContextFromRoot(simulator.get_mutable_context()).SetContinuousState(x0)
    return _timed_advance(simulator, end_time)


def _child_env():
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    env.setdefault("MPLBACKEND", "Agg")
    return env


def process_cpu(command):
    """CPU s (user + system) of `command` run to completion as a child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(command, env=_child_env(), cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _system_modules():
    from quad_drake.systems import controller, estimators, faults, plant, sensors, trajectory

    return controller, estimators, faults, plant, sensors, trajectory


def layout_floor(scenario):
    """CPU s of one run of the scenario's Diagram with every handler of quad_drake.systems
    emptied (a no-op: states and outputs keep what they hold): the same systems, ports, events
    and steps, Drake's noise sources and loggers, and no maths. No handler code, however fast,
    makes the run cheaper than this."""

    with replaced_handlers(_system_modules(), empty):
        return time_scenario(scenario)


def breakdown(scenario):
    """Lines: CPU per 2 ms tick of each system's handlers (exclusive of the handlers they cause
    to run through their input ports) over one run, and the rest: Drake's framework, the noise
    sources, port plumbing between handlers and the logger. Each handler is timed with
    ``time.thread_time`` (CPU, not wall) by a wrapper; its two clock reads (~1 us) are included."""
    totals, calls, stack = {}, {}, [0.0]

    def timed(key, method):
        def handler(self, context, arg):
            stack.append(0.0)
            start = time.thread_time()
            try:
                return method(self, context, arg)
            finally:
                elapsed = time.thread_time() - start
                nested = stack.pop()
                stack[-1] += elapsed
                totals[key] = totals.get(key, 0.0) + elapsed - nested
                calls[key] = calls.get(key, 0) + 1

        return handler

    with replaced_handlers(_system_modules(), timed):
        total = time_scenario(scenario)
    ticks = scenario.end_time / 0.002
    lines = [f"breakdown of one run: {total:.3f} s CPU = {1e6 * total / ticks:.1f} us per 2 ms tick"]
    for key in sorted(totals, key=totals.get, reverse=True):
        lines.append(
            f"  {key:<38}{calls[key] / ticks:5.2f}/tick {1e6 * totals[key] / ticks:7.1f} us/tick "
            f"{100 * totals[key] / total:5.1f} %"
        )
    rest = total - sum(totals.values())
    lines.append(
        f"  {'the rest (framework, noise, logger)':<44}{1e6 * rest / ticks:7.1f} us/tick "
        f"{100 * rest / total:5.1f} %"
    )
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "scenario", nargs="?", default="11_gps_update", help="bundled scenario (default 11_gps_update)"
    )
    parser.add_argument("--runs", type=int, default=3, help="rounds, >= 1 (default 3)")
    parser.add_argument("--breakdown", action="store_true", help="also time each handler over one run")
    parser.add_argument("--baseline-process", type=float, metavar="SECONDS", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.baseline_process is not None:  # the C++ baseline as a whole process: no quad_drake imports
        time_cpp_baseline(args.baseline_process)
        return 0
    if args.runs < 1:
        parser.error("--runs must be >= 1")

    from quad_drake.running import catalog

    scenario = catalog.load(args.scenario)
    end_time = scenario.end_time
    with tempfile.TemporaryDirectory() as out:
        ours_process = [sys.executable, "-m", "quad_drake", "run", args.scenario, "--no-plots", "--out", out]
        base_process = [sys.executable, str(Path(__file__).resolve()), "--baseline-process", str(end_time)]
        time_scenario(scenario), process_cpu(ours_process), process_cpu(base_process)  # warm-up
        rounds = []
        for _ in range(args.runs):
            rounds.append(
                (
                    time_scenario(scenario),
                    time_cpp_baseline(end_time),
                    process_cpu(ours_process),
                    process_cpu(base_process),
                    layout_floor(scenario),
                )
            )
    ours, base, ours_whole, base_whole, floor = (
        statistics.median(column) for column in zip(*rounds, strict=True)
    )
    ratio = statistics.median(r[0] / r[1] for r in rounds)
    whole_ratio = statistics.median(r[2] / r[3] for r in rounds)

    print(
        f"{args.scenario}, {end_time:g} s simulated; CPU s, median of {args.runs} rounds "
        "(ratios: median of the rounds' ratios)"
    )
    print(f"{'':34}{'CPU s':>8}{'x real':>8}")
    print(f"{'ours, in-process':34}{ours:8.3f}{end_time / ours:8.1f}")
    print(f"{'ours, whole process':34}{ours_whole:8.3f}{end_time / ours_whole:8.1f}")
    print(f"{'C++ baseline, in-process':34}{base:8.3f}{end_time / base:8.1f}")
    print(f"{'C++ baseline, whole process':34}{base_whole:8.3f}{end_time / base_whole:8.1f}")
    print(f"{'ours, layout floor (no-op handlers)':34}{floor:8.3f}{end_time / floor:8.1f}")
    print(f"ratio in-process (ours / C++): {ratio:.1f}; whole process (ours / C++): {whole_ratio:.2f}")
    verdict = "met" if end_time / ours >= TARGET_REAL_TIME_FACTOR else "NOT met"
    print(f"target {TARGET_REAL_TIME_FACTOR:g}x real time in-process: {verdict} ({end_time / ours:.1f}x)")
    reachable = "within" if end_time / floor >= TARGET_REAL_TIME_FACTOR else "beyond"
    print(
        f"  the Diagram's layout alone runs at {end_time / floor:.1f}x real time (handlers "
        f"{ours - floor:.3f} s, layout {floor:.3f} s): {TARGET_REAL_TIME_FACTOR:g}x is {reachable} its reach"
    )
    verdict = "met" if whole_ratio <= TARGET_PROCESS_RATIO else "NOT met"
    print(
        f"target whole process <= {TARGET_PROCESS_RATIO:g}x the C++ baseline's: {verdict} "
        f"({whole_ratio:.2f}x)"
    )
    if args.breakdown:
        print("\n".join(breakdown(scenario)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
