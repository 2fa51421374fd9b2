"""quad-drake: a quadrotor's scenarios, campaigns, tuning, flight-log replay and grading on Drake.

Commands: ``list | run | montecarlo | tune | replay | diagram | noise-std | grade | export |
warmup``.

Exit codes: 0 every criterion passed, 1 a criterion failed, 2 bad input
(one line on stderr, no traceback), 3 results could not be written (a full disk, a folder
that became unwritable: one line; every file already written is whole), 4 your own estimator
raised during a flight (one line, then your code's traceback), 130 interrupted (Ctrl-C;
finished runs are kept).
"""

import argparse
import gc
import importlib
import os
import sys
import warnings
from pathlib import Path

from . import __version__
from .config.errors import ConfigError
from .config.loader import load_scenario
from .estimation.custom import EstimatorProblem, EstimatorRaised
from .output.outdir import check_output_dir, is_result_folder
from .running import catalog

EXIT_WRITE_FAILED = 3
"""Exit code when results could not be written (an OSError while saving; one line on stderr)."""
EXIT_ESTIMATOR_RAISED = 4
"""Exit code when a custom estimator raised during a flight (``custom.EstimatorRaised``)."""

EXIT_CODES = """exit codes:
  0    every criterion passed (montecarlo: every consistency criterion; tune: held-out check)
  1    a criterion failed
  2    bad input: one line on stderr naming the file and the field; nothing ran
  3    results could not be written (disk full, folder unwritable): one line on stderr;
       files already written are whole (each is written to a temporary file, then renamed)
  4    your own estimator (kind: custom) raised during a flight: one line naming the
       method, the vehicle, the sim time and the seed, then your code's traceback
  130  interrupted (Ctrl-C): the finished runs are kept"""


def cmd_list(args) -> int:
    scenarios = catalog.bundled_scenarios()
    width = max(map(len, scenarios))  # the longest name sets the column
    for name, path in scenarios.items():
        try:
            description = load_scenario(path).description
        except ConfigError as e:
            description = f"(invalid: {e})"
        print(f"{name:{width}s}  {description}")
    return 0


def _table(rows):
    width = max([len("scenario"), *(len(s["scenario"]) for s in rows)])
    header = (
        f"{'scenario':{width}s} {'seed':>5s} {'criteria':>9s} {'result':>7s} {'wall[s]':>8s} {'x real':>7s}"
    )
    lines = [header, "-" * len(header)]
    for s in rows:
        passed = sum(c["passed"] for c in s["criteria"])
        verdict = "PASS" if s["passed"] else "FAIL"
        if not s["criteria"]:
            verdict = "-"
        lines.append(
            f"{s['scenario']:{width}s} {s['seed']:5d} {passed:4d}/{len(s['criteria']):<4d} "
            f"{verdict:>7s} {s['wall_time_s']:8.2f} {s['real_time_factor']:7.1f}"
        )
    return "\n".join(lines)


def _import_for_flights() -> None:
    """Import the modules a flight runs on (``running.simulation``: numba, pydrake's systems, the
    kernels; most of a run's start) with the cyclic garbage collector paused, then move every
    object made so far into its permanent generation (``gc.freeze``): modules and their objects
    live as long as the process, so scanning them is wasted work (about 0.06 s of ``run``'s CPU:
    a third of its collections, and the full passes then skip the imported heap). Only where
    this call is their import (a fresh ``quad-drake`` process, or the first run of a session that
    had not imported them): a process that imported them before is left as it is."""
    module = f"{__package__}.running.simulation"
    if module in sys.modules:
        return
    collecting = gc.isenabled()
    gc.disable()
    try:
        importlib.import_module(module)
    finally:
        gc.freeze()
        if collecting:
            gc.enable()


