"""Pure: against which truth and reference the logged errors are taken (README "Fidelity").

Two definitions, one per mode (:class:`~quad_drake.models.fidelity.Fidelity`'s
``errors_at_onboard_tick``):

- **at the sample** (the physical default): at a 5 ms log sample t, ``Est.E.*`` is the
  estimate held at t (the one of the last 2 ms tick) minus the truth at t; ``PosFollowErr`` is
  |p_ref(t) - p(t)| and ``Ref.*`` the reference, both looked up at t. The error a user should
  trust: the estimate the controller flies on at t against where the vehicle is at t.
- **at the onboard tick** (``fidelity: reference``, the binary, SPEC §7 and §0.2): the binary
  computes its errors in ``UpdateTrueError`` and ``PosFollowErr`` right after each control
  tick, against that tick's truth, and logs ``Ref.*`` as that tick's trajectory point; its 5 ms
  grapher then samples what the last tick left (the tick 1 ms before samples at odd ms, 2 ms
  before those at even ms). A vehicle then also logs :data:`TICK_LOG_WIDTHS`: the true state
  and the reference held since its last onboard tick (``simulation.add_tick_holds``), and the
  errors are taken against them.

The truth signals themselves (``Pos.*``, ``Vel.*``, ``Roll`` ...) and the estimate (``Est.*``)
are the sample's in both definitions, as the binary's are.
"""

import numpy as np

TICK_STATE = "tick_state"
"""Log of the true state (13, the ``state`` layout) at the last onboard tick before each sample."""
TICK_REFERENCE = "tick_reference"
"""Log of the reference (10, the ``reference`` layout) of the last onboard tick before each sample."""
TICK_LOG_WIDTHS = {TICK_STATE: 13, TICK_REFERENCE: 10}
"""The logs a vehicle adds under ``errors_at_onboard_tick`` (name: width)."""


def error_truth(logs) -> np.ndarray:
    """The true state (n, 13) (or a fleet batch's (n, N, 13)) the logged estimate errors are taken
    against: the tick's (:data:`TICK_STATE`) when the logs have it, else the sample's ``state``."""
    return logs[TICK_STATE] if TICK_STATE in logs else logs["state"]


def error_reference(logs) -> np.ndarray:
    """The reference (n, 10) ``Ref.*`` and ``PosFollowErr`` are taken from: the tick's
    (:data:`TICK_REFERENCE`) when the logs have it, else the sample's ``reference``."""
    return logs[TICK_REFERENCE] if TICK_REFERENCE in logs else logs["reference"]
