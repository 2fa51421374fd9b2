"""The measurements of docs/measurements/failsafe.md that are not a campaign table.

python benchmarks/failsafe_checks.py walls --runs 40 [--set KEY=VALUE ...]
    where the EKF7's walls come from in 23's 10 s outage with the failsafe: per run that hits
    a wall, when, when the failsafe began and where the vehicle and its estimate were then
python benchmarks/failsafe_checks.py tracking --seed 2000 --runs 200
    23's largest true tracking error per run in each window (before, during, after the outage)
python benchmarks/failsafe_checks.py batch
    a fleet run in a batch of 8 and alone: bit-identical logs (no cross-vehicle mixing)
python benchmarks/failsafe_checks.py noise
    Drake's RandomSource against the fleet's NoiseStreamSource: distribution and redraw times
python benchmarks/failsafe_checks.py compare FLEET_RUN POOL_RUN [POOL_RUN ...]
    two campaigns of the same scenario (saved `quad-drake montecarlo` folders; a side may be
    several folders, e.g. chunks of seeds): per criterion (matched by its text) the pass counts
    with their Clopper-Pearson intervals and Fisher's exact p, and the run summaries' medians
    with the Mann-Whitney p, over the seeds both sides flew
"""

import argparse
import csv
import json
from pathlib import Path

import numpy as np

EKF7 = (
    "vehicles.0.estimator={kind: ekf7, q_pos_xy_std: 0.05, q_vel_xy_std: 0.35, q_vel_z_std: 0.2, "
    "q_yaw_std: 0.06, gps_pos_xy_std: 0.7, gps_pos_z_std: 2.0}"
)


def walls(seed, runs, overrides):
    from quad_drake.campaigns.fleet.diagram import run_fleet
    from quad_drake.running import catalog

    failsafe = ["vehicles.0.failsafe={}", "safety.landing_time=15", "safety.tracking=false"]
    scenario = catalog.load("23_gps_outage_baro", overrides=[EKF7, *failsafe, *overrides])
    seeds = np.arange(seed, seed + runs)
    t, logs, _ = run_fleet(scenario, seeds)
    quad = logs["Quad"]
    hits, phase = quad["contacts"][..., 2], quad["failsafe"][..., 2]
    state, estimate = quad["state"], quad["estimated_state"]
    for j, s in enumerate(seeds):
        if not (hits[:, j] > 0).any():
            continue
        entered = (phase[:, j] >= 1).any()
        k = int(np.argmax(phase[:, j] >= 1)) if entered else 0
        print(
            f"seed {s}: wall at {t[np.argmax(hits[:, j] > 0)]:.2f} s, failsafe from "
            f"{t[k] if entered else float('nan'):.2f} s; then true p {np.round(state[k, j, 0:2], 1)} "
            f"v {np.round(state[k, j, 7:9], 1)}, estimated p {np.round(estimate[k, j, 0:2], 1)} "
            f"v {np.round(estimate[k, j, 7:9], 1)}"
        )
    print(f"runs at a wall: {int((hits[-1] > 0).sum())} of {runs}")


def tracking(seed, runs):
    from quad_drake.campaigns.fleet.diagram import run_fleet
    from quad_drake.judging.signals import vehicle_signals
    from quad_drake.running import catalog

    scenario = catalog.load("23_gps_outage_baro")
    windows = [(0, 10), (10, 20), (20, 23), (23, 25.1)]
    maxima = []
    for start in range(seed, seed + runs, 100):
        t, logs, _ = run_fleet(scenario, np.arange(start, min(start + 100, seed + runs)))
        error = vehicle_signals("Quad", logs["Quad"])["Quad.PosFollowErr"].values
        maxima.append([error[(t >= a) & (t < b)].max(axis=0) for a, b in windows])
    m = np.concatenate(maxima, axis=1)
    for (a, b), row in zip(windows, m, strict=True):
        q = np.quantile(row, [0.5, 0.95, 0.99, 1.0])
        print(
            f"[{a}, {b}) s: largest PosFollowErr median {q[0]:.2f}, p95 {q[1]:.2f}, p99 {q[2]:.2f}, "
            f"max {q[3]:.2f} m; above 6 m in {(row > 6).sum()}/{row.size}"
        )


def batch():
    from quad_drake.campaigns.fleet.diagram import run_fleet
    from quad_drake.running import catalog

    scenario = catalog.load("23_gps_outage_baro", overrides=[EKF7])
    seeds = np.arange(1000, 1008)
    _, together, _ = run_fleet(scenario, seeds)
    for j in (0, 3, 7):
        _, alone, _ = run_fleet(scenario, seeds[j : j + 1])
        differ = [
            name
            for name in alone["Quad"]
            if not np.array_equal(together["Quad"][name][:, j], alone["Quad"][name][:, 0], equal_nan=True)
        ]
        print(f"seed {seeds[j]}: in a batch of 8 vs alone:", differ or "every log bit-identical")


