"""The manual's fault table (docs/measurements/faults.md): each fault scenario with its mitigation on
and off, by campaign.

For every row of ROWS it runs a Monte Carlo campaign through the project's campaign API
(``quad_drake.campaigns.run_campaign``; run i flies seed S + i, exactly as
``quad-drake montecarlo <scenario> --runs N --seed S [--set ...]``), and rewrites the table
between that page's ``<!-- fault-table -->`` markers. Pass rates carry a 95 % Wilson score
interval. Each finished row is cached as JSON in ``--cache`` (keyed by scenario, overrides,
runs, seed and runner), so an interrupted table resumes where it stopped; ``--fresh`` ignores the cache.

    nice -n 10 python benchmarks/fault_table.py --runs 50 --seed 100 --jobs 1

``--fleet B`` flies every row on the fleet runner in batches of B runs (``quad-drake montecarlo
... --fleet --batch B``; its noise streams differ from the per-vehicle path's, the manual's
"Fleet mode"); without it every row flies one Diagram per run. The cache key names the runner
(``_fleetB`` or nothing) and a cached row is used only if its recorded runner is that one; the
table's runner column says which runner measured each row.

``--check-seeds A B`` instead flies every bundled fault scenario (12-18, mitigation on) with
its default seed and with seeds A..B (issue 11: 0-19), prints the failures and exits 1 if any.
"""

import argparse
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from scipy.stats import binomtest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from quad_drake import campaigns  # noqa: E402
from quad_drake.running import catalog  # noqa: E402

BEGIN, END = "<!-- fault-table -->", "<!-- /fault-table -->"
EKF7 = (
    "vehicles.0.estimator={kind: ekf7, q_pos_xy_std: 0.05, q_vel_xy_std: 0.35, q_vel_z_std: 0.2,"
    " q_yaw_std: 0.06, gps_pos_xy_std: 0.7, gps_pos_z_std: 2.0}"
)
"""The EKF7 with 11's former tuning in place of a fault scenario's ESKF (their files give the same)."""
ESKF = "vehicles.0.estimator={kind: eskf}"


@dataclass(frozen=True)
class Row:
    """One table row: a bundled scenario flown with `overrides` (``--set`` values), labelled."""

    scenario: str
    label: str
    overrides: tuple = ()

    @property
    def key(self):
        return re.sub(r"[^A-Za-z0-9]+", "_", f"{self.scenario} {' '.join(self.overrides)}").strip("_")


ROWS = (
    Row("12_gps_outage", "ESKF (bundled, 2 s outage)"),
    Row("12_gps_outage", "EKF7", (EKF7,)),
    Row("13_gps_outlier", "EKF7, 5σ gate (bundled)"),
    Row("13_gps_outlier", "EKF7, gate off", ("vehicles.0.estimator.gps_gate_sigma=0",)),
    Row("13_gps_outlier", "ESKF, 5σ gate", (ESKF,)),
    Row("14_gps_delay", "ESKF + delay compensation (bundled)"),
    Row("14_gps_delay", "ESKF, no compensation", ("vehicles.0.gps_delay_compensation=0",)),
    Row("15_gps_step", "ESKF, 5σ gate (bundled, 2 s step)"),
    Row("15_gps_step", "ESKF, gate off", ("vehicles.0.estimator={kind: eskf, gps_gate_sigma: 0}",)),
    Row("15_gps_step", "EKF7, 5σ gate", (EKF7,)),
    Row("16_mag_disturbance", "ESKF, 5σ gate (bundled)"),
    Row(
        "16_mag_disturbance",
        "ESKF, mag gate off",
        ("vehicles.0.estimator={kind: eskf, mag_gate_sigma: 0}",),
    ),
    Row("16_mag_disturbance", "EKF7, 5σ gate", (EKF7,)),
    Row("17_imu_bias", "ESKF, biases estimated (bundled)"),
    Row("17_imu_bias", "EKF7", (EKF7,)),
    Row("18_imu_dropout", "ESKF (bundled)"),
    Row("18_imu_dropout", "EKF7", (EKF7,)),
    Row("23_gps_outage_baro", "ESKF + barometer (bundled, 10 s outage)"),
    Row("23_gps_outage_baro", "ESKF, no barometer", ("vehicles.0.sensors.baro=null",)),
    Row("24_mag3_disturbance", "ESKF, 3-axis field, 5σ gate (bundled)"),
    Row("24_mag3_disturbance", "ESKF, field gate off", ("vehicles.0.estimator.mag_field.gate_sigma=0",)),
    Row(
        "24_mag3_disturbance",
        "ESKF, hard iron not calibrated",
        ("vehicles.0.estimator.mag_field.hard_iron=[0, 0, 0]",),
    ),
    Row("25_baro_step", "EKF7, baro gate + bias reset (bundled)"),
    Row("25_baro_step", "EKF7, baro gate off", ("vehicles.0.estimator.baro.gate_sigma=0",)),
    Row(
        "25_baro_step",
        "ESKF, baro gate + bias reset",
        ("vehicles.0.estimator={kind: eskf, estimate_biases: false}",),
    ),
)
"""Per fault scenario: the bundled mitigation, then without it, then (where the bundled one
is not the only estimator that copes) the other estimator with the same mitigation."""

