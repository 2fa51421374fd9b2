"""Benchmark: why a log tuning's held-out NIS lies outside its band, per sensor and per dof.

Replays a flight log whole with a ReplayConfig (the start: PX4's defaults, or a tuned.yaml that
``quad-drake tune LOG`` wrote) and prints, per fused channel and per component (dof), on the
training part [5 s, f T) and on the held-out part [f T, T) (airborne and landed separately where
the log has PX4's land detector):

- the NIS per dof and its χ² band (the band of a white, consistent filter's mean over N samples),
- the normalised innovations' autocorrelation at lags 1..5 and the effective sample count of a
  lag-1 correlation ρ, N (1 - ρ) / (1 + ρ) (how many independent samples the band really has),
- the direct per-component fit of the measurement noise (Mehra 1970; Myers and Tapley 1976):
  r̂² = mean(ν²) - mean(σ⁻²), the innovations' variance less the filter's prior variance of the
  measured state (H P⁻ Hᵀ), beside the std the filter assumed, and the NIS per dof that the
  assumed r would give with the prior as replayed, had r been r̂ (the best any measurement noise
  can do without changing the prior),
- the logged values' quantum q (the smallest nonzero step between samples) and the uniform
  quantisation std q / sqrt(12);

and the replay's innovation-gate counts (GPS, magnetometer, barometer samples rejected).

Per channel and part, a line ``spread``: the share of the part's Σ NIS that its largest 5 % of
samples carry (with their stamps: is the mean one event's?) and the 95 % interval of the NIS per
dof when the part's SPLIT_BLOCK blocks are resampled whole (a block bootstrap, 2000 draws, fixed
seed): how far the mean moves with which blocks a part holds, where the χ² band assumes every
sample independent of every other (a correlated or manoeuvre-driven channel's block interval is
several times the band). ``--phases 0:19,19:25.76`` adds each phase's NIS per dof (stamps in
[start, end) s) to that line (the bundled SITL log: on the ground, in flight, after the touchdown).

Last, per channel: the held-out part's NIS per dof over the training part's (what a tuning that
matches the training part to 1 leaves held out) beside the 95 % interval of that ratio between
two random halves of the log's blocks (4000 draws, fixed seed; every sample from COMPARE_AFTER on):
the ratio a split could show by which blocks each half holds, with the same values throughout.

The field and the barometer are judged on the filter's own NIS (no innovation logged; every
update's, from the diagnostics logged every 2 ms tick as the tuner judges them): only the NIS per
dof, its band and autocorrelation.

Usage::

    python benchmarks/log_tune_diagnosis.py sitl_takeoff_land_gps [--config out/sitl_tune/tuned.yaml]
        [--phases 0:19,19:25.76]
"""

import argparse
import dataclasses
import math

import numpy as np

from quad_drake.estimation.vocabulary import DIAG
from quad_drake.flightlogs.reader import read_flight_log
from quad_drake.flightlogs.replay import COMPARE_AFTER, replay
from quad_drake.flightlogs.settings import load_replay, resolve_log
from quad_drake.judging import innovations
from quad_drake.judging.consistency import chi2_band
from quad_drake.tuning.logs import SPLIT_BLOCK, _judged, assumed_std, split
from quad_drake.tuning.settings import LOG_SPLITS, LogTuneSettings

GPS_COLUMNS = {"X": 0, "Y": 1, "Z": 2, "VX": 3, "VY": 4, "VZ": 5}


def quantum(values) -> float:
    """The smallest nonzero step between successive logged values (m,) (0 where none)."""
    steps = np.abs(np.diff(np.asarray(values, dtype=float)))
    steps = steps[steps > 1e-9]
    return float(steps.min()) if len(steps) else 0.0


def parts(log, settings):
    """[(label, windows ((start, end), ...) s, the land detector's state kept or None)] judged."""
    training, held = split(log, settings)
    found = [("training", training, None), ("held-out", held, None)]
    if log.landed is not None:
        for state, label in ((0, "training airborne"), (0, "held-out airborne"), (1, "held-out landed")):
            found.append((label, training if label.startswith("training") else held, state))
    return found


def landed_at(log, stamps) -> np.ndarray:
    """(m,) PX4's land detector's state (0 or 1) at the stamps (the last value at or before)."""
    index = np.searchsorted(log.landed.times, stamps, side="right") - 1
    return log.landed.values[np.clip(index, 0, None), 0]


