"""Pure: estimator consistency statistics over logged arrays.

NEES_k = e_k^T P_k^-1 e_k over the states an estimator's vocabulary puts in its NEES, with
e = estimate - truth as the vocabulary computes it (``estimation/vocabulary.py``: EKF7 7 dof,
ESKF 9 navigation states); NIS = nu^T S^-1 nu of each fresh GPS (6 dof) or magnetometer
(1 dof) update, as the estimator reports it in its ``diagnostics`` log. For a consistent filter
each is chi^2(dof); the mean over M independent runs, times M, is chi^2(dof M), which gives the
95 % band of
:func:`chi2_band`. Also: the fleet sigma fraction of one multi-vehicle run and a binomial
confidence interval for pass rates.
"""

import functools
import math

import numpy as np
from scipy.stats import beta, chi2, t

from ..estimation.vocabulary import NIS_COLUMNS, NIS_DOF  # noqa: F401 (NIS_DOF re-exported)
from .evaluation import sigma_share
from .signals import stamp_fresh


def nees_of(vocabulary, logs, errors=None) -> np.ndarray:
    """(n,) NEES of one vehicle's logged run over the vocabulary's ``nees_states``.

    errors: the run's ``vocabulary.errors(logs)`` when the caller has them already.
    """
    errors = vocabulary.errors(logs) if errors is None else errors
    return _nees(errors, covariance_matrices(logs["covariance"]), vocabulary.nees_states)


def covariance_matrices(covariance_log) -> np.ndarray:
    """(n, k, k) covariances from an (n, k*k) row-major log ((n, N, k, k) from (n, N, k*k))."""
    covariance_log = np.asarray(covariance_log, dtype=float)
    k = math.isqrt(covariance_log.shape[-1])
    return covariance_log.reshape(covariance_log.shape[:-1] + (k, k))


def nees(errors, covariances) -> np.ndarray:
    """(n,) e_k^T P_k^-1 e_k of (n, k) errors and (n, k, k) covariances (or (n, N) of (n, N, k),
    (n, N, k, k)); NaN where e or P is not finite or P is singular (det P <= 0)."""
    errors = np.asarray(errors, dtype=float)
    return _nees(errors, covariances, range(errors.shape[-1]))


def _nees(errors, covariances, states):
    """:func:`nees` of errors[:, states] and covariances[:, states, states].

    A compiled loop over the samples solves each positive-definite P by Cholesky; the samples
    where that fails (P not positive definite, or not finite) take the general rule: NaN unless
    det P > 0 and e, P are finite, else e^T P^-1 e by LU.
    """
    shape = np.shape(errors)[:-1]
    errors = np.asarray(errors, dtype=float).reshape(-1, np.shape(errors)[-1])
    covariances = np.asarray(covariances, dtype=float)
    covariances = covariances.reshape((-1,) + covariances.shape[-2:])
    states = np.asarray(states, dtype=np.int64)
    result = _cholesky_nees_kernel()(errors, covariances, states)
    rest = np.isnan(result)
    if rest.any():
        e = errors[rest][:, states]
        P = covariances[rest][:, states[:, None], states[None, :]]
        ok = np.isfinite(e).all(axis=1) & np.isfinite(P).all(axis=(1, 2))
        ok[ok] &= np.linalg.det(P[ok]) > 0.0
        values = np.full(e.shape[0], np.nan)
        if ok.any():
            solved = np.linalg.solve(P[ok], e[ok][:, :, None])[:, :, 0]
            values[ok] = np.einsum("ij,ij->i", e[ok], solved)
        result[rest] = values
    return result.reshape(shape)


def _cholesky_nees(errors, covariances, states):
    """(n,) e^T P^-1 e = |L^-1 e|^2 with P = L L^T over `states`; NaN where the Cholesky
    factorisation fails or a value is not finite (compiled by numba: one sample at a time,
    its sub-matrix gathered once and factorised in place, lower triangle)."""
    n, k = errors.shape[0], states.shape[0]
    result = np.full(n, np.nan)
    L = np.empty((k, k))
    y = np.empty(k)
    for i in range(n):
        finite = 0.0  # x - x is 0 for a finite x and NaN otherwise: one branch-free pass
        for r in range(k):
            for c in range(k):
                x = covariances[i, states[r], states[c]]
                finite += x - x
                L[r, c] = x
            y[r] = errors[i, states[r]]
            finite += y[r] - y[r]
        if finite != 0.0:
            continue
        ok = True
        for r in range(k):
            for c in range(r + 1):
                s = L[r, c]
                for m in range(c):
                    s -= L[r, m] * L[c, m]
                if r == c:
                    if not s > 0.0:
                        ok = False
                        break
                    L[r, r] = math.sqrt(s)
                else:
                    L[r, c] = s / L[c, c]
            if not ok:
                break
        if not ok:
            continue
        total = 0.0
        for r in range(k):
            s = y[r]
            for m in range(r):
                s -= L[r, m] * y[m]
            y[r] = s / L[r, r]
            total += y[r] * y[r]
        result[i] = total
    return result


@functools.cache
def _cholesky_nees_kernel():
    """:func:`_cholesky_nees` compiled by numba (cached on disk), imported on first use only."""
    from quad_drake.kernels.jit import njit_cached

    return njit_cached(_cholesky_nees)