HEADER = (
    "| scenario | configuration | runs (seeds) | all criteria [95 % Wilson CI] | floor strikes (runs) "
    "| max \\|Est.E.Pos\\| [m] | max PosFollowErr [m] | runner | `--set` |\n"
    "|---|---|---|---|---|---|---|---|---|"
)


def wilson(passes, runs):
    """(low, high) 95 % Wilson score interval of a pass rate, in percent."""
    ci = binomtest(passes, runs).proportion_ci(confidence_level=0.95, method="wilson")
    return 100.0 * ci.low, 100.0 * ci.high


def summarize(campaign):
    """The row's figures from a CampaignResult: passes, floor strikes, worst errors, seeds."""
    records = campaign.records
    floor = sum(any(c["kind"] == "floor" and not c["passed"] for c in r.criteria) for r in records)

    def worst(key):
        return max(value["max"] for r in records for name, value in r.metrics.items() if name.endswith(key))

    return {
        "runs": campaign.runs,
        "seeds": list(campaign.seeds),
        "passes": sum(r.passed for r in records),
        "floor_strikes": int(floor),
        "max_est_pos": worst(".Est.E.Pos"),
        "max_follow": worst(".PosFollowErr"),
        "failed_seeds": [r.seed for r in records if not r.passed],
        "runner": campaign.runner,
    }


def row_line(row, figures):
    runs, passes = figures["runs"], figures["passes"]
    low, high = wilson(passes, runs)
    first, last = figures["seeds"]
    sets = " ".join(f"--set '{o}'" if " " in o else f"--set {o}" for o in row.overrides)
    return (
        f"| {row.scenario} | {row.label} | {runs} ({first}–{last}) "
        f"| {passes}/{runs} = {100 * passes / runs:.0f} % [{low:.0f}, {high:.0f}] "
        f"| {figures['floor_strikes']} | {figures['max_est_pos']:.2f} | {figures['max_follow']:.2f} "
        f"| {figures['runner']} | {f'`{sets}`' if sets else ''} |"
    )


def table(rows_and_figures):
    """The Markdown table (header and one line per (Row, figures))."""
    return "\n".join([HEADER] + [row_line(row, figures) for row, figures in rows_and_figures])


def replace_table(text, new_table):
    """`text` with everything between the fault-table markers replaced by `new_table`."""
    start, end = text.find(BEGIN), text.find(END)
    if start < 0 or end < start:
        raise ValueError(f"no {BEGIN} ... {END} block")
    return text[: start + len(BEGIN)] + "\n" + new_table + "\n" + text[end:]


