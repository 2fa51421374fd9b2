"""Is the ESKF honest while it dead-reckons? Per-dof consistency in a GPS outage window.

Usage: python benchmarks/outage_consistency.py [scenario] [--runs 100] [--seed 7000]
       [--start 10] [--end 20] [--set KEY=VALUE ...]

Flies ``--runs`` runs of the scenario (default 23_gps_outage_baro, whose GPS is out from 10 s to
20 s) as one fleet (``quad_drake.campaigns.fleet``) and judges the estimate's true error against
its own covariance in the window [start, end) s, per error-state dof d of the vocabulary's NEES
states (the ESKF's X Y Z VX VY VZ AttN AttE AttD):

- **band share** (the target's measure): at each log sample in the window, the mean over the runs
  of e_d^2 / P_dd lies inside the two-sided 95 % band of the mean of ``--runs`` chi^2(1) variables
  (``consistency.chi2_band(1, runs)``: [0.74, 1.30] at 100 runs); the share of the window's
  samples where it does. A consistent filter keeps it near 95 %; "honest in every window" asks
  >= 80 % for every dof.
- **mean e^2/P** over the window and the runs (1 = consistent, > 1 over-confident);
- **within 1 sigma / 2 sigma**: the share of (run, sample) pairs with |e_d| <= sigma_d (68 %
  expected) and <= 2 sigma_d (95 %): what one run's plot shows;
- the 9-dof NEES of each run at each sample inside its chi^2(9) 95 % band (95 % expected).
"""

import argparse

import numpy as np
from scipy.stats import chi2

from quad_drake.campaigns.fleet.diagram import run_fleet
from quad_drake.campaigns.fleet.runner import batch_logs
from quad_drake.estimation.registry import vehicle_vocabulary
from quad_drake.judging import consistency as cons
from quad_drake.running import catalog

TARGET = 0.80
"""The least band share every dof must keep in the window."""


def window_statistics(scenario, runs, first_seed, start, end):
    """(vocabulary, per-dof rows, NEES share) of `runs` fleet runs from `first_seed` in [start, end) s.

    Rows: one (name, band share, mean e^2/P, share within 1 sigma, share within 2 sigma) per NEES
    dof of the first vehicle with an estimator; NEES share: the (run, sample) pairs whose NEES
    lies in its chi^2 95 % band."""
    times, logs, _ = run_fleet(scenario, range(first_seed, first_seed + runs))
    vehicle = next(v for v in scenario.vehicles if vehicle_vocabulary(v) is not None)
    vocabulary = vehicle_vocabulary(vehicle)
    window = (times >= start) & (times < end)
    run_logs = [batch_logs(logs, j)[vehicle.name] for j in range(runs)]
    ratios = np.array(
        [
            cons.normalized_squared_errors(vocabulary.errors(r), cons.covariance_matrices(r["covariance"]))
            for r in run_logs
        ]
    )[:, window]
    band = cons.chi2_band(1, runs)
    rows = []
    for k in vocabulary.nees_states:
        per_sample = ratios[:, :, k].mean(axis=0)
        rows.append(
            (
                vocabulary.state_names[k],
                cons.in_band_fraction(per_sample, band),
                float(ratios[:, :, k].mean()),
                float(np.mean(ratios[:, :, k] <= 1.0)),
                float(np.mean(ratios[:, :, k] <= chi2.ppf(0.95, 1))),
            )
        )
    nees = np.array([cons.nees_of(vocabulary, r) for r in run_logs])[:, window]
    dof = vocabulary.nees_dof
    nees_share = float(np.mean((nees >= chi2.ppf(0.025, dof)) & (nees <= chi2.ppf(0.975, dof))))
    return vocabulary, rows, nees_share, band


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default="23_gps_outage_baro")
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--seed", type=int, default=7000, help="first run seed")
    parser.add_argument("--start", type=float, default=10.0, help="window start, s")
    parser.add_argument("--end", type=float, default=20.0, help="window end, s")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    scenario = catalog.load(args.scenario, None, args.set)
    vocabulary, rows, nees_share, band = window_statistics(
        scenario, args.runs, args.seed, args.start, args.end
    )
    print(
        f"{scenario.name} ({vocabulary.kind}), {args.runs} fleet runs from seed {args.seed}, "
        f"window [{args.start:g}, {args.end:g}) s; band of the {args.runs}-run mean of e^2/P: "
        f"[{band[0]:.2f}, {band[1]:.2f}]"
    )
    print("| dof | band share | mean e²/P | within 1σ | within 2σ | ≥ 80 % |")
    print("|---|---|---|---|---|---|")
    for name, share, mean, one, two in rows:
        print(
            f"| {name} | {100 * share:.0f} % | {mean:.2f} | {100 * one:.0f} % | {100 * two:.0f} % | "
            f"{'yes' if share >= TARGET else 'no'} |"
        )
    print(
        f"NEES ({vocabulary.nees_dof} dof) of each run inside its chi^2 95 % band: {100 * nees_share:.1f} %"
    )


if __name__ == "__main__":
    main()
