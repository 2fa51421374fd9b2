"""Pure quadrotor physics: motor lag, X-layout mixer, rigid body in NED/FRD, room limits.

State layout (13, see ``conventions``): p_NB (m, NED), q_NB (wxyz, body to world),
v_NB (m/s, NED), w_NB_B (rad/s, FRD body). Thrust acts along body -z, gravity is
``(0, 0, +GRAVITY)`` in N. All functions take and return plain floats / lists (the
plant steps at 1 kHz, so the hot path avoids small numpy arrays).

Motor layout (X configuration, arm length L from the centre, moment arm L/sqrt(2)):

======  ===========  ===================  ================  =========================
index   name         position (x, y)      spin seen from    reaction yaw moment
                     in body FRD          above             on the body (about +z)
======  ===========  ===================  ================  =========================
0       front-left   (+L/√2, -L/√2)       clockwise         -kappa F0
1       front-right  (+L/√2, +L/√2)       counter-clockw.   +kappa F1
2       rear-left    (-L/√2, -L/√2)       counter-clockw.   +kappa F2
3       rear-right   (-L/√2, +L/√2)       clockwise         -kappa F3
======  ===========  ===================  ================  =========================

Body +z points down, so a positive Mz yaws the nose to the right (towards +y).
"""

import math

import numpy as np

from quad_drake.conventions import GRAVITY, SQRT2
from quad_drake.models.fidelity import PHYSICAL


def clamped_noisy_commands(
    commands, noise_unit, min_thrust, max_thrust, noise_half_width
) -> tuple[float, float, float, float]:
    """Target force of each of the four motors, N: clamp(cmd, min, max) + half_width (2u - 1), u in [0, 1].

    The noise is added after the clamp, so the target may slightly exceed the limits
    (SPEC §3 step 1).
    """
    c0, c1, c2, c3 = commands  # unrolled: a zip over four motors costs as much as the maths
    u0, u1, u2, u3 = noise_unit
    return (
        (min_thrust if c0 < min_thrust else max_thrust if c0 > max_thrust else c0)
        + noise_half_width * (2.0 * u0 - 1.0),
        (min_thrust if c1 < min_thrust else max_thrust if c1 > max_thrust else c1)
        + noise_half_width * (2.0 * u1 - 1.0),
        (min_thrust if c2 < min_thrust else max_thrust if c2 > max_thrust else c2)
        + noise_half_width * (2.0 * u2 - 1.0),
        (min_thrust if c3 < min_thrust else max_thrust if c3 > max_thrust else c3)
        + noise_half_width * (2.0 * u3 - 1.0),
    )


def motor_lag_step(forces_old, forces_cmd, dt, tau_up, tau_down) -> tuple[float, float, float, float]:
    """The four motor forces (N) after one backward-Euler first-order lag step of dt s.

    F = Fcmd dt/(dt + tau) + Fold tau/(dt + tau), with tau = tau_up when Fcmd >= Fold
    (spinning up) and tau_down otherwise.
    """
    o0, o1, o2, o3 = forces_old
    c0, c1, c2, c3 = forces_cmd
    t0 = tau_up if c0 >= o0 else tau_down
    t1 = tau_up if c1 >= o1 else tau_down
    t2 = tau_up if c2 >= o2 else tau_down
    t3 = tau_up if c3 >= o3 else tau_down
    return (
        (c0 * dt + o0 * t0) / (dt + t0),
        (c1 * dt + o1 * t1) / (dt + t1),
        (c2 * dt + o2 * t2) / (dt + t2),
        (c3 * dt + o3 * t3) / (dt + t3),
    )


def wrench_from_thrusts(
    forces, arm_length, kappa, com_offset=(0.0, 0.0)
) -> tuple[float, float, float, float]:
    """(T, Mx, My, Mz): total thrust (N, along body -z) and moments about the CoM (N m, FRD).

    forces: the four motor forces (N) in the order of the module table. com_offset: the
    centre of mass (cx, cy) in body x, y (m); it adds cy T to Mx and -cx T to My.
    """
    f0, f1, f2, f3 = forces
    arm = arm_length / SQRT2
    thrust = f0 + f1 + f2 + f3
    return (
        thrust,
        arm * (f0 - f1 + f2 - f3) + com_offset[1] * thrust,
        arm * (f0 + f1 - f2 - f3) - com_offset[0] * thrust,
        kappa * (-f0 + f1 + f2 - f3),
    )