def _fly(scenario):
    """SimulationResult of one scenario (with progress on stderr from progress.LONG_FLIGHT_S
    of simulated time on); a numerical breakdown of the flight is one line."""
    from .running.progress import LONG_FLIGHT_S, FlightProgress
    from .running.simulation import run

    progress = (
        FlightProgress(scenario.name, scenario.end_time) if scenario.end_time >= LONG_FLIGHT_S else None
    )
    try:
        return run(scenario, progress)
    except ArithmeticError as e:  # e.g. a filter whose covariance stopped being usable
        raise ConfigError(
            f"{scenario.name}: the simulation broke down numerically ({type(e).__name__}: {e}); "
            "check the noise and covariance settings"
        ) from None
    finally:
        if progress is not None:
            progress.close()


def _check_costs(scenarios):
    """Refuse a scenario whose run would not fit in memory (``limits.check_run``)."""
    from .running.limits import check_run

    for scenario in scenarios:
        check_run(scenario)


def _warn(scenarios):
    """Every input being good: print on stderr what a long run will take and the criteria and
    faults that cannot matter for the flight's length (``config.ineffective_settings``)."""
    from .config.validation import ineffective_settings
    from .running.limits import cost_warnings

    for scenario in scenarios:
        for line in cost_warnings(scenario):
            print(line, file=sys.stderr)
        for line in ineffective_settings(scenario):
            print(f"quad-drake: warning: {scenario.name}: {line}", file=sys.stderr)


def cmd_run(args) -> int:
    from .output.jsonio import dump_json
    from .output.report import estimator_health
    from .output.results import claim_run_folder, save_run, variant_name

    if args.all and args.names:
        named = " ".join(args.names)
        raise ConfigError(f"run: name scenarios or give --all, not both (got {named} and --all)")
    names = list(catalog.bundled_scenarios()) if args.all else args.names
    if not names:
        raise ConfigError("run: name at least one scenario, or --all")
    _import_for_flights()  # before loading: a scenario's load imports the simulation
    scenarios = [catalog.load(n, args.seed, args.set) for n in names]  # all input checked first
    reproduced = [catalog.run_folder_of(n) for n in names]
    folders = [
        variant_name(s.name if source is None else source.name, args.seed, args.set)
        for s, source in zip(scenarios, reproduced, strict=True)
    ]
    _check_distinct_names(scenarios, folders)
    out = _run_out(args, reproduced)
    _check_costs(scenarios)
    _warn(scenarios)
    summaries = []
    try:
        for scenario, folder, source in zip(scenarios, folders, reproduced, strict=True):
            print(f"== {scenario.name} (seed {scenario.seed}, {scenario.end_time:g} s)", flush=True)
            try:
                result = _fly(scenario)
            except EstimatorRaised as e:
                raise e.with_context(f"seed {scenario.seed}") from None
            for criterion in result.criteria:
                print(criterion.line)
            for line in estimator_health(result):
                print(line)
            if result.compile_time > 0:
                compiled = f"{result.compile_time:.1f} s"
                print(
                    f"(numba compiled its kernels for {compiled} first: not in the wall time; "
                    "`quad-drake warmup` compiles every kernel once)"
                )
            # a reproduction goes beside its run folder, never over it
            run_dir = claim_run_folder(out, folder, scenario, replace=source is None)
            if args.smooth:
                from .flightlogs.recording import smooth_vehicles

                for line in smooth_vehicles(result, run_dir):
                    print(line)
            run_dir = save_run(result, run_dir)  # logs first: nothing is lost if a plot fails
            if not args.no_plots:
                from .output.plots import write_run_artifacts

                write_run_artifacts(result, run_dir)
            if args.meshcat:
                from .output.meshcat_animation import show_live

                show_live(result)
            summaries.append(result.summary())
            dump_json(out / "summary.json", summaries)
            print(f"saved {run_dir}/", flush=True)
    except KeyboardInterrupt:
        index = _write_index(args, summaries, out)
        kept = f"kept the {len(summaries)} finished run(s) in {out}/" if summaries else "no run had finished"
        print(f"quad-drake: interrupted; {kept}" + (f", {index}" if index else ""), file=sys.stderr)
        return 130
    index = _write_index(args, summaries, out)
    print()
    print(_table(summaries))
    if index:
        print(f"open {index}")
    return 0 if all(s["passed"] for s in summaries) else 1


