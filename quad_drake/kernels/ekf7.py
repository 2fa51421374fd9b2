"""The 7-state EKF of N vehicles (SPEC §4), compiled: what ``systems.estimators.Ekf`` runs each tick.

State, per vehicle: x = (p_N (3, m), v_N (3, m/s), yaw (rad)), NED world N, FRD body B;
covariance P (7 x 7). Roll and pitch are not states: they come from the attitude filter
(``kernels/attitude.py``), whose yaw (the gyro-integrated posterior yaw of the last tick) also
replaces x[6] before each prediction.

Prediction over dt (one IMU sample f_B m/s^2, the specific force, held over the step), with
the attitude's trig (c, s of roll r, pitch p, yaw y; ``ekf.attitude_trig``):

    u       = Ry(p) Rx(r) f_B                      yaw-free rotation  (ekf.yaw_free_rotation_of)
    a_N     = Rz(y) u + (0, 0, g_z)                g_z = +9.81, or -9.81 for the reference's
                                                   accelerometer (ekf.gravity_z; specific_force_in_n)
    x'      = (p + v dt, v + a_N dt, y)            (ekf.state_after)
    G       = I7 + dt at (0..2, 3..5) + (dRz/dy u) dt at (3..4, 6)   (dRz/dy u has no z entry)
    P'      = sym(G P Gᵀ) + Q  [+ a aᵀ + b bᵀ on (v, yaw)]            sym(M) = (M + Mᵀ) / 2

Q = diag(q_std²) dt_imu (``ekf.process_noise``); the optional tilt-aware term adds the
attitude filter's predicted roll/pitch error mapped through d(a_N, yaw rate)/d(roll, pitch)
(``ekf.tilt_jacobian_of``, ``ekf.scaled_tilt_factors``, gains ``ekf.TiltNoise.gains`` of the
tick's time; (0, 0) = :data:`NO_TILT` switches it off).

Measurements (each fused in Joseph form, its NIS nu S⁻¹ nu gated by the caller's policy):

- magnetometer, z = yaw (rad):   h(x) = x[6],  H = e6ᵀ (1 x 7),  R = mag_yaw_std² (rad²);
  nu = wrap(z - x[6]) the short way round, S = P66 + R (``ekf.mag_innovation``),
  K = P[:, 6] / S, x' = x + K nu (yaw wrapped), P' = P - K P[6, :] - P[:, 6] Kᵀ + S K Kᵀ;
- GPS, z = (p_N m, v_N m/s):     h(x) = x[0:6], H = [I6 0] (6 x 7) or the rows of the groups
  the gates accept, R = diag(gps_pos_std², gps_vel_std²) (m², (m/s)²); the Joseph update of
  ``kernels/fusion.py`` (dx added to x).

The scalar formulas above are the pure functions' own code compiled by numba (``ekf.py``: they
exist once); the covariance products are hand-unrolled loops over G's and H's few nonzeros,
whose reference oracles are ``ekf.predict_with_yaw`` / ``ekf.predict_covariance``,
``ekf.mag_update`` and ``ekf.kalman_update`` (matrix form, tested to 1e-12 on seeded random
inputs in ``tests/test_estimator_kernels.py``; no simulation calls them, ``tests/test_oracles.py``).

Shapes: x (N, 7), P (N, 7, 7), attitude (N, 3) rad, f_B (N, 3), imu (N, 6), gps (N, 7: p, v,
stamp s), mag (N, 2: yaw rad, stamp s). A non-finite measurement leaves its vehicle's (x, P)
unchanged and gives NaN NIS. Pure: numba and numpy, no pydrake.
"""

import collections

import numpy as np

from quad_drake.estimation import ekf
from quad_drake.estimation.vocabulary import DIAG
from quad_drake.kernels import fusion, rotations
from quad_drake.kernels.fusion import (
    GPS_SLOT,
    fresh,
    fresh_mag,
    looks_healthy,
    mag_gate,
    mag_innovation,
)
from quad_drake.kernels.imu_hold import (
    IMU_FINITE,
    IMU_MISSING,
    bridge_imu_row,
    hold_weight,
    row_finite,
)
from quad_drake.kernels.jit import compiled, njit_cached