def thrusts_from_wrench(thrust, mx, my, mz, arm_length, kappa) -> tuple[float, float, float, float]:
    """Motor forces (F0, F1, F2, F3), N, realising (T, Mx, My, Mz); the exact inverse of
    :func:`wrench_from_thrusts` for a centred CoM (SPEC §5 step 8). Not clamped."""
    dx = mx / (2.0 * SQRT2 * arm_length)
    dy = my / (2.0 * SQRT2 * arm_length)
    dz = mz / (4.0 * kappa)
    t4 = 0.25 * thrust
    return (t4 - dz + dy + dx, t4 + dz + dy - dx, t4 + dz - dy + dx, t4 - dz - dy - dx)


NO_EXTRA = (0.0, 0.0, 0.0)
"""No further acceleration (m/s^2, NED), and no wind (m/s, NED): a drag-free or windless step."""


def has_drag(params) -> bool:
    """True when PhysicsParams has any non-zero rotor or parasitic drag coefficient."""
    r, p = params.rotor_drag, params.parasitic_drag
    return r[0] != 0.0 or r[1] != 0.0 or r[2] != 0.0 or p[0] != 0.0 or p[1] != 0.0 or p[2] != 0.0


def drag_force_body(v_rel_B, rotor_drag, parasitic_drag) -> tuple[float, float, float]:
    """Aerodynamic drag force on the body, N, body FRD (3):
    F_B = -K v_rel - |v_rel| C v_rel, K = diag(rotor_drag), C = diag(parasitic_drag).

    v_rel_B: the body's velocity relative to the air, expressed in B (m/s, FRD): R_NB^T (v_NB -
    wind_N). rotor_drag (3, N s/m): the induced (rotor, "blade-flapping") drag, linear in the
    body-frame air-relative velocity, per body axis, summed over the rotors (the multirotor drag
    model of PX4's EKF2 drag fusion and of RotorPy, there k_d * rotor speed per rotor, here its
    value at hover: the thrust varies little about hover). parasitic_drag (3, N s^2/m^2): the
    body's quadratic (parasitic) drag, 1/2 rho C_D A per axis. Its Jacobian is
    :func:`drag_force_jacobian`.
    """
    vx, vy, vz = v_rel_B[0], v_rel_B[1], v_rel_B[2]
    speed = (vx * vx + vy * vy + vz * vz) ** 0.5
    return (
        -(rotor_drag[0] + parasitic_drag[0] * speed) * vx,
        -(rotor_drag[1] + parasitic_drag[1] * speed) * vy,
        -(rotor_drag[2] + parasitic_drag[2] * speed) * vz,
    )


def drag_force_jacobian(v_rel_B, rotor_drag, parasitic_drag) -> tuple[tuple[float, float, float], ...]:
    """d F_B / d v_rel_B (3 x 3 nested tuples, N s/m) of :func:`drag_force_body`:
    -K - C (|v| I + v v^T / |v|) (the second term 0 at v = 0, where it is continuous)."""
    speed = (v_rel_B[0] ** 2 + v_rel_B[1] ** 2 + v_rel_B[2] ** 2) ** 0.5
    rows = []
    for i in range(3):
        row = []
        for j in range(3):
            outer = v_rel_B[i] * v_rel_B[j] / speed if speed > 0.0 else 0.0
            diagonal = rotor_drag[i] + parasitic_drag[i] * speed if i == j else 0.0
            row.append(-diagonal - parasitic_drag[i] * outer)
        rows.append(tuple(row))
    return tuple(rows)


