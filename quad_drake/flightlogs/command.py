"""``quad-drake replay``: the command behind the CLI's parser (``cli.cmd_replay``).

Every input is checked before anything runs (the config, the log file, ``--out``); a bad one is a
ConfigError, which the CLI prints as one line with exit code 2.
"""

import math
from pathlib import Path

from quad_drake.config.errors import ConfigError
from quad_drake.flightlogs.replay import COMPARE_AFTER, breakdown_error, replay, replay_many, save_replay
from quad_drake.flightlogs.settings import distinct_logs, estimator_mapping, load_replay
from quad_drake.output.outdir import check_output_dir, is_result_folder, write_text_atomic
from quad_drake.output.results import claim_run_folder, variant_name

TABLE_STATES = ("Roll", "Pitch", "Yaw", "X", "Y", "Z", "VX", "VY", "VZ")
"""The columns (RMS of ours - PX4's) of the table over many logs."""
LOG_SUFFIXES = (".ulg", ".csv")


def expand_logs(names) -> list[str]:
    """The logs of the command line's LOG arguments: a folder stands for its .ulg and .csv files
    (sorted); anything else as given. ConfigError for a folder without any."""
    logs = []
    for name in names:
        path = Path(str(name))
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix.lower() in LOG_SUFFIXES)
            if not found:
                raise ConfigError(f"{path}: a folder without .ulg or .csv flight logs")
            logs += [str(p) for p in found]
        else:
            logs.append(str(name))
    return logs


def given_logs(*groups, done) -> list[list[str]]:
    """Each group of LOG arguments as its logs (:func:`expand_logs`), each file once within its
    group (``settings.distinct_logs``); one note over all the groups naming the repeats left out,
    which were `done` ("replayed", "taken") once. ConfigError for a name that is no log."""
    kept, repeated = [], []
    for names in groups:
        logs, again = distinct_logs(expand_logs(names))
        kept.append(logs)
        repeated += again
    if repeated:
        print(f"note: {', '.join(repeated)}: given more than once (the same file); {done} once")
    return kept


def _out_folder(args, log):
    """(output folder, the replay folder reproduced or None): ``--out`` (default ``out``), or for
    LOG = a replay folder's config.yaml without ``--out`` the folder holding that replay folder."""
    path = Path(log)
    reproduced = (
        path.resolve().parent if path.name == "config.yaml" and is_result_folder(path.parent) else None
    )
    if args.out is None and reproduced is not None:
        return check_output_dir(reproduced.parent), reproduced
    out = check_output_dir(args.out or "out")
    if is_result_folder(out):
        raise ConfigError(
            f"--out {out}: is a run or replay folder (it holds summary.json or logs.npz); "
            "give the folder that holds it, or a new one"
        )
    return out, reproduced


def result_lines(result) -> list[str]:
    """The console lines of a ReplayResult: differences, NIS, health and notes."""
    lines = [f"  against PX4's own estimate (another estimator, not the truth), from {COMPARE_AFTER:g} s on:"]
    if result.attitude or result.position:
        lines.append(f"  {'state':6s} {'unit':5s} {'RMS':>9s} {'max':>9s} {'our σ':>9s}")
        for d in result.attitude + result.position:
            if d.count == 0:
                lines.append(f"  {d.state:6s} {d.unit:5s} {d.reason}")
                continue
            sigma = f"{d.sigma_rms:9.4f}" if math.isfinite(d.sigma_rms) else f"{'n/a':>9s}"
            lines.append(f"  {d.state:6s} {d.unit:5s} {d.rms:9.4f} {d.max_abs:9.4f} {sigma}")
    for s in result.nis:
        where = "in" if s.in_band else ("below" if s.mean < s.band[0] else "above")
        lines.append(
            f"  NIS {s.sensor} ({s.dof} dof): mean {s.mean:.3g} over {s.count} updates, 95 % band "
            f"[{s.band[0]:.3g}, {s.band[1]:.3g}]: {where}; {100 * s.single_share:.0f} % of single "
            "updates in theirs"
        )
    if result.truth:
        lines.append(f"  against the simulator's ground truth, from {COMPARE_AFTER:g} s on (RMS error):")
        lines.append(f"  {'state':6s} {'unit':5s} {'ours':>9s} {'PX4':>9s}")
        for e in result.truth:
            if e.count == 0:
                lines.append(f"  {e.state:6s} {e.unit:5s} {e.reason}")
            else:
                lines.append(f"  {e.state:6s} {e.unit:5s} {e.ours_rms:9.4f} {e.figure(e.px4_rms):>9s}")
    for s in result.truth_nees:
        where = "in" if s.in_band else ("below" if s.mean < s.band[0] else "above")
        lines.append(
            f"  NEES {s.block} ({s.dof} dof, ours): mean {s.mean:.3g} over {s.count} samples, 95 % band "
            f"[{s.band[0]:.3g}, {s.band[1]:.3g}]: {where} (samples correlated in time: a guide)"
        )
    lines.append("  " + result.health_line())
    lines += [f"  note: {line}" for line in result.notes()[1:]]
    return lines


