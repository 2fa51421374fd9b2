"""The quadrotor plant (SPEC §3) of n vehicles: a 1 kHz discrete system over ``dynamics.plant_step``,
run as its compiled form (``kernels.flight.plant_steps``: the scalar function's own code compiled by
numba, about a third of its Python cost per step)."""

import copy

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import NUM_MOTORS, ONBOARD_PERIOD, PHYSICS_PERIOD, PLANT_OFFSET, STATE_SIZE
from quad_drake.kernels import flight as kernels
from quad_drake.models import dynamics, sensor_models
from quad_drake.models.fidelity import PHYSICAL
from quad_drake.systems._io import discrete_group, row_reader


class QuadrotorPlant(LeafSystem):
    """n rigid quadrotors (default 1) with lagged, noisy motors in a room, stepped every PHYSICS_PERIOD.

    Within each onboard tick t_k = k ONBOARD_PERIOD the plant steps twice: at
    t_k + PLANT_OFFSET (integrating t_k -> t_k + PHYSICS_PERIOD) and at
    t_k + PHYSICS_PERIOD + PLANT_OFFSET (the next millisecond); RK4, wrench held
    constant (or, with ``fidelity.semi_implicit_euler``, the reference's semi-implicit
    Euler step). Systems ticking earlier within t_k see the state at t_k.

    Constructor: params (PhysicsParams, shared by the n vehicles), initial_state (13, every
    vehicle's in the default context), fidelity (:class:`~quad_drake.models.fidelity.Fidelity`, default
    physical), n (vehicles). Every port carries the n per-vehicle vectors below concatenated
    vehicle-major (size n k, vehicle j at [j k, (j + 1) k)).
    Inputs:
      ``motor_thrusts`` (4, N): commanded force per motor 0..3 = front-left, front-right,
        rear-left, rear-right; clamped to [min_motor_thrust, max_motor_thrust].
      ``motor_noise`` (8, uniform in [0, 1], random kUniform): two draws u per tick,
        entries 0..3 for the first step and 4..7 for the second; each adds
        motor_noise (2u - 1) N per motor after the clamp. Wire
        ``RandomSource(RandomDistribution.kUniform, n noise_size, noise_period)`` (or a
        ``systems.noise.NoiseStreamSource``): it redraws at t_k, before the plant's steps of
        that tick.
      ``wind`` (3, m/s, NED; only when PhysicsParams has drag, ``dynamics.has_drag``): the air's
        velocity (``systems.wind.Wind``); the drag ``dynamics.drag_acceleration`` of the
        air-relative velocity is held over each step. Without drag the wind cannot act and the
        port does not exist.
    Outputs (state output ports, no feedthrough):
      ``state`` (13): p_NB (m, NED), q_NB (wxyz), v_NB (m/s, NED), w_NB_B (rad/s, FRD).
      ``acceleration`` (3, m/s^2): a_NB, NED kinematic acceleration (v_new - v_old)/dt of
        the last step, after the room limits (zero while resting on the floor).
      ``motor_forces`` (4, N): the lagged motor forces of the last step.
      ``contacts`` (3): on the floor now (1/0); touchdowns so far (steps that ended on the
        floor after one that did not; a vehicle that starts on the floor has not touched
        down); steps so far that ended at a wall or the ceiling (``dynamics.outside_room``);
        counted by ``dynamics.count_contacts``.
      ``delta_velocity`` (3, m/s, FRD): the body-frame integral of the specific force over the
        last onboard tick's two steps (``sensor_models.delta_velocity_step``; the floor's support,
        a touchdown's impulse and the drag included, gravity not), what a delta-velocity IMU
        reads (``ImuParams.delta_velocity``); before the first step R_NB^T (-g_N) ONBOARD_PERIOD
        of the initial attitude (at rest).
    ``acceleration`` and ``motor_forces`` are zero before the first step. At the first
    step the motor lag starts from the first command (pre-clamp, no noise), as the
    reference does at t = 0; a flag in discrete state records that it happened.
    """

    noise_size = 2 * NUM_MOTORS
    noise_period = ONBOARD_PERIOD
    noise_distribution = RandomDistribution.kUniform

    def __init__(self, params, initial_state, fidelity=PHYSICAL, n=1) -> None:
        super().__init__()
        initial_state = np.asarray(initial_state, dtype=float)
        if initial_state.shape != (STATE_SIZE,):
            raise ValueError(f"initial_state: expected {STATE_SIZE} values, got shape {initial_state.shape}")
        self._params, self._n = copy.deepcopy(params), n
        self._frozen_params, self._frozen_fidelity = kernels.frozen(self._params), kernels.frozen(fidelity)
        self._read_commands = row_reader(self.DeclareVectorInputPort("motor_thrusts", n * NUM_MOTORS), n)
        noise = self.DeclareVectorInputPort(
            "motor_noise", n * self.noise_size, random_type=self.noise_distribution
        )
        self._read_noise = row_reader(noise, n)
        initial = np.tile(initial_state, (n, 1))
        self._state = discrete_group(self, initial.ravel(), "state")
        self._acceleration = discrete_group(self, 3 * n, "acceleration")
        self._forces = discrete_group(self, NUM_MOTORS * n, "motor_forces")
        self._started = discrete_group(self, 1)  # 0 until the first step
        self._contacts = discrete_group(self, self._initial_contacts(initial).ravel(), "contacts")
        self._delta_v = discrete_group(self, self._initial_delta_v(initial).ravel(), "delta_velocity")
        self._no_wind = np.zeros((n, 3))
        self._read_wind = None
        if dynamics.has_drag(self._params):
            self._read_wind = row_reader(self.DeclareVectorInputPort("wind", 3 * n), n)
        self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, PLANT_OFFSET, self._first_step)
        self.DeclarePeriodicDiscreteUpdateEvent(
            ONBOARD_PERIOD, PHYSICS_PERIOD + PLANT_OFFSET, self._second_step
        )

    def _initial_contacts(self, states):
        """(n, 3) contact counts of the (n, 13) `states`: on the floor or not, none counted."""
        floor = kernels.on_floor(states, self._params).astype(float)
        return np.stack([floor, np.zeros(len(states)), np.zeros(len(states))], axis=1)

    @staticmethod
    def _initial_delta_v(states):
        """(n, 3) delta-velocity of one onboard tick at rest at the (n, 13) `states`' attitudes."""
        return (
            np.array(
                [sensor_models.specific_force(x[3:7], (0.0, 0.0, 0.0)) for x in states.tolist()]
            ).reshape(-1, 3)
            * ONBOARD_PERIOD
        )

    def set_initial_state(self, context, state) -> None:
        """Set every vehicle's state in `context` to `state` (13, or (n, 13)), re-arm the
        motor-lag initialisation and reset the contact counts."""
        states = np.broadcast_to(np.asarray(state, dtype=float), (self._n, STATE_SIZE))
        context.SetDiscreteState(self._state, states.ravel())
        context.SetDiscreteState(self._started, [0.0])
        context.SetDiscreteState(self._contacts, self._initial_contacts(states).ravel())
        context.SetDiscreteState(self._delta_v, self._initial_delta_v(states).ravel())

    def _first_step(self, context, discrete_state):
        self._step(context, discrete_state, 0)

    def _second_step(self, context, discrete_state):
        self._step(context, discrete_state, NUM_MOTORS)

    def _step(self, context, discrete_state, column):
        """One physics step of every vehicle on the noise columns column..column + 3, in place;
        the first starts the motor lag from the commands and sets the started flag."""
        n, get = self._n, discrete_state.get_mutable_value
        commands = self._read_commands(context)
        forces = get(self._forces).reshape(n, NUM_MOTORS)
        flag = get(self._started)
        if not flag[0]:
            forces[:] = commands
            flag[0] = 1.0
        kernels.plant_steps(
            get(self._state).reshape(n, STATE_SIZE),
            forces,
            commands,
            self._read_noise(context),
            column,
            self._frozen_params,
            PHYSICS_PERIOD,
            self._frozen_fidelity,
            get(self._acceleration).reshape(n, 3),
            get(self._contacts).reshape(n, 3),
            self._no_wind if self._read_wind is None else self._read_wind(context),
            get(self._delta_v).reshape(n, 3),
        )
