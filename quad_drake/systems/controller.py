"""Drake glue for the cascade controller (SPEC §5): :class:`CascadeController` of n vehicles, which
runs ``control.cascade.cascade_step`` as its compiled form (``kernels.flight.cascade_steps``)."""

import numpy as np
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import (
    CONTROLLER_OFFSET,
    GRAVITY,
    NUM_MOTORS,
    ONBOARD_PERIOD,
    REFERENCE_SIZE,
    STATE_SIZE,
)
from quad_drake.kernels import flight as kernels
from quad_drake.models.fidelity import PHYSICAL
from quad_drake.systems._io import discrete_group, row_reader


class CascadeController(LeafSystem):
    """The FCND cascade controller of n vehicles (default 1), ticking at ONBOARD_PERIOD (offset
    CONTROLLER_OFFSET). Every port carries the n per-vehicle vectors below concatenated
    vehicle-major (size n k, vehicle j at [j k, (j + 1) k)).

    Inputs:
      state (13): p_NB (m, NED), q_NB (wxyz), v_NB (m/s, NED), w_NB_B (rad/s, FRD),
        true or estimated (the controller does not know which).
      reference (10): p (m), v (m/s), a feed-forward (m/s^2), yaw (rad).
    Output:
      motor_thrusts (4, N): motors 0..3 = FL, FR, RL, RR; unclamped commands, a state
        output port (no direct feedthrough); mass g / 4 each before the first tick.
    Discrete state: the altitude-error integrals (n, m s) and the last motor commands (4 n, N).
    ``params`` (ControllerParams) are shared by the n vehicles; ``fidelity``
    (:class:`~quad_drake.models.fidelity.Fidelity`) picks the lateral acceleration limit (horizontal
    norm, or the reference's 3-D norm).
    """

    def __init__(self, params, fidelity=PHYSICAL, n=1) -> None:
        super().__init__()
        self._n = n
        self._frozen_params, self._frozen_fidelity = kernels.frozen(params), kernels.frozen(fidelity)
        self._read_state = row_reader(self.DeclareVectorInputPort("state", n * STATE_SIZE), n)
        self._read_reference = row_reader(self.DeclareVectorInputPort("reference", n * REFERENCE_SIZE), n)
        self._integral = discrete_group(self, n)
        hover = params.mass * GRAVITY / NUM_MOTORS
        self._thrusts = discrete_group(self, np.full(n * NUM_MOTORS, hover), "motor_thrusts")
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, CONTROLLER_OFFSET, self._update)

    def integral_index(self) -> int:
        """Discrete-state group index of the altitude-error integrals (n, m s)."""
        return self._integral

    def _update(self, context, discrete_state):
        kernels.cascade_steps(
            self._read_state(context),
            self._read_reference(context),
            discrete_state.get_mutable_value(self._integral),
            ONBOARD_PERIOD,
            self._frozen_params,
            self._frozen_fidelity,
            discrete_state.get_mutable_value(self._thrusts).reshape(self._n, NUM_MOTORS),
        )
