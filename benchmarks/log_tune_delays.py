"""Benchmark: ``quad-drake tune LOG`` recovers known sensor delays and noise from simulated logs.

Each seed flies 11_gps_update_eskf (20 s; the magnetometer's heading noise 0.02 rad so that a 40 ms
delay shows against it) once (``flightlogs.recording``); each case writes that run as a replay CSV
with the GPS and magnetometer samples logged at their arrival, the injected delay after their
measurement. The log tuner starts from PX4's default noise and zero delays (the replay's
defaults, the IMU noise set to the simulator's: it is not searched) and must recover each delay
within ±20 ms and each sensor noise std within ±25 %.

Usage: ``python benchmarks/log_tune_delays.py [--seeds 2001 2002 2003 2004] [--budget 90]
[--cases 0 1 2 3] [--cache DIR [--record-only]] [--markdown table.md]``; prints ``case | quantity |
true | recovered | seeds``. On a busy machine: record each seed once into a cache (one process
per seed with ``--record-only``), then one process per case.
"""

import argparse
import pickle
import tempfile
import time
from pathlib import Path

from quad_drake.flightlogs.recording import record_run, write_run_csv
from quad_drake.running import catalog
from quad_drake.tuning.logs import prepare, tune_logs
from quad_drake.tuning.settings import LogTuneSettings

CASES = ((0.0, 0.0), (0.05, 0.04), (0.1, 0.0), (0.2, 0.04))
"""(GPS delay s, magnetometer delay s) injected."""
TRUE_NOISE = {"gps_pos_xy": 0.7, "gps_pos_z": 2.0, "gps_vel_xy": 0.1, "gps_vel_z": 0.3, "heading": 0.02}
"""The simulator's sensor noise (GpsParams defaults; the heading's set below)."""
FLIGHT = ["end_time=20", "vehicles.0.sensors.mag.yaw_std=0.02"]
REPLAY = [
    "estimator.accel_std=[0.5, 0.5, 1.5]",
    "estimator.gyro_std=[0.5, 0.5, 0.5]",
    "estimator.estimate_biases=false",
]
"""The replay's IMU noise is the simulator's (ImuParams defaults, no bias): not searched here."""
DELAY_TOLERANCE = 0.020  # s
NOISE_TOLERANCE = 0.25  # relative


def recorded_run(seed, cache):
    """The RecordedRun of `seed` (kept in, or read from, the folder `cache` when given)."""
    path = None if cache is None else cache / f"seed{seed}.pkl"
    if path is not None and path.is_file():
        return pickle.loads(path.read_bytes())
    record = record_run(catalog.load("11_gps_update_eskf", seed, FLIGHT))
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(pickle.dumps(record))
    return record


def recovered(record, seed, case, budget, folder):
    """{dimension: tuned value} of the log tuner on the run `record` written with `case`'s delays."""
    path = write_run_csv(record, Path(folder) / f"seed{seed}.csv", {"gps": case[0], "mag": case[1]})
    problem = prepare(
        [str(path)], [], REPLAY, LogTuneSettings(budget=budget, curve_points=0, imu_noise=False)
    )
    result = tune_logs(problem, progress=False)
    return {d.name: d.value(x) for d, x in zip(problem.space, result.search.best.x, strict=True)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[2001, 2002, 2003, 2004])
    parser.add_argument("--budget", type=int, default=90)
    parser.add_argument(
        "--cases", type=int, nargs="+", default=list(range(len(CASES))), help="indices of CASES"
    )
    parser.add_argument("--cache", type=Path, help="folder keeping each seed's recorded run (pickle)")
    parser.add_argument(
        "--record-only", action="store_true", help="record the seeds into --cache, tune nothing"
    )
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()
    rows = []
    start = time.process_time()
    with tempfile.TemporaryDirectory() as folder:
        records = {seed: recorded_run(seed, args.cache) for seed in args.seeds}
        if args.record_only:
            return
        for case in [CASES[i] for i in args.cases]:
            found = []
            for seed in args.seeds:
                found.append(recovered(records[seed], seed, case, args.budget, folder))
                shown = ", ".join(f"{k} {v:.4g}" for k, v in found[-1].items())
                print(f"case {case} seed {seed}: {shown}", flush=True)
            label = f"GPS {1e3 * case[0]:.0f} ms, mag {1e3 * case[1]:.0f} ms"
            truth = {"gps_delay": case[0], "mag_delay": case[1], **TRUE_NOISE}
            for name, true in truth.items():
                values = [f[name] for f in found]
                if name.endswith("_delay"):
                    ok = sum(abs(v - true) <= DELAY_TOLERANCE for v in values)
                    shown = ", ".join(f"{1e3 * v:.0f}" for v in values) + " ms"
                    true_text = f"{1e3 * true:.0f} ms"
                else:
                    ok = sum(abs(v / true - 1.0) <= NOISE_TOLERANCE for v in values)
                    shown = ", ".join(f"{v:.3g}" for v in values)
                    true_text = f"{true:g}"
                rows.append(f"| {label} | {name} | {true_text} | {shown} | {ok}/{len(values)} |")
                print(rows[-1], flush=True)
    table = "\n".join(
        ["| case | quantity | true | recovered (per seed) | seeds within |", "|---|---|---|---|---|", *rows]
    )
    print(f"\n{table}\nCPU {time.process_time() - start:.0f} s (user+sys of this process)")
    if args.markdown:
        args.markdown.write_text(table + "\n")


if __name__ == "__main__":
    main()
