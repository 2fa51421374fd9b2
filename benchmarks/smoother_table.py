"""The RTS smoother against its ESKF on a scenario's runs: RMSE and NEES per state group.

Each seed: the scenario flown (``flightlogs.recording.record_run``), written as a replay CSV,
replayed through the same ESKF tick by tick (its estimate checked equal to the run's to 1e-9),
smoothed (``flightlogs.smoothing.smooth_run``) and both passes compared with the truth at every
2 ms tick. Prints a markdown table, one row per state group (position, velocity, attitude, the
IMU biases when estimated): the RMSE over all runs and ticks of the filter and of the smoother,
their ratio with a 95 % bootstrap interval over runs, the ratio the filter's own model predicts
for it (σ ratio: the square root of the smoother's mean error variance, the trace of its P block
over runs and ticks, over the filter's), and each pass's NEES per dof: the mean
over runs of each run's time-mean (``consistency.per_dof_interval``: Student's t interval over
runs) against the 95 % chi² interval of a mean of `runs` NEES values per tick
(``consistency.chi2_band``) and the share of ticks whose ensemble mean lies inside that band.

    PYTHONPATH=$PWD python benchmarks/smoother_table.py --first-seed 5000 --runs 100
    PYTHONPATH=$PWD python benchmarks/smoother_table.py --runs 30 \\
        --set vehicles.0.estimator.estimate_biases=true
"""

import argparse
import signal
import tempfile
import time

import numpy as np
from scipy.stats import bootstrap
from tqdm import tqdm

from quad_drake.estimation.vocabulary import nominal_errors
from quad_drake.flightlogs.recording import smooth_run
from quad_drake.judging.consistency import chi2_band, per_dof_interval
from quad_drake.running import catalog

GROUPS = {"position": slice(0, 3), "velocity": slice(3, 6), "attitude": slice(6, 9),
          "accel bias": slice(9, 12), "gyro bias": slice(12, 15)}  # fmt: skip
UNITS = {"position": "m", "velocity": "m/s", "attitude": "rad", "accel bias": "m/s²", "gyro bias": "rad/s"}


def per_dof_band(dof, runs):
    """95 % interval of the mean over `runs` of a chi²(dof) NEES, per dof (``chi2_band`` / dof)."""
    low, high = chi2_band(dof, runs)
    return low / dof, high / dof


def nees(errors, P, states):
    """(T,) NEES of the error columns `states` against the matching block of P (T, n, n)."""
    e = errors[:, states]
    block = P[:, states, states]
    return np.einsum("ti,ti->t", e, np.linalg.solve(block, e[:, :, None])[:, :, 0])


