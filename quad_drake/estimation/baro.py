"""Pure: barometer fusion for both estimators (EKF7 and ESKF), and their baro bias.

Measurement (``sensor_models.baro_measurement``): the barometer reads the height h = -p_z + b
(m, up; p_z the NED down position, b the baro's bias: its datum offset plus a slow drift).
Both filters carry p_z at index :data:`HEIGHT_INDEX` of their state (EKF7: x = (p, v, yaw)) or
error state (ESKF: dx = (dp, dv, dtheta, ...)). They differ in where the bias lives.

**The ESKF: the bias is an error state** (its last entry, nominal x[16]; ``eskf.carries_baro_bias``),
as PX4's EKF2 carries its height-sensor offsets in its state:

    h(x) = -p_z + b,  H = -e_2 + e_(n-1) (1 x n),  R = height_std^2,
    nu = h - (-p_z + b_hat),  S = H P H^T + R = P22 - 2 P2b + Pbb + R,  b = P H^T = P[:, n-1] - P[:, 2],
    K = b / S,  dx = K nu,  P' = P - K b^T - b K^T + S K K^T  (Joseph form, scalar),
    NIS = nu^2 / S (chi^2, 1 dof)

(:func:`bias_state_innovation`, :func:`bias_state_correction`), then injected (``eskf.inject``:
the height correlates with the attitude, the IMU biases and the baro bias, so one sample corrects
them all). The bias takes its random walk in the prediction (Q = bias_walk_std^2 dt). The filter
learns it from its own GPS height updates, through the covariance of height and bias the baro
updates build: no separate filter, no double counting of the GPS, and the bias error, common to
every baro sample, is in P with its correlations, so the height's variance is honest without a
floor. During a GPS outage nothing observes the bias: its variance and the height's grow together.

- the first finite sample sets the datum (PX4 sets its baro offset on the first sample too):
  b = h + p_z against the filter's own height (:func:`bias_reset`), whose error is then
  dp_z - n: the bias's row and column in P take the height's and its variance P22 +
  height_std^2 (:func:`bias_state_reset`). The height is not moved: a datum hundreds of metres
  off (a pressure altitude above sea level) fused as a measurement would drag the height by
  P22 / S of it. ``bias_init`` and ``bias_init_std`` hold only until then;
- a baro sample rejected by its gate for ``reset_timeout`` s in a row (a pressure step: weather,
  a door, a gust on the static port) resets the bias the same way: the filter keeps its height
  and takes the baro back with its new offset.

**The EKF7: a scalar filter beside the estimator** (PX4's ``EKF/bias_estimator``, one
``BiasEstimator`` per height source that is not the reference): a 1-state Kalman filter in the
baro book whose estimate b_hat corrects each sample before the update of z = h - b_hat,
h(x) = -p_z, H = -e_2, R = height_std^2 (:func:`height_innovation`, :func:`height_correction`):

- the first finite sample is not fused: it sets the datum, b_meas = h + p_z of variance
  height_std^2 + P[2, 2] against the filter's own height (:func:`first_datum`). Where the prior
  describes the barometer (a simulated one, whose bias starts at ``BaroParams.bias`` within
  ``bias_init_std`` of ``bias_init``) b_meas is fused against it; where no prior knows the datum
  (``datum_from_first_sample``: a flight log's barometer reads a pressure altitude, hundreds of
  metres above sea level) b_meas is taken as it is, the ESKF's rule and PX4's: b = h + p_z,
  P_b = height_std^2 + P[2, 2] (:func:`bias_reset`). Fused against a 1 m prior with PX4's 3.5 m
  baro noise, a 300 m datum would move only 7 % of the way, and the baro would then be rejected
  by its gate for ``reset_timeout`` s until a reset set it;
- at every GPS sample stamped with the latest baro sample's time (20 ms and 100 ms periods are
  commensurate) it takes b_meas = h + z_gps of variance height_std^2 + gps_z_std^2, gated as the
  baro; between samples its variance P_b grows by the random walk (bias_walk_std^2 per s). It is
  fed by the GPS, never by the filter's baro-aided height, so it does not learn the baro from
  itself; during a GPS outage it is frozen (the bias is unobservable without an absolute height)
  and P_b grows;
- the bias error e_b = b - b_hat is common to every sample: fused one by one as independent, the
  samples would shrink P[2, 2] far below P_b (the cross-covariance the scalar filter drops). So
  after each fusion the height variance is floored at P_b (:func:`floored_height_variance`). The
  price, measured on 23's 10 s outage when the ESKF still fused this way (100 runs, seeds
  7000-7099): the height over-confident (e^2/P 1.26) and the vertical velocity conservative
  (0.78): the floor adds height uncertainty that no vertical velocity explains;
- a reset as the ESKF's, b = h + p_z, P_b = height_std^2 + P[2, 2].

**Both: a GPS height that disagrees with the barometer persistently is caught** sample by sample,
by Page's CUSUM test on the bias innovations h + z_gps - b_hat, of variance P_b + height_std^2 +
gps_z_std^2 (P_b the book's for the EKF7, the bias's diagonal entry of P for the ESKF):
(:func:`offset_log_likelihood`, :func:`accumulated_evidence`): each GPS height adds the
log-likelihood ratio of "the GPS height is off by +gps_check_offset m" (and, for the other side,
-gps_check_offset m) against "it is right", given the innovation's spread; a side's sum restarts
at 0 whenever it would go negative and, once it passes ``gps_check_threshold``
(:func:`gps_height_disagrees`), the GPS height feeds neither the bias nor the filter's height,
and the bias goes back to its value before the first sample of that run (the CUSUM's
change-point estimate: what the disagreeing samples taught it is undone). The bias is a slow
random walk (7 mm/sqrt(s)); a GPS height 3 m off for a minute is no bias change but a GPS error
(multipath, a wrong datum), and a bias that followed it would take the baro-held height, and the
vehicle 1 m above the floor, 3 m down with it. Single samples cannot show it to a gate (the GPS
height's 2 m noise puts 3 m inside any per-sample gate); their accumulated evidence does, in
0.9-2.7 s for 3 m. A side's sum is capped at twice the threshold, so a GPS height that comes
right again is trusted again within a few seconds. While it disagrees the filter does not fuse
the GPS height either, nor reset to it (``fusion.fuse_gps``): the barometer holds the height.
PX4 makes the same choice with the barometer as its height reference (``EKF2_HGT_REF``, the GNSS
height's offset then learnt by its own bias estimator), ArduPilot by taking its height from the
barometer (``EK3_SRC1_POSZ``) and correcting its origin's height with GNSS heights through a
per-sample innovation gate only. A baro bias reset (above) starts both sums again at 0.

The restore is the EKF7's alone: its scalar filter takes back its bias and its variance P_b (the
book's). The ESKF's bias is one entry of a joint state: the disagreeing GPS heights it fused moved
the height and the bias together, through their covariance, and shrank P, so moving the nominal
bias back alone would leave it where P and the height do not say it is (and a proper undo would
need a copy of the state and P from the start of each run). Nor is there much to undo: the ESKF
learns the bias from its GPS height updates slowly, through the covariance, and on the 3 m GPS
height step (100 runs, seeds 7000-7099) restoring the nominal bias with P kept changed the median
largest height error by under 1 mm (0.117 against 0.118 m). So when the check fires the ESKF
withholds the GPS height and restores nothing.

**Both: a GPS height restart moves the bias with the height** (``fusion.fuse_gps``,
``gating.height_restarts``; PX4's ``resetVerticalPositionTo`` / ``resetAltitudeTo`` in
``ekf_helper.cpp``: ``_baro_b_est.setBias(_baro_b_est.getBias() + delta_z)``): the height's step
dz (m, NED down) is added to the bias,
b' = b + dz (:func:`moved_bias`), so the baro innovation h - (-p_z + b) is what it was and the
barometer does not pull the height back to where the reset took it from (it would: with the GPS
height's variance in P22 the next baro samples carry most of their innovation into the height).
The bias's variance and (the ESKF's) its covariances with the states other than the height are
kept, as PX4 keeps its bias estimator's variance; the height's are the reset's
(``gating.reset_states``). The exact propagation of the ESKF's reset (e_z' = -n, e_b' = e_b - e_z
- n for the sample's error n: the bias's variance grows by the height's innovation variance) was
measured farther from PX4's vertical velocity on x500v2_v6xrt (vz 0.204 against 0.185 m/s RMS;
``docs/measurements/replay.md``), and the EKF7's b + dz with P_b + R likewise (0.742 against 0.598).
A reset to a GPS height the gate rejected (after its timeout, or at a regain) leaves the bias
where it is, unlike PX4, which moves it at every vertical reset: such a height is the suspect one
(a step, multipath), and the barometer, unmoved, is then the independent check that pulls the
height back or makes the GPS height withheld (:func:`gps_height_disagrees`), instead of
following a wrong GPS height into the floor.

Every function works on plain floats and on a covariance array P (n x n), so
``kernels/`` compile them as they are (the code here, not a copy).
"""

