"""Glue: the one function that flies a candidate's campaign, and the runner it flies on.

Every campaign of ``quad-drake tune`` (each candidate on the training seeds, the before/after
comparison on the held-out seeds) goes through :func:`fly_campaign`, so the choice of the
runner is made in one place: every campaign is flown as fleet batches (``quad_drake.campaigns.fleet``).
The candidates of one CMA-ES generation are scored at once, one candidate per worker
(:func:`score_candidates`): a candidate's runs fly as one fleet batch in its worker, so a
worker's fixed cost per tick is shared by all of a candidate's runs, and the workers of the
session's runner (a ``with`` block) are started once.
"""

import math
from collections.abc import Iterator
from dataclasses import dataclass

from ..campaigns import InProcessRunner, ProcessPoolRunner, run_campaign
from ..campaigns.runners import TaskFailed
from ..campaigns.statistics import CampaignResult
from ..estimation.custom import EstimatorRaised
from .objective import Score, breakdown_score, score


def campaign_runner(scenario, jobs) -> InProcessRunner | ProcessPoolRunner:
    """The runner of the tuning campaigns: in this process for one job, else a process pool
    (use it as a context manager to keep its workers for the whole session)."""
    return InProcessRunner() if jobs == 1 else ProcessPoolRunner(jobs)


def fly_campaign(scenario, first_seed, runs, runner, progress=False, run_command=None) -> CampaignResult:
    """CampaignResult of `runs` runs of `scenario` with seeds first_seed.. on `runner`
    (run_command: the command that flies one run alone, ``campaigns.campaign.one_run_command``).

    The same seeds for every candidate (common random numbers): the loss is a deterministic
    function of the parameters, and differences between candidates are not seed noise.
    """
    return run_campaign(
        scenario,
        runs,
        runner=runner,
        seed=first_seed,
        progress=progress,
        fleet_batch=fleet_batch(runs, runner),
        run_command=run_command,
    )


def fleet_batch(runs, runner) -> int:
    """Runs per fleet batch for a campaign of `runs` on `runner` (one batch per worker)."""
    return math.ceil(runs / getattr(runner, "jobs", 1))


@dataclass(frozen=True)
class CandidateTask:
    """One candidate's campaign: `scenario` (the candidate's values applied) on the training
    seeds first_seed.., scored with `objective` against the χ² band of `target_runs` runs;
    `run_command` flies one of its runs alone (its values as ``--set``s), or None."""

    scenario: object
    first_seed: int
    runs: int
    objective: str
    target_runs: int
    run_command: object = None


def score_candidate(task) -> Score:
    """Worker entry point: the Score of a CandidateTask, its campaign flown in this process. A
    run that broke down numerically is the candidate's fault (:func:`.objective.breakdown_score`);
    any other failure is raised."""
    try:
        campaign = fly_campaign(
            task.scenario, task.first_seed, task.runs, InProcessRunner(), run_command=task.run_command
        )
    except RuntimeError as e:
        if isinstance(e.__cause__, ArithmeticError):
            return breakdown_score()
        raise
    return score(campaign, task.objective, task.target_runs)


def score_candidates(tasks, runner) -> Iterator[tuple[int, Score]]:
    """Iterator of (index into tasks, Score) of CandidateTasks on `runner`, one candidate per
    task, in completion order; a failed candidate raises RuntimeError naming its campaign (a
    custom estimator that raised: its ``custom.EstimatorRaised``)."""
    try:
        yield from runner.map(score_candidate, tasks)
    except TaskFailed as e:
        task = tasks[e.index]
        if isinstance(e.error, EstimatorRaised):  # the user's own code: its line and frames
            raise e.error.with_context("in a candidate of the tune") from None
        raise RuntimeError(
            f"a candidate's campaign failed ({task.scenario.name}, seeds {task.first_seed}.."
            f"{task.first_seed + task.runs - 1}): {e.error!r}"
        ) from e.error