def drag_acceleration(state, wind_N, params) -> tuple[float, float, float]:
    """Drag acceleration of the vehicle, m/s^2, NED (3): R_NB F_B / m, with F_B the
    :func:`drag_force_body` of the air-relative velocity v_rel_B = R_NB^T (v_NB - wind_N).

    state: 13 floats (q_NB wxyz, v_NB m/s NED); wind_N: the air's velocity (3, m/s, NED);
    params: PhysicsParams (mass, rotor_drag, parasitic_drag).
    """
    qw, qx, qy, qz = state[3], state[4], state[5], state[6]
    dx, dy, dz = state[7] - wind_N[0], state[8] - wind_N[1], state[9] - wind_N[2]
    s = 2.0 / (qw * qw + qx * qx + qy * qy + qz * qz)
    r00, r01, r02 = 1.0 - s * (qy * qy + qz * qz), s * (qx * qy - qw * qz), s * (qx * qz + qw * qy)
    r10, r11, r12 = s * (qx * qy + qw * qz), 1.0 - s * (qx * qx + qz * qz), s * (qy * qz - qw * qx)
    r20, r21, r22 = s * (qx * qz - qw * qy), s * (qy * qz + qw * qx), 1.0 - s * (qx * qx + qy * qy)
    v_rel_B = (
        r00 * dx + r10 * dy + r20 * dz,
        r01 * dx + r11 * dy + r21 * dz,
        r02 * dx + r12 * dy + r22 * dz,
    )
    fx, fy, fz = drag_force_body(v_rel_B, params.rotor_drag, params.parasitic_drag)
    m = params.mass
    return (
        (r00 * fx + r01 * fy + r02 * fz) / m,
        (r10 * fx + r11 * fy + r12 * fz) / m,
        (r20 * fx + r21 * fy + r22 * fz) / m,
    )


def _rates(qw, qx, qy, qz, wx, wy, wz, c, mx, my, mz, kx, ky, kz, extra):
    """(q_dot (4), w_dot (3), a_NB (3)) at attitude q and body rate w.

    c = -2 T / m; (mx, my, mz) = M / I; (kx, ky, kz) = ((Iyy - Izz)/Ixx, (Izz - Ixx)/Iyy,
    (Ixx - Iyy)/Izz). a_NB = R(q) (0, 0, -T/m) + g_N + extra uses only R's third column;
    extra: a further NED acceleration held over the step (the drag of :func:`drag_acceleration`,
    m/s^2; ``NO_EXTRA`` adds exact zeros, so a drag-free flight is bit-identical to before).
    """
    return (
        0.5 * (-qx * wx - qy * wy - qz * wz),
        0.5 * (qw * wx + qy * wz - qz * wy),
        0.5 * (qw * wy - qx * wz + qz * wx),
        0.5 * (qw * wz + qx * wy - qy * wx),
        mx + kx * wy * wz,
        my + ky * wz * wx,
        mz + kz * wx * wy,
        c * (qx * qz + qw * qy) + extra[0],
        c * (qy * qz - qw * qx) + extra[1],
        GRAVITY + 0.5 * c - c * (qx * qx + qy * qy) + extra[2],
    )


def _coefficients(thrust, moment, mass, inertia):
    ixx, iyy, izz = inertia
    return (
        -2.0 * thrust / mass,
        moment[0] / ixx,
        moment[1] / iyy,
        moment[2] / izz,
        (iyy - izz) / ixx,
        (izz - ixx) / iyy,
        (ixx - iyy) / izz,
    )


def rigid_body_derivatives(state, thrust, moment, mass, inertia, extra=NO_EXTRA) -> tuple[float, ...]:
    """Time derivative (13-tuple) of the state under thrust T (N) and body moment M (N m).

    p_dot = v; q_dot = q (x) (0, w) / 2; v_dot = R(q) (0, 0, -T)/m + g_N + extra (the NED
    acceleration a_NB, entries 7:10; extra: e.g. drag, m/s^2, NED); w_dot = I^-1 (M - w x I w)
    with I = diag(inertia).
    """
    qw, qx, qy, qz, vx, vy, vz, wx, wy, wz = (float(s) for s in state[3:13])
    qdw, qdx, qdy, qdz, wdx, wdy, wdz, ax, ay, az = _rates(
        qw, qx, qy, qz, wx, wy, wz, *_coefficients(thrust, moment, mass, inertia), extra
    )
    return (vx, vy, vz, qdw, qdx, qdy, qdz, ax, ay, az, wdx, wdy, wdz)


