"""Pure: a replay's innovations judged without truth, per channel: consistent and white.

A filter whose noise model is right has innovations ν_k (sample minus the prediction before it)
with covariance S_k = H P_k⁻ Hᵀ + R, so the normalised innovations z_k = ν_k / sqrt(S_k) have
mean square 1 (the NIS per dof) and are white: uncorrelated from one sample to the next (Mehra,
"On the identification of variances and adaptive Kalman filtering", IEEE TAC 1970). Too large
or too small an R moves the NIS per dof off 1; a sensor delay left out adds the vehicle's motion
over the delay (v δ, a δ, yaw rate δ) to ν, a slowly varying term that correlates successive
z. Neither needs the truth.

A **channel** is one group of innovation components a noise value sets:

- ``gps_pos_xy``, ``gps_pos_z``, ``gps_vel_xy``, ``gps_vel_z``, ``heading``: per component,
  z = ν / sqrt(σ⁻² + r²) with σ⁻ the filter's prior σ of that state (the covariance logged before
  the sample arrived, ``comparison.state_sigmas``) and r the std the filter assumed;
- ``field`` (3 dof) and ``baro`` (1 dof): the filter's own NIS (``vocabulary.DIAGNOSTICS``), whose
  whiteness is judged on the centred NIS sequence (independent innovations give independent NIS).

:func:`channel_statistics` gives per channel the NIS per dof with the χ² band of its mean, the
autocorrelation at lags 1..LAGS with its ±1.96/sqrt(N) band, and the Ljung–Box p-value;
:func:`loss` is what ``quad-drake tune LOG`` minimises: Σ over channels of (ln NIS per dof)² +
Σ_k ρ_k² (0 for a consistent, white filter; each term dimensionless).
"""

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from quad_drake.flightlogs.comparison import attitude_sigmas, fresh_rows, state_sigmas
from quad_drake.judging.consistency import chi2_band, fresh_nis
from quad_drake.models.rotations import euler_from_quats, wrap_angles

LAGS = 5
"""Lags (in samples of the channel) whose autocorrelation is judged and minimised."""
COMPONENT_CHANNELS = {
    "gps_pos_xy": ("gps", ("X", "Y"), (0, 1)),
    "gps_pos_z": ("gps", ("Z",), (2,)),
    "gps_vel_xy": ("gps", ("VX", "VY"), (3, 4)),
    "gps_vel_z": ("gps", ("VZ",), (5,)),
    "heading": ("mag", ("Yaw",), (0,)),
}
"""channel -> (sensor log, the states its components measure, their innovation columns)."""
NIS_CHANNELS = {"field": 3, "baro": 1}
"""channel -> dof: judged on the filter's own NIS."""
UPDATE_DIAGNOSTICS = "update_diagnostics"
"""The log name of an estimator's ``diagnostics`` logged every 2 ms tick (every replay's): each
fresh update's NIS, where the 5 ms LOG_PERIOD log shows only the last
of the updates within one of its periods (the bundled SITL log's barometer samples come in pairs
4 ms apart: at a barometer delay of 2 ms, or of 292 ms, half of them were never judged)."""


@dataclass(frozen=True)
class ChannelStatistics:
    """One channel's innovations over a window: NIS per dof (mean square of z, or the mean NIS /
    dof) and the χ² band of that mean (per dof), autocorrelation at lags 1..LAGS (mean over the
    components) and its whiteness band ±white_band, the Ljung–Box p-value."""

    channel: str
    dof: int
    count: int  # samples
    nis_per_dof: float
    band: tuple  # (low, high) per dof
    autocorrelation: tuple  # LAGS values
    white_band: float  # 1.96 / sqrt(count)
    ljung_box_p: float
    log_variance: float = math.nan  # mean of ln s² over samples and components (component channels)

    @property
    def in_band(self) -> bool:
        return self.band[0] <= self.nis_per_dof <= self.band[1]

    @property
    def white(self) -> bool:
        """Every lag's autocorrelation inside ±white_band."""
        return bool(np.all(np.abs(self.autocorrelation) <= self.white_band))

    @property
    def max_autocorrelation(self) -> float:
        return float(np.max(np.abs(self.autocorrelation)))


