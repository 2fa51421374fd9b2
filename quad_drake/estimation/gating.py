"""Pure: chi-squared innovation gates, reset to the GPS after continuous rejection, covariance health.

Shared by every estimator (7-state EKF, error-state EKF) and by fault-injection scenarios.

Gate (PX4 EKF2 / ArduPilot EKF3 practice): a measurement with innovation nu and innovation
covariance S has the normalised innovation squared ``nis = nu^T S^-1 nu``, chi^2(m) for a
consistent filter (m = len(nu)). A gate of ``g`` sigma accepts the sample when
``nis <= threshold``, where the threshold has the same false-alarm probability as a scalar
|nu| <= g sqrt(S) test: ``P_fa = erfc(g / sqrt 2)`` (5.7e-7 at 5 sigma), ``threshold =
chi2.ppf(1 - P_fa, m)``. The *test ratio* nis / threshold is above 1 for a rejected sample,
as PX4's ``*_test_ratio``. ``g = 0`` turns the gate off (threshold = inf).

Reset: after ``timeout`` s of continuous rejection of one sensor (no accepted sample in
between) the filter re-initialises the states that sensor measures to the measurement,
with the measurement's covariance and no cross-covariance (ArduPilot's reset to GPS after
its retry time). ``timeout = 0`` never resets.

Covariance health (PX4 ``fixCovarianceErrors``): P must be finite, symmetric and positive
semi-definite. :func:`repaired_covariance` symmetrises, clips negative eigenvalues to zero,
and replaces a non-finite P by a fallback (the initial covariance); it says what it did.
"""

import math

import numpy as np

COVARIANCE_OK, COVARIANCE_REPAIRED, COVARIANCE_RESET = 0, 1, 2
"""Outcomes of :func:`repaired_covariance`: untouched, eigenvalues clipped, replaced by the fallback."""


def false_alarm_probability(gate_sigma):
    """Probability that a consistent sample fails a ``gate_sigma`` gate (any dof); 0 when the gate is off."""
    if gate_sigma <= 0.0:
        return 0.0
    return math.erfc(gate_sigma / math.sqrt(2.0))


def gate_threshold(dof, gate_sigma):
    """NIS threshold of a ``gate_sigma`` gate on a ``dof``-dimensional innovation (inf when off)."""
    if dof < 1:
        raise ValueError(f"gate_threshold: dof must be >= 1, got {dof}")
    if gate_sigma <= 0.0:
        return math.inf
    from scipy.special import chdtri  # = scipy.stats.chi2.isf; imported here: scipy.stats costs ~1 s

    return float(chdtri(dof, false_alarm_probability(gate_sigma)))


def gate_ratio(nis, threshold):
    """nis / threshold: above 1 rejects the sample (0 when the gate is off, NaN for a NaN nis)."""
    return nis / threshold


def gate_accepts(nis, threshold):
    """True when a finite ``nis`` passes the gate; a NaN nis (no update possible) is not accepted."""
    return nis <= threshold


def rejection_start(previous_start, accepted, stamp):
    """Time (s) the current run of consecutive rejections began: NaN after an accepted sample.

    previous_start: the value returned for the previous sample (NaN if none rejected);
    stamp: this sample's measurement time, s.
    """
    if accepted:
        return math.nan
    return stamp if math.isnan(previous_start) else previous_start


def reset_due(start, stamp, timeout):
    """True when the sensor has been rejected continuously since ``start`` for >= ``timeout`` s (> 0)."""
    return timeout > 0.0 and not math.isnan(start) and stamp - start >= timeout


def reset_states(x, P, indices, values, covariance):
    """(x, P) with x[indices] = values, P[indices, indices] = covariance and zero cross-covariance.

    x: state (n); P: (n, n); indices: the m reset states; values (m); covariance (m, m).
    Returns new arrays.
    """
    x = np.array(x, dtype=float)
    P = np.array(P, dtype=float)
    idx = np.asarray(indices)
    x[idx] = values
    P[idx, :] = 0.0
    P[:, idx] = 0.0
    P[np.ix_(idx, idx)] = covariance
    return x, P


def covariance_looks_healthy(P):
    """Cheap per-step check: every entry finite and every variance >= 0 (not a full PSD test)."""
    return math.isfinite(float(P.sum())) and float(P.diagonal().min()) >= 0.0


def repaired_covariance(P, fallback):
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
