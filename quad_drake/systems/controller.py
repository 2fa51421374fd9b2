"""Drake glue for the cascade controller (SPEC §5): :class:`CascadeController`, which runs
``control.cascade.cascade_step`` as its compiled form for one vehicle (``fleet.kernels.cascade_steps``
with N = 1)."""

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
from quad_drake.fidelity import PHYSICAL
from quad_drake.fleet import kernels
from quad_drake.systems._io import row_reader


class CascadeController(LeafSystem):
    """The FCND cascade controller, ticking at ONBOARD_PERIOD (offset CONTROLLER_OFFSET).

    Inputs:
      state (13): p_NB (m, NED), q_NB (wxyz), v_NB (m/s, NED), w_NB_B (rad/s, FRD),
        true or estimated (the controller does not know which).
      reference (10): p (m), v (m/s), a feed-forward (m/s^2), yaw (rad).
    Output:
      motor_thrusts (4, N): motors 0..3 = FL, FR, RL, RR; unclamped commands, a state
        output port (no direct feedthrough); mass g / 4 each before the first tick.
    Discrete state: the altitude-error integral (1, m s) and the last motor command (4, N).
    ``fidelity`` (:class:`~quad_drake.fidelity.Fidelity`) picks the lateral acceleration
    limit (horizontal norm, or the reference's 3-D norm).
    """

    def __init__(self, params, fidelity=PHYSICAL):
        super().__init__()
        self._frozen_params, self._frozen_fidelity = kernels.frozen(params), kernels.frozen(fidelity)
        self._read_state = row_reader(self.DeclareVectorInputPort("state", STATE_SIZE))
        self._read_reference = row_reader(self.DeclareVectorInputPort("reference", REFERENCE_SIZE))
        self._integral_index = self.DeclareDiscreteState(1)
        hover = params.mass * GRAVITY / NUM_MOTORS
        self._thrusts_index = self.DeclareDiscreteState(np.full(NUM_MOTORS, hover))
        self.DeclareStateOutputPort("motor_thrusts", self._thrusts_index)
        self._integral_group, self._thrusts_group = int(self._integral_index), int(self._thrusts_index)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, CONTROLLER_OFFSET, self._update)

    def integral_index(self):
        """Discrete-state group index of the altitude-error integral (m s)."""
        return self._integral_index

    def _update(self, context, discrete_state):
        kernels.cascade_steps(
            self._read_state(context),
            self._read_reference(context),
            discrete_state.get_mutable_value(self._integral_group),
            ONBOARD_PERIOD,
            self._frozen_params,
            self._frozen_fidelity,
            discrete_state.get_mutable_value(self._thrusts_group).reshape(1, NUM_MOTORS),
        )
