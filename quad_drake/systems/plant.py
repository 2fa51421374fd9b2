"""The quadrotor plant (SPEC §3): a 1 kHz discrete system over ``dynamics.plant_step``, run as its
compiled form for one vehicle (``fleet.kernels.plant_steps`` with N = 1: the scalar function's own
code compiled by numba, about a third of its Python cost per step)."""

import copy

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import NUM_MOTORS, ONBOARD_PERIOD, PHYSICS_PERIOD, PLANT_OFFSET, STATE_SIZE
from quad_drake.dynamics import on_floor
from quad_drake.fidelity import PHYSICAL
from quad_drake.fleet import kernels
from quad_drake.systems._io import row_reader


class QuadrotorPlant(LeafSystem):
    """Rigid quadrotor with lagged, noisy motors in a room, stepped every PHYSICS_PERIOD.

    Within each onboard tick t_k = k ONBOARD_PERIOD the plant steps twice: at
    t_k + PLANT_OFFSET (integrating t_k -> t_k + PHYSICS_PERIOD) and at
    t_k + PHYSICS_PERIOD + PLANT_OFFSET (the next millisecond); RK4, wrench held
    constant (or, with ``fidelity.semi_implicit_euler``, the reference's semi-implicit
    Euler step). Systems ticking earlier within t_k see the state at t_k.

    Constructor: params (PhysicsParams), initial_state (13, the default context's state),
    fidelity (:class:`~quad_drake.fidelity.Fidelity`, default physical).
    Inputs:
      ``motor_thrusts`` (4, N): commanded force per motor 0..3 = front-left, front-right,
        rear-left, rear-right; clamped to [min_motor_thrust, max_motor_thrust].
      ``motor_noise`` (8, uniform in [0, 1], random kUniform): two draws u per tick,
        entries 0..3 for the first step and 4..7 for the second; each adds
        motor_noise (2u - 1) N per motor after the clamp. Wire
        ``RandomSource(RandomDistribution.kUniform, noise_size, noise_period)``: it redraws
        at t_k, before the plant's steps of that tick.
    Outputs (state output ports, no feedthrough):
      ``state`` (13): p_NB (m, NED), q_NB (wxyz), v_NB (m/s, NED), w_NB_B (rad/s, FRD).
      ``acceleration`` (3, m/s^2): a_NB, NED kinematic acceleration (v_new - v_old)/dt of
        the last step, after the room limits (zero while resting on the floor).
      ``motor_forces`` (4, N): the lagged motor forces of the last step.
      ``contacts`` (3): on the floor now (1/0); touchdowns so far (steps that ended on the
        floor after one that did not; a vehicle that starts on the floor has not touched
        down); steps so far that ended at a wall or the ceiling (``dynamics.outside_room``);
        counted by ``dynamics.count_contacts``.
    ``acceleration`` and ``motor_forces`` are zero before the first step. At the first
    step the motor lag starts from the first command (pre-clamp, no noise), as the
    reference does at t = 0; a flag in discrete state records that it happened.
    """

    noise_size = 2 * NUM_MOTORS
    noise_period = ONBOARD_PERIOD

    def __init__(self, params, initial_state, fidelity=PHYSICAL):
        super().__init__()
        initial_state = np.asarray(initial_state, dtype=float)
        if initial_state.shape != (STATE_SIZE,):
            raise ValueError(f"initial_state: expected {STATE_SIZE} values, got shape {initial_state.shape}")
        self._params = copy.deepcopy(params)
        self._frozen_params, self._frozen_fidelity = kernels.frozen(self._params), kernels.frozen(fidelity)
        self._read_commands = row_reader(self.DeclareVectorInputPort("motor_thrusts", NUM_MOTORS))
        noise = self.DeclareVectorInputPort(
            "motor_noise", self.noise_size, random_type=RandomDistribution.kUniform
        )
        self._read_noise = row_reader(noise)
        state = self.DeclareDiscreteState(initial_state)
        acceleration = self.DeclareDiscreteState(3)
        forces = self.DeclareDiscreteState(NUM_MOTORS)
        started = self.DeclareDiscreteState(1)  # 0 until the first step
        contacts = self.DeclareDiscreteState(self._initial_contacts(initial_state))
        self.DeclareStateOutputPort("state", state)
        self.DeclareStateOutputPort("acceleration", acceleration)
        self.DeclareStateOutputPort("motor_forces", forces)
        self.DeclareStateOutputPort("contacts", contacts)
        self._contacts_group = int(contacts)
        # Plain int group indices: faster than DiscreteStateIndex in the 1 kHz handler.
        self._state_group, self._acceleration_group = int(state), int(acceleration)
        self._forces_group, self._started_group = int(forces), int(started)
        self._groups = (
            self._state_group,
            self._acceleration_group,
            self._forces_group,
            self._started_group,
            self._contacts_group,
        )
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, PLANT_OFFSET, self._first_step)
        self.DeclarePeriodicDiscreteUpdateEvent(
            ONBOARD_PERIOD, PHYSICS_PERIOD + PLANT_OFFSET, self._second_step
        )

    def _initial_contacts(self, state):
        return np.array([1.0 if on_floor(state, self._params) else 0.0, 0.0, 0.0])

    def set_initial_state(self, context, state):
        """Set the 13-vector state in `context`, re-arm the motor-lag initialisation and
        reset the contact counts."""
        context.SetDiscreteState(self._state_group, np.asarray(state, dtype=float))
        context.SetDiscreteState(self._started_group, [0.0])
        context.SetDiscreteState(self._contacts_group, self._initial_contacts(state))

    def _first_step(self, context, discrete_state):
        self._step(context, discrete_state, 0)

    def _second_step(self, context, discrete_state):
        self._step(context, discrete_state, NUM_MOTORS)

    def _step(self, context, discrete_state, column):
        step_plants(
            discrete_state,
            self._groups,
            self._read_commands(context),
            self._read_noise(context),
            column,
            self._frozen_params,
            self._frozen_fidelity,
        )


def step_plants(discrete_state, groups, commands, noise, column, params, fidelity):
    """One physics step of N vehicles IN PLACE on `discrete_state` (this plant's, N = 1, and
    ``fleet.systems.FleetPlant``'s): groups, the indices of the state, acceleration, motor-force,
    started-flag and contact groups; commands (N, 4) N; noise (N, 8) uniforms, this step's on
    columns column..column + 3; params, fidelity: ``fleet.kernels.frozen``. The first step
    starts the motor lag from the commands and sets the started flag."""
    state, acceleration, motor_forces, started, contacts = groups
    n = commands.shape[0]
    forces = discrete_state.get_mutable_value(motor_forces).reshape(n, NUM_MOTORS)
    flag = discrete_state.get_mutable_value(started)
    if not flag[0]:
        forces[:] = commands
        flag[0] = 1.0
    kernels.plant_steps(
        discrete_state.get_mutable_value(state).reshape(n, STATE_SIZE),
        forces,
        commands,
        noise,
        column,
        params,
        PHYSICS_PERIOD,
        fidelity,
        discrete_state.get_mutable_value(acceleration).reshape(n, 3),
        discrete_state.get_mutable_value(contacts).reshape(n, 3),
    )
