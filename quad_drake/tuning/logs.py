"""``quad-drake tune LOG [LOG ...]``: an ESKF's noise and the sensor delays found from flight logs'
own innovations, without truth.

The objective (``judging.innovations``): per fused channel (GPS horizontal and vertical position and
velocity, the heading or the 3-axis field, the barometer), the innovations' negative
log-likelihood per sample, Σ z² + ln s² over the channel's components (s the innovation's std the
filter assumed), summed over channels and training logs (:func:`innovations.likelihood`); a
channel whose replay logs only the filter's NIS (the 3-axis field, the barometer) adds instead
its squared log of the NIS per dof plus the squared autocorrelations of its NIS at lags 1..LAGS
(:func:`innovations.loss`, also reported as each candidate's ``consistency``: 0 for a filter whose
innovations are consistent and white). The likelihood is what makes a delay identifiable: a wrong
delay adds the vehicle's motion over the error to the innovations, and a noise inflated to hide it
brings the NIS per dof back to 1 and the autocorrelation down (the consistency loss then barely
prefers the right delay) but costs its larger ln s².

The search (:func:`tune_logs`): evaluation 0 is the start (the ReplayConfig as loaded: PX4's
default noise, or with ``--set px4_parameters=true`` the log's own EKF2_* values); stage 1 moves
each channel's noise so that its NIS per dof would be 1 if the prior covariance were small beside
the noise (R scaled by the NIS per dof: covariance matching), repeated until each NIS per dof is
within MATCH_TOLERANCE of 1 (:func:`match_noise`); stage 2 profiles the IMU's noise
(PX4's EKF2_ACC_NOISE, body x-y and z apart, and EKF2_GYR_NOISE; ``LogTuneSettings.imu_noise``),
then each delay
(:func:`profile`: the measurement noise re-matched at each candidate value, a coarse grid, the
noise matched to convergence at the grid's best, then SciPy's bounded scalar search within a grid
step);
a profile that cannot say where its coordinate belongs (too few replays left for its grid, or a
delay whose objective is least at MAX_DELAY) keeps the coordinate as it was and says why
(``LogTuneResult.kept``); stage 3 re-matches the noise at the delays found; stage 4 is SciPy's Powell
(``scipy.optimize.minimize``, bounded, derivative-free: the objective is a replay) polishing every
noise multiplier (log10, -DECADES_DOWN..+DECADES_UP) and every sensor delay (0..MAX_DELAY) but the
kept ones together until
the budget of replays is spent or it converges. Each candidate replays each training log up to
its last training window's end and is scored on its training windows (:func:`split`: interleaved
4 s blocks, the first ``train_fraction`` of each tuned on, or the log's first share; a 20 s
stretch replays in under 1 s of CPU). The held-out judgement replays every log whole with the
start and the tuned values and judges its held-out windows, and any ``holdout_logs`` whole.
Ctrl-C keeps the best so far (its files are written, the held-out judgement skipped).
"""

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from ..config.errors import ConfigError
from ..flightlogs.px4_parameters import field_at, log_delays, with_field
from ..flightlogs.reader import FlightLog, Samples, read_flight_log
from ..flightlogs.replay import COMPARE_AFTER, replay
from ..flightlogs.settings import load_replay, resolve_log
from ..judging import innovations
from .search import Evaluation, SearchResult
from .session import CandidateProgress
from .settings import LOG_SPLITS

