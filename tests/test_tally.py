"""The campaign's consistency tally (``campaigns.tally``) against the computation it replaces:
every run's series kept and stacked (np.vstack, :func:`stack_by_stamp`), np.mean over
the realisations. Same rows to 1e-12 whatever the order the records arrive in and however they
are split into merged partial tallies; the tally does not grow with the runs; a campaign keeps
slim records (no per-sample arrays)."""

import dataclasses
import itertools
import warnings

import numpy as np
import pytest

from quad_drake.campaigns import CampaignResult, InProcessRunner, Runner, RunRecord, run_campaign
from quad_drake.campaigns.output import rows
from quad_drake.campaigns.records import campaign_vocabulary, slim
from quad_drake.campaigns.tally import ConsistencyTally, fold_records
from quad_drake.config.schema import (
    GpsParams,
    ImuParams,
    MagParams,
    ScenarioConfig,
    SensorsConfig,
    VehicleConfig,
)
from quad_drake.judging import consistency as cons
from quad_drake.running import catalog

RTOL = 1e-12


def stack_by_stamp(series):
    """(stamps, (m, k) values) of m (stamps, values) pairs at the stamps all share: how the NIS
    series were stacked before the tally (stamps compare exactly: nominal times)."""
    common = series[0][0]
    for stamps, _ in series[1:]:
        common = np.intersect1d(common, stamps)
    return common, np.vstack([np.asarray(values)[np.isin(stamps, common)] for stamps, values in series])


def test_stack_by_stamp_keeps_common_stamps_in_order():
    stamps, values = stack_by_stamp(
        [
            (np.array([0.1, 0.2, 0.3]), np.array([1.0, 2.0, 3.0])),
            (np.array([0.2, 0.3, 0.4]), np.array([20.0, 30.0, 40.0])),
        ]
    )
    np.testing.assert_array_equal(stamps, [0.2, 0.3])
    np.testing.assert_array_equal(values, [[2.0, 3.0], [20.0, 30.0]])


def stacked(records):
    """{statistic: (stamps, mean, realisations)} as CampaignResult computed them before the tally:
    records by index, all series stacked, np.mean over the realisations."""
    records = sorted(records, key=lambda r: r.index)
    first, result = records[0], {}
    if first.nees:
        series = np.vstack([r.nees[v] for r in records for v in r.nees])
        means = [float(np.mean(row)) for row in series]
        result["NEES"] = (np.asarray(first.times), series.mean(axis=0), series.shape[0], means)
    for sensor in cons.NIS_DOF:
        series = [r.nis[key] for r in records for key in r.nis if key[1] == sensor]
        if series:
            stamps, values = stack_by_stamp(series)
            means = [float(np.mean(v)) for _, v in series]
            result[f"NIS {sensor}"] = (stamps, values.mean(axis=0), values.shape[0], means)
    return result


def expected_rows(scenario, records):
    """The consistency rows of the stacked series: the average per dof with its t interval over the
    realisations' time means against the tolerance, and the chi^2 95 % band share."""
    dofs = {"NEES": campaign_vocabulary(scenario).nees_dof}
    dofs.update((f"NIS {sensor}", dof) for sensor, dof in cons.NIS_DOF.items())
    rows = []
    for name, (times, mean, count, run_means) in stacked(records).items():
        band = cons.chi2_band(dofs[name], count)
        in_band = cons.in_band_fraction(mean, band)
        per_dof, low, high = cons.per_dof_interval(run_means, dofs[name])
        rows.append(
            {
                "statistic": name,
                "dof": dofs[name],
                "realisations": count,
                "per_dof": per_dof,
                "per_dof_ci95": [low, high],
                "tolerance": [1 / cons.COVARIANCE_TOLERANCE, cons.COVARIANCE_TOLERANCE],
                "band": list(band),
                "time_mean": float(np.mean(mean)),
                "in_band": in_band,
                "below": float(np.mean(mean < band[0])),
                "above": float(np.mean(mean > band[1])),
                "passed": cons.within_tolerance((low, high)),
                "times": times,
                "mean": mean,
            }
        )
    return rows


def assert_same_rows(actual, expected):
    """Equal rows: the series and time means to RTOL (NaN where NaN), everything else exactly."""
    assert [row["statistic"] for row in actual] == [row["statistic"] for row in expected]
    for a, e in zip(actual, expected, strict=True):
        assert a.keys() == e.keys()
        where = e["statistic"]
        np.testing.assert_array_equal(a["times"], e["times"], err_msg=where)
        np.testing.assert_allclose(a["mean"], e["mean"], rtol=RTOL, atol=0, equal_nan=True, err_msg=where)
        np.testing.assert_allclose(a["time_mean"], e["time_mean"], rtol=RTOL, atol=0, equal_nan=True)
        rest = [key for key in e if key not in ("times", "mean", "time_mean")]
        assert {key: a[key] for key in rest} == {key: e[key] for key in rest}, where


