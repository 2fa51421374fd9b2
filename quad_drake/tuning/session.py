"""``tune``: search an estimator's noise parameters on training seeds, judge on held-out seeds.

:func:`prepare` checks everything (keys, counts, seeds, objective) before any run flies;
:func:`tune` runs the search (CMA-ES, :mod:`.search`), each candidate scored by one campaign
on the training seeds (:func:`.scoring.score_candidates`: a generation's candidates at once,
one per worker of the session's runner), then flies the start and the best
candidate on the held-out seeds, and writes the outputs (:mod:`.output`). Ctrl-C keeps the
best so far: its tuned.yaml, the history and the plot are written, the held-out comparison is
skipped, and the result says it was interrupted.
"""

import math
import shlex
import sys
import time
from dataclasses import dataclass, field
from typing import Optional

from tqdm import tqdm

from ..config.errors import ConfigError
from ..config.validation import check_seed_range
from ..judging.verdicts import check_criteria
from ..models.accuracy_bound import accuracy_bound
from ..running.simulation import available_signals
from . import output
from .objective import pass_rate, score
from .scoring import CandidateTask, campaign_runner, fly_campaign, score_candidates
from .search import search
from .settings import OBJECTIVES, TuneSettings
from .space import SEARCH_DECADES, apply, overrides, search_space


@dataclass
class TuneProblem:
    """What ``quad-drake tune`` searches: the starting scenario, the parameters and the settings."""

    scenario: object  # ScenarioConfig as given (the start)
    space: list  # [space.Parameter]
    settings: TuneSettings
    run_command: Optional[str] = None  # flies the start's one run alone (campaign.one_run_command)


@dataclass
class TuneResult:
    """A finished (or interrupted) tuning: the search, the tuned scenario and its held-out check."""

    problem: TuneProblem
    search: object  # search.SearchResult
    tuned: object  # ScenarioConfig at the best candidate
    search_time: float  # s
    before: object = None  # CampaignResult on the held-out seeds (None: skipped or interrupted)
    after: object = None
    holdout_time: float = math.nan  # s
    interrupted: bool = False
    files: list = field(default_factory=list)


def _check_count(value, option):
    if value < 1:
        raise ConfigError(f"tune: {option} must be >= 1, got {value}")


def prepare(scenario, keys, settings, run_command=None) -> TuneProblem:
    """TuneProblem; ConfigError (one line) for any bad input, before any run flies. run_command:
    the command that flies one run of `scenario` alone (``campaigns.campaign.one_run_command``),
    for the "reproduce with" hint of a failing run (a candidate's gets its values as ``--set``)."""
    if settings.objective not in OBJECTIVES:
        raise ConfigError(
            f"tune: --objective must be one of {', '.join(OBJECTIVES)}, got {settings.objective!r}"
        )
    _check_count(settings.budget, "--budget")
    _check_count(settings.train_runs, "--seeds")
    _check_count(settings.holdout_runs, "--holdout")
    _check_count(settings.jobs, "--jobs")
    check_seed_range(settings.train_seed, settings.train_runs, "tune: --seed")
    check_seed_range(settings.holdout_seed, settings.holdout_runs, "tune: --holdout-seed")
    train = range(settings.train_seed, settings.train_seed + settings.train_runs)
    held = range(settings.holdout_seed, settings.holdout_seed + settings.holdout_runs)
    if settings.holdout and set(train) & set(held):
        raise ConfigError(
            f"tune: the held-out seeds {held.start}..{held.stop - 1} overlap the training seeds "
            f"{train.start}..{train.stop - 1}; move --holdout-seed or --seed"
        )
    space = search_space(scenario, keys)
    check_criteria(scenario, available_signals(scenario))
    if settings.objective != "consistency":
        try:
            bounded = [accuracy_bound(scenario.vehicles[i]) for p in space for i, _ in p.targets]
        except ValueError as e:
            raise ConfigError(
                f"tune: --objective {settings.objective} needs an accuracy bound ({e})"
            ) from None
        if not any(bounded):
            raise ConfigError(f"tune: --objective {settings.objective} needs an accuracy bound (no GPS)")
    return TuneProblem(scenario, space, settings, run_command)


