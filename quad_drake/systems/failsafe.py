"""Drake glue for the no-aiding failsafe (``quad_drake.control.failsafe``): :class:`FailsafeSupervisor`
of n vehicles, between the trajectory and the controller and between the controller and the
plant, running the compiled ``kernels.failsafe.failsafe_steps``."""

import numpy as np
from pydrake.systems.framework import DiscreteStateIndex, LeafSystem

from quad_drake.control import failsafe
from quad_drake.conventions import FAILSAFE_OFFSET, NUM_MOTORS, ONBOARD_PERIOD, REFERENCE_SIZE, STATE_SIZE
from quad_drake.estimation.vocabulary import DIAG, DIAGNOSTICS_SIZE
from quad_drake.kernels import failsafe as kernels
from quad_drake.kernels.flight import frozen
from quad_drake.systems._io import discrete_group, row_reader

_GPS_COLUMNS = (DIAG["gps_stamp"], DIAG["gps_gated"], DIAG["gps_resets"])


class FailsafeSupervisor(LeafSystem):
    """The no-aiding failsafe of n vehicles (default 1), ticking at ONBOARD_PERIOD (offset
    FAILSAFE_OFFSET: after the estimator, before the controller). Ports carry the n per-vehicle
    vectors concatenated vehicle-major.

    Inputs:
      estimated_state (13): the estimate the controller flies on (p m NED, q wxyz, v m/s, w rad/s).
      diagnostics (``vocabulary.DIAGNOSTICS_SIZE``): the estimator's; its GPS stamp and counters
        say when the position was last aided.
      reference (10): the trajectory's p (m), v (m/s), a (m/s^2), yaw (rad).
      motor_thrusts (4, N): the controller's commands.
    Outputs:
      reference (10): what the controller flies: the trajectory's, or the failsafe's descent
        (state output: the value chosen at this tick).
      failsafe (3): ``control.failsafe.STATUS``: position valid (1/0), s without position aiding,
        phase (0 nominal, 1 descending, 2 landed); state output.
      motor_thrusts (4, N): the controller's commands, or 0 (the plant's idle, its
        min_motor_thrust) once landed; computed from the input and the phase (no loop: the
        controller's output is a state port).
    Discrete state: the memory (n x ``control.failsafe.MEMORY_SIZE``), the command and the status.
    ``params``: a FailsafeConfig shared by the n vehicles.
    """

    def __init__(self, params, n=1) -> None:
        super().__init__()
        self._n = n
        self._params = frozen(params)
        self._read_estimate = row_reader(self.DeclareVectorInputPort("estimated_state", n * STATE_SIZE), n)
        self._read_diagnostics = row_reader(
            self.DeclareVectorInputPort("diagnostics", n * DIAGNOSTICS_SIZE), n
        )
        self._read_reference = row_reader(self.DeclareVectorInputPort("reference", n * REFERENCE_SIZE), n)
        thrusts = self.DeclareVectorInputPort("motor_thrusts", n * NUM_MOTORS)
        self._memory = discrete_group(self, np.tile(failsafe.initial_memory(), n))
        self._command = discrete_group(self, n * REFERENCE_SIZE, "reference")
        status = np.tile([1.0, 0.0, failsafe.NOMINAL], n)
        self._status = discrete_group(self, status, "failsafe")
        self.DeclareVectorOutputPort(
            "motor_thrusts",
            n * NUM_MOTORS,
            self._calc_thrusts,
            prerequisites_of_calc={
                thrusts.ticket(),
                self.discrete_state_ticket(DiscreteStateIndex(self._status)),
            },
        )
        self._thrusts = thrusts
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, FAILSAFE_OFFSET, self._update)

    def _update(self, context, discrete_state):
        n = self._n
        kernels.failsafe_steps(
            discrete_state.get_mutable_value(self._memory).reshape(n, failsafe.MEMORY_SIZE),
            context.get_time(),
            ONBOARD_PERIOD,
            self._read_diagnostics(context),
            _GPS_COLUMNS,
            self._read_estimate(context),
            self._read_reference(context),
            self._params,
            discrete_state.get_mutable_value(self._command).reshape(n, REFERENCE_SIZE),
            discrete_state.get_mutable_value(self._status).reshape(n, failsafe.STATUS_SIZE),
        )

    def _calc_thrusts(self, context, output):
        output.SetFrom(self._thrusts.EvalBasicVector(context))
        phase = context.get_discrete_state(self._status).value().reshape(self._n, failsafe.STATUS_SIZE)[:, 2]
        landed = phase == failsafe.LANDED
        if landed.any():
            output.get_mutable_value().reshape(self._n, NUM_MOTORS)[landed] = 0.0
