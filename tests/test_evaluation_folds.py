"""The analyzers' folds (``evaluation.*Fold``) fed N runs chunk by chunk give each run the
verdict of its own whole log (``evaluation.window_threshold`` …), whatever the split: what a
fleet batch's streamed verdicts rest on."""

import numpy as np
import pytest

from quad_drake.config.schema import CriterionConfig
from quad_drake.judging.evaluation import (
    CriterionStream,
    bound_threshold,
    evaluate_criterion,
    floor_touchdowns,
    recovery_threshold,
    room_contacts,
    sigma_threshold,
    state_finite,
    tracking_bound,
    window_threshold,
)

RUNS, SAMPLES = 7, 400
TIMES = 0.005 * np.arange(1, SAMPLES + 1)


def _splits(rng):
    """Chunk boundaries: one whole chunk, single samples at the start, empty chunks, random cuts."""
    cuts = np.sort(rng.choice(np.arange(1, SAMPLES), size=9, replace=False))
    return [[0, SAMPLES], [0, 1, 2, 3, SAMPLES], [0, 0, 5, 5, SAMPLES], [0, *cuts.tolist(), SAMPLES]]


def _signals(rng):
    """{name: (values (n, N), fresh (n, N))}: noisy errors with violations, NaNs, sparse fresh
    masks (one run never fresh), cumulative counters and flags."""
    noise = rng.normal(0.0, 1.0, (SAMPLES, RUNS))
    noise[:, 5:][rng.random((SAMPLES, RUNS - 5)) < 0.01] = np.nan  # diverged samples in runs 5, 6
    noise[:, 0] *= 0.2  # a run that mostly stays within
    fresh = rng.random((SAMPLES, RUNS)) < 0.2
    fresh[:, 1] = False
    every = np.ones((SAMPLES, RUNS), dtype=bool)
    steps = np.cumsum(rng.random((SAMPLES, RUNS)) < 0.003, axis=0).astype(float)
    steps[:, 2] = 0.0
    contact = (rng.random((SAMPLES, RUNS)) < 0.05).astype(float)
    contact[:, 3] = 1.0  # never took off
    finite = (rng.random((SAMPLES, RUNS)) > 0.002).astype(float)
    return {
        "Quad.E": (noise, every),
        "Quad.GPS": (noise, fresh),
        "Quad.Ref": (rng.normal(0.0, 0.1, (SAMPLES, RUNS)), every),
        "Quad.S": (np.abs(rng.normal(1.0, 0.3, (SAMPLES, RUNS))), every),
        "Quad.FloorTouchdowns": (steps, every),
        "Quad.FloorContact": (contact, every),
        "Quad.WallContactSteps": (steps, every),
        "Quad.StateFinite": (finite, every),
        "Quad.PosFollowErr": (np.abs(noise) * 3.0, every),
    }


CRITERIA = [
    CriterionConfig(kind="window", signal="Quad.E", threshold=1.5, window=0.2),
    CriterionConfig(kind="window", signal="Quad.GPS", threshold=1.0, window=0.1),
    CriterionConfig(kind="sigma", signal="Quad.GPS", sigma=0.9, min_percent=50, max_percent=80, window=0.3),
    CriterionConfig(
        kind="sigma",
        signal="Quad.E",
        ref_signal="Quad.Ref",
        sigma_signal="Quad.S",
        min_percent=55,
        max_percent=90,
        window=0.5,
    ),
    CriterionConfig(kind="bound", signal="Quad.E", threshold=2.5, start=0.3, end=1.1),
    CriterionConfig(kind="recovery", signal="Quad.E", threshold=2.0, start=0.5, window=0.6),
    CriterionConfig(kind="recovery", signal="Quad.E", threshold=3.5, start=1.0, window=0.2),
    CriterionConfig(kind="floor", signal="Quad.FloorTouchdowns"),
    CriterionConfig(kind="floor", signal="Quad.FloorTouchdowns", landing_time=1.2),
    CriterionConfig(kind="room", signal="Quad.WallContactSteps"),
    CriterionConfig(kind="finite", signal="Quad.StateFinite"),
    CriterionConfig(kind="tracking", signal="Quad.PosFollowErr", threshold=8.0),
]


