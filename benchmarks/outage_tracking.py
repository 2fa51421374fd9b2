"""Where does the true tracking error of a GPS outage come from? Per run, around one outage.

Usage: python benchmarks/outage_tracking.py [scenario] [--runs 100] [--seed 3000] [--batch 50]
       [--recovery 3] [--set KEY=VALUE ...] [--per-run]

Flies ``--runs`` runs of the scenario (default
benchmarks/scenarios/mag3_disturbance_outage.yaml) as fleets of ``--batch`` runs
(``quad_drake.campaigns.fleet``) around the first vehicle's first ``gps_outage`` fault [s, e) s and
prints, over the runs, the largest true tracking error |``PosFollowErr``| (m) before the outage
[0, s), during it [s, e), in the recovery window [e, e + recovery) and after it [e + recovery,
end]; the estimate's horizontal position error |``Est.E.X``, ``Est.E.Y``| (m) and its own
horizontal sigma sqrt(``Est.S.X``^2 + ``Est.S.Y``^2) (m) at the outage's end (its last sample
before e); the largest horizontal estimate error during the outage; the 3-axis field samples the
estimator accepted during the outage (fresh ``Est.FieldNIS`` samples less the rise of
``Est.MagGated``); and the runs that touched a wall or the floor. With ``--per-run`` one line per
run. These are the numbers behind the flight-safety rule that does not judge the tracking error
while the position dead-reckons (``quad_drake.judging.safety``).
"""

import argparse

import numpy as np

from quad_drake.campaigns.fleet.diagram import run_fleet
from quad_drake.estimation.registry import vehicle_vocabulary
from quad_drake.judging.signals import vehicle_signals
from quad_drake.running import catalog


def _window_max(values, times, start, end):
    """(N,) largest |values| (samples, N) over times in [start, end); NaN where no sample."""
    inside = (times >= start) & (times < end)
    if not inside.any():
        return np.full(values.shape[1], np.nan)
    return np.abs(values[inside]).max(axis=0)


def outage_rows(scenario, seeds, recovery):
    """One dict per run of `seeds` (see the module docstring) for the scenario's first vehicle."""
    vehicle = scenario.vehicles[0]
    outage = next(f for f in vehicle.faults if f.kind == "gps_outage")
    start, end = outage.start, outage.end
    times, logs, _ = run_fleet(scenario, seeds)
    signals = vehicle_signals(vehicle.name, logs[vehicle.name], vehicle_vocabulary(vehicle))

    def values(name):
        return np.asarray(signals[f"{vehicle.name}.{name}"].values, dtype=float)

    follow = values("PosFollowErr")
    horizontal = np.hypot(values("Est.E.X"), values("Est.E.Y"))
    sigma = np.hypot(values("Est.S.X"), values("Est.S.Y"))
    last = np.flatnonzero(times < end)[-1]
    if f"{vehicle.name}.Est.FieldNIS" in signals:
        # a sample logged at t shows the state just before the updates at t: the outage's
        # samples show on (start, end]
        shown = (times > start) & (times <= end)
        fresh = np.asarray(signals[f"{vehicle.name}.Est.FieldNIS"].fresh, dtype=bool)[shown].sum(axis=0)
        gated = values("Est.MagGated")
        accepted = fresh - (gated[np.flatnonzero(shown)[-1]] - gated[np.flatnonzero(times <= start)[-1]])
    else:
        accepted = np.zeros(len(seeds))
    walls = values("WallContactSteps")[-1] > 0
    floor = values("FloorTouchdowns")[-1] > 0
    columns = {
        "before": _window_max(follow, times, 0.0, start),
        "during": _window_max(follow, times, start, end),
        "recovering": _window_max(follow, times, end, end + recovery),
        "after": _window_max(follow, times, end + recovery, np.inf),
        "est_err_end": horizontal[last],
        "sigma_end": sigma[last],
        "est_err_max": _window_max(horizontal, times, start, end),
        "field_accepted": accepted,
        "wall": walls,
        "floor": floor,
    }
    return [{"seed": int(s), **{k: v[j] for k, v in columns.items()}} for j, s in enumerate(seeds)]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default="benchmarks/scenarios/mag3_disturbance_outage.yaml")
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--seed", type=int, default=3000, help="first run seed")
    parser.add_argument("--batch", type=int, default=50, help="runs per fleet")
    parser.add_argument("--recovery", type=float, default=3.0, help="s after the GPS returns")
    parser.add_argument("--bound", type=float, default=6.0, help="m, the tracking bound counted")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--per-run", action="store_true")
    args = parser.parse_args()
    scenario = catalog.load(args.scenario, None, args.set)
    rows = []
    last = args.seed + args.runs
    for first in range(args.seed, last, args.batch):
        rows += outage_rows(scenario, range(first, min(first + args.batch, last)), args.recovery)
    keys = [k for k in rows[0] if k != "seed"]
    table = {k: np.array([r[k] for r in rows], dtype=float) for k in keys}
    if args.per_run:
        print("seed " + " ".join(f"{k:>14}" for k in keys))
        for r in rows:
            print(f"{r['seed']} " + " ".join(f"{float(r[k]):14.3f}" for k in keys))
    print(f"{scenario.name}, {len(rows)} fleet runs from seed {args.seed}, --set {args.set}")
    print("| quantity | median | p90 | max | runs > bound |")
    print("|---|---|---|---|---|")
    for k in ("before", "during", "recovering", "after", "est_err_end", "sigma_end", "est_err_max"):
        x = table[k]
        print(
            f"| {k} | {np.nanmedian(x):.2f} | {np.nanpercentile(x, 90):.2f} | {np.nanmax(x):.2f} | "
            f"{int(np.sum(x > args.bound))} |"
        )
    print(
        f"field samples accepted in the outage: total {int(table['field_accepted'].sum())}, "
        f"runs with any {int(np.sum(table['field_accepted'] > 0))}; walls {int(table['wall'].sum())}, "
        f"floor {int(table['floor'].sum())}"
    )
    judged = (table["before"] > args.bound) | (table["after"] > args.bound)
    flight = np.nanmax([table[k] for k in ("before", "during", "recovering", "after")], axis=0)
    print(
        f"tracking > {args.bound:g} m over the whole flight: {int(np.sum(flight > args.bound))}; "
        f"before the outage or {args.recovery:g} s after it: {int(judged.sum())}"
    )
    ratio = table["est_err_end"] / table["sigma_end"]
    print(
        f"estimate error / own sigma at the outage's end: median {np.median(ratio):.2f}, "
        f"share within 1 sigma {np.mean(ratio <= 1):.2f}, within 2 sigma {np.mean(ratio <= 2):.2f}"
    )
    print(
        f"correlation of the largest tracking error during the outage with the estimate error at its end: "
        f"{np.corrcoef(table['during'], table['est_err_max'])[0, 1]:.2f}"
    )


if __name__ == "__main__":
    main()
