"""Pure: chi-squared innovation gates, the GPS gate-and-reset policy, covariance health.

Shared by every estimator (7-state EKF, error-state EKF, for one vehicle or a fleet: the GPS
policy is written for M vehicles at once, M = 1 for a single run) and by fault scenarios.

Gate (PX4 EKF2 / ArduPilot EKF3 practice): a measurement with innovation nu and innovation
covariance S has the normalised innovation squared ``nis = nu^T S^-1 nu``, chi^2(m) for a
consistent filter (m = len(nu)). A gate of ``g`` sigma accepts the sample when
``nis <= threshold``, where the threshold has the same false-alarm probability as a scalar
|nu| <= g sqrt(S) test: ``P_fa = erfc(g / sqrt 2)`` (5.7e-7 at 5 sigma), ``threshold =
chi2.ppf(1 - P_fa, m)``. The *test ratio* nis / threshold is above 1 for a rejected sample,
as PX4's ``*_test_ratio``. ``g = 0`` turns the gate off (threshold = inf).

GPS policy (:class:`GpsGates`, :func:`gps_gate_decisions`). A GPS sample (p_N, v_N) is gated
in three groups, each against the marginal of its own innovation: the horizontal position
(2 dof), the height (1 dof) and the velocity (3 dof), as PX4 gates GNSS position, height and
velocity apart (``EKF2_GPS_P_GATE``, ``EKF2_GPS_V_GATE``). The groups that pass are fused; a
wrong velocity never makes the filter refuse a good position. A group rejected for its own
``reset_timeouts`` s in a row (no accepted sample in between) is reset to the sample: a
consistent filter rejects a 5-sigma sample with probability 5.7e-7, so a run of rejections is
the filter, not the sensor, once it outlasts the glitches the timeout is sized for (velocity
0.5 s and height 1 s by default: a vehicle 1 m above the floor cannot fly longer on a height or
velocity it cannot check; the horizontal position waits 5 s, longer than a multipath step).
After ``regain_time`` s without a finite GPS sample (an outage) the returning sample is never
gated: each group is fused if its gate accepts it and reset to it otherwise (PX4's reset to
GNSS on regained aiding). Where the GPS is the height reference (PX4's ``EKF2_HGT_REF`` GNSS;
the estimator's ``gps_height_restart``) a sample that comes more than :data:`GPS_HEIGHT_TIMEOUT`
after the previous finite one resets the height to it whether its gate accepts it or not: PX4
stops fusing the GNSS height when its samples stop and restarts it at the next with a height
reset. A reset sets the group's states to the measurement with the measurement's covariance and
no cross-covariance (ArduPilot's reset to GPS); a reset group is not fused.

Covariance health (PX4 ``fixCovarianceErrors``): P must be finite, symmetric and positive
semi-definite. :func:`repaired_covariance` symmetrises, clips negative eigenvalues to zero,
and replaces a non-finite P by a fallback (the initial covariance); it says what it did.
"""

import math
from dataclasses import dataclass

import numpy as np

from quad_drake.conventions import PX4_UPDATE_PERIOD

COVARIANCE_OK, COVARIANCE_REPAIRED, COVARIANCE_RESET = 0, 1, 2
"""Outcomes of :func:`repaired_covariance`: untouched, eigenvalues clipped, replaced by the fallback."""

GPS_GROUPS = ("horizontal", "height", "velocity")
"""The GPS groups gated, fused and reset apart (:class:`GpsGates`)."""
GPS_GROUP_COMPONENTS = ((0, 1), (2,), (3, 4, 5))
"""Indices into a GPS sample (p_N m, v_N m/s) of each group of GPS_GROUPS."""
GPS_LAST_SAMPLE = 0
GPS_REJECTED_SINCE = slice(1, 1 + len(GPS_GROUPS))
GPS_NIS_MEAN = slice(1 + len(GPS_GROUPS), 1 + 2 * len(GPS_GROUPS))
GPS_BOOK_SIZE = 1 + 2 * len(GPS_GROUPS)
"""Columns of a filter's GPS book (:func:`gps_gate_decisions`)."""
STAMP_TOLERANCE = 1e-9
"""s: stamps are sums of sensor periods, so 0.5 s of 10 Hz samples may read 0.49999999999999994."""
GPS_HEIGHT_TIMEOUT = 1.0
"""s without a GPS sample after which PX4 EKF2 stops fusing the GNSS height, and restarts it at
the next sample with a reset of the height to it where the GNSS is its height reference
(``EKF2_HGT_REF`` 1): PX4-Autopilot ``src/modules/ekf2/EKF/aid_sources/gnss/gnss_height_control.cpp``,
``controlGnssHeightFusion`` ("stopping GNSS height fusion, no data" after 2 ``GNSS_MAX_INTERVAL``,
0.5 s in ``common.h``; "starting GNSS height fusion, resetting height"). PX4 tests it once per
filter update (``conventions.PX4_UPDATE_PERIOD``, 10 ms), so a sample less than one update late was never
missed: :func:`height_restarts` restarts after gaps longer than the sum (a 1 Hz receiver's
1.000-1.008 s spacing restarts nothing; on x500v2_v6xrt PX4's height reset counter steps at the
fixes after its longer gaps)."""


