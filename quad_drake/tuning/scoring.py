"""Glue: the one function that flies a candidate's campaign, and the runner it flies on.

Every campaign of ``quad-drake tune`` (each candidate on the training seeds, the before/after
comparison on the held-out seeds) goes through :func:`fly_campaign`, so the runner is chosen
in one place (:func:`campaign_runner`), and so is the choice of the fleet runner: a scenario
that fleet mode flies (``quad_drake.fleet``) is flown as fleet batches, the others one Diagram
per run.
"""

import math

from ..campaigns import InProcessRunner, ProcessPoolRunner, run_campaign
from ..fleet.simulation import unsupported_reason


def campaign_runner(scenario, jobs):
    """The runner of the tuning campaigns: in this process for one job, else a process pool."""
    return InProcessRunner() if jobs == 1 else ProcessPoolRunner(jobs)


def fly_campaign(scenario, first_seed, runs, runner, progress=False):
    """CampaignResult of `runs` runs of `scenario` with seeds first_seed.. on `runner`.

    The same seeds for every candidate (common random numbers): the loss is a deterministic
    function of the parameters, and differences between candidates are not seed noise.
    """
    return run_campaign(
        scenario,
        runs,
        runner=runner,
        seed=first_seed,
        progress=progress,
        fleet_batch=fleet_batch(scenario, runs, runner),
    )


def fleet_batch(scenario, runs, runner):
    """Runs per fleet batch for a campaign of `runs` on `runner` (one batch per worker), or None
    when fleet mode cannot fly `scenario` (then each run is its own Diagram)."""
    if unsupported_reason(scenario) is not None:
        return None
    return math.ceil(runs / getattr(runner, "jobs", 1))
