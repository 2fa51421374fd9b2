"""The quadrotor plant (SPEC §3): a 1 kHz discrete system over ``dynamics.plant_step``."""

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import NUM_MOTORS, PHYSICS_PERIOD, PLANT_OFFSET, STATE_SIZE
from quad_drake.dynamics import plant_step


class QuadrotorPlant(LeafSystem):
    """Rigid quadrotor with lagged, noisy motors in a room, stepped every PHYSICS_PERIOD.

    The step at t_k + PLANT_OFFSET integrates from t_k to t_k + PHYSICS_PERIOD (RK4,
    wrench held constant), so systems ticking earlier within t_k see the pre-step state.

    Constructor: params (PhysicsParams), initial_state (13, the default context's state).
    Inputs:
      ``motor_thrusts`` (4, N): commanded force per motor 0..3 = front-left, front-right,
        rear-left, rear-right; clamped to [min_motor_thrust, max_motor_thrust].
      ``motor_noise`` (4, uniform in [0, 1], random kUniform): adds
        motor_noise (2u - 1) N per motor after the clamp. Wire
        ``RandomSource(RandomDistribution.kUniform, 4, PHYSICS_PERIOD)``.
    Outputs (state output ports, no feedthrough):
      ``state`` (13): p_NB (m, NED), q_NB (wxyz), v_NB (m/s, NED), w_NB_B (rad/s, FRD).
      ``acceleration`` (3, m/s^2): a_NB, NED kinematic acceleration (v_new - v_old)/dt of
        the last step, after the room limits (zero while resting on the floor).
      ``motor_forces`` (4, N): the lagged motor forces of the last step.
    ``acceleration`` and ``motor_forces`` are zero before the first step. At the first
    step the motor lag starts from the first command (pre-clamp, no noise), as the
    reference does at t = 0; a flag in discrete state records that it happened.
    """

    def __init__(self, params, initial_state):
        super().__init__()
        initial_state = np.asarray(initial_state, dtype=float)
        if initial_state.shape != (STATE_SIZE,):
            raise ValueError(f"initial_state: expected {STATE_SIZE} values, got shape {initial_state.shape}")
        self._params = params
        self._commands_port = self.DeclareVectorInputPort("motor_thrusts", NUM_MOTORS)
        self._noise_port = self.DeclareVectorInputPort(
            "motor_noise", NUM_MOTORS, random_type=RandomDistribution.kUniform)
        state = self.DeclareDiscreteState(initial_state)
        acceleration = self.DeclareDiscreteState(3)
        forces = self.DeclareDiscreteState(NUM_MOTORS)
        started = self.DeclareDiscreteState(1)  # 0 until the first step
        self.DeclareStateOutputPort("state", state)
        self.DeclareStateOutputPort("acceleration", acceleration)
        self.DeclareStateOutputPort("motor_forces", forces)
        # Plain int group indices: faster than DiscreteStateIndex in the 1 kHz handler.
        self._state_group, self._acceleration_group = int(state), int(acceleration)
        self._forces_group, self._started_group = int(forces), int(started)
        self.DeclarePeriodicDiscreteUpdateEvent(PHYSICS_PERIOD, PLANT_OFFSET, self._step)

    def set_initial_state(self, context, state):
        """Set the 13-vector state in `context` and re-arm the motor-lag initialisation."""
        context.SetDiscreteState(self._state_group, np.asarray(state, dtype=float))
        context.SetDiscreteState(self._started_group, [0.0])

    def DoCalcTimeDerivatives(self, context, derivatives):
        """No-op: avoids the default per-derivative overhead of Python systems (DESIGN §9)."""

    def _step(self, context, discrete_state):
        commands = self._commands_port.Eval(context).tolist()
        noise = self._noise_port.Eval(context).tolist()
        if discrete_state.get_value(self._started_group)[0]:
            forces_old = discrete_state.get_value(self._forces_group).tolist()
        else:
            forces_old = commands
            discrete_state.get_mutable_value(self._started_group)[0] = 1.0
        state, accel, forces = plant_step(discrete_state.get_value(self._state_group).tolist(),
                                          forces_old, commands, noise, self._params, PHYSICS_PERIOD)
        # Writing lists through the numpy views: set_value(list) costs ~6 us on drake 1.58.
        discrete_state.get_mutable_value(self._state_group)[:] = state
        discrete_state.get_mutable_value(self._acceleration_group)[:] = accel
        discrete_state.get_mutable_value(self._forces_group)[:] = forces
