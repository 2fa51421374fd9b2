"""Measurement fusion shared by the EKF7 and ESKF kernels: freshness, the books, the mag gate, the
GPS Joseph update of any component subset, the gated GPS policy, covariance health and repair.

Every estimator's fusion works IN PLACE on its :class:`Filters` arrays (x (N, width), P (N, k,
k), diagnostics (N, DIAGNOSTICS_SIZE), book (N, BOOK_SIZE), hold (N, imu_hold.HOLD_SIZE)); the
GPS states are the first six of x (p m, v m/s, NED) in both estimators.

- GPS update (:func:`joseph_rows`): with H = the rows of [I6 0] a vehicle fuses (its ``mask``),
  nu = z - H x, S = H P H^T + R, K = P H^T S^-1, dx = K nu, P' = (I - K H) P (I - K H)^T + K R K^T
  symmetrised, nis = nu^T S^-1 nu; the estimator then adds dx (EKF7) or injects it (ESKF). A
  hand-unrolled Gaussian elimination (LAPACK's gesv result to rounding) whose reference oracles
  are ``estimation.ekf.kalman_update`` and ``estimation.eskf.joseph_update`` (matrix form,
  tested to 1e-12 in ``tests/test_estimator_kernels.py``).
- Gates: ``estimation.gating``'s GPS policy (numpy over the vehicles with a fresh sample) and the
  magnetometer's NIS gate (:func:`mag_gate`).
- Health: ``gating.covariance_looks_healthy``'s own code compiled per vehicle every tick; at a
  GPS sample the full check, ``gating.repaired_covariance``, behind a compiled Cholesky test.

Pure: numba and numpy, no pydrake.
"""

import collections
import math

import numpy as np

from quad_drake.conventions import NO_SAMPLE_STAMP
from quad_drake.estimation import baro, ekf, gating
from quad_drake.estimation.vocabulary import DIAG, DIAGNOSTICS_SIZE
from quad_drake.kernels import rotations
from quad_drake.kernels.jit import compiled, njit_cached

GPS_SLOT, MAG_SLOT = 0, 1
GPS_POLICY = slice(2, 2 + gating.GPS_BOOK_SIZE)
BOOK_SIZE = 2 + gating.GPS_BOOK_SIZE
"""Columns of an estimator's book (N, BOOK_SIZE): the last GPS and mag stamps seen (s;
freshness), then the GPS policy's book (``gating.gps_gate_decisions``)."""

NO_GPS_SAMPLE = np.array([0.0] * 6 + [NO_SAMPLE_STAMP])
NO_MAG_SAMPLE = np.array([0.0, NO_SAMPLE_STAMP])
"""One vehicle's GPS (p, v, stamp) and yaw magnetometer (yaw, stamp) input when it has none."""

Filters = collections.namedtuple("Filters", ["x", "P", "diagnostics", "book", "hold"])
"""An estimator's (N, ...) arrays that its tick updates IN PLACE (views of its discrete state)."""

_NONFINITE, _MAG_NIS, _MAG_GATED = DIAG["nonfinite_samples"], DIAG["mag_nis"], DIAG["mag_gated"]

mag_innovation = compiled(ekf.mag_innovation, wrap_to_pi=rotations.wrap_to_pi)
looks_healthy = compiled(gating.covariance_looks_healthy)


def initial_book() -> np.ndarray:
    """One vehicle's book before its first tick: no sample seen, the GPS policy's initial book."""
    return np.concatenate(([NO_SAMPLE_STAMP, NO_SAMPLE_STAMP], gating.initial_gps_book()))


# ----- freshness and the magnetometer gate ---------------------------------------------------------


@njit_cached
def fresh(stamps, seen) -> np.ndarray | bool:
    """True where a stamp (s) differs from the last one seen and is a sample (not NO_SAMPLE_STAMP):
    (N,) bool of stamps and seen (N,), or one bool of two floats (as the compiled kernels call it)."""
    return (stamps != seen) & (stamps != NO_SAMPLE_STAMP)