def rigid_body_step(
    state, thrust, moment, mass, inertia, dt, extra=NO_EXTRA
) -> tuple[tuple[float, ...], tuple[float, float, float]]:
    """One classical RK4 step of dt s with the wrench (and `extra`, a NED acceleration in m/s^2
    such as the drag of :func:`drag_acceleration`) held constant; q renormalised.

    Returns (state_new: 13 floats, a_NB: (3,) mean NED acceleration over the
    step, (v_new - v_old)/dt, m/s^2). RK4 costs about the same as RK3 here and is
    1e-11 m accurate over 2 s of tumbling flight (explicit Euler: cm).
    """
    px, py, pz, qw, qx, qy, qz, vx, vy, vz, wx, wy, wz = state
    c, mx, my, mz, kx, ky, kz = _coefficients(thrust, moment, mass, inertia)
    h = 0.5 * dt
    qw1, qx1, qy1, qz1, wx1, wy1, wz1, ax1, ay1, az1 = _rates(
        qw, qx, qy, qz, wx, wy, wz, c, mx, my, mz, kx, ky, kz, extra
    )
    qw2, qx2, qy2, qz2, wx2, wy2, wz2, ax2, ay2, az2 = _rates(
        qw + h * qw1,
        qx + h * qx1,
        qy + h * qy1,
        qz + h * qz1,
        wx + h * wx1,
        wy + h * wy1,
        wz + h * wz1,
        c,
        mx,
        my,
        mz,
        kx,
        ky,
        kz,
        extra,
    )
    qw3, qx3, qy3, qz3, wx3, wy3, wz3, ax3, ay3, az3 = _rates(
        qw + h * qw2,
        qx + h * qx2,
        qy + h * qy2,
        qz + h * qz2,
        wx + h * wx2,
        wy + h * wy2,
        wz + h * wz2,
        c,
        mx,
        my,
        mz,
        kx,
        ky,
        kz,
        extra,
    )
    qw4, qx4, qy4, qz4, wx4, wy4, wz4, ax4, ay4, az4 = _rates(
        qw + dt * qw3,
        qx + dt * qx3,
        qy + dt * qy3,
        qz + dt * qz3,
        wx + dt * wx3,
        wy + dt * wy3,
        wz + dt * wz3,
        c,
        mx,
        my,
        mz,
        kx,
        ky,
        kz,
        extra,
    )
    d6 = dt / 6.0
    qw += d6 * (qw1 + 2.0 * (qw2 + qw3) + qw4)
    qx += d6 * (qx1 + 2.0 * (qx2 + qx3) + qx4)
    qy += d6 * (qy1 + 2.0 * (qy2 + qy3) + qy4)
    qz += d6 * (qz1 + 2.0 * (qz2 + qz3) + qz4)
    n = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    ax = (ax1 + 2.0 * (ax2 + ax3) + ax4) / 6.0
    ay = (ay1 + 2.0 * (ay2 + ay3) + ay4) / 6.0
    az = (az1 + 2.0 * (az2 + az3) + az4) / 6.0
    # p(dt) = p + v dt + integral of (dt - s) a(s) ds; RK4's stage velocities give this:
    p2 = dt * d6
    new = (
        px + dt * vx + p2 * (ax1 + ax2 + ax3),
        py + dt * vy + p2 * (ay1 + ay2 + ay3),
        pz + dt * vz + p2 * (az1 + az2 + az3),
        qw * n,
        qx * n,
        qy * n,
        qz * n,
        vx + dt * ax,
        vy + dt * ay,
        vz + dt * az,
        wx + d6 * (wx1 + 2.0 * (wx2 + wx3) + wx4),
        wy + d6 * (wy1 + 2.0 * (wy2 + wy3) + wy4),
        wz + d6 * (wz1 + 2.0 * (wz2 + wz3) + wz4),
    )
    return new, (ax, ay, az)


