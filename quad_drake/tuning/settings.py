"""Pure: what ``quad-drake tune`` can be asked for, light enough for the CLI's parser to read
its defaults without importing the search (SciPy, CMA-ES, the campaigns)."""

from dataclasses import dataclass

OBJECTIVES = ("consistency", "accuracy", "both")
"""The losses ``tune`` can minimise (``objective.score``)."""


@dataclass(frozen=True)
class TuneSettings:
    """What ``quad-drake tune`` was asked for (CLI defaults)."""

    objective: str = "both"  # one of OBJECTIVES
    budget: int = 20  # candidates scored, the start included
    train_seed: int = 1000  # first training seed; candidate campaigns use train_seed..+train_runs-1
    train_runs: int = 10
    holdout_seed: int = 0  # first held-out seed
    holdout_runs: int = 50
    jobs: int = 1
    search_seed: int = 0  # seeds CMA-ES's sampler
    holdout: bool = True  # fly the before/after comparison