def _check_distinct_names(scenarios, folders):
    """ConfigError when two scenarios of one command would share a folder name (the same
    scenario name): the later would go to a numbered folder, hard to tell apart."""
    seen = set()
    for scenario, folder in zip(scenarios, folders, strict=True):
        if folder in seen:
            raise ConfigError(
                f"run: two scenarios are named {scenario.name!r} and would share {folder}/; "
                "give one another name (name: in its file, or --set name=...)"
            )
        seen.add(folder)


def _run_out(args, reproduced):
    """The output folder of ``run``: ``--out`` (default ``out``), or, when every NAME is the
    config.yaml of a run folder and no ``--out`` is given, the folder holding those run folders
    (the reproduction is written beside the run, not inside it). A result folder given as
    ``--out`` is refused: its own files would be replaced."""
    if args.out is None:
        parents = {source.parent for source in reproduced if source is not None}
        if len(parents) == 1 and all(source is not None for source in reproduced):
            return check_output_dir(parents.pop())
    return _check_out_is_not_a_result(check_output_dir(args.out or "out"))


def _check_out_is_not_a_result(out):
    """`out`, unless it is a run's or campaign's folder (ConfigError naming --out)."""
    if is_result_folder(out):
        raise ConfigError(
            f"--out {out}: is a run or campaign folder (it holds summary.json or logs.npz); "
            "give the folder that holds it, or a new one"
        )
    return out


def _write_index(args, summaries, out):
    """Path of out/index.html (every run and campaign folder under out), or None (none
    finished, --no-plots)."""
    if args.no_plots or not summaries:
        return None
    from .output.report import write_index

    return write_index(out)


def cmd_replay(args) -> int:
    """Replay a flight log through an estimator (``flightlogs.replay``), print the comparison with
    the log's own estimate and the NIS, save OUT/<log>-<estimator>[-setHASH]/ and the index."""
    from .flightlogs.command import replay_command

    return replay_command(args)


def cmd_noise_std(args) -> int:
    from .judging.noise_std import measured_noise_std
    from .output.results import load_logs, signals_from_logs

    _, logs = load_logs(args.run_dir)
    for name, std in measured_noise_std(signals_from_logs(logs)).items():
        print(f"{name}: {std:.4f}")
    return 0


def cmd_grade(args) -> int:
    import shutil

    from .grading import grader
    from .grading.course import StudentProblem

    if args.template is not None:
        folder = Path(args.template)
        target = folder / "my_estimator.py"
        if target.exists():
            raise ConfigError(f"{target} exists; not overwritten")
        folder.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(Path(grader.__file__).with_name("student_template.py"), target)
        print(f"wrote {target}: fill in the STUDENT CODE parts, then quad-drake grade {target}")
        return 0
    if args.module is None:
        raise ConfigError("grade: give the student's module (my_estimator.py) or --template DIR")
    if args.runs < 1 or args.jobs < 1:
        raise ConfigError(f"--runs {args.runs} --jobs {args.jobs}: each must be at least 1")
    names = args.scenario or list(grader.COURSE_SCENARIOS)
    unknown = [n for n in names if n not in grader.COURSE_SCENARIOS]
    if unknown:
        raise ConfigError(f"--scenario {unknown[0]}: one of {', '.join(grader.COURSE_SCENARIOS)}")

    def progress(scenario_grade):
        print("\n".join(grader.scenario_lines(scenario_grade)), flush=True)

    try:
        result = grader.grade(args.module, args.runs, args.seed, names, progress, args.jobs)
    except StudentProblem as e:
        raise ConfigError(str(e)) from None
    print(grader.grade_lines(result)[-1])
    return 0 if result.passed else 1