def rigid_body_step_semi_implicit(
    state, thrust, moment, mass, inertia, dt, extra=NO_EXTRA
) -> tuple[tuple[float, ...], tuple[float, float, float]]:
    """One step of dt s of the reference's semi-implicit Euler body (SPEC §3 steps 4-6).

    From the state at the start of the step: a = R(q) (0, 0, -T)/m + g_N + extra; v += a dt;
    p += v_new dt; q = normalise(q + q (x) (0, w) dt / 2) with the body rate w of the start
    of the step; w += I^-1 (M - w x I w) dt. Returns (state_new: 13 floats, a_NB:
    (3,) m/s^2, NED). First order: 02 moves ~2 cm / 0.02 rad from RK4 (README "Fidelity").
    """
    px, py, pz, qw, qx, qy, qz, vx, vy, vz, wx, wy, wz = state
    qdw, qdx, qdy, qdz, wdx, wdy, wdz, ax, ay, az = _rates(
        qw, qx, qy, qz, wx, wy, wz, *_coefficients(thrust, moment, mass, inertia), extra
    )
    vx, vy, vz = vx + dt * ax, vy + dt * ay, vz + dt * az
    qw, qx, qy, qz = qw + dt * qdw, qx + dt * qdx, qy + dt * qdy, qz + dt * qdz
    n = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    new = (
        px + dt * vx,
        py + dt * vy,
        pz + dt * vz,
        qw * n,
        qx * n,
        qy * n,
        qz * n,
        vx,
        vy,
        vz,
        wx + dt * wdx,
        wy + dt * wdy,
        wz + dt * wdz,
    )
    return new, (ax, ay, az)


def apply_room_constraints(state_new, state_old, params) -> tuple[float, ...]:
    """State (13 floats) after the room limits of SPEC §3 step 7; inputs are not modified.

    params: PhysicsParams (x_bounds, y_bounds, z_bounds in m, NED). Sticky floor: when
    z >= z_max, p reverts to p_old with z = z_max, vx = vy = 0, vz = min(0, vz), w = 0.
    Then x or y outside its bounds reverts to its old value with zero velocity, and
    z < z_min reverts z with vz = 0.
    """
    px, py, pz, qw, qx, qy, qz, vx, vy, vz, wx, wy, wz = state_new
    z_min, z_max = params.z_bounds
    if pz >= z_max:
        px, py, pz = state_old[0], state_old[1], z_max
        vx = vy = 0.0
        vz = min(0.0, vz)
        wx = wy = wz = 0.0
    x_min, x_max = params.x_bounds
    if px < x_min or px > x_max:
        px, vx = state_old[0], 0.0
    y_min, y_max = params.y_bounds
    if py < y_min or py > y_max:
        py, vy = state_old[1], 0.0
    if pz < z_min:
        pz, vz = state_old[2], 0.0
    return (px, py, pz, qw, qx, qy, qz, vx, vy, vz, wx, wy, wz)


def on_floor(state, params) -> bool:
    """True when the vehicle rests on the (sticky) floor: z >= z_max (m, NED; the constraint
    sets z = z_max exactly). False for a non-finite z."""
    return state[2] >= params.z_bounds[1]


def outside_room(state, params) -> bool:
    """True when x or y is outside its bounds or z is above the ceiling (z < z_min), m, NED;
    :func:`apply_room_constraints` then stops the vehicle at that wall or the ceiling. False
    for non-finite coordinates, which the constraints leave alone too."""
    x_min, x_max = params.x_bounds
    y_min, y_max = params.y_bounds
    x, y = state[0], state[1]
    return x < x_min or x > x_max or y < y_min or y > y_max or state[2] < params.z_bounds[0]