import math
from dataclasses import dataclass

import numpy as np

from quad_drake.config.fields import number

HEIGHT_INDEX = 2
"""Index of p_z (m, NED down) in the EKF7 state and in the ESKF error state."""

BIAS, BIAS_VAR, LAST_HEIGHT, LAST_STAMP, REJECTED_SINCE, GPS_STAMP, DATUM_SET = range(7)
EVIDENCE_HIGH, EVIDENCE_LOW, RUN_BIAS_HIGH, RUN_BIAS_LOW, RUN_BIAS_VAR_HIGH, RUN_BIAS_VAR_LOW = range(7, 13)
BARO_BOOK_SIZE = 13
"""Columns of a filter's baro book: bias estimate (m), its variance (m^2), the latest baro height
(m, NaN when it was not finite) and its stamp (s; -1 before the first), when its current run of
gate rejections began (s, NaN: none), the stamp of the last GPS sample seen (s, -1: none),
1 once a finite sample has set the datum (0 before); the GPS-height check's accumulated evidence
(log-likelihood ratio, :func:`accumulated_evidence`) that the bias innovations run high (the GPS
height below the barometer's) and low, and the bias (m) and its variance (m^2) before the first
sample of each side's current run (all 0 at first)."""


@dataclass
class BaroFusionParams:
    """What an estimator assumes of the barometer (fused only when the vehicle carries one)."""

    height_std: float = number(0.1, positive=True, noise_std=True)  # m per sample, white noise
    bias_init: float = number(0.0)  # m, the bias estimate at t = 0
    bias_init_std: float = number(1.0, positive=True, noise_std=True)  # m
    bias_walk_std: float = number(0.007, nonnegative=True, noise_std=True)  # m/sqrt(s), bias random walk
    gate_sigma: float = number(5.0, nonnegative=True)  # sigma; the baro height gate, 0 = off
    # s of rejected baro before a bias reset, 0 = never (1 s as the GPS height's: a vehicle 1 m above
    # the floor cannot fly long on a height it cannot check)
    reset_timeout: float = number(1.0, nonnegative=True)
    # m; the persistent GPS-height error the check is tuned to catch (the CUSUM's offset,
    # :func:`offset_log_likelihood`), 0 = off (the bias then follows a GPS height error)
    gps_check_offset: float = number(2.0, nonnegative=True)
    # the log-likelihood ratio at which the accumulated evidence declares the GPS height wrong
    # (14: with the default offset and a 2 m GPS height noise, Siegmund's approximation puts a
    # consistent GPS's two sums past it about once in 4e6 samples, some 100 h at 10 Hz)
    gps_check_threshold: float = number(14.0, positive=True)
    # true: the first finite sample sets the EKF7's bias, b = h + p_z (:func:`first_datum`; a flight
    # log's barometer, whose datum no prior knows); false: it is fused against bias_init ±
    # bias_init_std. The ESKF sets its datum from its first sample either way (module docstring)
    datum_from_first_sample: bool = False