def cache_path(cache, row, runs, seed, fleet_batch):
    """The JSON file caching `row` measured with `runs` runs from `seed` on the fleet runner in
    batches of `fleet_batch` (None: one Diagram per run)."""
    runner_key = f"_fleet{fleet_batch}" if fleet_batch is not None else ""
    return cache / f"{row.key}_n{runs}_s{seed}{runner_key}.json"


def measured_by(figures, fleet_batch):
    """Whether cached `figures` were measured on the runner of `fleet_batch`: the fleet in
    batches of B (runner "fleet (batch B) on ..."), or for None one Diagram per run."""
    runner = figures.get("runner", "")
    if fleet_batch is None:
        return not runner.startswith("fleet")
    return runner.startswith(f"fleet (batch {fleet_batch}) ")


def cached(path, fleet_batch):
    """The figures cached in `path`, or None when there are none or another runner measured them."""
    if not path.exists():
        return None
    figures = json.loads(path.read_text())
    return figures if measured_by(figures, fleet_batch) else None


def measure(row, runs, seed, runner, fleet_batch=None):
    scenario = catalog.load(row.scenario, None, list(row.overrides))
    campaign = campaigns.run_campaign(scenario, runs, runner=runner, seed=seed, fleet_batch=fleet_batch)
    return summarize(campaign)


def check_seeds(first, last, runner):
    """Failed (scenario, seed) pairs of every bundled fault scenario at its default seed and first..last."""
    failures = []
    for name in dict.fromkeys(row.scenario for row in ROWS):
        scenario = catalog.load(name)
        default = campaigns.run_campaign(scenario, 1, runner=runner, progress=False)
        seeds = campaigns.run_campaign(scenario, last - first + 1, runner=runner, seed=first)
        failed = [r.seed for r in default.records + seeds.records if not r.passed]
        print(f"{name}: seed {scenario.seed} and {first}-{last}: failed {failed or 'none'}", flush=True)
        failures += [(name, seed) for seed in failed]
    return failures


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--seed", type=int, default=100, help="first seed S; run i flies S + i")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--page", type=Path, default=ROOT / "docs" / "measurements" / "faults.md")
    parser.add_argument("--cache", type=Path, default=ROOT / "out" / "fault_table")
    parser.add_argument("--fresh", action="store_true", help="re-measure rows already in the cache")
    parser.add_argument("--only", nargs="*", default=None, help="scenario names to measure (default: all)")
    parser.add_argument("--fleet", type=int, metavar="B", help="fleet batch size (see the docstring)")
    parser.add_argument("--check-seeds", nargs=2, type=int, metavar=("A", "B"), help="see the docstring")
    args = parser.parse_args(argv)
    runner = campaigns.InProcessRunner() if args.jobs == 1 else campaigns.ProcessPoolRunner(args.jobs)
    if args.check_seeds:
        sys.exit(1 if check_seeds(*args.check_seeds, runner) else 0)
    args.cache.mkdir(parents=True, exist_ok=True)
    measured = {}
    selected = [row for row in ROWS if args.only is None or row.scenario in args.only]
    for row in sorted(selected, key=lambda row: not row.overrides):  # the "off" rows first
        path = cache_path(args.cache, row, args.runs, args.seed, args.fleet)
        figures = None if args.fresh else cached(path, args.fleet)
        if figures is None:
            figures = measure(row, args.runs, args.seed, runner, args.fleet)
            path.write_text(json.dumps(figures, indent=1))
        print(row_line(row, figures), flush=True)
        measured[row] = figures
    if args.only is None:
        rows = [(row, measured[row]) for row in ROWS]
        args.page.write_text(replace_table(args.page.read_text(), table(rows)))
        print(f"rewrote the fault table in {args.page}")


if __name__ == "__main__":
    main()