DECADES_DOWN = 3.0
"""Each noise is searched down to 1/1000 of its start: PX4's defaults lie that far above a
simulator's noise (the bundled SITL log's barometer NIS per dof is 5e-4 at PX4's 3.5 m; its GPS
horizontal velocity innovations, RMS 0.0026 m/s, are under 1 % of PX4's 0.3 m/s, so the former
floor at 1/100, 0.003 m/s, held their NIS per dof at 0.05-0.4, and the gyro's sat on it too)."""
DECADES_UP = 2.0
"""... and up to 100 times its start (a real flight's vibration and interference: the IMU noise
of a log without GPS ran to this bound already, where nothing observes it)."""
MAX_DELAY = 0.3
"""s: the largest sensor delay searched (PX4's EKF2_*_DELAY range ends at 300 ms)."""
DELAY_UNIT = 0.1
"""s per unit of the search's delay coordinate (so a delay and a decade of noise move alike)."""
NOISE_FIELDS = {
    "gps_pos_xy": ("gps_pos_std", (0, 1)),
    "gps_pos_z": ("gps_pos_std", (2,)),
    "gps_vel_xy": ("gps_vel_std", (0, 1)),
    "gps_vel_z": ("gps_vel_std", (2,)),
    "heading": ("mag_yaw_std", None),
    "field": ("mag_field.field_std", (0, 1, 2)),
    "baro": ("baro.height_std", None),
    "accel_xy": ("accel_std", (0, 1)),
    "accel_z": ("accel_std", (2,)),
    "gyro": ("gyro_std", (0, 1, 2)),
}
"""channel, or the IMU's accelerometer or gyro -> (the ESKF field below ``estimator`` that holds
its noise, the vector's indices or None for a scalar)."""
PROCESS_NOISE = ("accel_xy", "accel_z", "gyro")
"""The IMU's noise (PX4's EKF2_ACC_NOISE and EKF2_GYR_NOISE): no channel's NIS sets it, so it is
profiled like a delay (:func:`profile`). The accelerometer's body x-y and z axes have a multiplier
each: the horizontal and the vertical velocity's prediction errors differ (on the bundled SITL log
one multiplier for all three settled at 0.85 m/s² per sample, the vertical velocity, stopped at
the touchdown without the IMU sensing it, asking for a large one, and the horizontal velocity's
prior variance was then 16 times its innovations' variance: NIS per dof 0.05-0.08); PX4's one
EKF2_ACC_NOISE is written as their mean (``px4_parameters.our_value``)."""
DELAY_OF = {"gps": "gps_delay", "heading": "mag_delay", "field": "mag_delay", "baro": "baro_delay"}
"""A channel's sensor -> the ReplayConfig's delay field."""


@dataclass(frozen=True)
class Dimension:
    """One searched coordinate: a channel's noise (log10 multiplier of its start) or a delay field
    (x DELAY_UNIT s)."""

    name: str  # a channel ("gps_vel_xy") or a delay field ("gps_delay")
    start: float  # the start's noise (first component, its unit) or delay (s)

    @property
    def is_delay(self) -> bool:
        return self.name.endswith("_delay")

    @property
    def is_profiled(self) -> bool:
        """Set by a profile (:func:`profile`) rather than by covariance matching."""
        return self.is_delay or self.name in PROCESS_NOISE

    @property
    def bounds(self) -> tuple:
        return (0.0, MAX_DELAY / DELAY_UNIT) if self.is_delay else (-DECADES_DOWN, DECADES_UP)

    @property
    def grid_step(self) -> float:
        """The profile's coarse grid step in the coordinate (GRID_STEP s of delay, a decade of IMU
        noise)."""
        return GRID_STEP / DELAY_UNIT if self.is_delay else 1.0

    @property
    def tolerance(self) -> float:
        """The profile's bounded scalar search tolerance in the coordinate."""
        return DELAY_TOLERANCE / DELAY_UNIT if self.is_delay else 0.02

    def x0(self) -> float:
        return self.start / DELAY_UNIT if self.is_delay else 0.0

    def value(self, x) -> float:
        """The delay (s) or the noise (the start's first component scaled) at coordinate x."""
        return float(x) * DELAY_UNIT if self.is_delay else self.start * 10.0 ** float(x)


@dataclass
class LogTuneProblem:
    """What ``quad-drake tune LOG ...`` searches: the start, the logs, the coordinates, the settings."""

    config: object  # ReplayConfig as loaded (the start)
    logs: list  # [FlightLog] tuned on (their training part) and judged after it
    holdout_logs: list  # [FlightLog] judged whole, never tuned on
    space: list  # [Dimension]
    settings: object  # settings.LogTuneSettings


@dataclass(frozen=True)
class LogScore:
    """A candidate's loss (the objective searched, :func:`innovations.likelihood`), its consistency
    loss (:func:`innovations.loss`: 0 when consistent and white) and its channels' statistics per
    training log."""

    loss: float
    consistency: float
    statistics: tuple  # ({channel: ChannelStatistics} per training log)

    @property
    def feasible(self) -> bool:
        return math.isfinite(self.loss)


