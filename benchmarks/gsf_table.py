"""The EKF-GSF's measured table (docs/measurements/gsf.md): yaw without a magnetometer, a lying
magnetometer and a lost one, each a pass rate on unseen seeds with its 95 % Clopper-Pearson
interval, flown in fleet mode (``quad-drake montecarlo ... --fleet``: one Diagram per batch).

- ``alignment``: 26_gsf_yaw_alignment (no magnetometer) with the true initial heading uniform on
  [-180 deg, 180 deg): ``--headings H`` headings, one drawn uniformly in each of H equal
  strata of the circle from ``--seed`` (a stratified uniform sample), each flown
  (``--end-time`` s, the second criterion's bound ending there) with
  ``--runs-per-heading R`` seeds (the fleet flies one VehicleConfig per batch, so a heading is a
  batch), H x R runs in all. Besides the scenario's criteria it reports, per check time T of
  ``CHECK_TIMES``, the share of runs with |yaw error| < 5 deg at T s:
  the distribution of the alignment time.
- ``mag_bias`` (27_gsf_mag_bias) and ``mag_lost`` (28_gsf_mag_lost): ``--runs`` seeds each, with
  the GSF on (the bundled configuration) and off.

Each row is cached as JSON in ``--cache`` (keyed by its row, runs and seed), so an interrupted
table resumes; ``--fresh`` ignores the cache. Prints the Markdown rows.

    nice -n 10 python benchmarks/gsf_table.py --seed 5000 --headings 8 --runs-per-heading 125 --runs 100
"""

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import binomtest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from quad_drake import campaigns  # noqa: E402
from quad_drake.config.schema import CriterionConfig  # noqa: E402
from quad_drake.running import catalog  # noqa: E402

CHECK_TIMES = (2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0)
"""s: the check times of the alignment-time distribution (|yaw error| < 5 deg at the sample at T)."""
YAW_TOLERANCE = math.radians(5.0)
CHECK_SIGNAL, CHECK_WINDOW = "Quad.Est.E.Yaw", 0.005
OFF = "vehicles.0.estimator.gsf.enabled=false"


def clopper_pearson(passes, runs) -> tuple[float, float]:
    """(low, high) 95 % Clopper-Pearson interval of a pass rate, in percent."""
    ci = binomtest(passes, runs).proportion_ci(confidence_level=0.95, method="exact")
    return 100.0 * ci.low, 100.0 * ci.high


def headings(count, seed) -> np.ndarray:
    """`count` headings (rad), one uniform in each of `count` equal strata of [-pi, pi)."""
    rng = np.random.default_rng(seed)
    return -math.pi + (np.arange(count) + rng.uniform(size=count)) * (2.0 * math.pi / count)


def with_check_times(scenario):
    """`scenario` with one yaw bound per check time appended after its own criteria."""
    checks = [
        CriterionConfig(
            kind="bound", signal=CHECK_SIGNAL, threshold=YAW_TOLERANCE, start=t, end=t + CHECK_WINDOW
        )
        for t in CHECK_TIMES
    ]
    scenario.criteria = list(scenario.criteria) + checks
    return scenario


def fly(name, overrides, runs, seed, batch):
    """The records of `runs` fleet runs of scenario `name` from `seed` (batches of `batch`)."""
    scenario = catalog.load(name, None, list(overrides))
    if name.startswith("26_"):
        scenario = with_check_times(scenario)
    runner = campaigns.InProcessRunner()
    campaign = campaigns.run_campaign(
        scenario, runs, runner=runner, seed=seed, fleet_batch=batch, progress=False
    )
    return campaign


def summary(records, own_criteria, check_times=()):
    """{passes, runs, failed seeds, check-time passes, unsafe runs} of campaign records: a run
    passes when its scenario's own criteria (the first `own_criteria`) and the safety criteria all
    pass; the `check_times` bounds follow its own criteria."""
    checks, failed, passes, unsafe, reasons = [0] * len(check_times), [], 0, 0, {}
    for r in records:
        safety = [c for c in r.criteria if c["kind"] in ("floor", "room", "finite", "tracking")]
        safe = all(c["passed"] for c in safety)
        verdict = safe and all(c["passed"] for c in r.criteria[:own_criteria])
        passes += verdict
        unsafe += not safe
        if not verdict:
            failed.append(r.seed)
            for c in r.criteria[:own_criteria] + safety:
                if not c["passed"]:
                    reasons[c["description"]] = reasons.get(c["description"], 0) + 1
        for k, check in enumerate(r.criteria[own_criteria : own_criteria + len(check_times)]):
            checks[k] += check["passed"]
    return {
        "passes": passes, "runs": len(records), "failed": failed, "checks": checks, "unsafe": unsafe,
        "reasons": reasons,
    }  # fmt: skip