def cmd_export(args) -> int:
    from .output.export import export_csv

    if args.out is not None:
        check_output_dir(args.out)
    for path in export_csv(args.run_dir, args.out):
        print(path)
    return 0


def cmd_diagram(args) -> int:
    from .running.diagram_svg import write_diagram_svg

    scenario = catalog.load(args.name, None, args.set)
    path = Path(args.output or f"{scenario.name}_diagram.svg")
    if path.suffix.lower() != ".svg":
        raise ConfigError(f"diagram -o {path}: the diagram is written as SVG; name a .svg file")
    if path.is_dir():
        raise ConfigError(f"diagram -o {path}: is a folder; name a .svg file")
    check_output_dir(path.parent, option=f"diagram -o {path}: folder")
    print(write_diagram_svg(scenario, path, max_depth=args.depth))
    return 0


def _add_jobs_argument(parser):
    """``--jobs`` of the commands that fly campaigns: worker processes, all cores by default."""
    parser.add_argument(
        "--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: all cores)"
    )


def _add_montecarlo_arguments(parser):
    """Arguments of ``quad-drake montecarlo``."""
    parser.add_argument("name", metavar="NAME", help="scenario name or YAML path")
    parser.add_argument("--runs", type=int, default=100, help="number of runs (default: 100)")
    _add_jobs_argument(parser)
    parser.add_argument("--seed", type=int, help="first seed S; run i uses S+i (default: the scenario's)")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config field, e.g. vehicles.0.estimator.q_yaw_std=0.1",
    )
    parser.add_argument("--out", default="out", help="output folder (default: out)")
    parser.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on a Dask cluster, e.g. tcp://host:8786 (the 'cluster' extra)",
    )
    parser.add_argument(
        "--fleet", action="store_true", help="fly the runs in fleet batches (manual: guide, 'Fleet mode')"
    )
    parser.add_argument(
        "--batch", type=int, metavar="B", help="with --fleet: runs per batch (default: by memory, <= 1000)"
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    return parser


def _add_tune_arguments(parser):
    """Arguments of ``quad-drake tune``."""
    from .tuning.settings import LOG_SPLITS, OBJECTIVES, LogTuneSettings, TuneSettings

    d = TuneSettings()
    parser.add_argument(
        "name",
        metavar="NAME",
        nargs="+",
        help="scenario name or YAML path; or flight logs (.ulg, .csv, a bundled log's name or a folder "
        "of logs): then the ESKF's noise and sensor delays are tuned on the logs' own innovations",
    )
    parser.add_argument(
        "--params",
        nargs="+",
        metavar="KEY",
        help="dotted config keys to search, e.g. estimator.q_vel_xy_std vehicles.0.estimator.q_yaw_std "
        "(default: the estimator's process- and measurement-noise fields)",
    )
    parser.add_argument(
        "--objective", choices=OBJECTIVES, default=d.objective, help=f"(default: {d.objective})"
    )
    parser.add_argument(
        "--budget",
        type=int,
        default=None,
        help=f"candidates to score, the start included (default: {d.budget}; logs: {LogTuneSettings.budget})",
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=d.train_runs,
        help=f"training runs per candidate (default: {d.train_runs})",
    )
    parser.add_argument(
        "--seed", type=int, default=d.train_seed, help=f"first training seed (default: {d.train_seed})"
    )
    parser.add_argument(
        "--holdout", type=int, default=d.holdout_runs, help=f"held-out runs (default: {d.holdout_runs})"
    )
    parser.add_argument(
        "--holdout-seed",
        type=int,
        default=d.holdout_seed,
        help=f"first held-out seed (default: {d.holdout_seed})",
    )
    parser.add_argument("--no-holdout", action="store_true", help="skip the before/after campaigns")
    parser.add_argument("--search-seed", type=int, default=d.search_seed, help="seed of the CMA-ES sampler")
    _add_jobs_argument(parser)
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override a config field first"
    )
    parser.add_argument("--out", help="output folder (default: out/NAME_tune)")
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    logs = parser.add_argument_group("flight logs")
    logs.add_argument(
        "--train-fraction",
        type=float,
        default=LogTuneSettings.train_fraction,
        help="share tuned on (of each --split block, or of each log); the rest is held out "
        "(default: %(default)s)",
    )
    logs.add_argument(
        "--split",
        choices=LOG_SPLITS,
        default=LogTuneSettings.split,
        help="blocks: the first share of each 4 s block tuned on, the rest held out (every flight phase "
        "in both parts); tail: the log's first share tuned on, its tail held out (default: %(default)s)",
    )
    logs.add_argument("--holdout-logs", nargs="+", default=[], metavar="LOG", help="logs only judged")
    logs.add_argument("--no-delays", action="store_true", help="keep the sensor delays as they start")
    logs.add_argument(
        "--no-imu-noise",
        action="store_true",
        help="keep the IMU noise as it starts",
    )
    logs.add_argument("--no-curves", action="store_true", help="skip the delays' objective curves")
    return parser


