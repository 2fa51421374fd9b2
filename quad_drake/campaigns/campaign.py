"""``run_campaign``: N seeded runs of a scenario on a runner, as a CampaignResult.

Run i uses seed S + i, so any run reproduces alone with ``quad-drake run NAME --seed S+i``.
Records are ordered by run index, so the statistics do not depend on the runner.
"""

import dataclasses
import sys
import time

from tqdm import tqdm

from ..config import ConfigError
from ..simulation import available_signals
from ..verdicts import check_criteria
from .records import RunTask, simulate_run
from .runners import InProcessRunner, TaskFailed
from .statistics import CampaignResult


class CampaignInterrupted(KeyboardInterrupt):
    """Ctrl-C during a campaign; ``campaign`` holds the runs that finished (``partial``)."""

    def __init__(self, campaign):
        super().__init__(f"interrupted after {campaign.runs} of {campaign.planned} runs")
        self.campaign = campaign


class Progress:
    """Progress of a campaign on `stream` (stderr): a tqdm bar on a terminal; elsewhere (a
    log file, a pipe) a plain line about every tenth of the runs, so no ``\\r`` lands in logs."""

    def __init__(self, label, total, enabled=True, stream=None):
        self.label, self.total = label, total
        self.stream = stream or sys.stderr
        self.done = self.failed = 0
        self.start = time.perf_counter()
        terminal = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.bar = tqdm(total=total, desc=label, unit="run", file=self.stream) if terminal else None
        self.lines = enabled and not terminal
        self.every = max(1, total // 10)

    def update(self, record):
        self.done += 1
        self.failed += not record.passed
        if self.bar is not None:
            self.bar.set_postfix(failed=self.failed, refresh=False)
            self.bar.update(1)
        elif self.lines and (self.done % self.every == 0 or self.done == self.total):
            elapsed = time.perf_counter() - self.start
            eta = elapsed / self.done * (self.total - self.done)
            self.stream.write(
                f"{self.label}: {self.done}/{self.total} runs, {self.failed} failed, "
                f"{elapsed:.0f} s, ETA {eta:.0f} s\n"
            )
            self.stream.flush()

    def close(self):
        if self.bar is not None:
            self.bar.close()


def run_campaign(scenario, runs, runner=None, seed=None, progress=True):
    """CampaignResult of `runs` runs of a ScenarioConfig, run i with seed (seed or scenario.seed) + i.

    runner: a :class:`~quad_drake.campaigns.runners.Runner` (default: in this process).
    progress: report progress on stderr. A failing run raises RuntimeError naming its seed;
    Ctrl-C raises :class:`CampaignInterrupted` holding the finished runs.
    """
    runner = runner or InProcessRunner()
    if runs < 1:
        raise ConfigError(f"montecarlo: --runs must be >= 1, got {runs}")
    first = scenario.seed if seed is None else seed
    if first < 0:
        raise ConfigError(f"montecarlo: --seed must be >= 0, got {first}")
    check_criteria(scenario, available_signals(scenario))
    scenario = dataclasses.replace(scenario, seed=first)
    tasks = [RunTask(scenario, i, first + i) for i in range(runs)]
    records = {}
    bar = Progress(scenario.name, runs, progress)
    start = time.perf_counter()

    def campaign():
        ordered = [records[i] for i in sorted(records)]
        return CampaignResult(scenario, ordered, time.perf_counter() - start, runner.name, planned=runs)

    try:
        for index, record in runner.map(simulate_run, tasks):
            records[index] = record
            bar.update(record)
    except TaskFailed as e:
        seed_i = tasks[e.index].seed
        raise RuntimeError(
            f"run {e.index} (seed {seed_i}) failed: {e.error!r}; reproduce with "
            f"quad-drake run {scenario.name} --seed {seed_i}"
        ) from e.error
    except KeyboardInterrupt:
        raise CampaignInterrupted(campaign()) from None
    finally:
        bar.close()
    return campaign()