def normalized_squared_errors(errors, covariances) -> np.ndarray:
    """(n, k) e_i^2 / P_ii per state ((n, N, k) of a batch): 1 on average for a consistent filter."""
    variances = np.diagonal(np.asarray(covariances, dtype=float), axis1=-2, axis2=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.square(np.asarray(errors, dtype=float)) / variances


def fresh_nis(diagnostics, sensor) -> tuple[np.ndarray, np.ndarray]:
    """(stamps (s), nis) of the fresh updates of ``sensor`` ("gps" or "mag") in a diagnostics log.

    diagnostics: (n, DIAGNOSTICS_SIZE), layout ``vocabulary.DIAGNOSTICS``. An update is fresh
    on the first logged sample that shows its stamp (SPEC §0.2); updates
    faster than the log period are seen only once per log sample.
    """
    nis_column, stamp_column = NIS_COLUMNS[sensor]
    diagnostics = np.asarray(diagnostics, dtype=float)
    fresh = stamp_fresh(diagnostics[:, stamp_column])
    return diagnostics[fresh, stamp_column], diagnostics[fresh, nis_column]


def chi2_band(dof, count, probability=0.95) -> tuple[float, float]:
    """(low, high): central `probability` interval of the mean of `count` chi^2(dof) variables."""
    if dof < 1 or count < 1:
        raise ValueError(f"chi2_band: dof and count must be >= 1, got {dof}, {count}")
    tail = (1.0 - probability) / 2.0
    low, high = chi2.ppf([tail, 1.0 - tail], dof * count) / count
    return float(low), float(high)


COVARIANCE_TOLERANCE = 1.5
"""Campaign consistency criterion: the filter's average NEES (or NIS) per degree of freedom
must be compatible with the interval [1 / COVARIANCE_TOLERANCE, COVARIANCE_TOLERANCE], i.e. the
covariance the filter reports is within a factor 1.5 of its actual error covariance on average
(its sigmas within about 22 %). A filter off by a factor 2 fails it in 400 runs; a consistent
one passes at 20 and at 400 (tests/test_consistency.py)."""


def per_dof_interval(run_means, dof, confidence=0.95) -> tuple[float, float, float]:
    """(mean, low, high) of the average statistic per degree of freedom over realisations.

    run_means: each realisation's (run's, vehicle's) time mean of its NEES or NIS: independent
    across runs (distinct seeds), unlike the samples of one run, so Student's t interval of
    their mean (``scipy.stats.t``) holds whatever the time correlation within a run. A
    non-finite realisation (a diverged run) makes all three NaN; one realisation gives the
    interval (0, inf): it cannot bound the mean.
    """
    values = np.asarray(run_means, dtype=float) / dof
    if values.size == 0 or not np.isfinite(values).all():
        return math.nan, math.nan, math.nan
    mean = float(np.mean(values))
    if values.size < 2:
        return mean, 0.0, math.inf
    sem = float(np.std(values, ddof=1) / math.sqrt(values.size))
    if sem == 0.0:
        return mean, mean, mean
    low, high = t.interval(confidence, values.size - 1, loc=mean, scale=sem)
    return mean, float(low), float(high)


def within_tolerance(interval, tolerance=COVARIANCE_TOLERANCE) -> bool:
    """True when the confidence interval (low, high) of the average statistic per dof meets
    [1 / tolerance, tolerance]: the runs do not show (at the interval's confidence) that the
    filter is off by more than `tolerance` in covariance. False for a NaN interval."""
    low, high = interval
    return bool(low <= tolerance and high >= 1.0 / tolerance)


def in_band_fraction(values, band) -> float:
    """Share of samples with low <= value <= high (a non-finite sample counts as outside)."""
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return math.nan
    low, high = band
    return float(np.mean((values >= low) & (values <= high)))


def binomial_interval(successes, trials, confidence=0.95) -> tuple[float, float]:
    """(low, high) Clopper-Pearson ("exact") interval of a success probability; fractions."""
    if trials < 1 or not 0 <= successes <= trials:
        raise ValueError(
            f"binomial_interval: need 0 <= successes <= trials, trials >= 1; got {successes}/{trials}"
        )
    tail = (1.0 - confidence) / 2.0
    low = 0.0 if successes == 0 else float(beta.ppf(tail, successes, trials - successes + 1))
    high = 1.0 if successes == trials else float(beta.ppf(1.0 - tail, successes + 1, trials - successes))
    return low, high


def fleet_samples(signals, error_suffix, sigma_suffix) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(errors, sigmas): per vehicle V with a ``V.<error_suffix>`` signal (e.g. ``Est.E.X``), the
    fresh samples of that error and of its own ``V.<sigma_suffix>`` (e.g. ``Est.S.X``).

    signals: {name: Signal}. Raises ValueError when no vehicle has the error signal or a
    sigma signal is missing.
    """
    tail = "." + error_suffix
    vehicles = sorted(name[: -len(tail)] for name in signals if name.endswith(tail))
    if not vehicles:
        raise ValueError(f"fleet_samples: no signal ends with {tail!r}")
    errors, sigmas = [], []
    for vehicle in vehicles:
        error = signals[vehicle + tail]
        sigma_name = f"{vehicle}.{sigma_suffix}"
        if sigma_name not in signals:
            raise ValueError(f"fleet_samples: no signal {sigma_name!r}")
        errors.append(error.values[error.fresh])
        sigmas.append(signals[sigma_name].values[error.fresh])
    return errors, sigmas


def fleet_sigma_fraction(signals, error_suffix, sigma_suffix, multiple) -> float:
    """Share of (vehicle, fresh sample) pairs with |error| <= multiple * sigma, in [0, 1]
    (NaN without samples), over the vehicles of :func:`fleet_samples`.

    For a consistent Gaussian estimate the share is 0.683 at 1 sigma and 0.954 at 2 sigma.
    """
    inside, total = sigma_share(*fleet_samples(signals, error_suffix, sigma_suffix), multiple)
    return inside / total if total else math.nan