def _campaign_runner(args):
    from .campaigns import DaskRunner, InProcessRunner, ProcessPoolRunner

    if args.scheduler:
        return DaskRunner(args.scheduler)
    return InProcessRunner() if args.jobs == 1 else ProcessPoolRunner(args.jobs)


def _fleet_batch(args, scenario):
    """Runs per fleet batch of ``--fleet [--batch B]`` (None without --fleet)."""
    if args.batch is not None and not args.fleet:
        raise ConfigError("montecarlo: --batch needs --fleet")
    if not args.fleet:
        return None
    if args.batch is not None:
        return args.batch
    from .campaigns.fleet.runner import default_batch_size

    return default_batch_size(scenario, args.runs, 1 if args.scheduler else args.jobs)


def cmd_montecarlo(args) -> int:
    """Run a campaign, print its table, save OUT/NAME_montecarlo/ and refresh OUT/index.html.

    The last line explains the exit code: 0 every campaign consistency criterion passed (or
    there is none), 1 one failed; Ctrl-C keeps the finished runs (partial summary) and exits 130.
    """
    if args.runs < 1 or args.jobs < 1:  # the limits first: before the heavy imports
        raise ConfigError(f"montecarlo: --runs and --jobs must be >= 1, got {args.runs} and {args.jobs}")
    if args.batch is not None and args.batch < 1:
        raise ConfigError(f"montecarlo: --batch must be >= 1, got {args.batch}")
    from . import campaigns
    from .campaigns.campaign import one_run_command
    from .output.report import write_index
    from .output.results import variant_name

    scenario = catalog.load(args.name, args.seed, args.set)
    out_dir = _check_out_is_not_a_result(check_output_dir(args.out))
    out_dir = out_dir / variant_name(f"{scenario.name}_montecarlo", args.seed, args.set)
    _check_costs([scenario])
    runner, fleet_batch = _campaign_runner(args), _fleet_batch(args, scenario)
    campaigns.plan_campaign(scenario, args.runs, runner, fleet_batch=fleet_batch)  # checks all first
    _warn([scenario])
    try:
        campaign = campaigns.run_campaign(
            scenario,
            args.runs,
            runner=runner,
            progress=not args.quiet,
            fleet_batch=fleet_batch,
            run_command=one_run_command(args.name, args.set),
        )
    except campaigns.CampaignInterrupted as interrupted:
        partial = interrupted.campaign
        campaigns.save(partial, out_dir, plots=False)
        write_index(args.out)
        print(
            f"quad-drake: interrupted after {partial.runs} of {partial.planned} runs; "
            f"the finished ones are in {out_dir}/ (runs.csv, summary.json marked partial)",
            file=sys.stderr,
        )
        return 130
    print(campaigns.table(campaign))
    print(campaigns.timing_line(campaign))
    campaigns.save(campaign, out_dir, plots=not args.no_plots)
    index = write_index(args.out)
    print(
        f"saved {out_dir}/: runs.csv, summary.json, table.txt, report.html"
        + (", consistency.npz" if campaign.consistency else "")
        + (", plots" if not args.no_plots else "")
        + f"; index: {index}"
    )
    print(campaign.verdict())
    return 0 if campaign.passed else 1