@dataclass
class LogTuneResult:
    """A finished (or interrupted) log tuning: the search, the tuned ReplayConfig, the delays'
    curves and the held-out judgement of the start and the tuned values."""

    problem: LogTuneProblem
    search: SearchResult
    tuned: object = None  # ReplayConfig at the best candidate
    search_time: float = 0.0  # s
    curves: dict = field(default_factory=dict)  # delay field -> (delays s, losses)
    before: list = field(default_factory=list)  # [(label, {channel: ChannelStatistics})] held out
    after: list = field(default_factory=list)
    interrupted: bool = False
    files: list = field(default_factory=list)
    kept: dict = field(default_factory=dict)  # profiled coordinate -> why its profile did not set it

    @property
    def best(self) -> Evaluation | None:
        """The tuned Evaluation: the least loss among those whose kept coordinates (``kept``) are at
        the start's values (a kept delay's grid points were replayed too, and the least of them
        would otherwise stand as the tuning); None before any. The one best of a log tuning: its
        progress, files and held-out judgement all use it (``search.best`` is the scenario
        tuner's, which keeps no coordinate)."""
        history = self.search.history
        kept = [i for i, d in enumerate(self.problem.space) if d.name in self.kept]
        eligible = [e for e in history if all(e.x[i] == history[0].x[i] for i in kept)]
        return min(eligible, key=lambda e: e.score.loss) if eligible else None


def is_log_name(name) -> bool:
    """A ``tune`` argument names flight logs (not a scenario): a .ulg or .csv path, a bundled
    log's name, or a folder (its logs, as ``quad-drake replay`` takes one)."""
    from ..flightlogs.settings import bundled_logs

    text = str(name)
    return text.lower().endswith((".ulg", ".csv")) or text in bundled_logs() or Path(text).is_dir()


def assumed_std(config) -> dict:
    """{component channel: (k,) the std the ReplayConfig's ESKF assumes} (``judging.innovations``)."""
    found = {}
    for channel in innovations.COMPONENT_CHANNELS:
        path, indices = NOISE_FIELDS[channel]
        value = field_at(config.estimator, path)
        found[channel] = [value[i] for i in indices] if indices is not None else [value]
    return found


def noise_of(config, channel) -> float:
    """The first component of a channel's noise in the ReplayConfig `config`."""
    path, indices = NOISE_FIELDS[channel]
    value = field_at(config.estimator, path)
    return float(value[indices[0]] if indices is not None else value)


def apply(config, space, x) -> object:
    """A copy of the ReplayConfig `config` at the search coordinates x (one per Dimension)."""
    for d, xi in zip(space, x, strict=True):
        if d.is_delay:
            config = dataclasses.replace(config, **{d.name: d.value(xi)})
            continue
        path, indices = NOISE_FIELDS[d.name]
        scale = 10.0 ** float(xi)
        start = field_at(config.estimator, path)
        if indices is None:
            value = start * scale
        else:
            value = list(start)
            for i in indices:
                value[i] = start[i] * scale
        config = dataclasses.replace(config, estimator=with_field(config.estimator, path, value))
    return config


def cut(log, end) -> FlightLog:
    """The FlightLog `log` up to `end` s (every stream's samples at or before it)."""

    def part(samples):
        if samples is None:
            return None
        keep = samples.times <= end
        return Samples(samples.times[keep], samples.values[keep])

    names = [f.name for f in dataclasses.fields(log) if isinstance(getattr(log, f.name), Samples)]
    return dataclasses.replace(log, **{name: part(getattr(log, name)) for name in names})


SPLIT_BLOCK = 4.0
"""s: the blocks of the interleaved split (``LogTuneSettings.split == "blocks"``): the first
``train_fraction`` of each block from COMPARE_AFTER on is tuned on, the rest held out, so that both
parts hold every phase of a flight longer than a block (the bundled SITL log sits on the ground
until 19 s and flies 19-26 s: the tail split's training part, 5-18.7 s, held no flight at all)."""


