"""How much the EKF7's z against PX4's depends on which baro sample set its datum, on replayed logs.

With the barometer as the height reference the EKF7's baro bias learns from no GPS height, so
the datum its first sample sets (``baro.first_datum``) stays, and its z follows it one for one.
For each replay folder under OUT (``quad-drake replay ... --estimator '{kind: ekf7}' --out OUT``),
this takes the saved estimate and shifts its z by (d - datum) for other datums d = h_k + p_z,k:
each single sample k of the first 2 s, and the mean over the first 5, 10 and 25 samples (PX4
low-passes its first samples, ``_baro_lpf``). It prints the RMS of z from PX4's from 5 s on for
each (an approximation: the replay's own interpolation differs by a few mm; the first sample's
row is the replay's figure within 0.015 m).

    python benchmarks/baro_datum_spread.py OUT
"""

import argparse
import sys
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from quad_drake.estimation.vocabulary import DIAG  # noqa: E402
from quad_drake.flightlogs.reader import read_flight_log  # noqa: E402
from quad_drake.flightlogs.replay import COMPARE_AFTER  # noqa: E402
from quad_drake.flightlogs.settings import resolve_log  # noqa: E402

SINGLE_SAMPLES_WITHIN = 2.0  # s after the first baro sample
MEANS_OVER = (5, 10, 25)  # samples


def spread(folder) -> str:
    """One line: the z RMS (m) from PX4's for the datums of the module docstring, in `folder`."""
    config = yaml.safe_load((folder / "config.yaml").read_text(encoding="utf-8"))
    log = read_flight_log(resolve_log(config["log"]))
    if log.baro is None or log.reference_position is None:
        return f"{folder.name}: no barometer or no PX4 position"
    saved = np.load(folder / "logs.npz")
    times, state = saved["times"], saved["replay/estimated_state"]
    datum = saved["replay/diagnostics"][-1, DIAG["baro_bias"]]
    ref = log.reference_position
    compared = (ref.times >= COMPARE_AFTER) & (ref.times <= times[-1]) & np.isfinite(ref.values[:, 2])
    z_ours = np.interp(ref.times[compared], times, state[:, 2])
    heights, stamps = log.baro.values[:, 0], log.baro.times
    datums = heights + np.interp(stamps, times, state[:, 2])  # h_k + p_z,k

    def rms(d):
        return np.sqrt(np.mean((z_ours + (d - datum) - ref.values[compared, 2]) ** 2))

    singles = np.array([rms(d) for d in datums[stamps < stamps[0] + SINGLE_SAMPLES_WITHIN]])
    means = "/".join(f"{rms(np.mean(datums[:n])):.3f}" for n in MEANS_OVER)
    within = f"each of the {len(singles)} samples of the first {SINGLE_SAMPLES_WITHIN:g} s"
    over = "/".join(map(str, MEANS_OVER))
    return (
        f"{folder.name}: first sample {singles[0]:.3f} m; {within}: median {np.median(singles):.3f} "
        f"[{singles.min():.3f}, {singles.max():.3f}]; mean of the first {over}: {means}"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="a replay's --out folder (EKF7)")
    args = parser.parse_args()
    folders = sorted(p.parent for p in args.out.glob("*/logs.npz"))
    if not folders:
        print(f"baro_datum_spread: no replay folders with logs.npz under {args.out}", file=sys.stderr)
        return 2
    for folder in folders:
        print(spread(folder))
    return 0


if __name__ == "__main__":
    sys.exit(main())
