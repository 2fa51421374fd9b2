"""Batched kernel of the no-aiding failsafe: :func:`quad_drake.control.failsafe.failsafe_step`'s own
code compiled by numba and run per vehicle, reading and writing the supervisor's arrays in place
(``systems/failsafe.py``). ``tests/test_failsafe.py`` checks it against the scalar function to
1e-12. Pure: no pydrake."""

import collections
import dataclasses

from quad_drake.config.schema import FailsafeConfig
from quad_drake.control import failsafe
from quad_drake.kernels.jit import compiled, njit_cached

FailsafeTuple = collections.namedtuple("FailsafeTuple", [f.name for f in dataclasses.fields(FailsafeConfig)])

_step_compiled = compiled(failsafe.failsafe_step)


@njit_cached
def failsafe_steps(
    memory, t, dt, diagnostics, gps_columns, estimate, reference, params, command, status
) -> None:
    """:func:`~quad_drake.control.failsafe.failsafe_step` of N vehicles IN PLACE.

    memory (N, MEMORY_SIZE): replaced by the new memory; t, dt s (floats); diagnostics (N, k): the
    estimators' diagnostics, read in place at gps_columns (3 ints: the GPS stamp, gated and resets
    columns); estimate (N, 13); reference (N, 10); params: the ``kernels.flight.frozen``
    FailsafeConfig; command (N, 10) and status (N, STATUS_SIZE): written.
    """
    stamp_column, gated_column, resets_column = gps_columns
    config = FailsafeTuple(*params)
    for i in range(memory.shape[0]):
        m = (
            memory[i, 0], memory[i, 1], memory[i, 2], memory[i, 3],
            memory[i, 4], memory[i, 5], memory[i, 6], memory[i, 7],
        )  # fmt: skip
        x = (
            estimate[i, 0], estimate[i, 1], estimate[i, 2], estimate[i, 3], estimate[i, 4],
            estimate[i, 5], estimate[i, 6], estimate[i, 7], estimate[i, 8], estimate[i, 9],
        )  # fmt: skip
        ref = (
            reference[i, 0], reference[i, 1], reference[i, 2], reference[i, 3], reference[i, 4],
            reference[i, 5], reference[i, 6], reference[i, 7], reference[i, 8], reference[i, 9],
        )  # fmt: skip
        stamp, gated = diagnostics[i, stamp_column], diagnostics[i, gated_column]
        new, out, flags = _step_compiled(
            m, t, dt, stamp, gated, diagnostics[i, resets_column], x, ref, config
        )
        for k in range(8):
            memory[i, k] = new[k]
        for k in range(10):
            command[i, k] = out[k]
        status[i, 0], status[i, 1], status[i, 2] = flags