def split(log, settings) -> tuple[tuple, tuple]:
    """(training windows, held-out windows) of `log`, each ((start, end), ...) s from COMPARE_AFTER on
    (:func:`innovations.inside`): ``settings.split`` "tail" tunes on [COMPARE_AFTER, f T) and holds
    out [f T, T) (none where f T is within 1 s of the end); "blocks" cuts the log into SPLIT_BLOCK
    blocks and tunes on the first share f of each, holding out the rest (the last block's open to the
    end)."""
    f, duration = settings.train_fraction, log.duration
    if settings.split == "tail":
        end = f * duration
        return ((COMPARE_AFTER, end),), (((end, math.inf),) if end < duration - 1.0 else ())
    starts = np.arange(COMPARE_AFTER, duration, SPLIT_BLOCK)
    training = tuple((float(a), float(min(a + f * SPLIT_BLOCK, duration))) for a in starts)
    held = [
        (a + f * SPLIT_BLOCK, a + SPLIT_BLOCK if a + SPLIT_BLOCK < duration else math.inf)
        for a in starts
        if a + f * SPLIT_BLOCK < min(a + SPLIT_BLOCK, duration)
    ]
    return training, tuple((float(a), float(b)) for a, b in held)


def train_end(log, settings) -> float:
    """s: where a candidate's replay of `log` stops (its last training window's end)."""
    return split(log, settings)[0][-1][1]


def training_length(log, settings) -> float:
    """s of `log` tuned on (its training windows' total)."""
    return float(sum(end - start for start, end in split(log, settings)[0]))


def channel_statistics(config, log, windows) -> dict:
    """{channel: ChannelStatistics} of the ReplayConfig `config` replaying `log`, judged over
    windows (((start, end), ...) s)."""
    result = replay(dataclasses.replace(config, name=config.name or "tune"), log)
    return innovations.channel_statistics(result.vocabulary, result.logs, _judged(config, result), windows)


def _judged(config, result):
    """{channel: assumed std or None} of the channels a replay fused: GPS (unless fake; its height
    not where the barometer is the height reference, as PX4 then fuses none), the heading or the
    3-axis field, the barometer where fused."""
    judged = {}
    if result.log.gps is not None and not result.fake_position:
        unfused = ("gps_pos_z",) if result.aiding.baro_height_reference else ()
        judged |= {
            c: s for c, s in assumed_std(result.config).items() if c.startswith("gps_") and c not in unfused
        }
    if result.log.heading is not None:
        judged["heading"] = assumed_std(result.config)["heading"]
    elif result.log.mag_field is not None:
        judged["field"] = None
    if result.aiding.baro_fused:
        judged["baro"] = None
    return judged


def prepare(log_names, holdout_names, overrides, settings) -> LogTuneProblem:
    """LogTuneProblem of the logs (paths or bundled names) with ReplayConfig overrides (``--set``);
    ConfigError (one line) for a missing or unreadable log or a bad setting, before any search."""
    if settings.budget < 2:
        raise ConfigError(f"tune: --budget must be >= 2 for logs, got {settings.budget}")
    if not 0.0 < settings.train_fraction <= 1.0:
        raise ConfigError(f"tune: --train-fraction must be in (0, 1], got {settings.train_fraction}")
    paths = [resolve_log(n) for n in [*log_names, *holdout_names]]
    tuned_files = {p.resolve() for p in paths[: len(log_names)]}
    for name, path in zip(holdout_names, paths[len(log_names) :], strict=True):
        if path.resolve() in tuned_files:
            raise ConfigError(
                f"tune: {name} is both tuned on and held out; a held-out log must be one the search "
                "never replays"
            )
    config = load_replay(log_names[0], "{kind: eskf}", overrides)
    if not any(o.partition("=")[0].strip() == "gps_receiver_accuracy" for o in overrides):
        # the search is over the GPS noise the filter fuses: the receiver's reported accuracy,
        # which a replay puts above it by default (as PX4), would hide every value below it
        config = dataclasses.replace(config, gps_receiver_accuracy=False)
    logs = [read_flight_log(p) for p in paths]
    tuned_on, held = logs[: len(log_names)], logs[len(log_names) :]
    if settings.split not in LOG_SPLITS:
        raise ConfigError(f"tune: --split must be one of {', '.join(LOG_SPLITS)}, got {settings.split!r}")
    for log in tuned_on:
        if log.duration <= COMPARE_AFTER + 1.0 or training_length(log, settings) <= 1.0:
            raise ConfigError(
                f"tune: {log.source}: its training part from {COMPARE_AFTER:g} s on is under 1 s; "
                "use a longer log or a larger --train-fraction"
            )
    if settings.train_fraction == 1.0 and not held:
        raise ConfigError("tune: --train-fraction 1 leaves nothing held out; name --holdout-logs")
    first = replay(config, cut(tuned_on[0], train_end(tuned_on[0], settings)))
    channels = list(_judged(config, first))
    if not channels:
        raise ConfigError(f"tune: {tuned_on[0].source} fuses no aiding sensor; nothing to tune")
    space = [Dimension(c, noise_of(first.config, c)) for c in channels]
    if settings.imu_noise:
        space += [Dimension(name, noise_of(first.config, name)) for name in PROCESS_NOISE]
    if settings.delays:
        fields = sorted({DELAY_OF[c.split("_")[0] if c.startswith("gps") else c] for c in channels})
        space += [Dimension(f, getattr(first.config, f)) for f in fields]
    # the start: the config as loaded with the first log's sensor delays where left to the log
    # (``px4_parameters.log_delays``, as its replay took them), or with px4_parameters the log's
    # values written into it (and the option off, so that a candidate's values are not overwritten
    # by the log's again)
    if config.px4_parameters:
        start = dataclasses.replace(first.config, px4_parameters=False)
    else:
        start = log_delays(config, tuned_on[0].parameters)
    return LogTuneProblem(start, tuned_on, held, space, settings)