def _same(a, b):
    """Verdicts equal field by field (NaN equal to NaN), plot series aside."""
    np.testing.assert_equal(a.to_dict(), b.to_dict())


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("criterion", CRITERIA, ids=lambda c: f"{c.kind}-{c.signal}")
def test_chunked_folds_of_n_runs_give_each_run_its_whole_log_verdict(criterion, seed):
    rng = np.random.default_rng(seed)
    signals = _signals(rng)
    for split in _splits(rng):
        stream = CriterionStream(criterion, RUNS, ["Quad"])
        for a, b in zip(split[:-1], split[1:], strict=True):
            stream.update(TIMES[a:b], lambda name, a=a, b=b: tuple(x[a:b] for x in signals[name]))
        for j in range(RUNS):
            whole = evaluate_criterion(
                criterion, TIMES, lambda name, j=j: tuple(x[:, j] for x in signals[name])
            )
            _same(stream.result(j), whole)


def test_the_whole_log_functions_are_the_one_run_folds():
    """The public one-run functions and evaluate_criterion agree (the same fold behind both)."""
    rng = np.random.default_rng(5)
    signals = _signals(rng)
    col = {name: (v[:, 4], f[:, 4]) for name, (v, f) in signals.items()}

    def lookup(name):
        return col[name]

    e, fresh = col["Quad.GPS"]
    pairs = [
        (CRITERIA[1], window_threshold(TIMES, e, 1.0, 0.1, "Quad.GPS", fresh)),
        (CRITERIA[2], sigma_threshold(TIMES, e, fresh, 0.0, 0.9, 50, 80, 0.3, "Quad.GPS")),
        (CRITERIA[4], bound_threshold(TIMES, col["Quad.E"][0], 2.5, 0.3, 1.1, "Quad.E")),
        (CRITERIA[5], recovery_threshold(TIMES, col["Quad.E"][0], 2.0, 0.5, 0.6, "Quad.E")),
        (
            CRITERIA[7],
            floor_touchdowns(TIMES, col["Quad.FloorTouchdowns"][0], col["Quad.FloorContact"][0], "Quad"),
        ),
        (CRITERIA[9], room_contacts(TIMES, col["Quad.WallContactSteps"][0], "Quad")),
        (CRITERIA[10], state_finite(TIMES, col["Quad.StateFinite"][0], "Quad")),
        (CRITERIA[11], tracking_bound(TIMES, col["Quad.PosFollowErr"][0], 8.0, "Quad.PosFollowErr")),
    ]
    for criterion, direct in pairs:
        _same(evaluate_criterion(criterion, TIMES, lookup, ["Quad"]), direct)


def test_the_folds_see_both_verdicts():
    """The random signals give passing and failing runs of each kind (the comparison is not vacuous)."""
    rng = np.random.default_rng(0)
    signals = _signals(rng)
    for criterion in CRITERIA:
        verdicts = {
            evaluate_criterion(
                criterion, TIMES, lambda name, j=j: tuple(x[:, j] for x in signals[name])
            ).passed
            for j in range(RUNS)
        }
        assert verdicts == {True, False}, criterion


def test_a_fleet_sigma_fold_pools_its_vehicles_per_run():
    rng = np.random.default_rng(3)
    errors = {v: rng.normal(0.0, 1.0, (SAMPLES, RUNS)) for v in ("A", "B")}
    fresh = {v: rng.random((SAMPLES, RUNS)) < 0.3 for v in ("A", "B")}
    sigma = np.ones((SAMPLES, RUNS))
    criterion = CriterionConfig(
        kind="fleet_sigma", signal="Est.E.X", sigma_signal="Est.S.X", min_percent=60, max_percent=75
    )
    signals = {f"{v}.Est.E.X": (errors[v], fresh[v]) for v in errors}
    signals.update({f"{v}.Est.S.X": (sigma, fresh[v]) for v in errors})
    stream = CriterionStream(criterion, RUNS, ["A", "B"])
    for a, b in ((0, 150), (150, SAMPLES)):
        stream.update(TIMES[a:b], lambda name, a=a, b=b: tuple(x[a:b] for x in signals[name]))
    for j in range(RUNS):
        inside = sum(np.count_nonzero(np.abs(errors[v][fresh[v][:, j], j]) <= 1.0) for v in errors)
        total = sum(np.count_nonzero(fresh[v][:, j]) for v in errors)
        assert stream.result(j).percent == 100.0 * inside / total
        assert stream.result(j).samples == total