def initial_book(params) -> np.ndarray:
    """A filter's baro book (BARO_BOOK_SIZE) before its first sample (see the module docstring)."""
    book = np.empty(BARO_BOOK_SIZE)
    book[BIAS], book[BIAS_VAR] = params.bias_init, params.bias_init_std**2
    book[LAST_HEIGHT], book[LAST_STAMP], book[REJECTED_SINCE] = math.nan, -1.0, math.nan
    book[GPS_STAMP], book[DATUM_SET] = -1.0, 0.0
    book[EVIDENCE_HIGH:] = 0.0
    return book


def predicted_height(p_z) -> float:
    """h(x) = -p_z: the height (m, up) of the NED down position p_z (m)."""
    return -p_z


def height_jacobian(n) -> np.ndarray:
    """H (1 x n) of :func:`predicted_height` against a state or error state of size n: -1 at HEIGHT_INDEX."""
    H = np.zeros((1, n))
    H[0, HEIGHT_INDEX] = -1.0
    return H


def height_innovation(p_z, P, height, bias, R) -> tuple[float, float]:
    """(nu (m), S (m^2)) of a baro height (m) against the filter's p_z (m, NED) and P (n x n):
    nu = (height - bias) - (-p_z), S = P[2, 2] + R; R (m^2): height_std^2 (module docstring)."""
    return height - bias + p_z, P[HEIGHT_INDEX, HEIGHT_INDEX] + R


