"""Fly the grading campaign: the correct solution on 06-11 and each classic mistake on the
scenario meant to catch it, over many seeds; save every run's statistics (``grading/statistics``)
so that the criteria can be calibrated and re-judged without flying again, and print the table.

    nice python benchmarks/grading_campaign.py --runs 200 --first-seed 0 --out /tmp/grading_validation.json
    python benchmarks/grading_campaign.py --table /tmp/grading_validation.json

Variants: ``correct``, every name of ``tests/grading/mistakes.py``, and ``writeup:<label>`` (the
write-ups' tunings and attitude schemes, ``tests/grading/writeups.py``). Each variant's N runs of a
scenario are one fleet. The reference's single-seed verdict is the scenario's own criteria at
its default seed (08 and 09 have none in the reference).
"""

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "grading"))

from mistakes import CORRECT, MISTAKES, patched  # noqa: E402

from quad_drake.grading import grader  # noqa: E402
from quad_drake.grading.criteria import CRITERIA, ISOLATES  # noqa: E402
from quad_drake.judging.consistency import binomial_interval  # noqa: E402
from quad_drake.running import catalog  # noqa: E402

NO_REFERENCE_CRITERION = ("08_predict_state", "09_predict_covariance")


def variant_plan(names, folder, only=None):
    """{variant: (module path, scenarios to fly)}; `only`: fly only these scenarios."""
    plan = {}
    for name in names:
        if name == "correct":
            plan[name] = (CORRECT, grader.COURSE_SCENARIOS)
        elif name.startswith("writeup:"):
            from writeups import WRITEUPS, written

            plan[name] = (written(WRITEUPS[name.split(":", 1)[1]], folder), grader.COURSE_SCENARIOS)
        else:
            mistake = next(m for m in MISTAKES if m.name == name)
            plan[name] = (patched(mistake, folder), (mistake.scenario,))
    if only:
        plan = {name: (module, [s for s in only]) for name, (module, _) in plan.items()}
    return plan


def fly_campaign(names, runs, first_seed, only=None):
    """{variant: {scenario: {"stats": {statistic: [N]}, "reference": [N bool], "single_seed": bool|None,
    "cpu": s}}}."""
    out = {}
    with tempfile.TemporaryDirectory() as folder:
        for variant, (module, scenarios) in variant_plan(names, folder, only).items():
            out[variant] = {}
            for scenario in scenarios:
                seeds = tuple(range(first_seed, first_seed + runs))
                graded = grader.grade_scenario(scenario, module, seeds)
                single = None
                if scenario not in NO_REFERENCE_CRITERION:
                    seed = catalog.load(scenario).seed
                    if seed in seeds:  # the default seed flew in the fleet
                        single = bool(graded.reference_passed[seeds.index(seed)])
                    else:
                        single = bool(grader.grade_scenario(scenario, module, (seed,)).reference_passed[0])
                out[variant][scenario] = {
                    "stats": {k: v.tolist() for k, v in graded.values.items()},
                    "reference": graded.reference_passed.tolist(),
                    "single_seed": single,
                    "cpu": graded.cpu_time,
                }
                print(
                    f"{variant} {scenario}: {graded.passes}/{graded.runs} pass, {graded.cpu_time:.1f} s CPU",
                    flush=True,
                )
    return out


def passed(scenario, stats):
    """(N,) bool: runs passing every grading criterion of `scenario`."""
    ok = None
    for c in CRITERIA[scenario]:
        this = c.passed(np.asarray(stats[c.statistic], dtype=float))
        ok = this if ok is None else ok & this
    return ok


def rate_text(k, n):
    low, high = binomial_interval(k, n)
    return f"{100 * k / n:.1f} % [{100 * low:.1f}, {100 * high:.1f}] ({k}/{n})"


def table(results):
    """Markdown rows of the campaign: the correct solution per scenario, then each variant."""
    lines = [
        "| variant | function | scenario | grading: pass rate (correct) or detection rate [95 % CI] "
        "| the scenario's own criteria: pass rate, same seeds | the reference's single-seed verdict |",
        "|---|---|---|---|---|---|",
    ]
    mistakes = {m.name: m for m in MISTAKES}
    for variant, scenarios in results.items():
        for scenario, record in scenarios.items():
            ok = passed(scenario, record["stats"])
            n = len(ok)
            ref = np.asarray(record["reference"], dtype=bool)
            single = record["single_seed"]
            single_text = "— (none in the reference)" if single is None else ("PASS" if single else "FAIL")
            if variant in mistakes:
                function, shown = mistakes[variant].function, rate_text(int((~ok).sum()), n)
                ref_text = f"{100 * ref.mean():.1f} % pass"
            else:
                function, shown = ISOLATES[scenario], rate_text(int(ok.sum()), n)
                ref_text = f"{100 * ref.mean():.1f} % pass"
            lines.append(f"| {variant} | {function} | {scenario} | {shown} | {ref_text} | {single_text} |")
    return lines


def matrix(results):
    """Markdown rows: one per variant flown on every course scenario, its pass count per scenario
    and, in brackets, the reference's single-seed verdict (— where the reference has none)."""
    names = grader.COURSE_SCENARIOS
    lines = ["| variant | " + " | ".join(n[:2] for n in names) + " |", "|---|" + "---|" * len(names)]
    for variant, scenarios in results.items():
        if set(scenarios) != set(names):
            continue
        cells = []
        for name in names:
            record = scenarios[name]
            ok = passed(name, record["stats"])
            single = {None: "—", True: "PASS", False: "FAIL"}[record["single_seed"]]
            cells.append(f"{int(ok.sum())}/{len(ok)} ({single})")
        lines.append(f"| {variant} | " + " | ".join(cells) + " |")
    return lines


def sources():
    """Markdown rows: each mistake, its function, its patch and where it comes from."""
    lines = ["| mistake | function | where it comes from |", "|---|---|---|"]
    lines += [f"| {m.name} | {m.function} | {m.source} |" for m in MISTAKES]
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--variants", nargs="*", default=["correct", *[m.name for m in MISTAKES]])
    parser.add_argument("--scenarios", nargs="*", help="fly every variant on these scenarios only")
    parser.add_argument("--out", help="JSON file for the runs' statistics")
    parser.add_argument("--table", nargs="*", help="print the table of saved JSON files instead of flying")
    parser.add_argument("--sources", action="store_true", help="print the mistakes' sources")
    args = parser.parse_args(argv)
    if args.sources:
        print("\n".join(sources()))
        return
    if args.table:
        results = {}
        for path in args.table:  # later files add variants or replace a variant's scenarios
            for variant, scenarios in json.loads(Path(path).read_text())["results"].items():
                results.setdefault(variant, {}).update(scenarios)
    else:
        start = time.process_time()
        results = fly_campaign(args.variants, args.runs, args.first_seed, args.scenarios)
        meta = {"runs": args.runs, "first_seed": args.first_seed, "cpu": time.process_time() - start}
        if args.out:
            Path(args.out).write_text(json.dumps({"meta": meta, "results": results}))
        print(f"CPU {meta['cpu']:.0f} s")
    print("\n".join(table(results)))
    print()
    print("\n".join(matrix(results)))


if __name__ == "__main__":
    main()
