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


LOG_SPLITS = ("blocks", "tail")
"""How ``tune LOG`` splits a log into its training and held-out parts (``tuning.logs.split``):
interleaved blocks (each block's first share tuned on), or the log's first share and its tail."""


@dataclass(frozen=True)
class LogTuneSettings:
    """What ``quad-drake tune LOG ...`` was asked for."""

    budget: int = 200  # replays of the search (candidates), the start included
    train_fraction: float = 0.6  # share tuned on: of each split block, or of the log ("tail")
    split: str = "blocks"  # one of LOG_SPLITS (``tuning.logs.split``)
    delays: bool = True  # search the sensor delays too
    imu_noise: bool = True  # search the IMU's accelerometer and gyro noise too
    curve_points: int = 13  # points of each delay's objective curve (0: none)