def scalar_correction(P, index, sign, nu, S) -> tuple[np.ndarray, np.ndarray, float]:
    """(dx (n,), P' (n x n), nis) of a scalar measurement with H = sign * e_index (1 x n), innovation
    nu and innovation variance S = P[index, index] + R (:func:`joseph_scalar` with b = P H^T =
    sign * P[:, index]). Loops over the entries (numba compiles it; numpy runs it as well)."""
    n = P.shape[0]
    b = np.empty(n)
    for i in range(n):
        b[i] = sign * P[i, index]
    return joseph_scalar(P, b, nu, S)


def joseph_scalar(P, b, nu, S) -> tuple[np.ndarray, np.ndarray, float]:
    """(dx (n,), P' (n x n), nis) of a scalar measurement of H (1 x n) given b = P H^T (n,), its
    innovation nu and innovation variance S = H b + R: K = b / S, dx = K nu,
    P' = P - K b^T - b K^T + S K K^T (Joseph form), nis = nu^2 / S."""
    n = P.shape[0]
    dx = np.empty(n)
    k = np.empty(n)
    P_new = np.empty((n, n))
    for i in range(n):
        k[i] = b[i] / S
        dx[i] = k[i] * nu
    for i in range(n):
        for j in range(n):
            P_new[i, j] = P[i, j] - k[i] * b[j] - b[i] * k[j] + S * k[i] * k[j]
    return dx, P_new, nu * nu / S


def height_correction(P, nu, S) -> tuple[np.ndarray, np.ndarray, float]:
    """(dx (n,), P' (n x n), nis): the scalar Joseph update of H = -e_2 (module docstring) with
    innovation nu (m) and innovation variance S (m^2) from :func:`height_innovation`
    (:func:`scalar_correction`)."""
    return scalar_correction(P, HEIGHT_INDEX, -1.0, nu, S)


def bias_state_innovation(p_z, bias, P, height, R) -> tuple[float, float]:
    """(nu (m), S (m^2)) of a baro height (m, up) against a filter that carries the baro bias in
    its error state, last (the ESKF's, ``eskf.carries_baro_bias``), P (n x n): h(x) = -p_z + b,
    H = -e_2 + e_(n-1), nu = height - (-p_z + bias), S = P22 - 2 P2b + Pbb + R (R = height_std^2:
    the bias's uncertainty is in P, with its correlation with the height)."""
    last = P.shape[0] - 1
    S = P[HEIGHT_INDEX, HEIGHT_INDEX] - 2.0 * P[HEIGHT_INDEX, last] + P[last, last] + R
    return height + p_z - bias, S