def false_alarm_probability(gate_sigma) -> float:
    """Probability that a consistent sample fails a ``gate_sigma`` gate (any dof); 0 when the gate is off."""
    if gate_sigma <= 0.0:
        return 0.0
    return math.erfc(gate_sigma / math.sqrt(2.0))


def gate_threshold(dof, gate_sigma) -> float:
    """NIS threshold of a ``gate_sigma`` gate on a ``dof``-dimensional innovation (inf when off)."""
    if dof < 1:
        raise ValueError(f"gate_threshold: dof must be >= 1, got {dof}")
    if gate_sigma <= 0.0:
        return math.inf
    from scipy.special import chdtri  # = scipy.stats.chi2.isf; imported here: scipy.stats costs ~1 s

    return float(chdtri(dof, false_alarm_probability(gate_sigma)))


@dataclass(frozen=True)
class GpsGates:
    """The GPS gate-and-reset policy of one estimator (see the module docstring).

    thresholds: NIS threshold per GPS group (inf: that gate is off); reset_timeouts: s of
    continuous rejection after which a group is reset (0: never); regain_time: s without a
    finite GPS sample after which the returning sample is fused or reset, never gated (0: off);
    consistency_weight: the weight of each accepted sample in a group's running mean of NIS/dof,
    which widens that group's gate where it is above 1 (0: fixed gates).
    """

    thresholds: tuple
    reset_timeouts: tuple
    regain_time: float
    consistency_weight: float = 0.0

    @classmethod
    def from_params(cls, params, enabled=True) -> "GpsGates":
        """The policy of an estimator's parameters (``gps_gate_sigma``, ``gps_reset_timeout``
        (horizontal position), ``gps_height_reset_timeout``, ``gps_vel_reset_timeout``,
        ``gps_regain_time``, ``gps_gate_adaptation``); ``enabled=False``: no gates and no resets
        (the reference's EKF)."""
        if not enabled:
            return cls((math.inf,) * len(GPS_GROUPS), (0.0,) * len(GPS_GROUPS), 0.0)
        return cls(
            tuple(gate_threshold(len(c), params.gps_gate_sigma) for c in GPS_GROUP_COMPONENTS),
            (
                float(params.gps_reset_timeout),
                float(params.gps_height_reset_timeout),
                float(params.gps_vel_reset_timeout),
            ),
            float(params.gps_regain_time),
            float(params.gps_gate_adaptation),
        )


def innovation_nis(nu, S) -> np.ndarray:
    """(M,) nu^T S^-1 nu of innovations nu (M, m) with covariances S (M, m, m)."""
    return np.einsum("ij,ij->i", nu, np.linalg.solve(S, nu[..., None])[..., 0])


def gps_group_nis(nu, S) -> np.ndarray:
    """(M, 3) NIS of each GPS group (GPS_GROUPS) of the innovations nu (M, 6) with covariance S
    (M, 6, 6): each group against its own marginal block of S."""
    out = np.empty((len(nu), len(GPS_GROUPS)))
    for g, components in enumerate(GPS_GROUP_COMPONENTS):
        idx = np.asarray(components)
        out[:, g] = innovation_nis(nu[:, idx], S[:, idx[:, None], idx[None, :]])
    return out


def height_restarts(stamps, book, height_reference) -> np.ndarray:
    """(M,) bool: the M finite GPS samples at which PX4 restarts its GNSS height fusion with a reset
    of the height to the sample: the filter's GPS is its height reference (height_reference (M,)
    bool, ``gps_height_restart``) and the sample comes more than GPS_HEIGHT_TIMEOUT +
    PX4_UPDATE_PERIOD s after the filter's previous one (its book's, as :func:`gps_gate_decisions`
    reads it, before that call books this sample): PX4 tests the timeout once per 10 ms filter
    update, so a 1 Hz receiver's 1.000-1.008 s spacing restarts nothing (:data:`GPS_HEIGHT_TIMEOUT`).
    The first sample after the start is one (PX4 starts its GNSS height fusion with a reset)."""
    gap = np.asarray(stamps, dtype=float) - book[:, GPS_LAST_SAMPLE]
    return np.asarray(height_reference, dtype=bool) & (gap > GPS_HEIGHT_TIMEOUT + PX4_UPDATE_PERIOD)