def _score(problem, config) -> LogScore:
    per_log = []
    for log in problem.logs:
        training, _ = split(log, problem.settings)
        per_log.append(channel_statistics(config, cut(log, train_end(log, problem.settings)), training))
    return LogScore(innovations.likelihood(per_log), innovations.loss(per_log), tuple(per_log))


class _BudgetSpent(Exception):
    """Raised inside the objective when the budget of replays is spent (ends the SciPy search)."""


def matched(problem, x, score) -> np.ndarray:
    """The coordinates x with each channel's noise scaled by sqrt of its NIS per dof (averaged over
    the training logs) in `score`, the score of x (covariance matching: R scaled so that the NIS
    per dof would be 1 were the prior covariance small beside it); the profiled coordinates (the
    delays, the IMU noise) unchanged."""
    x = np.array(x, dtype=float)
    for i, d in enumerate(problem.space):
        per_dof = [s[d.name].nis_per_dof for s in score.statistics if d.name in s]
        good = [v for v in per_dof if math.isfinite(v) and v > 0]
        if not d.is_profiled and good:
            x[i] = float(np.clip(x[i] + 0.5 * math.log10(np.mean(good)), *d.bounds))
    return x


MATCH_TOLERANCE = 0.1
"""Covariance matching stops when every channel's NIS per dof is within this of 1 (relative)."""
MATCH_ITERATIONS = 3
"""At most this many matching steps (each a replay) in :func:`match_noise`."""


def match_noise(problem, x, evaluate, score_of) -> np.ndarray:
    """x with its noise matched (:func:`matched`) until every channel's NIS per dof on every training
    log is within MATCH_TOLERANCE of 1, at most MATCH_ITERATIONS replays; x evaluated already."""
    for _ in range(MATCH_ITERATIONS):
        score = score_of(x)
        per_dof = [s.nis_per_dof for per_log in score.statistics for s in per_log.values()]
        if all(math.isfinite(v) and abs(v - 1.0) <= MATCH_TOLERANCE for v in per_dof):
            break
        x = matched(problem, x, score)
        evaluate(x)
    return x


GRID_STEP = 0.05
"""s between the coarse grid's delays (each refined by a bounded scalar search within ±a step)."""
DELAY_TOLERANCE = 0.004
"""s: the bounded scalar search's tolerance on a delay."""


def grid_of(d) -> np.ndarray:
    """The profile's coarse grid of the Dimension `d`: its bounds every ``grid_step``."""
    low, high = d.bounds
    return np.arange(low, high + 1e-9, d.grid_step)


def grid_cost(d) -> int:
    """Replays a profile of the Dimension `d` needs before its refinement: each grid point and its
    re-match, then the matching at the grid's best (:func:`profile`)."""
    return 2 * len(grid_of(d)) + MATCH_ITERATIONS


