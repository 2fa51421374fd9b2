"""``quad-drake replay``: the command behind the CLI's parser (``cli.cmd_replay``).

Every input is checked before anything runs (the config, the log file, ``--out``); a bad one is a
ConfigError, which the CLI prints as one line with exit code 2.
"""

import math
from pathlib import Path

from quad_drake.config.errors import ConfigError
from quad_drake.flightlogs.replay import COMPARE_AFTER, replay, save_replay
from quad_drake.flightlogs.settings import estimator_mapping, load_replay
from quad_drake.output.outdir import check_output_dir, is_result_folder
from quad_drake.output.results import claim_run_folder, variant_name


def _out_folder(args):
    """(output folder, the replay folder reproduced or None): ``--out`` (default ``out``), or for
    LOG = a replay folder's config.yaml without ``--out`` the folder holding that replay folder."""
    path = Path(args.log)
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


def result_lines(result):
    """The console lines of a ReplayResult: differences, NIS, health and notes."""
    lines = [f"  against PX4's own estimate (another estimator, not the truth), from {COMPARE_AFTER:g} s on:"]
    if result.attitude or result.position:
        lines.append(f"  {'state':6s} {'unit':5s} {'RMS':>9s} {'max':>9s} {'our σ':>9s}")
        for d in result.attitude + result.position:
            sigma = f"{d.sigma_rms:9.4f}" if math.isfinite(d.sigma_rms) else f"{'-':>9s}"
            lines.append(f"  {d.state:6s} {d.unit:5s} {d.rms:9.4f} {d.max_abs:9.4f} {sigma}")
    for s in result.nis:
        where = "in" if s.in_band else ("below" if s.mean < s.band[0] else "above")
        lines.append(
            f"  NIS {s.sensor} ({s.dof} dof): mean {s.mean:.3g} over {s.count} updates, 95 % band "
            f"[{s.band[0]:.3g}, {s.band[1]:.3g}]: {where}; {100 * s.single_share:.0f} % of single "
            "updates in theirs"
        )
    lines.append("  " + result.health_line())
    lines += [f"  note: {line}" for line in result.notes()[1:]]
    return lines


def replay_command(args):
    """Run ``quad-drake replay`` (README "Replaying flight logs"); exit code 0 when it ran."""
    config = load_replay(args.log, args.estimator, args.set)
    out, reproduced = _out_folder(args)
    tuned = args.estimator and set(estimator_mapping(args.estimator)) != {"kind"}  # more than the kind
    overrides = ([f"--estimator={args.estimator}"] if tuned else []) + list(args.set)
    name = variant_name(f"{config.name or Path(config.log).stem}-{config.estimator.kind}", None, overrides)
    try:
        result = replay(config)
    except ArithmeticError as e:
        raise ConfigError(
            f"{config.log}: the replay broke down numerically ({type(e).__name__}: {e}); "
            "check the noise and covariance settings"
        ) from None
    sensors = ", ".join(["imu", *result.log.sensors()])
    print(
        f"== replay {result.config.name} on {config.estimator.kind}: {result.log.duration:.1f} s of log "
        f"({sensors}) in {result.wall_time:.2f} s"
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
    return 0