class CandidateProgress:
    """One tick per candidate: a tqdm bar on a terminal, else one plain line per candidate."""

    def __init__(self, name, total, enabled, stream=None):
        self.stream = stream or sys.stderr
        self.name, self.total, self.start = name, total, time.perf_counter()
        terminal = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.bar = (
            tqdm(total=total, desc=f"tune {name}", unit="candidate", file=self.stream) if terminal else None
        )
        self.lines = enabled and not terminal

    def update(self, evaluation, best) -> None:
        text = f"loss {evaluation.score.loss:.4g}, best {best.score.loss:.4g}"
        if self.bar is not None:
            self.bar.set_postfix_str(text, refresh=False)
            self.bar.update(1)
        elif self.lines:
            elapsed = time.perf_counter() - self.start
            self.stream.write(
                f"tune {self.name}: candidate {evaluation.index} ({evaluation.index + 1}/{self.total}; "
                f"0 is the start), {text}, {elapsed:.0f} s\n"
            )
            self.stream.flush()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _with_sets(run_command, texts):
    """`run_command` with ``--set`` texts appended (None stays None: the campaign's default)."""
    if run_command is None:
        return None
    return run_command + "".join(f" --set {shlex.quote(text)}" for text in texts)


def tune(problem, out_dir, progress=True) -> TuneResult:
    """TuneResult; writes the outputs into out_dir (:func:`.output.write`)."""
    s, scenario, space = problem.settings, problem.scenario, problem.space
    with campaign_runner(scenario, s.jobs) as runner:

        def evaluate(xs):
            tasks = [
                CandidateTask(
                    apply(scenario, space, x),
                    s.train_seed,
                    s.train_runs,
                    s.objective,
                    s.holdout_runs,
                    _with_sets(problem.run_command, overrides(space, x)),
                )
                for x in xs
            ]
            return score_candidates(tasks, runner)

        bar = CandidateProgress(scenario.name, s.budget, progress)
        start = time.perf_counter()
        try:
            found = search(evaluate, len(space), s.budget, SEARCH_DECADES, s.search_seed, bar.update)
        finally:
            bar.close()
        result = TuneResult(problem, found, None, time.perf_counter() - start, interrupted=found.interrupted)
        if found.best is not None:
            result.tuned = output.tuned_scenario(apply(scenario, space, found.best.x))
        result.files = output.write_search(result, out_dir)
        if result.interrupted or not s.holdout or found.best is None:
            return result
        start = time.perf_counter()
        try:
            result.before = fly_campaign(
                scenario, s.holdout_seed, s.holdout_runs, runner, progress, problem.run_command
            )
            tuned = _with_sets(problem.run_command, overrides(space, found.best.x))
            result.after = fly_campaign(result.tuned, s.holdout_seed, s.holdout_runs, runner, progress, tuned)
        except KeyboardInterrupt:
            result.interrupted = True
            result.before = result.after = None
            return result
    result.holdout_time = time.perf_counter() - start
    result.files += output.write_holdout(result, out_dir)
    return result


def verdict(result) -> tuple[bool, str]:
    """(passed, the line that explains the exit code) of a TuneResult with held-out campaigns:
    passed when the tuned scenario passes every criterion in every held-out run and its
    held-out loss is not above the start's."""
    objective = result.problem.settings.objective
    rate = pass_rate(result.after.criteria)
    runs = result.after.runs
    before = score(result.before, objective, result.before.runs).loss
    after = score(result.after, objective, runs).loss
    checks = [
        (rate == 1.0, f"tuned: every criterion passed in {round(rate * runs)} of {runs} held-out runs"),
        (after <= before, f"held-out loss {after:.4g} (start {before:.4g})"),
    ]
    if all(ok for ok, _ in checks):
        return True, "PASS: " + "; ".join(text for _, text in checks)
    return False, "FAIL: " + "; ".join(text for ok, text in checks if not ok)