TOP_SHARE = 0.05
"""The share of a part's largest samples whose part of Σ NIS ``spread`` reports."""
BOOTSTRAP_DRAWS = 2000


def spread(stamps, nis, dof, phases=()) -> str:
    """The ``spread`` line of a channel's part: stamps (m,) s, each sample's NIS (m,) of `dof` dof;
    phases ((start, end), ...) s. Empty for fewer than 3 samples."""
    stamps, nis = np.asarray(stamps, dtype=float), np.asarray(nis, dtype=float)
    if len(nis) < 3:
        return ""
    order = np.argsort(-nis)
    top = order[: max(1, int(round(TOP_SHARE * len(nis))))]
    block = np.floor((stamps - COMPARE_AFTER) / SPLIT_BLOCK).astype(int)
    ids = np.unique(block)
    sums = np.array([nis[block == i].sum() for i in ids])
    counts = np.array([np.count_nonzero(block == i) for i in ids])
    draws = np.random.default_rng(0).integers(0, len(ids), (BOOTSTRAP_DRAWS, len(ids)))
    low, high = np.percentile(sums[draws].sum(axis=1) / counts[draws].sum(axis=1) / dof, [2.5, 97.5])
    share = nis[top].sum() / nis.sum()
    text = (
        f"    spread: top {100 * TOP_SHARE:g} % ({len(top)}) carry {share:.2f} of Σ NIS, "
        f"at {np.round(np.sort(stamps[top[:6]]), 2)} s; {len(ids)} blocks resampled: [{low:.3g}, {high:.3g}]"
    )
    for start, end in phases:
        keep = (stamps >= start) & (stamps < end)
        if keep.any():
            text += f"; {start:g}-{end:g} s N={np.count_nonzero(keep)} {nis[keep].mean() / dof:.3g}"
    return text


HALVES_DRAWS = 4000


def halves(stamps, nis, training, held) -> str:
    """The held-out / training ratio line of a channel: stamps (m,) s and NIS (m,) of every sample
    from COMPARE_AFTER on, the split's training and held-out windows."""
    ratio = nis[innovations.inside(stamps, held)].mean() / nis[innovations.inside(stamps, training)].mean()
    block = np.floor((stamps - COMPARE_AFTER) / SPLIT_BLOCK).astype(int)
    ids = np.unique(block)
    sums = np.array([nis[block == i].sum() for i in ids])
    counts = np.array([np.count_nonzero(block == i) for i in ids])
    rng = np.random.default_rng(0)
    ratios = []
    for _ in range(HALVES_DRAWS):
        first = rng.permutation(len(ids)) < len(ids) // 2
        ratios.append((sums[first].sum() / counts[first].sum()) / (sums[~first].sum() / counts[~first].sum()))
    low, high = np.percentile(ratios, [2.5, 97.5])
    below = np.mean(np.asarray(ratios) <= ratio)
    return (
        f"held-out / training {ratio:.3g}; two random halves of {len(ids)} blocks: "
        f"[{low:.2f}, {high:.2f}], {below:.2f} of them <= it"
    )


def each_nis(result, channel, stds, windows) -> tuple:
    """(stamps (m,) s, each sample's NIS (m,), dof) of a judged channel of the replay `result`."""
    if channel in innovations.COMPONENT_CHANNELS:
        stamps, z, _ = innovations.normalised_innovations(
            result.vocabulary, result.logs, channel, stds[channel], windows
        )
        return stamps, np.sum(z**2, axis=1), z.shape[1]
    stamps, values = innovations.fresh_nis(result.logs[innovations.UPDATE_DIAGNOSTICS], channel)
    keep = innovations.inside(stamps, windows) & np.isfinite(values)
    return stamps[keep], values[keep], innovations.NIS_CHANNELS[channel]


