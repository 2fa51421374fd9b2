"""``run_campaign``: N seeded runs of a scenario on a runner, as a CampaignResult.

Run i uses seed S + i, so any run reproduces alone with ``quad-drake run NAME --seed S+i``.
Records are ordered by run index, so the statistics do not depend on the runner. Each record
is folded into the campaign's :class:`~.tally.ConsistencyTally` as it arrives and kept slim
(``records.slim``: no per-sample series), so the memory does not grow with the series.
With ``fleet_batch`` the runner's tasks are fleet batches (``quad_drake.campaigns.fleet.runner``):
B runs flown at once, each sending back its B slim records and their tally
(``tally.FoldedRecords``).
"""

import dataclasses
import shlex
import sys
import time
from collections.abc import Callable

from tqdm import tqdm

from ..config.errors import ConfigError
from ..config.schema import ScenarioConfig
from ..config.validation import check_scenario, check_seed_range
from ..estimation.custom import EstimatorRaised
from ..judging.verdicts import check_criteria
from ..running.limits import check_memory, check_run
from ..running.simulation import available_signals
from .records import RunTask, simulate_run
from .runners import InProcessRunner, TaskFailed
from .statistics import CampaignResult
from .tally import ConsistencyTally, fold_records


class CampaignInterrupted(KeyboardInterrupt):
    """Ctrl-C during a campaign; ``campaign`` holds the runs that finished (``partial``)."""

    def __init__(self, campaign):
        super().__init__(f"interrupted after {campaign.runs} of {campaign.planned} runs")
        self.campaign = campaign


LINE_INTERVAL_S = 30.0
"""s; in a log, a campaign's progress line comes at least this often while runs finish."""


