"""Strict JSON for every file the project writes (run, batch and campaign summaries).

Browsers' ``JSON.parse`` rejects ``NaN`` and ``Infinity``, so a non-finite number is written
as ``null``; numpy scalars and arrays become plain Python values.
"""

import json
import math
from pathlib import Path

import numpy as np


def to_json_ready(value) -> object:
    """Nested dicts/lists/tuples of JSON values: numpy -> Python, non-finite floats -> None,
    paths -> str, dict keys -> str."""
    if isinstance(value, dict):
        return {str(k): to_json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json_ready(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_json_ready(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    return value


def dumps_json(obj) -> str:
    """Indented strict JSON text of `obj` (after :func:`to_json_ready`), newline-terminated."""
    return json.dumps(to_json_ready(obj), indent=2, allow_nan=False) + "\n"


def dump_json(path, obj) -> Path:
    """Write `obj` as strict JSON to `path`, whole or not at all (``outdir.write_text_atomic``);
    returns the path."""
    from .outdir import write_text_atomic

    return write_text_atomic(path, dumps_json(obj))
