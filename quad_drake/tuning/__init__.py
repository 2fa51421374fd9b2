"""``quad-drake tune``: an estimator's noise parameters found by evidence.

- :mod:`.space` (pure): which config fields are searched, as log10 multipliers of their start;
- :mod:`.objective` (pure): the loss of a candidate from its campaign's statistics;
- :mod:`.search`: CMA-ES over the multipliers, deterministic for a seed and a budget;
- :mod:`.scoring`: the one function that flies a candidate's campaign (and its runner);
- :mod:`.session`: checks, search, held-out before/after; :mod:`.output`: the files.
"""

from .objective import OBJECTIVES, Score, score
from .session import TuneResult, TuneSettings, prepare, tune, verdict
from .space import DEFAULT_KEYS, Parameter, apply, search_space

__all__ = [
    "DEFAULT_KEYS",
    "OBJECTIVES",
    "Parameter",
    "Score",
    "TuneResult",
    "TuneSettings",
    "apply",
    "prepare",
    "score",
    "search_space",
    "tune",
    "verdict",
]
