"""Where in a flight an estimator is consistent: per-state e^2/P and the mean NEES in time bins.

Usage: python benchmarks/nees_over_time.py [scenario] [--runs 100] [--seed 1000] [--bin 2.5]
       [--set KEY=VALUE ...]

Flies the runs as one fleet (``quad_drake.campaigns.fleet``; every vehicle of the scenario with an
estimator), then prints, per time bin of ``--bin`` s, the mean over runs of each error-state
entry's e^2/P (1 = consistent, < 1 conservative, > 1 over-confident) and the mean NEES over
the vocabulary's NEES states, with the share of the bin's log samples inside the NEES's
``--runs``-run chi^2 95 % band (``consistency.chi2_band``: what campaigns report as "NEES in
band"). The errors, covariances and NEES are the vocabulary's and ``consistency``'s own.
"""

import argparse

import numpy as np

from quad_drake.campaigns.fleet.diagram import run_fleet
from quad_drake.campaigns.fleet.runner import batch_logs
from quad_drake.estimation.registry import vehicle_vocabulary
from quad_drake.judging import consistency as cons
from quad_drake.running import catalog


def over_time(scenario, runs, first_seed):
    """(times (n,), {vehicle name: (vocabulary, e^2/P mean over runs (n, k), mean NEES (n,))}) of
    `runs` fleet runs of `scenario` from seed `first_seed`."""
    times, logs, _ = run_fleet(scenario, range(first_seed, first_seed + runs))
    result = {}
    for vehicle in scenario.vehicles:
        vocabulary = vehicle_vocabulary(vehicle)
        if vocabulary is None:
            continue
        run_logs = [batch_logs(logs, j)[vehicle.name] for j in range(runs)]
        ratios = np.nanmean(
            [
                cons.normalized_squared_errors(
                    vocabulary.errors(r), cons.covariance_matrices(r["covariance"])
                )
                for r in run_logs
            ],
            axis=0,
        )
        nees = np.mean([cons.nees_of(vocabulary, r) for r in run_logs], axis=0)
        result[vehicle.name] = (vocabulary, ratios, nees)
    return times, result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default="11_gps_update")
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--seed", type=int, default=1000, help="first run seed")
    parser.add_argument("--bin", type=float, default=2.5, help="s per time bin")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    scenario = catalog.load(args.scenario, None, args.set)
    times, vehicles = over_time(scenario, args.runs, args.seed)
    for name, (vocabulary, ratios, nees) in vehicles.items():
        band = cons.chi2_band(vocabulary.nees_dof, args.runs)
        share = 100 * cons.in_band_fraction(nees, band)
        below, above = 100 * np.mean(nees < band[0]), 100 * np.mean(nees > band[1])
        print(
            f"{scenario.name} {name} ({vocabulary.kind}), {args.runs} runs from seed {args.seed}: "
            f"NEES ({vocabulary.nees_dof} dof) inside [{band[0]:.2f}, {band[1]:.2f}] "
            f"{share:.1f} % of the samples, below {below:.1f} %, above {above:.1f} %"
        )
        print(
            "t [s]      " + " ".join(f"{state:>6}" for state in vocabulary.state_names) + "   NEES  in band"
        )
        for start in np.arange(0.0, times[-1], args.bin):
            rows = (times > start) & (times <= start + args.bin)
            cells = " ".join(f"{r:6.2f}" for r in ratios[rows].mean(axis=0))
            inside = 100 * cons.in_band_fraction(nees[rows], band)
            print(f"{start:4.1f}-{start + args.bin:4.1f}  {cells} {nees[rows].mean():6.2f} {inside:6.0f} %")


if __name__ == "__main__":
    main()