def cmd_tune(args) -> int:
    """Search the estimator's noise parameters (``quad_drake.tuning``); write OUT (tuned.yaml,
    history.csv, objective.png, tune.json, before_after.txt). Exit 0 when the tuned scenario
    passes every criterion in every held-out run and its held-out loss is not above the start's,
    1 otherwise; Ctrl-C keeps the best so far and exits 130."""
    from .tuning.logs import is_log_name

    logs = [is_log_name(name) for name in args.name]
    if any(logs):
        if not all(logs):
            raise ConfigError(f"tune: give one scenario or flight logs, not both ({' '.join(args.name)})")
        return cmd_tune_logs(args)
    if len(args.name) > 1:
        raise ConfigError(f"tune: one scenario at a time, got {' '.join(args.name)}")
    args.name = args.name[0]
    from .tuning import TuneSettings, prepare, tune, verdict
    from .tuning.output import before_after

    settings = TuneSettings(
        objective=args.objective,
        budget=TuneSettings.budget if args.budget is None else args.budget,
        train_seed=args.seed,
        train_runs=args.seeds,
        holdout_seed=args.holdout_seed,
        holdout_runs=args.holdout,
        jobs=args.jobs,
        search_seed=args.search_seed,
        holdout=not args.no_holdout,
    )
    from .campaigns.campaign import one_run_command

    scenario = catalog.load(args.name, None, args.set)
    problem = prepare(scenario, args.params, settings, one_run_command(args.name, args.set))
    if args.out is None:  # out/NAME_tune, made with its parent
        out = check_output_dir("out") / f"{problem.scenario.name}_tune"
    else:
        out = check_output_dir(args.out)
    result = tune(problem, out, progress=not args.quiet)
    if result.interrupted:
        return _tune_interrupted(result, out, "held-out comparison skipped")
    best = result.search.best
    print(
        f"{len(result.search.history)} candidates in {result.search_time:.1f} s; best loss "
        f"{best.score.loss:.4g} at candidate {best.index} (start {result.search.history[0].score.loss:.4g})"
    )
    print(f"saved {out}/: " + ", ".join(Path(f).name for f in result.files))
    if args.out is None:  # out/NAME_tune: listed in out/index.html with the runs and campaigns
        from .output.report import write_index

        print(f"index: {write_index(out.parent)}")
    if result.after is None:
        print("tuned (no held-out comparison)")
        return 0
    print(before_after(result), end="")
    print(f"held-out campaigns in {result.holdout_time:.1f} s")
    passed, line = verdict(result)
    print(line)
    return 0 if passed else 1


def _tune_interrupted(result, out, skipped) -> int:
    """Exit code 130 of a tuning interrupted by Ctrl-C, after one line on stderr: what was kept in
    `out` (the best candidate's tuned.yaml, when one had finished) and what was `skipped`."""
    kept = "no candidate had finished"
    if result.search.best is not None:
        kept = f"kept the best of {len(result.search.history)} candidates in {out}/tuned.yaml"
    print(f"quad-drake: interrupted; {kept} ({skipped})", file=sys.stderr)
    return 130