def gps_gate_decisions(group_nis, stamps, book, gates, restarted=None) -> tuple[np.ndarray, np.ndarray]:
    """What to do with M finite GPS samples: (accepted (M, 3), reset (M, 3)); updates book IN PLACE.

    group_nis (M, 3) from :func:`gps_group_nis` of the prior; stamps (M,) s, the samples'
    measurement times; book (M, GPS_BOOK_SIZE), per filter: the stamp of its previous finite GPS
    sample (s; its start time before the first), then per group when its current run of
    rejections began (s, NaN: none) and its running mean of NIS/dof over accepted samples
    (1 at the start); gates a :class:`GpsGates`; restarted (M,) bool or None (none): the samples
    at which the filter restarts its GPS height (:func:`height_restarts`), whose height is reset to
    them, accepted or not.

    A group passes when its NIS is within its threshold times max(1, running mean): a filter
    whose innovations have been consistently larger than its covariance says widens its own gate
    (never below the chi^2 gate), so an over-confident but working filter keeps fusing; the
    mean moves only with accepted samples, so outliers and steps that the gate rejects never
    widen it. A group is reset where ``reset`` (rejected after its timeout, rejected at a sample
    that ends an outage longer than regain_time, or the height at a restart), else fused where
    accepted, else kept.
    """
    stamps = np.asarray(stamps, dtype=float)[:, None]
    since, mean = book[:, GPS_REJECTED_SINCE], book[:, GPS_NIS_MEAN]
    dof = np.array([len(c) for c in GPS_GROUP_COMPONENTS], dtype=float)
    accepted = group_nis <= np.asarray(gates.thresholds) * np.maximum(mean, 1.0)
    since = np.where(accepted, math.nan, np.where(np.isnan(since), stamps, since))
    timeouts = np.asarray(gates.reset_timeouts)
    timed_out = (timeouts > 0.0) & (stamps - since >= timeouts - STAMP_TOLERANCE)  # False where since is NaN
    gap = stamps - book[:, GPS_LAST_SAMPLE : GPS_LAST_SAMPLE + 1]
    outage = (gates.regain_time > 0.0) & (gap > gates.regain_time)  # (M, 1)
    reset = ~accepted & (timed_out | outage)
    if restarted is not None:
        reset[:, GPS_GROUPS.index("height")] |= np.asarray(restarted, dtype=bool)
    since[reset] = math.nan
    weight = gates.consistency_weight
    book[:, GPS_NIS_MEAN] = np.where(accepted, (1.0 - weight) * mean + weight * group_nis / dof, mean)
    book[:, GPS_REJECTED_SINCE] = since
    book[:, GPS_LAST_SAMPLE] = stamps[:, 0]
    return accepted, reset


def initial_gps_book() -> np.ndarray:
    """A filter's GPS book (GPS_BOOK_SIZE) before its first sample (see :func:`gps_gate_decisions`):
    its start, t = 0, is its last aiding; no rejections; means 1."""
    book = np.empty(GPS_BOOK_SIZE)
    book[GPS_LAST_SAMPLE] = 0.0
    book[GPS_REJECTED_SINCE] = math.nan
    book[GPS_NIS_MEAN] = 1.0
    return book


def component_mask(groups) -> np.ndarray:
    """(M, 6) bool over a GPS sample's components of a per-group flag array (M, 3)."""
    mask = np.empty((len(groups), 6), dtype=bool)
    for g, components in enumerate(GPS_GROUP_COMPONENTS):
        mask[:, list(components)] = groups[:, g : g + 1]
    return mask


def reset_states(x, P, indices, values, covariance) -> tuple[np.ndarray, np.ndarray]:
    """(x', P') of M filters with x[:, indices] = values, that block of P = covariance and no
    cross-covariance with the other states (a reset to a measurement).

    x (M, n); P (M, n, n); indices: the m reset states; values (M, m); covariance (m, m), or
    (M, m, m): each filter's own.
    Returns new arrays.
    """
    x = np.array(x, dtype=float)
    P = np.array(P, dtype=float)
    idx = np.asarray(indices)
    x[:, idx] = values
    P[:, idx, :] = 0.0
    P[:, :, idx] = 0.0
    P[:, idx[:, None], idx[None, :]] = covariance
    return x, P


def covariance_looks_healthy(P) -> bool:
    """Cheap per-step check: every entry finite and every variance >= 0 (not a full PSD test).

    Plain loops over a square array, the code the compiled estimator kernels run per vehicle
    (``kernels/fusion.py``): the entries' sum, row by row, is finite unless one of them is not
    (or it overflows)."""
    total = 0.0
    for a in range(P.shape[0]):
        if not P[a, a] >= 0.0:
            return False
        for b in range(P.shape[1]):
            total += P[a, b]
    return math.isfinite(total)


def repaired_covariance(P, fallback) -> tuple[np.ndarray, int]:
    """(P', outcome): P made symmetric positive semi-definite, and which repair it took.

    A non-finite P becomes ``fallback`` (COVARIANCE_RESET); a P with a negative eigenvalue
    (beyond round-off, -1e-12 of the largest) gets those eigenvalues set to zero
    (COVARIANCE_REPAIRED); otherwise the symmetrised P is returned (COVARIANCE_OK).
    """
    P = np.asarray(P, dtype=float)
    if not np.isfinite(P).all():
        return np.array(fallback, dtype=float), COVARIANCE_RESET
    S = 0.5 * (P + P.T)
    eigenvalues, vectors = np.linalg.eigh(S)
    if eigenvalues[0] >= -1e-12 * max(abs(eigenvalues[-1]), 1e-300):
        return S, COVARIANCE_OK
    clipped = (vectors * np.maximum(eigenvalues, 0.0)) @ vectors.T
    return 0.5 * (clipped + clipped.T), COVARIANCE_REPAIRED