def noise():
    from pydrake.common import RandomDistribution, RandomGenerator
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import LogVectorOutput, RandomSource
    from scipy import stats

    from quad_drake.systems.noise import NoiseStreamSource

    cases = (
        (RandomDistribution.kGaussian, 0.002),
        (RandomDistribution.kGaussian, 0.1),
        (RandomDistribution.kUniform, 0.002),
    )
    for distribution, period in cases:
        builder = DiagramBuilder()
        drake = builder.AddSystem(RandomSource(distribution, 6, period))
        ours = builder.AddSystem(NoiseStreamSource(distribution, 6, period, [7], "Quad/x"))
        logs = [LogVectorOutput(s.get_output_port(0), builder, publish_period=period) for s in (drake, ours)]
        diagram = builder.Build()
        simulator = Simulator(diagram)
        context = simulator.get_mutable_context()
        diagram.SetRandomContext(context, RandomGenerator(7))
        simulator.AdvanceTo(400 * period if period > 0.01 else 40.0)
        a, o = (log.FindLog(context).data().ravel() for log in logs)

        def lag1(x):
            column = x.reshape(-1, 6)[:, 0]
            return np.corrcoef(column[1:], column[:-1])[0, 1]

        print(
            f"{distribution} every {period} s, {a.size} values: mean {a.mean():+.4f} vs {o.mean():+.4f}, "
            f"std {a.std():.4f} vs {o.std():.4f}, lag-1 autocorrelation {lag1(a):+.3f} vs {lag1(o):+.3f}, "
            f"KS p = {stats.ks_2samp(a, o).pvalue:.3f}"
        )


SUMMARIES = (
    "Quad.Est.E.Pos.rms",
    "Quad.Est.E.Z.max",
    "Quad.Est.E.Yaw.rms",
    "Quad.PosFollowErr.max",
    "Quad.NEES.mean",
    "Quad.NIS.gps.mean",
)
"""The run summaries (runs.csv columns) whose distributions `compare` sets side by side."""


def _campaign_runs(folders) -> tuple[dict[str, np.ndarray], list[str]]:
    """(one array per runs.csv column, the criteria's texts) of saved campaign folders; a
    criterion's pass column is named by its text (``|Quad.Est.E.Z| < 0.5 m ...``), so campaigns
    whose criteria come in another order match."""
    rows, texts = [], []
    for folder in folders:
        criteria = json.loads((Path(folder) / "summary.json").read_text())["criteria"]
        names = {f"{c['column']}.passed": c["criterion"] for c in criteria}
        texts += [t for t in names.values() if t not in texts]
        with open(Path(folder) / "runs.csv", newline="") as f:
            rows += [{names.get(k, k): v for k, v in row.items()} for row in csv.DictReader(f)]
    return {key: np.array([float(row[key]) for row in rows]) for key in rows[0]}, texts


def compare(fleet_folder, pool_folders):
    from scipy import stats

    from quad_drake.judging.consistency import binomial_interval

    (fleet, fleet_criteria), (pool, pool_criteria) = (
        _campaign_runs([fleet_folder]),
        _campaign_runs(pool_folders),
    )
    seeds = np.intersect1d(fleet["seed"], pool["seed"])
    fleet = {k: v[np.isin(fleet["seed"], seeds)] for k, v in fleet.items()}
    pool = {k: v[np.isin(pool["seed"], seeds)] for k, v in pool.items()}
    n = len(seeds)
    print(f"{n} seeds both sides flew ({int(seeds.min())}-{int(seeds.max())})")
    print("| criterion | fleet | per-vehicle pool | Fisher's exact p |\n|---|---|---|---|")
    criteria = [text for text in fleet_criteria if text in pool_criteria]
    for name in [*criteria, "passed"]:
        a, b = int(fleet[name].sum()), int(pool[name].sum())
        cells = [
            f"{k}/{n} [{100 * lo:.1f}, {100 * hi:.1f}]"
            for k in (a, b)
            for lo, hi in [binomial_interval(k, n)]
        ]
        p = stats.fisher_exact([[a, n - a], [b, n - b]])[1]
        print(f"| {'all criteria' if name == 'passed' else name} | {cells[0]} | {cells[1]} | {p:.3g} |")
    print("| run summary (median) | fleet | per-vehicle pool | Mann-Whitney p |")
    for name in SUMMARIES:
        x, y = fleet[name][np.isfinite(fleet[name])], pool[name][np.isfinite(pool[name])]
        p = stats.mannwhitneyu(x, y).pvalue
        print(f"| {name} | {np.median(x):.4g} | {np.median(y):.4g} | {p:.3g} |")


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("what", choices=("walls", "tracking", "batch", "noise", "compare"))
    parser.add_argument("folders", nargs="*", help="compare: the fleet's campaign folder, then the pool's")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--runs", type=int, default=40)
    parser.add_argument("--set", action="append", default=[], dest="overrides")
    args = parser.parse_args()
    if args.what == "walls":
        walls(args.seed, args.runs, args.overrides)
    elif args.what == "tracking":
        tracking(args.seed, args.runs)
    elif args.what == "batch":
        batch()
    elif args.what == "compare":
        if len(args.folders) < 2:
            parser.error("compare needs the fleet's campaign folder and at least one of the pool's")
        compare(args.folders[0], args.folders[1:])
    else:
        noise()


if __name__ == "__main__":
    main()