def tally_of(records):
    """The records folded one after the other, in the order given."""
    tally = ConsistencyTally()
    for record in records:
        tally += ConsistencyTally.of(record)
    return tally


# ----- synthetic records ------------------------------------------------------------------------


SAMPLES = 40
TIMES = 0.005 * np.arange(1, SAMPLES + 1)
GPS_STAMPS = 0.004 + 0.1 * np.arange(12)
MAG_STAMPS = 0.008 + 0.01 * np.arange(20)


@pytest.fixture(scope="module")
def scenario():
    sensors = SensorsConfig(imu=ImuParams(), mag=MagParams(), gps=GpsParams())
    vehicles = [VehicleConfig(name=name, sensors=sensors) for name in ("A", "B")]
    return ScenarioConfig(name="t", end_time=0.2, seed=100, vehicles=vehicles)


def synthetic_records(count, rng):
    """`count` records of two vehicles: random NEES (one NaN sample), GPS NIS of both with one of
    the first three stamps missing (at random), magnetometer NIS of A only (one NaN value)."""
    records = []
    for i in range(count):
        nees = {v: rng.chisquare(7, SAMPLES) for v in ("A", "B")}
        nis = {}
        for v in ("A", "B"):
            kept = np.delete(np.arange(GPS_STAMPS.size), rng.integers(0, 3))  # one of the first 3 missing
            nis[(v, "gps")] = (GPS_STAMPS[kept], rng.chisquare(6, kept.size))
        nis[("A", "mag")] = (MAG_STAMPS, rng.chisquare(1, MAG_STAMPS.size))
        if i == 2:
            nees["B"][17] = np.nan
            nis[("A", "mag")][1][5] = np.nan
        records.append(RunRecord(i, 100 + i, True, [], {}, nees, {}, nis, 0.1, times=TIMES))
    return records


def campaign_of(scenario, records, tally):
    return CampaignResult(scenario, [slim(r) for r in records], tally, 1.0, "in-process")


def test_the_synthetic_records_exercise_every_rule():
    records = synthetic_records(6, np.random.default_rng(1))
    rows = stacked(records)
    assert rows["NEES"][2] == 12 and rows["NIS gps"][2] == 12 and rows["NIS mag"][2] == 6
    assert 0 < rows["NIS gps"][0].size < GPS_STAMPS.size  # the intersection drops stamps
    assert np.isnan(rows["NEES"][1][17]) and np.isnan(rows["NIS mag"][1][5])
    assert np.isfinite(np.delete(rows["NEES"][1], 17)).all()


def test_the_tally_gives_the_rows_of_the_stacked_series_whatever_the_order(scenario):
    rng = np.random.default_rng(2)
    records = synthetic_records(6, rng)
    expected = expected_rows(scenario, records)
    for order in itertools.islice(itertools.permutations(records), 0, None, 97):
        assert_same_rows(campaign_of(scenario, records, tally_of(order)).consistency, expected)


def test_merged_partial_tallies_give_the_same_rows(scenario):
    rng = np.random.default_rng(3)
    records = synthetic_records(9, rng)
    expected = expected_rows(scenario, records)
    for _ in range(10):
        shuffled = [records[i] for i in rng.permutation(len(records))]
        cuts = [0, *np.sort(rng.choice(np.arange(1, len(records)), 3, replace=False)), len(records)]
        parts = [tally_of(shuffled[a:b]) for a, b in itertools.pairwise(cuts)]
        merged = ConsistencyTally()
        for j in rng.permutation(len(parts)):
            merged = parts[j] + merged if j % 2 else merged + parts[j]
        assert_same_rows(campaign_of(scenario, records, merged).consistency, expected)


def test_the_tally_does_not_grow_with_the_runs():
    rng = np.random.default_rng(4)
    few, many = tally_of(synthetic_records(2, rng)), tally_of(synthetic_records(200, rng))
    assert many.sums["NEES"].count == 400

    def nbytes(tally):
        return sum(s.stamps.nbytes + s.total.nbytes for s in tally.sums.values())

    assert nbytes(many) <= nbytes(few) <= 8 * 2 * (SAMPLES + GPS_STAMPS.size + MAG_STAMPS.size)