Model = collections.namedtuple("Model", ["dt", "Q", "gravity_z", "r_mag", "mag_threshold"])
"""The filter's constants: dt s (the predict step), Q (7, 7) per step, gravity_z m/s^2
(``ekf.gravity_z``), r_mag = R_mag[0, 0] rad^2, mag_threshold: the mag gate's NIS threshold."""
NO_TILT = (0.0, 0.0)
"""Tilt gains (velocity, yaw) that switch the tilt-aware Q off."""

_NONFINITE = DIAG["nonfinite_samples"]
_attitude_trig = compiled(ekf.attitude_trig)
_yaw_free_rotation = compiled(ekf.yaw_free_rotation_of)
_specific_force_in_n = compiled(ekf.specific_force_in_n)
_state_after = compiled(ekf.state_after)
_tilt_jacobian = compiled(ekf.tilt_jacobian_of)
_scaled_tilt_factors = compiled(ekf.scaled_tilt_factors)


# ----- prediction ----------------------------------------------------------------------------------


@njit_cached
def _predict_row(x, P, i, roll, pitch, yaw, f_B, dt, Q, gravity_z, GP, M):
    """Vehicle i's prediction IN PLACE on x, P (GP, M: 7x7 buffers). Returns the attitude's trig
    and u = (ux, uy, uz, rolled_z), which the tilt-aware Q reuses."""
    trig = _attitude_trig(roll, pitch, yaw)
    cr, sr, cp, sp = trig[0], trig[1], trig[2], trig[3]
    u = _yaw_free_rotation(cr, sr, cp, sp, f_B[0], f_B[1], f_B[2])
    rf, rf_yaw = _specific_force_in_n(trig, u)  # Rz u, dRz/dyaw u
    prior = (x[i, 0], x[i, 1], x[i, 2], x[i, 3], x[i, 4], x[i, 5], x[i, 6])
    posterior = _state_after(prior, (rf[0], rf[1], rf[2] + gravity_z), yaw, dt)
    for k in range(7):
        x[i, k] = posterior[k]
    g36, g46 = rf_yaw[0] * dt, rf_yaw[1] * dt  # G's yaw column; G[5, 6] = rf_yaw[2] dt = 0
    # GP = G P, then M = (G P) G^T, from G's nonzeros
    for c in range(7):
        for r in range(3):
            GP[r, c] = P[i, r, c] + dt * P[i, r + 3, c]
        GP[3, c] = P[i, 3, c] + g36 * P[i, 6, c]
        GP[4, c] = P[i, 4, c] + g46 * P[i, 6, c]
        GP[5, c] = P[i, 5, c]
        GP[6, c] = P[i, 6, c]
    for r in range(7):
        for c in range(3):
            M[r, c] = GP[r, c] + GP[r, c + 3] * dt
        M[r, 3] = GP[r, 3] + GP[r, 6] * g36
        M[r, 4] = GP[r, 4] + GP[r, 6] * g46
        M[r, 5] = GP[r, 5]
        M[r, 6] = GP[r, 6]
    for r in range(7):  # P' = sym(G P G^T) + Q
        for c in range(7):
            P[i, r, c] = (M[r, c] + M[c, r]) * 0.5 + Q[r, c]
    return trig, u


@njit_cached
def _add_tilt_noise(P, i, trig, u, wy, wz, gains):
    """P[i, 3:7, 3:7] += a a^T + b b^T of the tilt-aware Q (``ekf.tilt_noise_factors``; gains =
    ``ekf.tilt_gains``), from the prediction's trig and u and the body rates wy, wz rad/s."""
    a, b = _scaled_tilt_factors(_tilt_jacobian(trig, u, wy, wz), gains[0], gains[1])
    for r in range(4):
        for c in range(4):
            P[i, 3 + r, 3 + c] += a[r] * a[c] + b[r] * b[c]


@njit_cached
def _predict_rows(x, P, attitude, f_B, dt, Q, gravity_z):
    GP, M = np.empty((7, 7)), np.empty((7, 7))
    for i in range(x.shape[0]):
        force = (f_B[i, 0], f_B[i, 1], f_B[i, 2])
        _predict_row(x, P, i, attitude[i, 0], attitude[i, 1], attitude[i, 2], force, dt, Q, gravity_z, GP, M)


def predict_with_yaw(
    x, P, attitude, f_B, dt, Q, reference_accelerometer=False
) -> tuple[np.ndarray, np.ndarray]:
    """(x', P') of the EKF7's 500 Hz step (``ekf.predict_with_yaw`` per row): yaw <- attitude yaw, predict.

    x (N, 7); P (N, 7, 7); attitude (N, 3) roll, pitch, yaw rad; f_B (N, 3); Q (7, 7).
    """
    x, P = np.array(x, dtype=float), np.array(P, dtype=float)
    _predict_rows(x, P, attitude, f_B, float(dt), Q, ekf.gravity_z(reference_accelerometer))
    return x, P