def bias_state_correction(P, nu, S) -> tuple[np.ndarray, np.ndarray, float]:
    """(dx (n,), P' (n x n), nis): the Joseph update of H = -e_2 + e_(n-1) (the baro bias last,
    :func:`bias_state_innovation`) with innovation nu (m) and innovation variance S (m^2):
    :func:`joseph_scalar` with b = P H^T = P[:, n-1] - P[:, 2]."""
    n = P.shape[0]
    b = np.empty(n)
    for i in range(n):
        b[i] = P[i, n - 1] - P[i, HEIGHT_INDEX]
    return joseph_scalar(P, b, nu, S)


def bias_state_reset(P, height_var) -> np.ndarray:
    """P' (n x n) of a filter that carries the baro bias last after its bias is reset to a baro
    height against the filter's own height, b = h + p_z (:func:`bias_reset`): the bias error is
    then e_b = dp_z - n_baro, so its row and column take the height's (Cov(e_b, dx) = P[2, :])
    and its variance P22 + height_var (m^2): the old bias's information is dropped, the height's
    kept."""
    n = P.shape[0]
    last = n - 1
    P_new = P.copy()
    for j in range(n):
        P_new[last, j] = P[HEIGHT_INDEX, j]
        P_new[j, last] = P[HEIGHT_INDEX, j]
    P_new[last, last] = P[HEIGHT_INDEX, HEIGHT_INDEX] + height_var
    return P_new


def moved_bias(bias, step) -> float:
    """The baro bias (m) after a GPS height reset moved the filter's height by `step` (m, NED
    down): bias + step, so the baro innovation is what it was (module docstring; PX4's
    ``_baro_b_est.setBias(_baro_b_est.getBias() + delta_z)``). Its variance is kept, as PX4's.
    Works on floats and element-wise on arrays."""
    return bias + step


def floored_height_variance(p_zz, bias_var) -> float:
    """The EKF7's height variance (m^2) after a baro fusion: at least the bias variance P_b.

    A baro-corrected height is no better known than the bias that corrects it, and that bias
    error is common to every sample: fused one by one as if independent, samples would shrink
    P[2, 2] far below P_b (the cross-covariance the scalar bias filter drops). Raising the one
    diagonal entry keeps P positive semi-definite (PX4's ``fixCovarianceErrors`` clamps variances
    per state the same way) and the height's NEES honest."""
    return bias_var if p_zz < bias_var else p_zz


def bias_predict(bias_var, dt, walk_std) -> float:
    """The bias variance (m^2) after dt s of its random walk of walk_std m/sqrt(s)."""
    return bias_var + walk_std * walk_std * dt


def bias_update(bias, bias_var, measured, measured_var) -> tuple[float, float]:
    """(bias, bias_var) after the scalar Kalman update with a bias measurement (m) of variance
    measured_var (m^2): K = P_b / (P_b + measured_var)."""
    gain = bias_var / (bias_var + measured_var)
    return bias + gain * (measured - bias), (1.0 - gain) * bias_var


def bias_from_gps(height, gps_z) -> float:
    """The bias measurement (m) of a baro height (m, up) and a GPS down position (m, NED) at one
    time: h - (-z)."""
    return height + gps_z


def offset_log_likelihood(innovation, innovation_var, offset) -> float:
    """The log-likelihood ratio of one bias innovation (m) of variance innovation_var (m^2) for
    "the GPS height is off by `offset` m" (its innovations then have the mean offset) against "it
    is right" (mean 0), both Gaussian of that variance: (offset * innovation - offset^2 / 2) /
    innovation_var. Under a consistent GPS its mean is -d^2/2 and its spread d, d = offset /
    sqrt(innovation_var); under a GPS height off by `offset` its mean is +d^2/2."""
    return (offset * innovation - 0.5 * offset * offset) / innovation_var