@njit_cached
def fresh_mag(mag, book, diagnostics, i) -> bool:
    """True when vehicle i has a fresh finite mag sample to fuse; books its stamp, counts a non-finite one."""
    stamp = mag[i, 1]
    if not fresh(stamp, book[i, MAG_SLOT]):
        return False
    book[i, MAG_SLOT] = stamp
    if not (math.isfinite(stamp) and math.isfinite(mag[i, 0])):
        diagnostics[i, _NONFINITE] += 1.0
        return False
    return True


@njit_cached
def mag_gate(diagnostics, i, nis, stamp, threshold) -> bool:
    """True when the gate accepts vehicle i's mag NIS; logs it and counts the gated and NaN ones."""
    if math.isnan(nis):
        diagnostics[i, _NONFINITE] += 1.0
        return False
    diagnostics[i, _MAG_NIS] = nis
    diagnostics[i, _MAG_NIS + 1] = stamp
    if nis <= threshold:
        return True
    diagnostics[i, _MAG_GATED] += 1.0
    return False


def mag_update(mag_tick, x, P, yaw_meas, R_mag) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x', P', nis) of one magnetometer yaw per vehicle, yaw_meas (N,) rad with R_mag (1, 1), fused
    by an estimator's ``mag_tick`` with every sample fresh and no gate: the batched form its scalar
    ``mag_update`` oracle is tested against. A non-finite yaw keeps (x, P) with NaN NIS."""
    x, P = np.array(x, dtype=float), np.array(P, dtype=float)
    count = x.shape[0]
    diagnostics = np.zeros((count, DIAGNOSTICS_SIZE))
    diagnostics[:, _MAG_NIS] = math.nan
    mag = np.column_stack((np.asarray(yaw_meas, dtype=float), np.zeros(count)))
    mag_tick(Filters(x, P, diagnostics, np.tile(initial_book(), (count, 1)), None), mag, R_mag, math.inf)
    return x, P, diagnostics[:, _MAG_NIS]


# ----- covariance health ---------------------------------------------------------------------------


@njit_cached
def _looks_healthy_rows(P):
    healthy = np.empty(P.shape[0], dtype=np.bool_)
    for i in range(P.shape[0]):
        healthy[i] = looks_healthy(P[i])
    return healthy


def covariance_looks_healthy(P) -> np.ndarray:
    """(N,) cheap per-tick check: all entries finite, variances >= 0 (``gating.covariance_looks_healthy``)."""
    return _looks_healthy_rows(P)


@njit_cached
def _symmetrise_checked(P, check):
    """For each checked vehicle with a finite P[i]: P[i] <- (P[i] + P[i]^T) / 2 IN PLACE. Returns (N,)
    True where the full check stays undecided: a non-finite P[i] (left as it is), or a symmetrised
    one without a Cholesky factor in floating point (a pivot <= 0).

    A successful factorisation bounds the smallest eigenvalue below by about -n^2 eps max(diag S),
    far inside ``gating.repaired_covariance``'s -1e-12 |largest| tolerance, so those matrices are
    COVARIANCE_OK without an eigendecomposition.
    """
    count, n = P.shape[0], P.shape[1]
    undecided = np.zeros(count, dtype=np.bool_)
    L = np.empty((n, n))
    for i in range(count):
        if not check[i]:
            continue
        finite = True
        for a in range(n):
            for b in range(n):
                finite = finite and math.isfinite(P[i, a, b])
        if not finite:
            undecided[i] = True
            continue
        for a in range(n):
            for b in range(a + 1):
                value = 0.5 * (P[i, a, b] + P[i, b, a])
                P[i, a, b] = P[i, b, a] = L[a, b] = value
        for k in range(n):
            pivot = L[k, k]
            for j in range(k):
                pivot -= L[k, j] * L[k, j]
            if not pivot > 0.0:
                undecided[i] = True
                break
            root = math.sqrt(pivot)
            L[k, k] = root
            for r in range(k + 1, n):
                value = L[r, k]
                for j in range(k):
                    value -= L[r, j] * L[k, j]
                L[r, k] = value / root
    return undecided


def repair_covariances(P, check, fallback) -> np.ndarray:
    """``gating.repaired_covariance`` IN PLACE on the vehicles flagged in check (N,); returns (N,) outcomes.

    P (N, n, n); fallback (n, n). The positive-definite ones (most) are only symmetrised (a
    compiled Cholesky test decides them); the others go through the scalar function itself
    (eigendecomposition), one by one. Unchecked vehicles: COVARIANCE_OK, P untouched.
    """
    outcomes = np.full(P.shape[0], gating.COVARIANCE_OK)
    for i in np.flatnonzero(_symmetrise_checked(P, np.asarray(check, dtype=bool))):
        P[i], outcomes[i] = gating.repaired_covariance(P[i], fallback)
    return outcomes


def repaired_covariance(P, fallback) -> tuple[np.ndarray, np.ndarray]:
    """(P', outcomes (M,)) of ``gating.repaired_covariance`` per row: symmetrised, clipped or reset."""
    P = np.array(P, dtype=float)
    return P, repair_covariances(P, np.ones(P.shape[0], dtype=bool), fallback)


# ----- GPS: the Joseph update of any component subset, the gated policy ----------------------------


@njit_cached
def _joseph_row(x, P, z, R, i, comps, m, P_out, dx, work):
    """The update of vehicle i with the m GPS components comps[:m] (indices into (p, v); H = those
    rows of [I6 0]) and its noise R[i] (6, 6): the correction into dx[i] and P' into P_out[i];
    returns (nis, singular). A
    singular S (an exactly zero pivot, as LAPACK's gesv) leaves them as they are.

    [K^T | S^-1 nu] = S^-1 [H P | nu] by Gaussian elimination with partial pivoting;
    P' = (I - K H) P (I - K H)^T + K R K^T symmetrised.
    """
    S, X, nu, K, T, KR = work
    n = P.shape[1]
    for a in range(m):  # nu = z - H x, S = H P H^T + R, X = [H P | nu]
        ca = comps[a]
        nu[a] = z[i, ca] - x[i, ca]
        for b in range(m):
            S[a, b] = P[i, ca, comps[b]] + R[i, ca, comps[b]]
        for c in range(n):
            X[a, c] = P[i, ca, c]
        X[a, n] = nu[a]
    for k in range(m):
        pivot, best = k, abs(S[k, k])
        for r in range(k + 1, m):
            if abs(S[r, k]) > best:
                pivot, best = r, abs(S[r, k])
        if best == 0.0:
            return math.nan, True
        if pivot != k:
            for c in range(m):
                S[k, c], S[pivot, c] = S[pivot, c], S[k, c]
            for c in range(n + 1):
                X[k, c], X[pivot, c] = X[pivot, c], X[k, c]
        for r in range(k + 1, m):
            f = S[r, k] / S[k, k]
            for c in range(k, m):
                S[r, c] -= f * S[k, c]
            for c in range(n + 1):
                X[r, c] -= f * X[k, c]
    for k in range(m - 1, -1, -1):
        for c in range(n + 1):
            value = X[k, c]
            for j in range(k + 1, m):
                value -= S[k, j] * X[j, c]
            X[k, c] = value / S[k, k]
    nis = 0.0
    for a in range(m):
        nis += nu[a] * X[a, n]
    for r in range(n):  # K = (S^-1 H P)^T, dx = K nu
        dx[i, r] = 0.0
        for k in range(m):
            K[r, k] = X[k, r]
            dx[i, r] += K[r, k] * nu[k]
    for r in range(n):  # T = (I - K H) P, KR = K R
        for c in range(n):
            value = P[i, r, c]
            for k in range(m):
                value -= K[r, k] * P[i, comps[k], c]
            T[r, c] = value
        for j in range(m):
            value = 0.0
            for k in range(m):
                value += K[r, k] * R[i, comps[k], comps[j]]
            KR[r, j] = value
    for r in range(n):  # P' = T (I - K H)^T + KR K^T
        for c in range(n):
            value = T[r, c]
            for k in range(m):
                value += KR[r, k] * K[c, k] - T[r, comps[k]] * K[c, k]
            P_out[i, r, c] = value
    for r in range(n):
        for c in range(r):
            value = (P_out[i, r, c] + P_out[i, c, r]) * 0.5
            P_out[i, r, c] = P_out[i, c, r] = value
    return nis, False


@njit_cached
def _joseph_rows(x, P, z, R, mask):
    n = P.shape[1]
    P_new, dx = P.copy(), np.zeros((x.shape[0], n))
    nis = np.full(x.shape[0], np.nan)
    work = (
        np.empty((6, 6)), np.empty((6, n + 1)), np.empty(6), np.empty((n, 6)), np.empty((n, n)),
        np.empty((n, 6)),
    )  # fmt: skip
    comps = np.empty(6, dtype=np.int64)
    fused = np.zeros(x.shape[0], dtype=np.bool_)
    singular = False
    for i in range(x.shape[0]):
        m = 0
        finite = True
        for a in range(6):
            if mask[i, a]:
                comps[m] = a
                m += 1
                finite = finite and math.isfinite(z[i, a])
        if m > 0 and finite:
            nis[i], skipped = _joseph_row(x, P, z, R, i, comps, m, P_new, dx, work)
            fused[i] = not skipped
            singular = singular or skipped
    return dx, P_new, nis, fused, singular


def joseph_rows(
    x, P, gps_pv, R_gps, mask=None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """(dx (N, n), P' (N, n, n), nis (N,), fused (N,) bool, singular) of GPS samples gps_pv (N, 6:
    p m, v m/s) with R_gps (6, 6; or (N, 6, 6), each vehicle's own) on x (N, width), P (N, n, n):
    the Joseph update of the module docstring.

    mask (N, 6) bool, optional: the components each vehicle fuses (default all six). A vehicle
    with none, a non-finite fused component or a singular S is not fused: P kept, dx = 0, NaN
    NIS; singular: True when any S was singular.
    """
    z = np.asarray(gps_pv, dtype=float)
    mask = np.ones((len(z), 6), dtype=bool) if mask is None else np.ascontiguousarray(mask, dtype=bool)
    R = np.ascontiguousarray(np.broadcast_to(np.asarray(R_gps, dtype=float), (len(z), 6, 6)))
    return _joseph_rows(x, P, z, R, mask)


def gps_update(x, P, gps_pv, R_gps, correct, mask=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(x', P', nis (N,), singular) of the Joseph update (:func:`joseph_rows`) of GPS samples gps_pv
    (N, 6) with R_gps (6, 6, or (N, 6, 6)) on x (N, width), P (N, n, n), the correction applied by the
    estimator's ``correct(x, P, dx, fused)`` (IN PLACE on the new arrays: added for the EKF7,
    injected for the ESKF). mask as :func:`joseph_rows`'; an unfused vehicle keeps (x, P)."""
    dx, P_new, nis, fused, singular = joseph_rows(x, P, gps_pv, R_gps, mask)
    x_new = np.array(x, dtype=float)
    correct(x_new, P_new, dx, fused)
    return x_new, P_new, nis, singular


GPS_HEIGHT_GROUP = gating.GPS_GROUPS.index("height")
"""The column of the GPS height in ``gating.gps_gate_decisions``' (M, 3) decisions."""


def fuse_gps(
    filters, gps, rows, correct, R, gates, height_withheld=None, height_restart=None, baro_bias=None
) -> np.ndarray:
    """Fuse the fresh GPS samples of the vehicles ``rows`` through the gates (``gating``'s GPS policy).

    filters: the estimator's :class:`Filters`, x, P, diagnostics and book updated IN PLACE for
    those rows; gps (N, 7) the samples (p m, v m/s, stamp s); rows: int indices (or a full slice)
    of the vehicles whose sample is fresh; correct(x, P, dx, fused): how the estimator applies a
    correction (``ekf7.correct``, ``eskf.correct``; :func:`gps_update`); R (6, 6), or (N, 6, 6):
    each vehicle's own; gates a ``gating.GpsGates``; height_withheld (N,) bool or None: the
    vehicles whose GPS height is neither fused nor reset to (it disagrees persistently with their
    barometer, ``BaroUpdate.withholds_gps_height``); height_restart (N,) bool or None: the vehicles
    whose GPS is their height reference (``gating.height_restarts``); baro_bias: the index in x
    of a baro bias the filter carries in its state, its error last in P (the ESKF's,
    ``eskf.BARO_BIAS_NOMINAL``), or None.

    Per vehicle: the stamp is booked; a non-finite stamp or sample counts a non-finite sample and
    keeps (x, P); otherwise the joint 6-dof NIS of the prior and the stamp are logged, the groups
    the gates accept and ``gating.gps_gate_decisions`` does not reset are fused in one update,
    and the groups it resets are set to the sample; ``gps_gated`` counts the samples with a
    rejected group, ``gps_resets`` those with a group reset to a sample its gate rejected (a filter
    that had lost the GPS), ``gps_height_restarts`` those at which the height restarted
    (``gating.height_restarts``; PX4's routine start of its GNSS height fusion). A height restart
    moves a baro bias in the state with the height (``baro.moved_bias``); a reset to a rejected
    height does not (``estimation/baro.py``).

    Returns (N,) each vehicle's height step dz (m, NED down) by a restart, NaN where its height was
    not restarted: what a baro bias outside the state must follow (``baro.moved_bias``).
    """
    x, P, diagnostics, book = filters.x, filters.P, filters.diagnostics, filters.book
    steps = np.full(x.shape[0], math.nan)
    s = gps[rows, 6]
    book[rows, GPS_SLOT] = s
    index = np.arange(x.shape[0])[rows]
    z_rows = gps[rows, 0:6]
    valid = np.isfinite(s) & np.isfinite(z_rows).all(axis=1)
    diagnostics[index[~valid], DIAG["nonfinite_samples"]] += 1.0
    if not valid.any():
        return steps
    index, s, z_rows = index[valid], s[valid], z_rows[valid]
    x_prior, P_prior = x[index], P[index]
    R = R if R.ndim == 2 else R[index]  # (6, 6) or (M, 6, 6): each fused vehicle's own
    nu = z_rows - x_prior[:, 0:6]
    S = P_prior[:, 0:6, 0:6] + R
    diagnostics[index, DIAG["gps_nis"]] = gating.innovation_nis(nu, S)
    diagnostics[index, DIAG["gps_stamp"]] = s
    policy_book = book[index, GPS_POLICY]
    restarted = (
        None if height_restart is None else gating.height_restarts(s, policy_book, height_restart[index])
    )
    accepted, reset = gating.gps_gate_decisions(gating.gps_group_nis(nu, S), s, policy_book, gates, restarted)
    book[index, GPS_POLICY] = policy_book
    if height_withheld is not None:
        withheld = height_withheld[index]
        accepted[withheld, GPS_HEIGHT_GROUP] = reset[withheld, GPS_HEIGHT_GROUP] = False
        if restarted is not None:
            restarted &= ~withheld
    diagnostics[index[~accepted.all(axis=1)], DIAG["gps_gated"]] += 1.0
    recovered = reset.copy()  # the resets of a filter that had lost the GPS: not the restarts
    if restarted is not None:
        recovered[restarted, GPS_HEIGHT_GROUP] &= ~accepted[restarted, GPS_HEIGHT_GROUP]
        diagnostics[index[restarted], DIAG["gps_height_restarts"]] += 1.0
    diagnostics[index[recovered.any(axis=1)], DIAG["gps_resets"]] += 1.0
    fused = gating.component_mask(accepted & ~reset)
    x_new, P_new, _, _ = gps_update(x_prior, P_prior, z_rows, R, correct, fused)
    for g, components in enumerate(gating.GPS_GROUP_COMPONENTS):
        due = reset[:, g]
        if due.any():
            idx = list(components)
            noise = R[np.ix_(idx, idx)] if R.ndim == 2 else R[due][:, idx][:, :, idx]
            values = z_rows[due][:, idx]
            moved = restarted & due if g == GPS_HEIGHT_GROUP and restarted is not None else None
            if moved is not None and moved.any():  # a restart moves the baro bias with the height (baro.py)
                step = z_rows[moved, idx[0]] - x_new[moved, baro.HEIGHT_INDEX]
                steps[index[moved]] = step
                if baro_bias is not None:  # the bias in the state
                    x_new[moved, baro_bias] = baro.moved_bias(x_new[moved, baro_bias], step)
            x_new[due], P_new[due] = gating.reset_states(x_new[due], P_new[due], idx, values, noise)
    x[index] = x_new
    P[index] = P_new
    return steps