class Progress:
    """Progress of a campaign on `stream` (stderr): a tqdm bar on a terminal; elsewhere (a
    log file, a pipe) a line when it starts (``start_line``), then a plain line about every tenth
    of the runs and at least every LINE_INTERVAL_S while runs finish, so no ``\\r`` lands in logs."""

    def __init__(self, label, total, enabled=True, stream=None):
        self.label, self.total = label, total
        self.stream = stream or sys.stderr
        self.done = self.failed = 0
        self.start = self.last_line = time.perf_counter()
        terminal = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.bar = tqdm(total=total, desc=label, unit="run", file=self.stream) if terminal else None
        self.lines = enabled and not terminal
        self.every = max(1, total // 10)

    def start_line(self, how) -> None:
        """In a log: one line saying the campaign started and how it flies (`how`, e.g. the runner)."""
        if self.lines:
            self.stream.write(f"{self.label}: 0/{self.total} runs, started ({how})\n")
            self.stream.flush()

    def update(self, records) -> None:
        """Count finished runs (a task's RunRecords: one run, or a fleet batch at once); at most
        one line per call."""
        before = self.done
        self.done += len(records)
        self.failed += sum(not record.passed for record in records)
        now = time.perf_counter()
        if self.bar is not None:
            self.bar.set_postfix(failed=self.failed, refresh=False)
            self.bar.update(len(records))
        elif self.lines and (
            self.done // self.every > before // self.every
            or self.done == self.total
            or now - self.last_line >= LINE_INTERVAL_S
        ):
            self.last_line = now
            elapsed = now - self.start
            eta = elapsed / self.done * (self.total - self.done)
            self.stream.write(
                f"{self.label}: {self.done}/{self.total} runs, {self.failed} failed, "
                f"{elapsed:.0f} s, ETA {eta:.0f} s\n"
            )
            self.stream.flush()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class _OrderedTally:
    """The campaign's ConsistencyTally, its tasks' tallies added in task order whatever order
    they finish in (a tally that arrives early waits), so its sums, and the statistics, are
    the same on every runner to the last bit."""

    def __init__(self):
        self._sum, self._waiting, self._next = ConsistencyTally(), {}, 0

    def add(self, index, tally):
        self._waiting[index] = tally
        while self._next in self._waiting:
            self._sum += self._waiting.pop(self._next)
            self._next += 1

    def total(self):
        """The tally of every task added so far (the waiting ones in task order)."""
        total = self._sum
        for index in sorted(self._waiting):
            total += self._waiting[index]
        return total


def _fleet_tasks(scenario, runs, first, batch):
    """(tasks, worker function, runner label) of a fleet campaign of `batch` runs per task."""
    from .fleet.runner import batches, simulate_batch

    if batch < 1:
        raise ConfigError(f"montecarlo: --batch must be >= 1, got {batch}")
    tasks = batches(scenario, runs, first, batch)
    return tasks, simulate_batch, f"fleet (batch {max(len(task.seeds) for task in tasks)})"


def _check_fleet_memory(scenario, batch, at_once):
    """ConfigError when `at_once` fleet batches of `batch` runs would not fit in memory
    (``fleet.summaries.summary_bytes``, ``limits.check_memory``)."""
    from .fleet.summaries import summary_bytes

    check_memory(
        summary_bytes(scenario, batch) * at_once,
        f"montecarlo --fleet: {at_once} batch(es) of {batch} runs of {scenario.end_time:g} s",
        "give a smaller --batch or a shorter end_time",
    )


def plan_campaign(
    scenario, runs, runner, seed=None, fleet_batch=None
) -> tuple[ScenarioConfig, list, Callable, str | None]:
    """(scenario with the first seed, tasks, worker function, fleet label or None) of a campaign,
    after every check it needs before anything flies (ConfigError, one line): the run count and
    seeds, the scenario as a loaded file is checked (``config.check_scenario``), its criteria's
    signals, and the memory of the runs (or fleet batches) the runner holds at once
    (``limits``). :func:`run_campaign` calls it; a front end may call it first to check."""
    if runs < 1:
        raise ConfigError(f"montecarlo: --runs must be >= 1, got {runs}")
    first = scenario.seed if seed is None else seed
    check_seed_range(first, runs, "montecarlo: --seed")
    check_scenario(scenario)
    check_criteria(scenario, available_signals(scenario))
    scenario = dataclasses.replace(scenario, seed=first)
    at_once = min(runs, getattr(runner, "jobs", 1))  # runs (or fleet batches) held at once
    if fleet_batch is None:
        check_run(scenario, at_once)
        return scenario, [RunTask(scenario, i, first + i) for i in range(runs)], simulate_run, None
    check_run(scenario)
    tasks, worker, label = _fleet_tasks(scenario, runs, first, fleet_batch)
    _check_fleet_memory(scenario, max(len(task.seeds) for task in tasks), min(len(tasks), at_once))
    return scenario, tasks, worker, label


def one_run_command(name, overrides=()) -> str:
    """The ``quad-drake run`` command line that flies one run of a campaign alone but for its
    ``--seed``: scenario `name` (a bundled name or a path) with every ``--set`` of `overrides`."""
    sets = "".join(f" --set {shlex.quote(text)}" for text in overrides)
    return f"quad-drake run {shlex.quote(str(name))}{sets}"


def run_campaign(
    scenario, runs, runner=None, seed=None, progress=True, fleet_batch=None, run_command=None
) -> CampaignResult:
    """CampaignResult of `runs` runs of a ScenarioConfig, run i with seed (seed or scenario.seed) + i.

    runner: a :class:`~quad_drake.campaigns.runners.Runner` (default: in this process; a
    ``ProcessPoolRunner`` in a script needs the ``if __name__ == "__main__":`` guard around the
    campaign, as every ``spawn`` process pool does: its workers import the script).
    fleet_batch: None (one Drake Diagram per run) or B, the runs each fleet task flies at once.
    progress: report progress on stderr. run_command: the command that flies one run alone but
    for its ``--seed`` (:func:`one_run_command`; default the scenario's name, no ``--set``): the
    failures' "reproduce with" hint and the report's. A failing run raises
    RuntimeError naming its seed and how to reproduce it; a custom estimator that raised,
    ``custom.EstimatorRaised`` with the same; Ctrl-C raises :class:`CampaignInterrupted`
    holding the finished runs.
    """
    run_command = run_command or one_run_command(scenario.name)
    runner = runner or InProcessRunner()
    scenario, tasks, worker, label = plan_campaign(scenario, runs, runner, seed, fleet_batch)
    runner_name = runner.name if label is None else f"{label} on {runner.name}"
    records, tally = {}, _OrderedTally()
    bar = Progress(scenario.name, runs, progress)
    bar.start_line(runner_name)
    start = time.perf_counter()

    def campaign():
        ordered = [records[i] for i in sorted(records)]
        return CampaignResult(
            scenario,
            ordered,
            tally.total(),
            time.perf_counter() - start,
            runner_name,
            planned=runs,
            run_command=run_command,
        )

    try:
        for index, result in runner.map(worker, tasks):
            folded = result if label else fold_records([result])
            tally.add(index, folded.tally)
            for record in folded.records:
                records[record.index] = record
            bar.update(folded.records)
    except TaskFailed as e:
        task = tasks[e.index]
        seeds = [task.seed] if label is None else task.seeds
        if isinstance(e.error, EstimatorRaised):  # the user's code: its own line and frames
            failed = seeds[e.error.copy] if label else seeds[0]
            reproduce = f"{run_command} --seed {failed}"
            raise e.error.with_context(f"seed {failed}; reproduce with {reproduce}") from None
        span = f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {seeds[0]}..{seeds[-1]}"
        raise RuntimeError(
            f"{'run' if label is None else 'fleet batch'} {e.index} ({span}) failed: {e.error!r}; "
            f"reproduce with {run_command} --seed {seeds[0]}"
        ) from e.error
    except KeyboardInterrupt:
        raise CampaignInterrupted(campaign()) from None
    finally:
        bar.close()
    return campaign()