def accumulated_evidence(evidence, log_likelihood, cap) -> float:
    """Page's CUSUM step: evidence' = min(cap, max(0, evidence + log_likelihood)); the sum of the
    log-likelihood ratios since the last time it was 0 (the estimated onset of a disagreement),
    capped so that it forgets a past disagreement within cap / (d^2 / 2) consistent samples."""
    total = evidence + log_likelihood
    if total < 0.0:
        return 0.0
    return cap if total > cap else total


def gps_height_disagrees(evidence_high, evidence_low, threshold) -> bool:
    """True when either side's accumulated evidence (:func:`accumulated_evidence`) is beyond
    `threshold` (> 0): the GPS height and the barometer disagree persistently, so the GPS height
    must not feed the bias (it would carry the bias, and with it the baro-held height, along its
    error). Works on floats and element-wise on arrays."""
    return (evidence_high > threshold) | (evidence_low > threshold)


def bias_reset(height, p_z, height_var, p_z_var) -> tuple[float, float]:
    """(bias, bias_var) of a bias reset to a baro height (m) against the filter's p_z (m, NED)
    of variance p_z_var: b = h + p_z, variance height_var + p_z_var."""
    return height + p_z, height_var + p_z_var


def first_datum(bias, bias_var, height, p_z, height_var, p_z_var, from_first_sample) -> tuple[float, float]:
    """(bias, bias_var) of the EKF7's scalar bias filter after its first finite baro height (m)
    against the filter's p_z (m, NED) of variance p_z_var (m^2): the datum b_meas = h + p_z of
    variance height_var + p_z_var, taken as it is when `from_first_sample` (:func:`bias_reset`, the
    ESKF's rule), else fused against the prior (bias m, bias_var m^2) (:func:`bias_update`)."""
    if from_first_sample:
        return bias_reset(height, p_z, height_var, p_z_var)
    return bias_update(bias, bias_var, height + p_z, height_var + p_z_var)


def ekf7_baro_update(x, P, height, bias, R) -> tuple[np.ndarray, np.ndarray, float]:
    """Oracle: (x', P', nis) of the EKF7 (x (7,), P) fusing a baro height (m) with the dense
    Kalman update (``ekf.kalman_update``) of :func:`height_jacobian`; z = height - bias,
    R (m^2). A non-finite height gives (x, P, nan)."""
    from quad_drake.estimation import ekf

    if not math.isfinite(height):
        return x, P, math.nan
    H = height_jacobian(P.shape[0])
    z = np.array([height - bias])
    return ekf.kalman_update(x, P, z, H, np.array([[R]]), H @ x)


def eskf_baro_update(x, P, height, R) -> tuple[np.ndarray, np.ndarray, float]:
    """Oracle: (x', P', nis) of the ESKF that carries the baro bias (nominal x (17,): its bias at
    ``eskf.BARO_BIAS_NOMINAL``; P (10 or 16 square), the bias error last) fusing a baro height (m):
    ``eskf.joseph_update`` with H = :func:`height_jacobian` + e_(n-1), nu = height - (-p_z + b),
    R (m^2) = height_std^2, then ``eskf.inject``. A non-finite height gives (x, P, nan)."""
    from quad_drake.estimation import eskf

    if not math.isfinite(height):
        return x, P, math.nan
    x = np.asarray(x, dtype=float)
    n = P.shape[0]
    H = height_jacobian(n)
    H[0, n - 1] = 1.0
    nu = np.array([height - (predicted_height(x[HEIGHT_INDEX]) + x[eskf.BARO_BIAS_NOMINAL])])
    dx, P_new, nis = eskf.joseph_update(P, H, np.array([[R]]), nu)
    x_new, P_new = eskf.inject(x, P_new, dx)
    return x_new, P_new, nis