def row(name, z, nu, s, r, values_all, count_min=3):
    count = len(z)
    if count < count_min:
        return f"  {name:10s} N={count:4d}: too few"
    per_dof = float(np.mean(z**2))
    low, high = chi2_band(1, count)
    rho = innovations.autocorrelation(z)
    r1 = rho[0] if math.isfinite(rho[0]) else 0.0
    effective = count * (1 - r1) / (1 + r1) if r1 < 1 else 1.0
    prior = s**2 - r**2
    fit = float(np.mean(nu**2) - np.mean(prior))
    r_hat = math.sqrt(fit) if fit > 0 else 0.0
    best = float(np.mean(nu**2 / (prior + r_hat**2))) if r_hat > 0 else float("nan")
    q = quantum(values_all)
    return (
        f"  {name:10s} N={count:4d} NIS {per_dof:9.4g} band [{low:.3g}, {high:.3g}] "
        f"{'in ' if low <= per_dof <= high else 'OUT'} rho1-5 {np.round(rho, 2)} N_eff {effective:6.1f} "
        f"| r {r:.4g} r_hat {r_hat:.4g} (mean nu2 {np.mean(nu**2):.3g}, mean prior {np.mean(prior):.3g}) "
        f"NIS at r_hat {best:.3g} | q {q:.3g} q/sqrt12 {q / math.sqrt(12):.3g}"
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log")
    parser.add_argument("--config", help="a ReplayConfig YAML (tuned.yaml); default: PX4's defaults")
    parser.add_argument("--train-fraction", type=float, default=LogTuneSettings.train_fraction)
    parser.add_argument("--split", choices=LOG_SPLITS, default=LogTuneSettings.split)
    parser.add_argument("--phases", default="", help="start:end s phases, comma-separated: 0:19,19:25.76")
    args = parser.parse_args()
    phases = [tuple(float(v) for v in p.split(":")) for p in args.phases.split(",") if p]
    settings = LogTuneSettings(train_fraction=args.train_fraction, split=args.split)
    log = read_flight_log(resolve_log(args.log))
    config = load_replay(args.config or args.log, "{kind: eskf}" if not args.config else None)
    result = replay(dataclasses.replace(config, name=config.name or "diagnosis"), log)
    judged = _judged(config, result)
    stds = assumed_std(result.config)
    print(f"{log.source}: {log.duration:.1f} s, split {args.split}; config {args.config or 'start'}")
    print(
        "delays gps/mag/baro "
        f"{result.config.gps_delay:.3f}/{result.config.mag_delay:.3f}/{result.config.baro_delay:.3f} s"
    )
    last = np.asarray(result.logs["diagnostics"], dtype=float)[-1]
    counts = {name: int(last[DIAG[name]]) for name in ("gps_gated", "gps_resets", "mag_gated", "baro_gated")}
    print("the whole replay's gate counts: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    for label, windows, landed in parts(log, settings):
        print(f"{label} {' '.join(f'{a:.1f}-{b:.1f}' for a, b in windows)} s")
        for channel in judged:
            if channel in innovations.COMPONENT_CHANNELS:
                sensor, states, _ = innovations.COMPONENT_CHANNELS[channel]
                stamps, z, s = innovations.normalised_innovations(
                    result.vocabulary, result.logs, channel, stds[channel], windows
                )
                keep = np.ones(len(stamps), bool) if landed is None else landed_at(log, stamps) == landed
                for k, state in enumerate(states):
                    r = float(stds[channel][k])
                    source = log.gps if sensor == "gps" else log.heading
                    logged = source.values[:, GPS_COLUMNS[state] if sensor == "gps" else 0]
                    zk, sk = z[keep, k], s[keep, k]
                    print(row(f"{channel}:{state}", zk, zk * sk, sk, r, logged))
                print(spread(stamps[keep], np.sum(z[keep] ** 2, axis=1), len(states), phases))
            else:
                stamps, values = innovations.fresh_nis(result.logs[innovations.UPDATE_DIAGNOSTICS], channel)
                keep = innovations.inside(stamps, windows) & np.isfinite(values)
                if landed is not None:
                    keep &= landed_at(log, stamps) == landed
                nis = values[keep]
                dof = innovations.NIS_CHANNELS[channel]
                if len(nis) < 3:
                    print(f"  {channel:10s} N={len(nis):4d}: too few")
                    continue
                low, high = (b / dof for b in chi2_band(dof, len(nis)))
                rho = innovations.autocorrelation(nis - nis.mean())
                per_dof = float(np.mean(nis)) / dof
                print(
                    f"  {channel:10s} N={len(nis):4d} NIS/dof {per_dof:9.4g} band [{low:.3g}, {high:.3g}] "
                    f"{'in ' if low <= per_dof <= high else 'OUT'} rho1-5 {np.round(rho, 2)}"
                )
                print(spread(stamps[keep], nis, dof, phases))
    training, held = split(log, settings)
    for channel in judged:
        stamps, nis, _ = each_nis(result, channel, stds, ((COMPARE_AFTER, math.inf),))
        print(f"{channel:10s} {halves(stamps, nis, training, held)}")


if __name__ == "__main__":
    main()
