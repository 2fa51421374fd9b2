"""Fleet estimator speed: CPU microseconds per vehicle per 2 ms tick of ``build_estimator(vehicle, n=N)``.

A source system publishes N vehicles' IMU samples every tick (from a bank of seeded random
samples), a fresh magnetometer sample every 5 ticks and a fresh GPS sample every 50 (100 Hz and
10 Hz, as the scenarios), so the figure includes the gated updates and the PSD check at each
GPS sample. The source alone is timed too and subtracted: ``estimator`` is what the estimator
Diagram costs (its handlers, port reads and Drake's event dispatch); ``vs scalar`` is the
per-vehicle estimator of ``systems/estimators.py`` (one vehicle) over the fleet's cost per
vehicle, measured in the same run (a ratio that survives machine load). The issue's budget for the
whole fleet vehicle (11_gps_update at >= 5,000 runs/min on 2 cores) is about 1 us per
vehicle-tick for the estimator.

    python benchmarks/bench_fleet_estimators.py [--seconds 1.0] [--sizes 1 100 1000] [--kinds ekf7 eskf]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from quad_drake.config.schema import GpsParams, ImuParams, MagParams, SensorsConfig, VehicleConfig  # noqa: E402
from quad_drake.conventions import GRAVITY, NO_SAMPLE_STAMP, ONBOARD_PERIOD  # noqa: E402
from quad_drake.estimation.registry import EskfEstimatorConfig  # noqa: E402
from quad_drake.systems.estimators import build_estimator  # noqa: E402

BANK = 16
"""Distinct random IMU samples the source cycles through."""
GPS_TICKS, MAG_TICKS = 50, 5


class SensorSource(LeafSystem):
    """N vehicles' ``imu``, ``gps``, ``mag`` samples (state ports), refreshed at t_k (offset 0)."""

    def __init__(self, n, seed=0):
        super().__init__()
        rng = np.random.default_rng(seed)
        self._n = n
        level = np.array([0.0, 0.0, -GRAVITY, 0.0, 0.0, 0.0])
        self._imu = level + rng.normal(scale=[0.3, 0.3, 0.3, 0.05, 0.05, 0.05], size=(BANK, n, 6))
        self._gps = np.column_stack([np.tile([0.0, 0.0, -1.0], (n, 1)), np.zeros((n, 3))])
        self._gps = self._gps + rng.normal(scale=[0.7, 0.7, 2.0, 0.1, 0.1, 0.3], size=(BANK, n, 6))
        self._mag = rng.normal(scale=0.1, size=(BANK, n))
        imu = self.DeclareDiscreteState(n * 6)
        gps = self.DeclareDiscreteState(np.tile([0.0] * 6 + [NO_SAMPLE_STAMP], n))
        mag = self.DeclareDiscreteState(np.tile([0.0, NO_SAMPLE_STAMP], n))
        self.DeclareStateOutputPort("imu", imu)
        self.DeclareStateOutputPort("gps", gps)
        self.DeclareStateOutputPort("mag", mag)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, 0.0, self._update)

    def _update(self, context, discrete_state):
        tick = round(context.get_time() / ONBOARD_PERIOD)
        discrete_state.get_mutable_value(0)[:] = self._imu[tick % BANK].ravel()
        if tick % MAG_TICKS == 0:
            mag = discrete_state.get_mutable_value(2).reshape(self._n, 2)
            mag[:, 0] = self._mag[tick % BANK]
            mag[:, 1] = tick * ONBOARD_PERIOD
        if tick % GPS_TICKS == 0:
            gps = discrete_state.get_mutable_value(1).reshape(self._n, 7)
            gps[:, 0:6] = self._gps[tick % BANK]
            gps[:, 6] = tick * ONBOARD_PERIOD


def cpu_seconds(n, kind, seconds, scalar=False):
    """CPU s of simulating `seconds` of the source (kind None) or the source + a fleet estimator
    (or, with `scalar`, the per-vehicle estimator of ``systems/estimators.py``; n = 1)."""
    builder = DiagramBuilder()
    source = builder.AddSystem(SensorSource(n))
    if kind is not None:
        sensors = SensorsConfig(imu=ImuParams(), gps=GpsParams(), mag=MagParams())
        vehicle = VehicleConfig(sensors=sensors)
        if kind == "eskf":
            vehicle = VehicleConfig(sensors=sensors, estimator=EskfEstimatorConfig())
        diagram = build_estimator(vehicle) if scalar else build_estimator(vehicle, n=n)
        estimator = builder.AddSystem(diagram)
        for name in ("imu", "gps", "mag"):
            builder.Connect(source.GetOutputPort(name), estimator.GetInputPort(name))
    simulator = Simulator(builder.Build())
    simulator.Initialize()
    simulator.AdvanceTo(0.1)  # warm-up: first-call costs out of the figure
    start = time.process_time()
    simulator.AdvanceTo(0.1 + seconds)
    return time.process_time() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated s per figure (500 ticks/s)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 100, 1000])
    parser.add_argument("--kinds", nargs="+", default=["ekf7", "eskf"], choices=["ekf7", "eskf"])
    args = parser.parse_args(argv)
    ticks = round(args.seconds / ONBOARD_PERIOD)
    header = f"{'estimator':>9} {'N':>6} {'us/vehicle-tick':>16} {'us/tick':>9} {'vs scalar':>10}"
    print(f"{header}  ({ticks} ticks, source subtracted)")
    source = cpu_seconds(1, None, args.seconds)
    scalar = {kind: (cpu_seconds(1, kind, args.seconds, scalar=True) - source) / ticks for kind in args.kinds}
    for kind in args.kinds:
        print(f"{kind:>9} {'scalar':>6} {scalar[kind] * 1e6:>16.3f} {scalar[kind] * 1e6:>9.1f} {1.0:>9.1f}x")
    for n in args.sizes:
        source = cpu_seconds(n, None, args.seconds)
        for kind in args.kinds:
            cost = (cpu_seconds(n, kind, args.seconds) - source) / ticks
            speedup = scalar[kind] * n / cost
            print(f"{kind:>9} {n:>6} {cost / n * 1e6:>16.3f} {cost * 1e6:>9.1f} {speedup:>9.1f}x")


if __name__ == "__main__":
    main()