# ----- magnetometer --------------------------------------------------------------------------------


@njit_cached
def _mag_update_row(x, P, i, nu, S, p6):
    """Vehicle i's magnetometer posterior IN PLACE: K = P[:, 6] / S, x += K nu (yaw wrapped),
    P -= K P[6, :] + P[:, 6] K^T - S K K^T; p6: a 7-buffer."""
    for a in range(7):
        p6[a] = P[i, a, 6]
    for a in range(7):
        Ka = p6[a] / S
        for b in range(7):
            Kb = p6[b] / S
            P[i, a, b] = P[i, a, b] - (Ka * p6[b] + Kb * p6[a]) + S * (Ka * Kb)
        x[i, a] = x[i, a] + Ka * nu
    x[i, 6] = rotations.wrap_to_pi(x[i, 6])


@njit_cached
def _mag_tick(x, P, mag, diagnostics, book, r, threshold):
    p6 = np.empty(7)
    for i in range(x.shape[0]):
        if fresh_mag(mag, book, diagnostics, i):
            nu, S = mag_innovation(mag[i, 0], x[i, 6], P[i, 6, 6], r)
            if mag_gate(diagnostics, i, nu * nu / S, mag[i, 1], threshold):
                _mag_update_row(x, P, i, nu, S, p6)


def mag_tick(filters, mag, R_mag, threshold) -> None:
    """The magnetometer step of one EKF7 tick IN PLACE on the ``fusion.Filters`` `filters`.

    mag (N, 2: yaw rad, stamp s). Fresh (changed stamp) samples are booked; non-finite ones
    counted; the others fused when the gate (NIS threshold) accepts them, else counted as gated.
    """
    f = filters
    _mag_tick(f.x, f.P, mag, f.diagnostics, f.book, float(R_mag[0, 0]), float(threshold))


def mag_update(x, P, yaw_meas, R_mag) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x', P', nis) after magnetometer yaws (N,) rad with R_mag (1, 1) (``ekf.mag_update`` per row):
    :func:`mag_tick` with every sample fresh and no gate (``fusion.mag_update``)."""
    return fusion.mag_update(mag_tick, x, P, yaw_meas, R_mag)


# ----- GPS -----------------------------------------------------------------------------------------


@njit_cached
def correct(x, P, dx, fused) -> None:
    """How the EKF7 applies a correction: x[i] += dx[i] IN PLACE for the fused vehicles (N,) bool,
    the yaw x[i, 6] wrapped to [-pi, pi) (``rotations.wrap_to_pi``); P is the update's own."""
    for i in range(x.shape[0]):
        if fused[i]:
            for k in range(x.shape[1]):
                x[i, k] += dx[i, k]
            x[i, 6] = rotations.wrap_to_pi(x[i, 6])


@njit_cached
def correct_gps(x, P, dx, fused) -> None:
    """The EKF7's GPS correction: :func:`correct` without the yaw wrap (the GPS moves the yaw only
    through the cross-covariance; the yaw is wrapped at its next magnetometer update and replaced
    by the attitude filter's at the next tick). Kept apart so the logs stay bit-identical to the
    update this seam replaced; wrapping here too would change them at the last bit."""
    for i in range(x.shape[0]):
        if fused[i]:
            for k in range(x.shape[1]):
                x[i, k] += dx[i, k]