def replay_command(args) -> int:
    """Run ``quad-drake replay`` (README "Replaying flight logs"): one log, or each of many and one
    table over them (``replay_table.csv`` in the output folder). Many logs whose settings allow it
    are replayed in one Diagram, a vehicle each (``replay.replay_many``; ``--separately``: each in
    its own). Exit code 0 when every log replayed; 2 when one could not (its line printed, the
    others replayed and saved)."""
    (logs,) = given_logs(args.log, done="replayed")
    overrides = [*args.set, *(["smooth=true"] if getattr(args, "smooth", False) else [])]
    configs = [load_replay(log, args.estimator, overrides) for log in logs]  # every input before any run
    if len(configs) == 1:
        out, reproduced = _out_folder(args, logs[0])
        try:
            result = replay(configs[0])
        except ArithmeticError as e:
            raise breakdown_error(configs[0], e) from None
        _report(args, logs[0], configs[0], result, out, reproduced)
        return 0
    folders = [_out_folder(args, log) for log in logs]
    outcomes = replay_many(configs, together=not getattr(args, "separately", False))
    rows, failed = [], False
    for log, config, folder, outcome in zip(logs, configs, folders, outcomes, strict=True):
        if isinstance(outcome, ConfigError):  # a log that cannot be replayed: said, and the others go on
            print(f"error: {outcome}")
            rows.append(table_row(config, None, str(outcome)))
            failed = True
            continue
        _report(args, log, config, outcome, *folder)
        rows.append(table_row(config, outcome))
    out = check_output_dir(args.out or "out")
    print_table(rows)
    path = save_table(rows, out / "replay_table.csv")
    print(f"saved {path}")
    return 2 if failed else 0


def table_row(config, result, error="") -> dict[str, str]:
    """{column: text} of one log in the table over many: its RMS differences (or n/a reasons)."""
    row = {"log": Path(config.log).stem, "estimator": config.estimator.kind}
    if result is None:
        return row | {"duration_s": "", **{s: "n/a: not replayed" for s in TABLE_STATES}, "note": error}
    row["duration_s"] = f"{result.log.duration:.1f}"
    figures = {d.state: d for d in result.attitude + result.position}
    for state in TABLE_STATES:
        d = figures.get(state)
        row[state] = "n/a: not compared" if d is None else d.figure(d.rms)
    return row | {"note": ""}


def print_table(rows) -> None:
    """Print the table over many logs (n/a reasons shortened to n/a; the CSV keeps them)."""
    columns = ["log", "estimator", "duration_s", *TABLE_STATES]
    widths = {c: max(len(c), *(len(_short(r[c])) for r in rows)) for c in columns}
    print("  ".join(f"{c:{widths[c]}s}" for c in columns))
    for row in rows:
        print("  ".join(f"{_short(row[c]):{widths[c]}s}" for c in columns))


def _short(text):
    return "n/a" if text.startswith("n/a") else text


def save_table(rows, path) -> Path:
    """Write the table over many logs as CSV (every column, the n/a reasons whole); its path."""
    import csv
    import io

    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(path, buffer.getvalue())
    return path


def _report(args, log, config, result, out, reproduced):
    """Print a replayed log's lines (its config resolved, its ReplayResult) and save its folder
    into `out` (``_out_folder``'s)."""
    tuned = args.estimator and set(estimator_mapping(args.estimator)) != {"kind"}  # more than the kind
    overrides = ([f"--estimator={args.estimator}"] if tuned else []) + list(args.set)
    overrides += ["smooth=true"] if config.smooth else []
    name = variant_name(f"{config.name or Path(config.log).stem}-{config.estimator.kind}", None, overrides)
    sensors = ", ".join(["imu", *result.log.sensors()])
    shared = f" (one Diagram of {result.logs_in_diagram} logs)" if result.logs_in_diagram > 1 else ""
    print(
        f"== replay {result.config.name} on {config.estimator.kind}: {result.log.duration:.1f} s of log "
        f"({sensors}) in {result.wall_time:.2f} s{shared}"
    )
    for line in result_lines(result):
        print(line)
    folder = claim_run_folder(out, name, result.config, replace=reproduced is None)
    save_replay(result, folder)
    if not args.no_plots:
        from quad_drake.flightlogs.page import write_replay_artifacts
        from quad_drake.output.report import write_index

        write_replay_artifacts(result, folder)
        print(f"saved {folder}/")
        print(f"open {write_index(out)}")
    else:
        print(f"saved {folder}/")
