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
  height_std^2 + P[2, 2] against the filter's own height;
- at every GPS sample stamped with the latest baro sample's time (20 ms and 100 ms periods are
  commensurate) it takes b_meas = h + z_gps of variance height_std^2 + gps_z_std^2, gated as the
  baro; between samples its variance P_b grows by the random walk (bias_walk_std^2 per s);
  during a GPS outage it is frozen;
- the bias error e_b = b - b_hat is common to every sample: fused one by one as independent, the
  samples would shrink P[2, 2] far below P_b (the cross-covariance the scalar filter drops). So
  after each fusion the height variance is floored at P_b (:func:`floored_height_variance`). The
  price, measured on 23's 10 s outage when the ESKF still fused this way (100 runs, seeds
  7000-7099): the height over-confident (e^2/P 1.26) and the vertical velocity conservative
  (0.78): the floor adds height uncertainty that no vertical velocity explains;
- a reset as the ESKF's, b = h + p_z, P_b = height_std^2 + P[2, 2].

**Both: a GPS height that disagrees with the barometer persistently is caught.** Every GPS
height's normalised bias innovation, (h + z_gps - b_hat) / sqrt(P_b + height_std^2 +
gps_z_std^2), is low-pass filtered (time constant ``gps_check_time``,
:func:`filtered_disagreement`) and, while that filtered value lies beyond ``gate_sigma`` of its
own spread under a consistent GPS (:func:`gps_height_disagrees`), the GPS height feeds neither
the bias nor the filter's height, nor is reset to (``fusion.fuse_gps``): the barometer holds the
height. The bias is a slow random walk (7 mm/sqrt(s)); a GPS height 3 m off for a minute is no
bias change but a GPS error (multipath, a wrong datum), and a bias that followed it would take
the baro-held height, and the vehicle 1 m above the floor, 3 m down with it. Single samples
cannot show it (the GPS height's 2 m noise puts 3 m inside any per-sample gate); their filtered
mean can, within about 2 s. PX4 makes the same choice with the barometer as its height
reference (``EKF2_HGT_REF``), ArduPilot by taking its height from the barometer
(``EK3_SRC1_POSZ``). A baro bias reset starts the filtered value again at 0.

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
DISAGREEMENT, DISAGREEMENT_VAR = 7, 8
BARO_BOOK_SIZE = 9
"""Columns of a filter's baro book: bias estimate (m), its variance (m^2), the latest baro height
(m, NaN when it was not finite) and its stamp (s; -1 before the first), when its current run of
gate rejections began (s, NaN: none), the stamp of the last GPS sample seen (s, -1: none),
1 once a finite sample has set the datum (0 before), and the filtered GPS-height disagreement and
its variance under a consistent GPS (:func:`filtered_disagreement`, both 0 at first)."""


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
    # s; the time constant of the filtered, normalised GPS-height disagreement with the barometer
    # (:func:`filtered_disagreement`): while it is beyond gate_sigma of its own spread the GPS height
    # does not feed the bias, 0 = off (the bias then follows a GPS height error)
    gps_check_time: float = number(5.0, nonnegative=True)


def initial_book(params) -> np.ndarray:
    """A filter's baro book (BARO_BOOK_SIZE) before its first sample (see the module docstring)."""
    book = np.empty(BARO_BOOK_SIZE)
    book[BIAS], book[BIAS_VAR] = params.bias_init, params.bias_init_std**2
    book[LAST_HEIGHT], book[LAST_STAMP], book[REJECTED_SINCE] = math.nan, -1.0, math.nan
    book[GPS_STAMP], book[DATUM_SET], book[DISAGREEMENT], book[DISAGREEMENT_VAR] = -1.0, 0.0, 0.0, 0.0
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


def filtered_disagreement(
    ratio, ratio_var, innovation, innovation_var, elapsed, time_constant
) -> tuple[float, float]:
    """(ratio', ratio_var'): the low-pass filtered normalised bias innovation after one GPS height,
    and its variance under a consistent GPS.

    ratio' = (1 - w) ratio + w innovation / sqrt(innovation_var), w = 1 - exp(-elapsed /
    time_constant) (elapsed s since the previous GPS sample, time_constant s > 0): for a consistent
    GPS the normalised innovations are white with unit variance, so ratio_var' = (1 - w)^2
    ratio_var + w^2 (sqrt(w / (2 - w)) at 10 Hz in steady state; after an outage's long elapsed
    time, one sample's spread, about 1). A GPS height offset that the bias cannot have taken (its
    random walk allows bias_walk_std sqrt(t)) holds ratio' at offset / sqrt(innovation_var)
    (PX4's bias estimator low-pass filters its signed innovation test ratio the same way)."""
    weight = 1.0 - math.exp(-elapsed / time_constant)
    keep = 1.0 - weight
    return keep * ratio + weight * innovation / math.sqrt(
        innovation_var
    ), keep * keep * ratio_var + weight * weight


def gps_height_disagrees(ratio, ratio_var, gate_sigma) -> bool:
    """True when the filtered disagreement `ratio` of :func:`filtered_disagreement` lies beyond
    gate_sigma (> 0) of its spread sqrt(ratio_var) under a consistent GPS: the GPS height and the
    barometer disagree persistently, so the GPS height must not feed the bias (it would carry the
    bias, and with it the baro-held height, along its error)."""
    return ratio * ratio > gate_sigma * gate_sigma * ratio_var


def bias_reset(height, p_z, height_var, p_z_var) -> tuple[float, float]:
    """(bias, bias_var) of a bias reset to a baro height (m) against the filter's p_z (m, NED)
    of variance p_z_var: b = h + p_z, variance height_var + p_z_var."""
    return height + p_z, height_var + p_z_var


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