def gps_update(x, P, gps_pv, R_gps, mask=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x', P', nis) after GPS samples gps_pv (N, 6: p m, v m/s) with R_gps (6, 6) (``ekf.gps_update``).

    mask (N, 6) bool, optional: the components each vehicle fuses (H = those rows of [I6 0]; a
    vehicle with none keeps (x, P) with NaN NIS); default all six. A singular innovation
    covariance raises LinAlgError, as the scalar update does (the running ``fusion.fuse_gps``
    keeps that vehicle's (x, P) instead).
    """
    x_new, P_new, nis, singular = fusion.gps_update(x, P, gps_pv, R_gps, correct_gps, mask)
    if singular:
        raise np.linalg.LinAlgError("Singular matrix")
    return x_new, P_new, nis


# ----- one tick ------------------------------------------------------------------------------------


@njit_cached
def tick(
    x, P, diagnostics, book, hold, attitude, imu, gps, mag,
    dt, Q, gravity_z, r_mag, mag_threshold, gains, healthy,
) -> bool:  # fmt: skip
    """The prediction and, on a quiet tick, the magnetometer step of one EKF7 tick IN PLACE
    (``systems.estimators.Ekf``), compiled as one call; True when the tick was quiet.

    x, P, diagnostics, book, hold: the ``fusion.Filters`` fields (x (N, 7), P (N, 7, 7), ...),
    updated; attitude (N, 3) roll, pitch, yaw rad (this tick's attitude filter), imu (N, 6: f_B
    m/s^2, w_B rad/s), gps (N, 7: p m, v m/s, stamp s), mag (N, 2: yaw rad, stamp s): the tick's
    samples; dt ... mag_threshold: the fields of the filter's :class:`Model` (``tick(*filters,
    attitude, imu, gps, mag, *model, gains, healthy)``: numba runs a loop over flat arguments
    about a third faster than over the fields of a namedtuple); gains: the tilt-aware Q's gains
    (velocity, yaw) of this tick (``ekf.TiltNoise.gains``; :data:`NO_TILT`: off); healthy (N,)
    bool: written with ``fusion.covariance_looks_healthy`` of the new P.

    Prediction (module docstring) with f_B = imu[:, 0:3]. A non-finite IMU sample counts in
    diagnostics and the vehicle dead-reckons on its running mean (``imu_hold``); a vehicle with
    no mean yet, or a non-finite attitude (also counted), is not predicted. A quiet tick is one
    where every P looks healthy and no vehicle has a fresh GPS sample (``fusion.fresh``): then
    the tick ends here with :func:`mag_tick`. Otherwise the caller runs the repair, the mag step
    and the measurement updates (``systems.updates.Fusion.fuse``).
    """
    GP, M = np.empty((7, 7)), np.empty((7, 7))
    weight = hold_weight(dt)
    quiet = True
    for i in range(x.shape[0]):
        status = bridge_imu_row(imu, hold, i, weight)
        attitude_finite = row_finite(attitude, i)
        if status != IMU_FINITE or not attitude_finite:
            diagnostics[i, _NONFINITE] += 1.0
        if status != IMU_MISSING and attitude_finite:
            s = imu if status == IMU_FINITE else hold  # the sample, or the running mean
            f_B = (s[i, 0], s[i, 1], s[i, 2])
            roll, pitch, yaw = attitude[i, 0], attitude[i, 1], attitude[i, 2]
            trig, u = _predict_row(x, P, i, roll, pitch, yaw, f_B, dt, Q, gravity_z, GP, M)
            if gains[0] > 0.0 or gains[1] > 0.0:
                _add_tilt_noise(P, i, trig, u, s[i, 4], s[i, 5], gains)  # w_B y, z
        healthy[i] = looks_healthy(P[i])
        if not healthy[i] or fresh(gps[i, 6], book[i, GPS_SLOT]):
            quiet = False
    if quiet:
        _mag_tick(x, P, mag, diagnostics, book, r_mag, mag_threshold)
    return quiet


# ----- the estimate in the ``state`` layout --------------------------------------------------------


@njit_cached
def _assembled_rows(attitude, ekf_state, body_rate, out):
    for i in range(attitude.shape[0]):
        q = rotations.quat_from_euler(attitude[i, 0], attitude[i, 1], ekf_state[i, 6])
        for k in range(3):  # entry by entry: a slice is a new array view per vehicle in numba
            out[i, k] = ekf_state[i, k]
            out[i, 7 + k] = ekf_state[i, 3 + k]
            out[i, 10 + k] = body_rate[i, k]
        for k in range(4):
            out[i, 3 + k] = q[k]


def estimated_state(attitude, ekf_state, body_rate, out=None) -> np.ndarray:
    """(N, 13) EKF7 estimates in the ``state`` layout (``systems.estimators.EstimatedStateAssembler``),
    written into `out` (an (N, 13) float array, e.g. a view of an output port) when given.

    p = x[0:3], q_NB = quat(roll, pitch, x[6]) wxyz, v = x[3:6], w = body rate; attitude (N, 3),
    ekf_state (N, 7), body_rate (N, 3).
    """
    if out is None:
        out = np.empty((attitude.shape[0], 13))
    _assembled_rows(attitude, ekf_state, body_rate, out)
    return out