def one_run(scenario, directory):
    run = smooth_run(scenario, directory)
    n = run.filtered.P_updated.shape[1]
    out = {}
    for name, P, x in (
        ("filter", run.filtered.P_updated, run.filtered.x_updated),
        ("smoother", run.smoothed.P, run.smoothed.x),
    ):
        e = nominal_errors(x, run.truth, n)
        groups = {g: s for g, s in GROUPS.items() if s.stop <= n}
        out[name] = {
            "sq": {g: np.sum(e[:, s] ** 2, axis=1) for g, s in groups.items()},
            "var": {g: np.trace(P[:, s, s], axis1=1, axis2=2) for g, s in groups.items()},
            "axes": (np.mean(e[:, 0:3] ** 2, axis=0), np.mean(np.diagonal(P, axis1=1, axis2=2), axis=0)[0:3]),
            "nees": {g: nees(e, P, s) for g, s in groups.items()} | {"all": nees(e, P, slice(0, n))},
        }
    return out, n


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="11_gps_update_eskf")
    parser.add_argument("--first-seed", type=int, default=5000)
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    started = time.process_time()
    results = []
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # a stopped campaign prints what it has
    try:
        with tempfile.TemporaryDirectory() as directory:
            for seed in tqdm(range(args.first_seed, args.first_seed + args.runs), desc="runs"):
                scenario = catalog.load(args.scenario, seed=seed, overrides=args.set)
                results.append(one_run(scenario, directory))
    except KeyboardInterrupt:
        print(f"stopped: the table of the first {len(results)} of {args.runs} runs")
    args.runs = len(results)
    if not results:
        return
    n = results[0][1]
    runs = [r for r, _ in results]
    groups = [g for g, s in GROUPS.items() if s.stop <= n]
    length = min(len(r["filter"]["sq"]["position"]) for r in runs)
    band = per_dof_band(3, len(runs))
    print(
        f"\n{args.scenario}, seeds {args.first_seed}-{args.first_seed + args.runs - 1} ({len(runs)} runs, "
        f"{length} ticks each, error state n = {n}); CPU {time.process_time() - started:.0f} s (user+sys)"
    )
    print(
        f"NEES band per dof, 95 % chi² interval of the mean of {len(runs)} runs: "
        f"3 dof {band[0]:.3f}-{band[1]:.3f}, "
        f"{n} dof {per_dof_band(n, len(runs))[0]:.3f}-{per_dof_band(n, len(runs))[1]:.3f}\n"
    )
    print(
        "| state | RMSE filter | RMSE smoother | ratio [95 % CI] | σ ratio of the model "
        "| NEES/dof filter [95 % CI] | NEES/dof smoother [95 % CI] "
        "| ticks in χ² band filter / smoother |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for group in [*groups, "all"]:
        dof = n if group == "all" else 3
        cells = []
        if group != "all":
            sq = {p: np.array([r[p]["sq"][group][:length] for r in runs]) for p in ("filter", "smoother")}
            rmse = {p: float(np.sqrt(sq[p].mean())) for p in sq}
            per_run = (sq["filter"].mean(axis=1), sq["smoother"].mean(axis=1))
            ci = bootstrap(
                per_run,
                lambda f, s, axis=-1: np.sqrt(s.mean(axis=axis) / f.mean(axis=axis)),
                paired=True,
                random_state=0,
                vectorized=True,
            ).confidence_interval
            ratio = rmse["smoother"] / rmse["filter"]
            var = {p: np.mean([r[p]["var"][group][:length] for r in runs]) for p in ("filter", "smoother")}
            unit = UNITS[group]
            cells += [
                f"{rmse['filter']:.4g} {unit}",
                f"{rmse['smoother']:.4g} {unit}",
                f"{ratio:.3f} [{ci.low:.3f}, {ci.high:.3f}]",
                f"{np.sqrt(var['smoother'] / var['filter']):.3f}",
            ]
        else:
            cells += ["", "", "", ""]
        low, high = per_dof_band(dof, len(runs))
        shares = []
        for p in ("filter", "smoother"):
            values = np.array([r[p]["nees"][group][:length] for r in runs])
            mean, lo, hi = per_dof_interval(values.mean(axis=1), dof)
            cells.append(f"{mean:.3f} [{lo:.3f}, {hi:.3f}]")
            ensemble = values.mean(axis=0) / dof
            shares.append(f"{100 * np.mean((ensemble >= low) & (ensemble <= high)):.0f} %")
        cells.append(" / ".join(shares))
        print(f"| {group if group != 'all' else f'all {n} (NEES)'} | " + " | ".join(cells) + " |")

    axes = {p: np.mean([r[p]["axes"] for r in runs], axis=0) for p in ("filter", "smoother")}
    rmse_ratio = np.sqrt(axes["smoother"][0] / axes["filter"][0])
    sigma_ratio = np.sqrt(axes["smoother"][1] / axes["filter"][1])
    print(
        f"\nposition per axis N, E, D: RMSE ratio {np.array2string(rmse_ratio, precision=3)}, "
        f"σ ratio of the model {np.array2string(sigma_ratio, precision=3)}; σ filter "
        f"{np.array2string(np.sqrt(axes['filter'][1]), precision=4)} m, σ smoother "
        f"{np.array2string(np.sqrt(axes['smoother'][1]), precision=4)} m"
    )


if __name__ == "__main__":
    main()