def cmd_tune_logs(args) -> int:
    """Tune the ESKF's noise and sensor delays on flight logs (``quad_drake.tuning.logs``); write
    OUT (tuned.yaml, px4_params.params, history.csv, plots, before_after.txt, report.html). Exit 0
    when every fused channel's NIS per dof lies inside its band on the held-out part, 1 otherwise;
    Ctrl-C keeps the best so far and exits 130."""
    from .tuning import log_output
    from .tuning.logs import prepare, tune_logs, verdict
    from .tuning.settings import LogTuneSettings

    settings = LogTuneSettings(
        budget=LogTuneSettings.budget if args.budget is None else args.budget,
        train_fraction=args.train_fraction,
        split=args.split,
        delays=not args.no_delays,
        imu_noise=not args.no_imu_noise,
        curve_points=0 if args.no_curves else LogTuneSettings.curve_points,
    )
    from .flightlogs.command import given_logs

    names, holdout_names = given_logs(args.name, args.holdout_logs, done="taken")
    problem = prepare(names, holdout_names, args.set, settings)
    stem = Path(problem.logs[0].source).stem
    out = check_output_dir("out") / f"{stem}_tune" if args.out is None else check_output_dir(args.out)
    result = tune_logs(problem, progress=not args.quiet)
    files = log_output.write(result, out)
    if result.interrupted:
        return _tune_interrupted(result, out, "held-out judgement skipped")
    print(f"{len(result.search.history)} replays in {result.search_time:.1f} s")
    print(f"saved {out}/: " + ", ".join(Path(f).name for f in files))
    print(log_output.before_after(result), end="")
    passed, _ = verdict(result)
    return 0 if passed else 1


