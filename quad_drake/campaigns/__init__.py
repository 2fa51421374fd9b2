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

from .campaign import CampaignInterrupted, plan_campaign, run_campaign
from .output import save, table, timing_line
from .records import RunRecord
from .runners import DaskRunner, InProcessRunner, ProcessPoolRunner, Runner, WorkersDied
from .statistics import CampaignResult

__all__ = [
    "CampaignInterrupted",
    "CampaignResult",
    "DaskRunner",
    "InProcessRunner",
    "ProcessPoolRunner",
    "plan_campaign",
    "RunRecord",
    "Runner",
    "run_campaign",
    "save",
    "table",
    "timing_line",
    "WorkersDied",
]