def profile(problem, x, evaluate, score_of, replays_left, kept) -> np.ndarray:
    """x with each profiled coordinate (the IMU noise, then each delay) in turn set where the
    profile objective is least: at each candidate value the measurement noise is re-matched to it
    (one :func:`matched` step) before the objective is taken, so that a delay is judged with the
    noise it implies. A coarse grid over the bounds (``Dimension.grid_step``; re-matched from x),
    the noise matched to convergence at the grid's best (:func:`match_noise`), then SciPy's bounded
    scalar search (``minimize_scalar``, to ``Dimension.tolerance``; re-matched from that noise)
    within a step of the grid's best.

    A coordinate keeps its value in x, the reason put in `kept` ({name: why}), where its profile
    cannot say where it belongs: when fewer replays are left (``replays_left()``) than its grid
    needs (:func:`grid_cost`; a grid cut by the budget would leave the coordinate at the last grid
    point tried, wherever the objective was still falling), and for a delay whose grid is least
    at MAX_DELAY, the end of PX4's range (the objective still falling there: no minimum inside
    the range, so no estimate of the delay; on x500v2_v6xrt the barometer's own innovations were
    flat in its delay and only the GPS height preferred ever larger ones). The start's delays are
    the log's own EKF2_*_DELAY."""
    x = np.array(x, dtype=float)
    profiled = [i for i, d in enumerate(problem.space) if d.is_profiled]
    order = sorted(profiled, key=lambda i: problem.space[i].is_delay)
    for i in order:
        d = problem.space[i]
        if replays_left() < grid_cost(d):
            kept[d.name] = f"not profiled: {replays_left()} replays left, its grid needs {grid_cost(d)}"
            continue
        tried = {}  # coordinate -> (objective, the re-matched coordinates)

        def at(value, base, i=i, tried=tried):
            trial = np.array(base)
            trial[i] = value
            evaluate(trial)
            rematched = matched(problem, trial, score_of(trial))
            tried[float(value)] = (evaluate(rematched), rematched)
            return tried[float(value)][0]

        low, high = d.bounds
        for value in grid_of(d):
            at(value, x)
        centre = min(tried, key=lambda k: tried[k][0])
        if d.is_delay and centre >= high - 1e-9:
            along = ", ".join(f"{tried[float(v)][0]:.4g}" for v in grid_of(d))
            kept[d.name] = (
                f"not identified: least at {1e3 * d.value(high):g} ms, the end of the range searched "
                f"(objective every {1e3 * GRID_STEP:g} ms from 0: {along})"
            )
            continue
        base = match_noise(problem, tried[centre][1], evaluate, score_of)
        minimize_scalar(
            lambda value, base=base: at(value, base),
            bounds=(max(low, centre - d.grid_step), min(high, centre + d.grid_step)),
            method="bounded",
            options={"xatol": d.tolerance},
        )
        x = min([(evaluate(base), base), *tried.values()], key=lambda pair: pair[0])[1]
    return x


def tune_logs(problem, progress=True) -> LogTuneResult:
    """LogTuneResult of the search, the delay curves and the held-out judgement (module docstring)."""
    s, space = problem.settings, problem.space
    result = LogTuneResult(problem, SearchResult())
    history = result.search.history
    bar = CandidateProgress("logs", s.budget, progress)
    cache = {}

    def key_of(x):
        return tuple(round(float(v), 12) for v in x)

    def evaluate(x, stage):
        key = key_of(x)
        if key in cache:
            return cache[key].score.loss if math.isfinite(cache[key].score.loss) else 1e9
        if len(history) >= s.budget:
            raise _BudgetSpent
        score = _score(problem, apply(problem.config, space, x))
        evaluation = Evaluation(len(history), stage, key, score)
        history.append(evaluation)
        cache[key] = evaluation
        bar.update(evaluation, result.best)  # the tuning's best, as the files will say
        return score.loss if math.isfinite(score.loss) else 1e9

    def score_of(x):
        return cache[key_of(x)].score

    start = time.perf_counter()
    x0 = np.array([d.x0() for d in space])
    try:
        evaluate(x0, 0)
        x1 = match_noise(problem, x0, lambda x: evaluate(x, 1), score_of)

        def replays_left():
            return s.budget - len(history)

        x2 = profile(problem, x1, lambda x: evaluate(x, 2), score_of, replays_left, result.kept)
        x3 = match_noise(problem, x2, lambda x: evaluate(x, 3), score_of)
        free = [i for i, d in enumerate(space) if d.name not in result.kept]  # the kept stay as they are

        def polished(x_free):
            x = x3.copy()
            x[free] = x_free
            return evaluate(x, 4)

        minimize(
            polished,
            x3[free],
            method="Powell",
            bounds=[space[i].bounds for i in free],
            options={"xtol": 1e-3, "ftol": 1e-4, "maxfev": s.budget},
        )
    except _BudgetSpent:
        pass
    except KeyboardInterrupt:
        result.interrupted = result.search.interrupted = True
    finally:
        bar.close()
    result.search_time = time.perf_counter() - start
    if result.best is None:
        return result
    result.tuned = apply(problem.config, space, result.best.x)
    if result.interrupted:
        return result
    try:
        result.curves = delay_curves(problem, result.best.x)
        result.before, result.after = holdout(problem, problem.config), holdout(problem, result.tuned)
    except KeyboardInterrupt:
        result.interrupted = True
        result.before, result.after = [], []
    return result


