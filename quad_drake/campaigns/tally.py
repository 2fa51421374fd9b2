"""A campaign's consistency series folded as the runs arrive: memory independent of the run count.

The campaign criteria judge the mean over realisations ((run, vehicle) pairs) of the NEES at
each log sample and of each sensor's NIS at each update stamp (:mod:`quad_drake.judging.consistency`).
A :class:`ConsistencyTally` keeps, per statistic, the running sum of the realisations at each
stamp and their count, so a 10,000-run campaign holds one (n,) sum per statistic instead of
10,000 series. Tallies add: ``a + b`` is the tally of both sets of realisations (in any
order and split, up to float rounding), so a worker may send a whole batch's partial sums.

A statistic keeps the stamps every realisation had (as the stacked series of the past did):
stamps are nominal sample times computed the same way in every run and compare exactly. A
NaN value makes the sum, and so the mean, at its stamp NaN (as ``np.mean``).
"""

from dataclasses import dataclass, field

import numpy as np

from .records import slim

NEES = "NEES"
"""Name of the NEES statistic (its stamps are the log sample times)."""


def nis_statistic(sensor) -> str:
    """Name of a sensor's NIS statistic, e.g. ``NIS gps``."""
    return f"NIS {sensor}"


@dataclass(frozen=True)
class StampSum:
    """Sum over `count` realisations of a statistic at the stamps all of them had.

    Arrays are never modified in place (a sum may share them with a record or another sum).
    """

    stamps: np.ndarray  # (k,) s, increasing
    total: np.ndarray  # (k,) sum of the realisations' values at `stamps`
    count: int  # realisations summed

    def __add__(self, other):
        if np.array_equal(self.stamps, other.stamps):
            return StampSum(self.stamps, self.total + other.total, self.count + other.count)
        stamps, mine, theirs = np.intersect1d(
            self.stamps, other.stamps, assume_unique=True, return_indices=True
        )
        return StampSum(stamps, self.total[mine] + other.total[theirs], self.count + other.count)

    @property
    def mean(self) -> np.ndarray:
        """(k,) mean over the realisations at each stamp."""
        return self.total / self.count


@dataclass(frozen=True)
class ConsistencyTally:
    """Per statistic (:data:`NEES`, :func:`nis_statistic`) the :class:`StampSum` of its
    realisations; ``ConsistencyTally()`` holds none (the zero of ``+``)."""

    sums: dict = field(default_factory=dict)  # statistic name -> StampSum

    def __add__(self, other):
        sums = dict(self.sums)
        for name, stamp_sum in other.sums.items():
            sums[name] = sums[name] + stamp_sum if name in sums else stamp_sum
        return ConsistencyTally(sums)

    @classmethod
    def of(cls, record) -> "ConsistencyTally":
        """The tally of one RunRecord's series: its NEES per vehicle at ``record.times`` and
        its NIS per (vehicle, sensor) at the update stamps."""
        series = [(NEES, record.times, values) for values in record.nees.values()]
        series += [(nis_statistic(key[1]), stamps, values) for key, (stamps, values) in record.nis.items()]
        tally = cls()
        for name, stamps, values in series:
            one = StampSum(np.asarray(stamps, dtype=float), np.asarray(values, dtype=float), 1)
            tally = tally + cls({name: one})
        return tally


@dataclass(frozen=True)
class FoldedRecords:
    """What a worker sends for several runs: their slim records (``records.slim``) and the
    tally of their series, so the series never travel."""

    records: list  # slim RunRecords
    tally: ConsistencyTally


def fold_records(records) -> FoldedRecords:
    """FoldedRecords of full RunRecords."""
    tally = ConsistencyTally()
    for record in records:
        tally += ConsistencyTally.of(record)
    return FoldedRecords([slim(record) for record in records], tally)