def count_contacts(contacts, state, hit_wall, params) -> tuple[float, float, float]:
    """The contact counts (on the floor 1/0, floor touchdowns, wall hits) after a physics step.

    contacts: the counts before the step (3 floats, the same three); state: the state after it
    (13 floats, p_NB m NED); hit_wall: the step's ``hit_wall`` from :func:`plant_step`; params:
    PhysicsParams. A touchdown counts when the vehicle is :func:`on_floor` after the step and was
    not before (one that starts on the floor has not touched down); a wall hit when the step
    ended at a wall or the ceiling. Returns a tuple of 3 floats.
    """
    was_on_floor, touchdowns, wall_hits = contacts[0], contacts[1], contacts[2]
    floor = on_floor(state, params)
    if floor and not was_on_floor:
        touchdowns += 1.0
    if hit_wall:
        wall_hits += 1.0
    return (1.0 if floor else 0.0, touchdowns, wall_hits)


def plant_step(
    state, forces_old, commands, noise_unit, params, dt, fidelity=PHYSICAL, wind=NO_EXTRA
) -> tuple[tuple[float, ...], tuple[float, float, float], tuple[float, float, float, float], bool]:
    """One physics step of SPEC §3 (steps 1-8), with the drag of :func:`drag_acceleration` in
    the air moving at `wind` (3, m/s, NED), held over the step, when PhysicsParams has drag
    (:func:`has_drag`; without it the wind does not act and the step is the drag-free one).

    state: 13 floats; forces_old: lagged motor forces (4, N); commands: commanded motor
    forces (4, N); noise_unit: four uniforms in [0, 1]; params: PhysicsParams; fidelity: a
    :class:`~quad_drake.models.fidelity.Fidelity`, whose ``semi_implicit_euler`` picks the
    reference's body step over RK4 and whose ``float32_state`` rounds the new state to
    float32 (after a_NB is taken from the unrounded velocities).
    Returns (state_new, a_NB, forces, hit_wall): a_NB = (v_new - v_old)/dt (3, m/s^2, NED)
    after the room limits, i.e. the kinematic acceleration the IMU senses (zero on the
    floor); hit_wall: the step ended outside the room (a wall or the ceiling) and was
    stopped there (:func:`outside_room`; the floor is :func:`on_floor` of state_new).
    """
    targets = clamped_noisy_commands(
        commands, noise_unit, params.min_motor_thrust, params.max_motor_thrust, params.motor_noise
    )
    forces = motor_lag_step(forces_old, targets, dt, params.motor_tau_up, params.motor_tau_down)
    thrust, mx, my, mz = wrench_from_thrusts(forces, params.arm_length, params.kappa, params.com_offset)
    drag = drag_acceleration(state, wind, params) if has_drag(params) else NO_EXTRA
    moment = (mx, my, mz)
    if fidelity.semi_implicit_euler:
        new, _ = rigid_body_step_semi_implicit(state, thrust, moment, params.mass, params.inertia, dt, drag)
    else:
        new, _ = rigid_body_step(state, thrust, moment, params.mass, params.inertia, dt, drag)
    hit_wall = outside_room(new, params)
    new = apply_room_constraints(new, state, params)
    accel = ((new[7] - state[7]) / dt, (new[8] - state[8]) / dt, (new[9] - state[9]) / dt)
    if fidelity.float32_state:
        new = float32_rounded(new)
    return new, accel, forces, hit_wall


def float32_rounded(state) -> tuple[float, ...]:
    """The 13 floats of `state` each rounded to the nearest float32 (a tuple of floats)."""
    px, py, pz, qw, qx, qy, qz, vx, vy, vz, wx, wy, wz = state
    return (
        to_float32(px),
        to_float32(py),
        to_float32(pz),
        to_float32(qw),
        to_float32(qx),
        to_float32(qy),
        to_float32(qz),
        to_float32(vx),
        to_float32(vy),
        to_float32(vz),
        to_float32(wx),
        to_float32(wy),
        to_float32(wz),
    )


def to_float32(value) -> float:
    """`value` rounded to the nearest float32, as a float (float64: the inner cast keeps numba's
    compiled form, ``kernels.flight``, from typing it float32)."""
    return float(np.float64(np.float32(value)))