def inside(stamps, windows) -> np.ndarray:
    """(m,) bool: each stamp (s) inside one of `windows`, ((start, end), ...) s (start included, end
    not): the parts of a log a statistic is taken over (one window, or a tuning's interleaved
    training or held-out blocks)."""
    stamps = np.asarray(stamps, dtype=float)
    keep = np.zeros(len(stamps), dtype=bool)
    for start, end in windows:
        keep |= (stamps >= start) & (stamps < end)
    return keep


def normalised_innovations(
    vocabulary, logs, channel, assumed_std, windows
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stamps (m,) s, z (m, k), s (m, k)) of a component channel in a replay's logs: each fresh
    sample stamped inside one of `windows` (((start, end), ...) s, :func:`inside`), its innovation ν
    over s = sqrt(prior σ² + assumed_std²), the innovation's std in the sensor's unit (assumed_std:
    (k,) the std the filter assumed per component)."""
    sensor, states, columns = COMPONENT_CHANNELS[channel]
    samples = np.asarray(logs[sensor], dtype=float)
    rows = fresh_rows(samples, min((start for start, _ in windows), default=math.inf))
    rows = rows[inside(samples[rows, -1], windows)]
    before = rows - 1
    estimate = np.asarray(logs["estimated_state"], dtype=float)
    if sensor == "gps":
        predicted = np.column_stack([estimate[before, 0:3], estimate[before, 7:10]])
        nu = (samples[rows, 0:6] - predicted)[:, list(columns)]
    else:
        nu = wrap_angles(samples[rows, 0] - euler_from_quats(estimate[before, 3:7])[2])[:, None]
    covariance = np.asarray(logs["covariance"])[before]
    if sensor == "gps":
        sigma = state_sigmas(vocabulary, covariance, states)
    else:  # the yaw's σ (the ESKF's rotation error about D, the EKF7's yaw)
        sigma = attitude_sigmas(vocabulary, covariance, euler_from_quats(estimate[before, 3:7])[2])[:, 2:3]
    s = np.sqrt(sigma**2 + np.asarray(assumed_std, dtype=float) ** 2)
    return samples[rows, -1], nu / s, s


def nis_sequence(diagnostics, channel, windows) -> np.ndarray:
    """(m,) the filter's own NIS of a NIS channel's fresh samples stamped inside one of `windows`
    (((start, end), ...) s)."""
    stamps, values = fresh_nis(diagnostics, channel)
    return values[inside(stamps, windows) & np.isfinite(values)]


def autocorrelation(z, lags=LAGS) -> np.ndarray:
    """(lags,) ρ_k = Σ_t z_t·z_(t+k) / Σ_t z_t·z_t at k = 1..lags, the mean over z's columns
    (z (m,) or (m, k)); NaN where the sequence is not longer than the lag."""
    z = np.asarray(z, dtype=float)
    z = z[:, None] if z.ndim == 1 else z
    energy = np.sum(z * z, axis=0)
    rho = np.full(lags, np.nan)
    for k in range(1, lags + 1):
        if len(z) > k and np.all(energy > 0):
            rho[k - 1] = float(np.mean(np.sum(z[:-k] * z[k:], axis=0) / energy))
    return rho


def ljung_box_p(rho, count) -> float:
    """Ljung–Box p-value of the autocorrelations rho (lags 1..L) of `count` samples: the chance
    that a white sequence shows autocorrelations this large."""
    k = np.arange(1, len(rho) + 1)
    if count <= len(rho) or not np.all(np.isfinite(rho)):
        return math.nan
    q = count * (count + 2) * float(np.sum(np.asarray(rho) ** 2 / (count - k)))
    return float(chi2.sf(q, len(rho)))


def statistics_of(channel, z_or_nis, dof, innovation_std=None) -> ChannelStatistics | None:
    """ChannelStatistics of a channel's normalised innovations z (m, k) (dof = k) with their
    innovation std s (m, k) where known, or of a NIS channel's NIS sequence (m,) with its dof;
    None with fewer than LAGS + 2 samples."""
    values = np.asarray(z_or_nis, dtype=float)
    count = len(values)
    if count < LAGS + 2:
        return None
    if channel in NIS_CHANNELS:
        per_dof = float(np.mean(values)) / dof
        rho = autocorrelation(values - np.mean(values))
    else:
        per_dof = float(np.mean(values**2))
        rho = autocorrelation(values)
    band = tuple(b / dof for b in chi2_band(dof, count))
    return ChannelStatistics(
        channel,
        dof,
        count,
        per_dof,
        band,
        tuple(float(r) for r in rho),
        1.96 / math.sqrt(count),
        ljung_box_p(rho, count),
        math.nan if innovation_std is None else float(np.mean(2.0 * np.log(innovation_std))),
    )


def channel_statistics(vocabulary, logs, assumed, windows) -> dict[str, ChannelStatistics]:
    """{channel: ChannelStatistics} of a replay's logs over windows = ((start, end), ...) s (the
    samples of every window in one sequence: under a white filter's hypothesis two samples of
    different windows are uncorrelated too, so the whiteness judgement holds). assumed:
    {component channel: (k,) std the filter assumed}; a channel absent from `assumed` (the
    component ones) or without samples in the window (the NIS ones) is left out. The NIS channels
    are read from ``logs[UPDATE_DIAGNOSTICS]`` where present, else from the LOG_PERIOD
    ``diagnostics`` (which shows one of two updates within 5 ms)."""
    found = {}
    for channel, std in assumed.items():
        if channel in COMPONENT_CHANNELS:
            _, z, s = normalised_innovations(vocabulary, logs, channel, std, windows)
            stats = statistics_of(channel, z, len(COMPONENT_CHANNELS[channel][1]), s)
        else:  # every update's NIS where the replay logged them (UPDATE_DIAGNOSTICS)
            diagnostics = logs.get(UPDATE_DIAGNOSTICS, logs["diagnostics"])
            stats = statistics_of(channel, nis_sequence(diagnostics, channel, windows), NIS_CHANNELS[channel])
        if stats is not None:
            found[channel] = stats
    return found


NONFINITE_TERM = 25.0
"""The loss term of a channel whose NIS per dof is not a positive finite number (a broken filter):
(ln 150)², more than any plausible miss."""


def channel_loss(stats) -> float:
    """(ln NIS per dof)² + Σ_k ρ_k² of one ChannelStatistics (0: consistent and white)."""
    if not (math.isfinite(stats.nis_per_dof) and stats.nis_per_dof > 0):
        return NONFINITE_TERM
    rho = np.nan_to_num(np.asarray(stats.autocorrelation), nan=1.0)
    return math.log(stats.nis_per_dof) ** 2 + float(np.sum(rho**2))


def loss(statistics) -> float:
    """Σ over channels of :func:`channel_loss` ({channel: ChannelStatistics}, or a list of such
    dicts, one per log: summed over them)."""
    return float(sum(channel_loss(s) for s in _each(statistics)))


def channel_likelihood(stats) -> float:
    """A component channel's mean negative log-likelihood per sample, dof·(NIS per dof + mean
    ln s²) (the Gaussian's, less its constant dof·ln 2π): Σ over its components of z² + ln s²,
    least for the innovations that are both consistent and smallest; a NIS channel (no innovation
    std known) its :func:`channel_loss`."""
    if not math.isfinite(stats.log_variance):
        return channel_loss(stats)
    if not (math.isfinite(stats.nis_per_dof) and stats.nis_per_dof > 0):
        return NONFINITE_TERM
    return stats.dof * (stats.nis_per_dof + stats.log_variance)


def likelihood(statistics) -> float:
    """Σ over channels of :func:`channel_likelihood` (statistics as :func:`loss` takes them): what
    ``quad-drake tune LOG`` minimises. Unlike :func:`loss` it does not fall when a wrong delay is
    hidden under a larger noise: the larger innovation variance costs its ln s²."""
    return float(sum(channel_likelihood(s) for s in _each(statistics)))


def _each(statistics):
    """The ChannelStatistics of a {channel: ChannelStatistics} or a list of such dicts."""
    for per_log in [statistics] if isinstance(statistics, dict) else statistics:
        yield from per_log.values()
