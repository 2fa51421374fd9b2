"""The manual's "Wind, drag and the IMU" tables (docs/measurements/wind.md): estimation under
model mismatch, by campaign, and the cost of the air.

For every row of ROWS it runs a Monte Carlo campaign through the project's campaign API
(``quad_drake.campaigns.run_campaign``; run i flies seed S + i, exactly as
``quad-drake montecarlo <scenario> --runs N --seed S --fleet [--set ...]``) on the fleet runner,
and prints one markdown row: the pass rate with its 95 % Clopper-Pearson interval (scipy's
``binomtest``, as the campaign reports it), NEES and GPS NIS per degree of freedom with their 95 %
intervals, the worst state's mean e^2/P, the position RMSE and its efficiency against the
posterior Cramer-Rao bound. The seeds (from 7000) were never used to tune anything.

    nice -n 10 python benchmarks/wind_table.py --runs 200 --seed 7000
    nice -n 10 python benchmarks/wind_table.py --cost --pairs 5

``--cost`` instead flies 11_gps_update one Diagram per run (the per-vehicle path), still air
against 22's air (wind, moderate turbulence, drag, delta-velocity IMU) at 11's geometry, seed by
seed (paired), and prints the process CPU time per simulated second of each and their ratio.
``--landing`` prints the pass rates of the new scenarios (19-22) on `--runs` seeds from `--seed`.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import binomtest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from quad_drake import campaigns  # noqa: E402
from quad_drake.campaigns.output import summary as campaign_summary  # noqa: E402
from quad_drake.running import catalog  # noqa: E402
from quad_drake.running.simulation import run  # noqa: E402

EKF7_11, ESKF_11 = "11_gps_update", "11_gps_update_eskf"
EKF7_22, ESKF_22 = "22_gps_update_turbulence", "22_gps_update_turbulence_eskf"
REAL_IMU = (
    "vehicles.0.sensors.imu.delta_velocity=true",
    "vehicles.0.sensors.imu.accel_limit=156.9",
    "vehicles.0.sensors.imu.gyro_limit=34.9",
)
LAST_STEP_IMU = ("vehicles.0.sensors.imu.delta_velocity=false",)
SEVERE = ("vehicles.0.wind.turbulence=severe",)
STILL = (
    "vehicles.0.wind.turbulence=none",
    "vehicles.0.wind.mean=[0, 0, 0]",
    "vehicles.0.physics.rotor_drag=[0, 0, 0]",
    "vehicles.0.physics.parasitic_drag=[0, 0, 0]",
)
AIR_AT_11 = (
    "vehicles.0.physics.rotor_drag=[0.22, 0.22, 0.44]",
    "vehicles.0.physics.parasitic_drag=[0.005, 0.005, 0.01]",
    "vehicles.0.wind={mean: [2.12, 2.12, 0.0], turbulence: moderate}",
    *REAL_IMU,
)

ROWS = (
    ("EKF7", "still air (11)", "last step", EKF7_11, ()),
    ("EKF7", "still air", "delta-v, 16 g", EKF7_11, REAL_IMU),
    ("EKF7", "22's flight (at 3 m), still air, no drag", "delta-v, 16 g", EKF7_22, STILL),
    ("EKF7", "3 m/s + moderate, drag (22)", "delta-v, 16 g", EKF7_22, ()),
    ("EKF7", "3 m/s + moderate, drag", "last step", EKF7_22, LAST_STEP_IMU),
    ("EKF7", "3 m/s + severe, drag", "delta-v, 16 g", EKF7_22, SEVERE),
    (
        "EKF7 q_vel_z_std 0.075",
        "3 m/s + moderate, drag",
        "delta-v, 16 g",
        EKF7_22,
        ("vehicles.0.estimator.q_vel_z_std=0.075",),
    ),
    ("ESKF", "still air (11)", "last step", ESKF_11, ()),
    ("ESKF", "still air", "delta-v, 16 g", ESKF_11, REAL_IMU),
    ("ESKF", "22's flight (at 3 m), still air, no drag", "delta-v, 16 g", ESKF_22, STILL),
    ("ESKF", "3 m/s + moderate, drag (22)", "delta-v, 16 g", ESKF_22, ()),
    ("ESKF", "3 m/s + moderate, drag", "last step", ESKF_22, LAST_STEP_IMU),
    ("ESKF", "3 m/s + severe, drag", "delta-v, 16 g", ESKF_22, SEVERE),
)

HEADER = (
    "| estimator | air | IMU | runs | pass [95 % CI] | NEES/dof [95 % CI] | GPS NIS/dof | worst e²/P "
    "| pos RMSE x, y, z (m) | efficiency vs PCRB (x, y, z) |\n"
    "|---|---|---|---|---|---|---|---|---|---|"
)


def _stat(summary, name):
    row = next(r for r in summary["consistency"] if r["statistic"] == name)
    low, high = row["per_dof_ci95"]
    return f"{row['per_dof']:.3f} [{low:.3f}, {high:.3f}]"


def table_row(estimator, air, imu, scenario, overrides, runs, seed, batch):
    """One markdown row of the campaign `scenario` with `overrides` on `runs` seeds from `seed`."""
    config = catalog.load(scenario, None, list(overrides))
    campaign = campaigns.run_campaign(config, runs, seed=seed, progress=False, fleet_batch=batch)
    summary = campaign_summary(campaign)
    passed = sum(r.passed for r in campaign.records)
    ci = binomtest(passed, runs).proportion_ci(0.95, method="exact")
    worst = max(summary["state_consistency"].items(), key=lambda kv: abs(np.log(kv[1])))
    efficiency = {e["state"]: e for e in summary["efficiency"]}
    rmse = ", ".join(f"{efficiency[s]['rmse']:.3f}" for s in "XYZ")
    eff = ", ".join(f"{efficiency[s]['pcrb_efficiency']:.2f}" for s in "XYZ")
    return (
        f"| {estimator} | {air} | {imu} | {runs} | {passed}/{runs} [{ci.low:.3f}, {ci.high:.3f}] "
        f"| {_stat(summary, 'NEES')} | {_stat(summary, 'NIS gps')} | {worst[0]} {worst[1]:.2f} "
        f"| {rmse} | {eff} |"
    )


def cost(pairs):
    """Paired CPU s per simulated s of 11_gps_update, still air against the air of 22."""
    run(catalog.load(EKF7_11, 0, list(AIR_AT_11) + ["end_time=1"]))  # compile and warm up
    run(catalog.load(EKF7_11, 0, ["end_time=1"]))
    still, air = [], []
    for seed in range(pairs):
        for overrides, out in (((), still), (AIR_AT_11, air)):
            scenario = catalog.load(EKF7_11, seed, list(overrides))
            start = time.process_time()
            run(scenario)
            out.append((time.process_time() - start) / scenario.end_time)
    still, air = np.array(still), np.array(air)
    ratio = air / still
    print(f"11_gps_update, {pairs} seeds, CPU s per simulated s (process time, per-vehicle path):")
    print(f"  still air  {still.mean():.4f} (min {still.min():.4f})")
    print(f"  air of 22  {air.mean():.4f} (min {air.min():.4f})")
    print(f"  ratio air/still per seed: {', '.join(f'{r:.3f}' for r in ratio)}; mean {ratio.mean():.3f}")


def scenario_rates(runs, seed, batch):
    for name in ("19_windy_hover", "20_gust_figure_eight", "21_landing", EKF7_22, ESKF_22):
        config = catalog.load(name, None, [])
        campaign = campaigns.run_campaign(config, runs, seed=seed, progress=False, fleet_batch=batch)
        passed = sum(r.passed for r in campaign.records)
        ci = binomtest(passed, runs).proportion_ci(0.95, method="exact")
        failed = [r.seed for r in campaign.records if not r.passed]
        seeds = f"{seed}-{seed + runs - 1}"
        rate = f"{passed}/{runs} [{ci.low:.3f}, {ci.high:.3f}]"
        print(f"| {name} | {runs} (seeds {seeds}) | {rate} | {failed} |")


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--seed", type=int, default=7000)
    parser.add_argument("--batch", type=int, default=200)
    parser.add_argument("--only", default="", help="only the rows whose estimator label contains this")
    parser.add_argument("--cost", action="store_true")
    parser.add_argument("--pairs", type=int, default=5)
    parser.add_argument("--landing", action="store_true", help="the new scenarios' pass rates")
    args = parser.parse_args()
    if args.cost:
        cost(args.pairs)
        return
    if args.landing:
        scenario_rates(args.runs, args.seed, args.batch)
        return
    print(HEADER)
    for row in ROWS:
        if args.only in row[0]:
            print(table_row(*row, args.runs, args.seed, args.batch), flush=True)


if __name__ == "__main__":
    main()