def test_no_realisation_is_the_zero_of_the_sum(scenario):
    records = synthetic_records(3, np.random.default_rng(5))
    tally = tally_of(records)
    assert (ConsistencyTally() + tally).sums == tally.sums
    empty = CampaignResult(scenario, [], ConsistencyTally(), 0.0, "in-process")
    assert empty.consistency == [] and empty.passed


# ----- an actual campaign -------------------------------------------------------------------------


class Recording(InProcessRunner):
    """In this process, keeping each record as the worker sent it (with its series)."""

    def __init__(self):
        self.sent = {}

    def map(self, fn, tasks):
        for index, record in super().map(fn, tasks):
            self.sent[record.index] = record
            yield index, record


class Replay(Runner):
    """Gives back records already flown, in the order given (as a pool might), flying nothing."""

    name = "in-process"

    def __init__(self, records):
        self.records = records

    def map(self, fn, tasks):
        for record in self.records:
            yield record.index, record


@pytest.fixture(scope="module")
def flown():
    """(scenario, campaign, the records its workers sent) of 3 short runs of 11_gps_update."""
    scenario = catalog.load("11_gps_update", None, ["end_time=2"])
    runner = Recording()
    campaign = run_campaign(scenario, 3, runner=runner, seed=1, progress=False)
    return scenario, campaign, [runner.sent[i] for i in range(3)]


def arrays_in(value):
    """Every numpy array inside a (nested) record, dict, list or tuple."""
    if isinstance(value, np.ndarray):
        yield value
    elif dataclasses.is_dataclass(value):
        for f in dataclasses.fields(value):
            yield from arrays_in(getattr(value, f.name))
    elif isinstance(value, dict):
        for item in value.values():
            yield from arrays_in(item)
    elif isinstance(value, (list, tuple)):
        for item in value:
            yield from arrays_in(item)


def test_a_campaign_gives_the_rows_of_its_runs_stacked_series(flown):
    scenario, campaign, sent = flown
    assert [row["statistic"] for row in campaign.consistency] == ["NEES", "NIS gps", "NIS mag"]
    assert_same_rows(campaign.consistency, expected_rows(scenario, sent))
    replayed = run_campaign(scenario, 3, runner=Replay(sent[::-1]), seed=1, progress=False)
    assert_same_rows(replayed.consistency, expected_rows(scenario, sent))
    assert rows(replayed) == rows(campaign)


def test_a_campaign_keeps_slim_records(flown):
    scenario, campaign, sent = flown
    assert sent[0].nees["Quad"].shape == (400,) and sent[0].times.shape == (400,)
    for kept, full in zip(campaign.records, sent, strict=True):
        assert (kept.nees, kept.nis, kept.times) == ({}, {}, None)
        assert kept.nees_mean == {"Quad": float(np.mean(full.nees["Quad"]))}
        assert kept.nis_mean == {key: float(np.mean(values)) for key, (_, values) in full.nis.items()}
        assert set(kept.nis_mean) == {("Quad", "gps"), ("Quad", "mag")}
        # the only arrays left: the per-state e^2/P time means
        assert [a.shape for a in arrays_in(kept)] == [(len(campaign.state_names),)]
        np.testing.assert_array_equal(kept.nse["Quad"], full.nse["Quad"])
        for f in dataclasses.fields(full):
            if f.name not in ("nees", "nis", "times", "nse", "nees_mean", "nis_mean"):
                assert getattr(kept, f.name) == getattr(full, f.name), f.name


def test_a_series_without_samples_slims_to_nan_without_a_warning():
    """A flight too short for a sensor's first fresh update (`quad-drake warmup` flies 0.3 s) has
    an empty NIS series: its mean is NaN, and numpy's "Mean of empty slice" is not printed."""
    record = RunRecord(
        0, 100, True, [], {}, {"A": np.array([])}, {}, {("A", "baro"): (np.array([]),) * 2}, 0.1
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        kept = slim(record)
    assert np.isnan(kept.nees_mean["A"]) and np.isnan(kept.nis_mean[("A", "baro")])


def test_folded_batches_give_the_rows_and_the_slim_records(scenario):
    """What a fleet worker sends (fold_records of its batch) merges into the campaign's rows."""
    rng = np.random.default_rng(6)
    records = synthetic_records(7, rng)
    parts = [fold_records(records[:3]), fold_records(records[3:])]
    merged = parts[1].tally + parts[0].tally
    sent = parts[0].records + parts[1].records
    assert [r.index for r in sent] == list(range(7))
    for record, full in zip(sent, records, strict=True):
        np.testing.assert_equal(dataclasses.asdict(record), dataclasses.asdict(slim(full)))  # NaN == NaN
    assert_same_rows(campaign_of(scenario, records, merged).consistency, expected_rows(scenario, records))