def delay_curves(problem, best_x) -> dict:
    """{delay field: (delays (m,) s, losses (m,))}: the training loss along each delay with every
    other coordinate at the best candidate's (the objective curves of the page)."""
    points = problem.settings.curve_points
    curves = {}
    for i, d in enumerate(problem.space):
        if not d.is_delay or points < 2:
            continue
        delays = np.linspace(0.0, MAX_DELAY, points)
        losses = []
        for delay in delays:
            x = np.array(best_x, dtype=float)
            x[i] = delay / DELAY_UNIT
            losses.append(_score(problem, apply(problem.config, problem.space, x)).loss)
        curves[d.name] = (delays, np.array(losses))
    return curves


def holdout(problem, config) -> list:
    """[(label, {channel: ChannelStatistics})]: each tuned log's held-out windows (:func:`split`),
    then each held-out log whole, replayed whole with the ReplayConfig `config`."""
    judged = []
    for log in problem.logs:
        _, held = split(log, problem.settings)
        if held:
            judged.append(
                (held_out_label(problem.settings, log, held), channel_statistics(config, log, held))
            )
    for log in problem.holdout_logs:
        judged.append(
            (
                f"{log_label(log)} (held-out log)",
                channel_statistics(config, log, ((COMPARE_AFTER, math.inf),)),
            )
        )
    return judged


def trained_part_text(settings) -> str:
    """The part of each log the split ``settings.split`` tunes on, in words ("the first 70 % of
    each log"; "the first 70 % of each 4 s block of each log"); its held-out part's label is
    :func:`held_out_label`, beside it."""
    share = f"the first {100 * settings.train_fraction:g} % of each"
    return f"{share} log" if settings.split == "tail" else f"{share} {SPLIT_BLOCK:g} s block of each log"


def held_out_label(settings, log, held) -> str:
    """The label of `log`'s held-out part under the split ``settings.split``, its windows `held`
    (:func:`split`): "NAME after 13.1 s"; "NAME held-out blocks"."""
    return (
        f"{log_label(log)} after {held[0][0]:.1f} s"
        if settings.split == "tail"
        else f"{log_label(log)} held-out blocks"
    )


def log_label(log) -> str:
    """A log's name in the tables: its file's stem."""
    return Path(log.source).stem


def verdict(result) -> tuple[bool, str]:
    """(passed, the line that explains the exit code): passed when every fused channel's NIS per
    dof lies inside its χ² band on every held-out part after tuning."""
    misses = [
        f"{label}: {c} {s.nis_per_dof:.3g} outside [{s.band[0]:.3g}, {s.band[1]:.3g}]"
        for label, stats in result.after
        for c, s in stats.items()
        if not s.in_band
    ]
    inside = sum(len(stats) for _, stats in result.after) - len(misses)
    if not misses:
        return (
            True,
            f"PASS: every fused channel's NIS per dof inside its band on the held-out part ({inside})",
        )
    return False, f"FAIL: {len(misses)} channel(s) outside their band on the held-out part: " + "; ".join(
        misses
    )
