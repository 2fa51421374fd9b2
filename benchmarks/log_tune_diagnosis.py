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

The field and the barometer are judged on the filter's own NIS (no innovation logged; every
update's, from the diagnostics logged every 2 ms tick as the tuner judges them): only the NIS per
dof, its band and autocorrelation.

Usage::

    python benchmarks/log_tune_diagnosis.py sitl_takeoff_land_gps [--config out/sitl_tune/tuned.yaml]
"""

import argparse
import dataclasses
import math

import numpy as np

from quad_drake.estimation.vocabulary import DIAG
from quad_drake.flightlogs.reader import read_flight_log
from quad_drake.flightlogs.replay import replay
from quad_drake.flightlogs.settings import load_replay, resolve_log
from quad_drake.judging import innovations
from quad_drake.judging.consistency import chi2_band
from quad_drake.tuning.logs import _judged, assumed_std, split
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
    args = parser.parse_args()
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


if __name__ == "__main__":
    main()