def cmd_warmup(args) -> int:
    """Compile every numba kernel into the on-disk cache (``quad_drake.warmup``)."""
    from .campaigns.warmup import warm_up_command

    return warm_up_command(force=args.force)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="quad-drake",
        description=__doc__.splitlines()[0],
        epilog=EXIT_CODES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command")
    sub.add_parser("list", help="bundled scenarios with a one-line description").set_defaults(func=cmd_list)
    run_parser = sub.add_parser("run", help="run scenarios, print PASS/FAIL and a summary table")
    run_parser.add_argument("names", nargs="*", metavar="NAME", help="scenario name or YAML path")
    run_parser.add_argument("--all", action="store_true", help="every bundled scenario")
    run_parser.add_argument("--seed", type=int, help="override the scenarios' seed")
    run_parser.add_argument(
        "--out",
        help="output folder (default: out; for NAME = a run folder's config.yaml, the folder above "
        "that run folder). A run goes to OUT/NAME[-seedN][-setHASH], numbered -2, -3 ... when that "
        "holds a run of another config",
    )
    run_parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config field, e.g. vehicles.0.physics.mass=0.8",
    )
    run_parser.add_argument(
        "--no-plots", action="store_true", help="skip plots, report.html, replay.html and index.html"
    )
    run_parser.add_argument(
        "--smooth",
        action="store_true",
        help="also the fixed-interval RTS smoother of each ESKF vehicle: smoothed_state and smoothed_sigma "
        "in logs.npz, the run written as a log (CSV) in its folder",
    )
    run_parser.add_argument(
        "--meshcat", action="store_true", help="also replay each flight live in Meshcat (opens a local URL)"
    )
    run_parser.set_defaults(func=cmd_run)
    _add_montecarlo_arguments(
        sub.add_parser("montecarlo", help="seeded runs in parallel: pass rates, NEES/NIS, accuracy bound")
    ).set_defaults(func=cmd_montecarlo)
    _add_tune_arguments(
        sub.add_parser("tune", help="search the estimator's noise parameters on seeded campaigns")
    ).set_defaults(func=cmd_tune)
    diagram = sub.add_parser("diagram", help="write the scenario's Drake diagram as SVG (Graphviz)")
    diagram.add_argument("name", metavar="NAME")
    diagram.add_argument("-o", "--output", help="SVG path (default: NAME_diagram.svg)")
    diagram.add_argument("--depth", type=int, help="sub-diagram depth to expand (default: all)")
    diagram.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    diagram.set_defaults(func=cmd_diagram)
    replay = sub.add_parser(
        "replay", help="replay a flight log (PX4 .ulg or .csv) through an estimator, compared with PX4's"
    )
    replay.add_argument(
        "log",
        metavar="LOG",
        nargs="+",
        help="a .ulg or .csv file, a bundled log's name, a replay's config.yaml, or a folder of logs; "
        "several: one table over them",
    )
    replay.add_argument(
        "--estimator", metavar="YAML", help="the estimator, e.g. '{kind: eskf}' (default: ekf7)"
    )
    replay.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="e.g. ekf.mag_yaw_std=0.1"
    )
    replay.add_argument(
        "--out",
        help="output folder (default: out; for LOG = a replay folder's config.yaml, the folder above it)",
    )
    replay.add_argument("--no-plots", action="store_true", help="skip the plots, report.html and index.html")
    replay.add_argument(
        "--smooth",
        action="store_true",
        help="ESKF only: also the fixed-interval RTS smoother of the pass, in the logs (= --set smooth=true)",
    )
    replay.add_argument(
        "--separately",
        action="store_true",
        help="several logs: each in a Diagram of its own (default: one Diagram, a vehicle per log, "
        "where the logs' estimator settings allow it)",
    )
    replay.set_defaults(func=cmd_replay)
    noise = sub.add_parser("noise-std", help="step 1: GPS-x and accel-x std devs from a run's logs")
    noise.add_argument("run_dir")
    noise.set_defaults(func=cmd_noise_std)
    grade = sub.add_parser(
        "grade", help="grade a student's estimator (the course's six functions) on 06-11 over many seeds"
    )
    grade.add_argument("module", nargs="?", metavar="MODULE.py", help="the student's module")
    grade.add_argument(
        "--template", metavar="DIR", help="write the starting file DIR/my_estimator.py instead"
    )
    grade.add_argument("--runs", type=int, default=50, help="seeds per scenario (default: 50)")
    grade.add_argument(
        "--jobs", type=int, default=2, help="worker processes, one scenario each at a time (default: 2)"
    )
    grade.add_argument("--seed", type=int, default=0, help="first seed (default: 0)")
    grade.add_argument(
        "--scenario", action="append", metavar="NAME", help="grade only this scenario (repeatable)"
    )
    grade.set_defaults(func=cmd_grade)
    export = sub.add_parser("export", help="a run's logs as CSV: one file per vehicle, signals as columns")
    export.add_argument("run_dir", metavar="RUN_DIR")
    export.add_argument("--out", help="folder for the CSV files (default: RUN_DIR/csv)")
    export.set_defaults(func=cmd_export)
    warmup = sub.add_parser(
        "warmup",
        help="compile every numba kernel into the on-disk cache now (a minute or two, once per install), "
        "so that no later run, campaign or fleet pauses to compile",
    )
    warmup.add_argument(
        "--force", action="store_true", help="fly the warm-up even where an earlier one's stamp is current"
    )
    warmup.set_defaults(func=cmd_warmup)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """A Python warning (e.g. a deprecated field) as one line on stderr, like the command's own."""
    print(f"quad-drake: warning: {message}", file=sys.stderr)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:  # bare `quad-drake`: the help, not an error
        parser.print_help()
        return 0
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return args.func(args)
    except (ConfigError, EstimatorProblem) as e:  # a user's mistake, their own estimator's included
        print(f"quad-drake: {e}", file=sys.stderr)
        return 2
    except EstimatorRaised as e:  # the user's own code failed mid-flight: its frames, not ours
        print(f"quad-drake: {e}", file=sys.stderr)
        print(e.user_frames, end="", file=sys.stderr)
        return EXIT_ESTIMATOR_RAISED
    except KeyboardInterrupt:
        print("quad-drake: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into e.g. `head`: stop quietly
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (flushed at exit)
        return 0
    except OSError as e:  # writing results failed: a full disk, a folder gone or made read-only
        where = f" {e.filename}" if e.filename else ""
        print(
            f"quad-drake: could not write{where}: {e.strerror or e}; the files written before are whole",
            file=sys.stderr,
        )
        return EXIT_WRITE_FAILED


if __name__ == "__main__":
    sys.exit(main())