def measure_alignment(args, flies_on):
    """The alignment row over the stratified headings (module docstring)."""
    own = len(catalog.load("26_gsf_yaw_alignment").criteria)
    totals = {"passes": 0, "runs": 0, "failed": [], "checks": [0] * len(CHECK_TIMES), "unsafe": 0}
    totals["reasons"] = {}
    for k, heading in enumerate(headings(args.headings, args.seed)):
        seed = args.seed + k * args.runs_per_heading
        overrides = [
            f"vehicles.0.initial_ypr=[{float(heading)!r}, 0, 0]",
            f"vehicles.0.flies_on={flies_on}",
            f"end_time={args.end_time!r}",
            f"criteria.1.end={args.end_time!r}",
        ]
        campaign = fly("26_gsf_yaw_alignment", overrides, args.runs_per_heading, seed, args.runs_per_heading)
        part = summary(campaign.records, own, CHECK_TIMES)
        for key in ("passes", "runs", "unsafe"):
            totals[key] += part[key]
        totals["failed"] += [(round(math.degrees(heading), 1), s) for s in part["failed"]]
        totals["checks"] = [a + b for a, b in zip(totals["checks"], part["checks"], strict=True)]
        for reason, count in part["reasons"].items():
            totals["reasons"][reason] = totals["reasons"].get(reason, 0) + count
        print(f"  heading {math.degrees(heading):7.1f} deg: {part['passes']}/{part['runs']}", flush=True)
    return totals


def measure_row(name, overrides, args):
    campaign = fly(name, overrides, args.runs, args.seed, min(args.runs, 100))
    return summary(campaign.records, len(catalog.load(name).criteria))


ROWS = {
    "alignment": ("26_gsf_yaw_alignment", "no magnetometer, flies on the truth, heading uniform", "truth"),
    "alignment_estimate": (
        "26_gsf_yaw_alignment",
        "no magnetometer, flies on its estimate, heading uniform",
        "estimate",
    ),
    "mag_bias": ("27_gsf_mag_bias", "persistent 0.5 rad magnetometer bias, GSF on (bundled)", ()),
    "mag_bias_off": ("27_gsf_mag_bias", "persistent 0.5 rad magnetometer bias, GSF off", (OFF,)),
    "mag_lost": ("28_gsf_mag_lost", "magnetometer lost at 5 s, GSF on (bundled)", ()),
    "mag_lost_off": ("28_gsf_mag_lost", "magnetometer lost at 5 s, GSF off", (OFF,)),
}  # fmt: skip


def line(key, figures, args):
    name, label, _ = ROWS[key]
    runs, passes = figures["runs"], figures["passes"]
    low, high = clopper_pearson(passes, runs)
    if key.startswith("alignment"):
        seeds = f"{args.headings} headings x {args.runs_per_heading} seeds from {args.seed}"
    else:
        seeds = f"seeds {args.seed}-{args.seed + runs - 1}"
    return (
        f"| {name} | {label} | {runs} ({seeds}) | {passes}/{runs} = {100 * passes / runs:.1f} % "
        f"[{low:.1f}, {high:.1f}] | {figures['unsafe']} |"
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=5000)
    parser.add_argument("--headings", type=int, default=8)
    parser.add_argument("--runs-per-heading", type=int, default=125)
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--end-time", type=float, default=9.0, help="s, the alignment rows' flights")
    parser.add_argument("--only", nargs="*", choices=list(ROWS), default=list(ROWS))
    parser.add_argument("--cache", type=Path, default=ROOT / "out" / "gsf_table")
    parser.add_argument("--fresh", action="store_true")
    args = parser.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    for key in args.only:
        alignment = f"h{args.headings}x{args.runs_per_heading}_t{args.end_time:g}"
        size = alignment if key.startswith("alignment") else f"n{args.runs}"
        path = args.cache / f"{key}_{size}_s{args.seed}.json"
        if path.exists() and not args.fresh:
            figures = json.loads(path.read_text())
        else:
            start = time.process_time()
            name, _, extra = ROWS[key]
            figures = (
                measure_alignment(args, extra)
                if key.startswith("alignment")
                else measure_row(name, extra, args)
            )
            figures["cpu_s"] = round(time.process_time() - start, 1)
            path.write_text(json.dumps(figures))
        print(line(key, figures, args), flush=True)
        if key.startswith("alignment"):
            shares = ", ".join(
                f"T={t:g} s: {100 * c / figures['runs']:.1f} %"
                for t, c in zip(CHECK_TIMES, figures["checks"], strict=True)
            )
            print(f"    |yaw error| < 5 deg at T: {shares}; failed criteria: {figures.get('reasons')}")
        else:
            print(f"    failed seeds: {figures['failed'][:30]}; failed criteria: {figures['reasons']}")


if __name__ == "__main__":
    main()
