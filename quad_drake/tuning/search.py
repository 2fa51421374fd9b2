"""The search of ``quad-drake tune``: CMA-ES (the ``cma`` package) over log10 multipliers.

Why CMA-ES: the loss is a black box (a Monte Carlo campaign per candidate) with step-like parts
(shares of samples inside a band), so gradients are unavailable and finite differences would
see the steps; CMA-ES uses only the ranking of the losses (the infeasibility penalty's size does
not distort it), adapts the search's scale and correlations (noise fields trade off against each
other: Q against R), handles box bounds, and its ask/tell interface lets the caller spend an
exact budget of campaigns, show progress per candidate and stop on Ctrl-C with the best so far.
Its sampler draws from a ``numpy.random.Generator`` seeded here (no global RNG), so for the
same seed, budget and (deterministic) loss the whole search is identical.

Evaluation 0 is the start (x = 0, the scenario as given); CMA-ES then proposes the others, a
generation at a time, which the caller may score at once (one candidate per worker).
"""

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import cma
import numpy as np

SIGMA0 = 0.25
"""Initial CMA-ES step in log10 multipliers (a factor of 1.8 per parameter), an eighth of the
box's width (2 decades). Measured on 60-candidate tunes of 11 (README "Tuning"): 0.5, a quarter
of the box as the ``cma`` documentation advises when the optimum may lie anywhere, moves ~10
parameters at once so far that almost every candidate breaks a training run, and it never
improved on a start near the optimum (the ESKF assuming the reference's 1 m / 3 m GPS noise);
0.15 found that one but escaped a failing start (the EKF7 at the reference's values) worse than
0.25, which did both."""


@dataclass(frozen=True)
class Evaluation:
    """One scored candidate."""

    index: int  # 0 = the start
    generation: int  # 0 = the start; CMA-ES generations from 1
    x: tuple  # log10 multipliers, one per parameter
    score: object  # objective.Score (anything with .loss)


@dataclass
class SearchResult:
    """What a noise-parameter search evaluated, in order, and whether Ctrl-C cut it short."""

    history: list = field(default_factory=list)  # [Evaluation] in order
    interrupted: bool = False  # Ctrl-C stopped the search; history holds what finished

    @property
    def best(self) -> Evaluation | None:
        """The Evaluation with the lowest loss (the earliest among equals), or None."""
        return min(self.history, key=lambda e: e.score.loss) if self.history else None


def population_size(dims, budget) -> int:
    """CMA-ES's default population 4 + 3 ln(n), made smaller on a small budget so that at
    least three generations fit (never below 4, or the budget left after the start)."""
    default = 4 + int(3 * math.log(dims))
    return max(2, min(default, max(4, (budget - 1) // 3), budget - 1))


def one_at_a_time(evaluate) -> Callable[[list], Iterator[tuple[int, object]]]:
    """A generation evaluator for :func:`search` from a function of one x: the candidates
    scored in order, ``evaluate(x) -> Score`` each."""
    return lambda xs: ((i, evaluate(x)) for i, x in enumerate(xs))


def search(evaluate, dims, budget, bound, seed=0, on_evaluation=None) -> SearchResult:
    """SearchResult of up to `budget` candidates x in [-bound, bound]^dims.

    evaluate(xs) scores a generation: an iterator of (index into xs, Score), in any order (the
    candidates of a generation may be scored at once; :func:`one_at_a_time` wraps a function
    of one x). The history is in candidate order whatever the completion order, so the search
    is the same for any evaluator that gives the same scores. on_evaluation(Evaluation, best
    Evaluation) is called as each score arrives (progress). A KeyboardInterrupt (Ctrl-C) ends
    the search early: ``interrupted``, and the history holds every candidate scored by then.
    """
    if budget < 1 or dims < 1:
        raise ValueError(f"search: budget and dims must be >= 1, got {budget}, {dims}")
    result = SearchResult()

    def generation_losses(xs, generation):
        first, scored = len(result.history), {}
        try:
            for i, score in evaluate(xs):
                scored[i] = Evaluation(first + i, generation, tuple(float(v) for v in xs[i]), score)
                if on_evaluation is not None:
                    best = min([*result.history, *scored.values()], key=lambda e: (e.score.loss, e.index))
                    on_evaluation(scored[i], best)
        finally:  # interrupted or not: keep what finished, in candidate order
            result.history.extend(scored[i] for i in sorted(scored))
        return [scored[i].score.loss for i in range(len(xs))]

    try:
        generation_losses([np.zeros(dims)], 0)
        if budget == 1:
            return result
        rng = np.random.default_rng(seed)
        options = {
            "bounds": [-bound, bound],
            "popsize": population_size(dims, budget),
            "seed": math.nan,  # "do nothing" to numpy's global RNG; the sampler below is seeded
            "randn": lambda lam, n: rng.standard_normal((lam, n)),
            "verbose": -9,
            "verb_log": 0,
            "verb_disp": 0,
        }
        strategy = cma.CMAEvolutionStrategy(np.zeros(dims), SIGMA0, options)
        generation = 0
        while len(result.history) < budget:
            generation += 1
            candidates = strategy.ask()
            room = budget - len(result.history)
            losses = generation_losses(candidates[:room], generation)
            if len(losses) < len(candidates):
                break  # the budget ended inside a generation: nothing left to tell
            strategy.tell(candidates, losses)
    except KeyboardInterrupt:
        result.interrupted = True
    return result
