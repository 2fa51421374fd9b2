"""``quad-drake tune``: an estimator's noise parameters found by evidence.

- :mod:`.space` (pure): which config fields are searched, as log10 multipliers of their start;
- :mod:`.objective` (pure): the loss of a candidate from its campaign's statistics;
- :mod:`.search`: CMA-ES over the multipliers, deterministic for a seed and a budget;
- :mod:`.scoring`: the one function that flies a candidate's campaign (and its runner);
- :mod:`.session`: checks, search, held-out before/after; :mod:`.output`: the files;
- :mod:`.settings` (pure): what ``tune`` can be asked for, and its defaults;
- :mod:`.logs`, :mod:`.log_output`: ``tune LOG ...``, the ESKF's noise and sensor delays from
  flight logs' own innovations (``judging.innovations``), no truth needed.
"""

import importlib

from .settings import OBJECTIVES, TuneSettings

_LAZY = {
    "Score": "objective",
    "score": "objective",
    "TuneResult": "session",
    "prepare": "session",
    "tune": "session",
    "verdict": "session",
    "Parameter": "space",
    "apply": "space",
    "search_space": "space",
}
"""Names imported from their module on first use: ``quad-drake`` reads :class:`TuneSettings`'
defaults for its parser, which must not import SciPy, CMA-ES and the campaigns for every command."""


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)


def __dir__():
    return sorted({*globals(), *_LAZY})


__all__ = [
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
