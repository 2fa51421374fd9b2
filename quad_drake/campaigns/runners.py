"""Where a campaign's runs execute: one interface, several back ends.

A :class:`Runner` maps a picklable function over a list of tasks and yields
``(index, result)`` pairs as the tasks complete (in any order); the caller orders the
results by index, so nothing a campaign reports depends on the runner. A task that raises
ends the map with :class:`TaskFailed` naming its index; closing the iterator, or a
KeyboardInterrupt, cancels the tasks not yet started (a process pool also stops its workers:
the runs in flight are abandoned). ``name`` goes into summaries. A runner
is also a context manager: inside ``with runner:`` a process pool keeps its workers from one
map to the next (a tuning session's many small campaigns pay the workers' start-up once).

Drake's Python systems cannot run in parallel in one process, so the parallel runners use
processes (``spawn``) or Dask workers started with one thread each. A ``spawn`` worker imports
the script that started it, so a script that runs a campaign on a :class:`ProcessPoolRunner`
keeps the campaign under ``if __name__ == "__main__":`` (as every ``spawn`` process pool needs)::

    from quad_drake.running import catalog
    from quad_drake.campaigns import ProcessPoolRunner, run_campaign

    if __name__ == "__main__":
        campaign = run_campaign(catalog.load("11_gps_update"), 20, runner=ProcessPoolRunner(2))
        print(campaign.verdict())

Without it each worker stops with one line saying so, and the campaign raises
:class:`WorkersDied` saying the same (not ``BrokenProcessPool``).
"""

import multiprocessing
from abc import ABC, abstractmethod
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool

from ..config.errors import ConfigError


class TaskFailed(Exception):
    """Task `index` raised `error` (the exception's __cause__ as well)."""

    def __init__(self, index, error):
        super().__init__(f"task {index} failed: {error!r}")
        self.index, self.error = index, error


MAIN_GUARD_HINT = (
    'a script that runs a campaign on a ProcessPoolRunner needs `if __name__ == "__main__":` '
    "around it (each spawned worker imports the script)"
)


class WorkersDied(RuntimeError):
    """The process pool's workers died before finishing their runs: a script without the
    ``__main__`` guard (see the module docstring), or a worker killed (e.g. out of memory)."""


def _check_not_a_worker_importing_main():
    """SystemExit (one line) in a spawned worker that is importing its parent's script: that
    script started a process pool outside ``if __name__ == "__main__":``. (``_inheriting`` is
    the flag multiprocessing's own check reads, ``spawn._check_not_importing_main``.)"""
    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise SystemExit(f"quad-drake worker: {MAIN_GUARD_HINT}")


class Runner(ABC):
    """Runs ``fn(task)`` for every task; see the module docstring for the contract."""

    name = "runner"

    @abstractmethod
    def map(self, fn, tasks) -> Iterator[tuple[int, object]]:
        """Iterator of (index into tasks, fn(tasks[index])) in completion order."""

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        return False


class InProcessRunner(Runner):
    """One task after the other in this process (no start-up cost, easy to debug)."""

    name = "in-process"

    def map(self, fn, tasks) -> Iterator[tuple[int, object]]:
        for index, task in enumerate(tasks):
            try:
                result = fn(task)
            except Exception as e:
                raise TaskFailed(index, e) from e
            yield index, result


def _stop(executor):
    """Shut a ProcessPoolExecutor down now: its workers terminated, its pending tasks cancelled.

    ``shutdown(wait=False)`` alone returns, but the interpreter's exit still waits for the
    workers to fly the runs they hold, their queued one included (Ctrl-C on 11 took 9 s).
    Python 3.14 has ``terminate_workers``; before it the worker processes are the executor's
    ``_processes``.
    """
    terminate = getattr(executor, "terminate_workers", None)
    if terminate is not None:
        terminate()
        return
    for process in list((getattr(executor, "_processes", None) or {}).values()):
        process.terminate()
    executor.shutdown(wait=False, cancel_futures=True)


class ProcessPoolRunner(Runner):
    """`jobs` worker processes (``spawn``: a fresh interpreter each, one simulation at a time).

    Scripts that use it need the ``if __name__ == "__main__":`` guard (spawn re-imports them).
    """

    def __init__(self, jobs):
        if jobs < 1:
            raise ConfigError(f"montecarlo: --jobs must be >= 1, got {jobs}")
        self.jobs = int(jobs)
        self.name = f"process-pool x{self.jobs}"
        self._kept = None  # the executor kept inside ``with``

    def _executor(self, workers):
        _check_not_a_worker_importing_main()
        return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))

    def __enter__(self):
        self._kept = self._executor(self.jobs)
        return self

    def __exit__(self, *exc_info):
        kept, self._kept = self._kept, None
        if kept is not None and exc_info[0] is None:
            kept.shutdown(wait=True, cancel_futures=True)
        elif kept is not None:
            _stop(kept)
        return False

    def map(self, fn, tasks) -> Iterator[tuple[int, object]]:
        if not tasks:
            return
        executor = self._kept or self._executor(min(self.jobs, len(tasks)))
        finished = False
        futures = {}
        try:
            futures = {executor.submit(fn, task): index for index, task in enumerate(tasks)}
            for future in as_completed(futures):
                index = futures[future]
                try:
                    result = future.result()
                except BrokenProcessPool:  # a worker died (e.g. a script without a main guard)
                    raise WorkersDied(
                        f"the process pool's workers died before finishing their runs: {MAIN_GUARD_HINT}, "
                        "or a worker was killed (out of memory?)"
                    ) from None
                except Exception as e:
                    raise TaskFailed(index, e) from e
                yield index, result
            finished = True
        finally:  # interrupted or failed: do not wait for the runs in flight
            if not finished and executor is self._kept:
                self._kept = None  # a later map inside ``with`` starts fresh workers
            if finished and executor is not self._kept:
                executor.shutdown(wait=True)
            elif not finished:
                _stop(executor)


class DaskRunner(Runner):
    """The workers of a Dask cluster at `scheduler` (e.g. ``tcp://host:8786``; the ``cluster``
    extra). Start the workers with one thread each (``--nthreads 1``)."""

    def __init__(self, scheduler):
        try:
            import distributed  # noqa: F401 (checked before any run)
        except ImportError:
            raise ConfigError("--scheduler needs dask: pip install 'quad_drake[cluster]'") from None
        self.scheduler = scheduler
        self.name = f"dask {scheduler}"

    def map(self, fn, tasks) -> Iterator[tuple[int, object]]:
        from distributed import Client, as_completed

        try:
            client = Client(self.scheduler, set_as_default=False)
        except (OSError, ValueError, TypeError) as e:
            raise ConfigError(f"--scheduler {self.scheduler}: cannot connect ({e})") from None
        with client:
            futures = client.map(fn, tasks, pure=False)
            index_of = {future.key: index for index, future in enumerate(futures)}
            try:
                for future in as_completed(futures, loop=client.loop):
                    index = index_of[future.key]
                    try:
                        result = future.result()
                    except Exception as e:
                        raise TaskFailed(index, e) from e
                    yield index, result
            finally:
                client.cancel([f for f in futures if not f.done()])
