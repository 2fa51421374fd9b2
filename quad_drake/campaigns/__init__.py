"""Monte Carlo campaigns: N seeded runs of a scenario on a runner, with statistics and output.

- :mod:`.runners`: where runs execute (in-process, process pool, Dask) behind one interface;
- :mod:`.records`: what a run sends back (:class:`RunRecord`);
- :mod:`.tally`: :class:`~.tally.ConsistencyTally`, the runs' NEES/NIS series summed as they
  arrive (memory independent of the run count; tallies add);
- :mod:`.campaign`: :func:`run_campaign`, progress, Ctrl-C keeping the finished runs;
- :mod:`.statistics`: :class:`CampaignResult` (pass rates with Clopper-Pearson intervals,
  distributions, NEES/NIS consistency, efficiency against the Kalman bound);
- :mod:`.output`, :mod:`.plots`, :mod:`.page`: table, CSV, JSON, NPZ, PNGs, HTML page.
"""

import importlib

_LAZY = {
    "CampaignInterrupted": "campaign",
    "plan_campaign": "campaign",
    "run_campaign": "campaign",
    "save": "output",
    "table": "output",
    "timing_line": "output",
    "RunRecord": "records",
    "DaskRunner": "runners",
    "InProcessRunner": "runners",
    "ProcessPoolRunner": "runners",
    "Runner": "runners",
    "WorkersDied": "runners",
    "CampaignResult": "statistics",
}
"""Names imported from their module on first use, so that the fleet (``campaigns.fleet``), which
imports what a run sends back (``records``, ``tally``), never loads the campaign that drives it."""


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)


def __dir__():
    return sorted({*globals(), *_LAZY})


__all__ = sorted(_LAZY)
