"""Pure wind models: the air's velocity around a vehicle, m/s, in the world frame N (NED).

wind_N(t) = mean + sum of the (1 - cos) gusts at t + the Dryden turbulence, turned from the
mean wind's axes (u along the mean wind's horizontal direction, v to its right, w down) into N.

**Dryden turbulence**, the low-altitude forms of MIL-F-8785C (MIL-HDBK-1797 writes the v and w
spectra with scale lengths defined differently; the spectra below are 8785C's), with the altitude h
and the wind speed at 20 ft (6.1 m) W20 in feet and ft/s::

    L_w = h,  L_u = L_v = h / (0.177 + 0.000823 h)^1.2           (scale lengths)
    sigma_w = 0.1 W20,  sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4
    H_u(s) = sigma_u sqrt(2 L_u / (pi V)) / (1 + (L_u/V) s)
    H_v(s) = sigma_v sqrt(L_v / (pi V)) (1 + sqrt(3) (L_v/V) s) / (1 + (L_v/V) s)^2,  H_w alike

for 10 ft <= h <= 1000 ft (h is clamped to that range: the low-altitude forms end at 1000 ft,
and below 10 ft the scale length L_w = h would vanish).
W20 is 15, 30, 45 knots for light, moderate, severe turbulence (MIL-F-8785C), unless a
wind speed at 6 m is given. V is the speed at which the frozen turbulence field passes the vehicle
(Taylor's hypothesis): the configured airspeed, else the mean wind's speed, at least 1 m/s (a
hovering multirotor has no airspeed of its own). The autocorrelations are
R_u(tau) = sigma_u^2 exp(-V tau / L_u) and R_v(tau) = sigma_v^2 (1 - V tau / (2 L_v)) exp(-V tau / L_v).

The filters are discretised exactly on the wind's update period (:func:`dryden_model`): the
state x (5: u 1, v 2, w 2) steps x_{k+1} = Phi x_k + G n_k, n_k unit normal, with
Phi = expm(A dt) and G G^T = P - Phi P Phi^T, P the stationary covariance, and starts in the
stationary distribution, x_0 = P^(1/2) n_0. So the discrete samples have exactly the continuous
process's variance and correlation, at any period. Pure: numpy and scipy; noise passed in.
"""

import math
from dataclasses import dataclass

import numpy as np

FT = 0.3048
"""m per foot."""
KNOT = 1852.0 / 3600.0
"""m/s per knot."""

TURBULENCE_W20 = {"light": 15.0 * KNOT, "moderate": 30.0 * KNOT, "severe": 45.0 * KNOT}
"""Wind speed at 20 ft (m/s) of each turbulence level, MIL-F-8785C (low altitude)."""

MIN_ALTITUDE = 10.0 * FT
MAX_ALTITUDE = 1000.0 * FT
MIN_TURBULENCE_SPEED = 1.0
"""m/s, the least speed of the turbulence field past the vehicle (:func:`turbulence_speed`)."""

TURBULENCE_STATES = 5
"""States of the three Dryden filters: u 1, v 2, w 2."""


def dryden_low_altitude(
    altitude, wind_speed_6m
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """(sigma_u, sigma_v, sigma_w) m/s and (L_u, L_v, L_w) m of MIL-F-8785C's low-altitude Dryden
    model at `altitude` m above ground (clamped to [10, 1000] ft) for the wind speed W20 at 6 m
    (20 ft), m/s."""
    h = min(max(altitude, MIN_ALTITUDE), MAX_ALTITUDE) / FT  # ft
    base = 0.177 + 0.000823 * h
    length_uv = h / base**1.2 * FT
    sigma_w = 0.1 * wind_speed_6m
    sigma_uv = sigma_w / base**0.4
    return (sigma_uv, sigma_uv, sigma_w), (length_uv, length_uv, h * FT)


def turbulence_speed(config) -> float:
    """V, m/s: the configured airspeed, else |mean wind| but at least MIN_TURBULENCE_SPEED."""
    if config.airspeed > 0.0:
        return config.airspeed
    return max(math.hypot(*config.mean), MIN_TURBULENCE_SPEED)


def turbulence_intensity(config) -> float:
    """W20, m/s, of a WindConfig: its wind_speed_6m, else its level's (0 for ``none``)."""
    if config.turbulence == "none":
        return 0.0
    return config.wind_speed_6m or TURBULENCE_W20[config.turbulence]


def _first_order(time_constant):
    """(A, B, C) of 1 / (1 + T s) driven by unit white noise."""
    return np.array([[-1.0 / time_constant]]), np.array([[1.0 / time_constant]]), np.array([[1.0]])


def _second_order(time_constant):
    """(A, B, C) of (1 + sqrt(3) T s) / (1 + T s)^2 driven by unit white noise."""
    t = time_constant
    a = np.array([[0.0, 1.0], [-1.0 / t**2, -2.0 / t]])
    return a, np.array([[0.0], [1.0 / t**2]]), np.array([[1.0, math.sqrt(3.0) * t]])


def _square_root(matrix):
    """A square root S S^T = matrix of a symmetric positive semi-definite matrix (eigenvalues
    below 0, from rounding, are taken as 0)."""
    values, vectors = np.linalg.eigh(0.5 * (matrix + matrix.T))
    return vectors * np.sqrt(np.clip(values, 0.0, None))


@dataclass(frozen=True)
class DrydenModel:
    """The exact discretisation of the three Dryden filters on a period (:func:`dryden_model`).

    phi (5, 5): state transition; noise_gain (5, 5): G, G G^T the process noise of one period;
    initial_gain (5, 5): P^(1/2), P the stationary covariance; output (3, 5): (u, v, w) m/s =
    output x; heading (rad): of the mean wind's horizontal direction, from north towards east;
    sigmas (3, m/s), lengths (3, m), speed (m/s): the model's parameters.
    """

    phi: np.ndarray
    noise_gain: np.ndarray
    initial_gain: np.ndarray
    output: np.ndarray
    heading: float
    sigmas: tuple
    lengths: tuple
    speed: float


def dryden_model(config, period) -> DrydenModel | None:
    """The :class:`DrydenModel` of a WindConfig on the update `period` s, or None when its
    turbulence is ``none``."""
    from scipy.linalg import expm, solve_continuous_lyapunov  # noqa: PLC0415 (scipy's import, 0.2 s, only here)

    w20 = turbulence_intensity(config)
    if w20 <= 0.0:
        return None
    sigmas, lengths = dryden_low_altitude(config.altitude, w20)
    speed = turbulence_speed(config)
    blocks = [
        _first_order(lengths[0] / speed),
        _second_order(lengths[1] / speed),
        _second_order(lengths[2] / speed),
    ]
    a = np.zeros((TURBULENCE_STATES, TURBULENCE_STATES))
    b = np.zeros((TURBULENCE_STATES, 3))
    c = np.zeros((3, TURBULENCE_STATES))
    start = 0
    for axis, (ak, bk, ck) in enumerate(blocks):
        stop = start + len(ak)
        a[start:stop, start:stop], b[start:stop, axis], c[axis, start:stop] = ak, bk[:, 0], ck[0]
        start = stop
    stationary = solve_continuous_lyapunov(a, -b @ b.T)
    c = c * (np.asarray(sigmas) / np.sqrt(np.einsum("ij,jk,ik->i", c, stationary, c)))[:, None]
    phi = expm(a * period)
    return DrydenModel(
        phi=phi,
        noise_gain=_square_root(stationary - phi @ stationary @ phi.T),
        initial_gain=_square_root(stationary),
        output=c,
        heading=math.atan2(config.mean[1], config.mean[0]),
        sigmas=tuple(sigmas),
        lengths=tuple(lengths),
        speed=speed,
    )


def turbulence_start(noise, model) -> np.ndarray:
    """(n, 5) filter states drawn from the stationary distribution: noise (n, 5) unit normals."""
    states = np.zeros(noise.shape)
    filter_rows(states, noise, 0.0 * model.phi, model.initial_gain)
    return states


def turbulence_step(states, noise, model) -> np.ndarray:
    """(n, 5) filter states one period later: Phi x + G n, noise (n, 5) unit normals."""
    stepped = states.copy()
    filter_rows(stepped, noise, model.phi, model.noise_gain)
    return stepped


def turbulence_velocity(states, model) -> np.ndarray:
    """(n, 3) turbulence velocity, m/s, NED, of the (n, 5) filter states: (u, v, w) in the mean
    wind's axes turned by its heading into N (w is down)."""
    out = np.empty((len(states), 3))
    velocity_rows(states, model.output, math.cos(model.heading), math.sin(model.heading), out)
    return out


def filter_rows(states, noise, phi, gain) -> None:
    """IN PLACE, row by row: states[i] = phi states[i] + gain noise[i] ((n, m) states and noise,
    (m, m) phi and gain). Summed entry by entry in a fixed order, so a row's result does not depend
    on n (a matrix product's rounding does); ``kernels.flight`` compiles this code."""
    n, m = states.shape
    row = np.empty(m)
    for i in range(n):
        for r in range(m):
            total = 0.0
            for k in range(m):
                total += phi[r, k] * states[i, k] + gain[r, k] * noise[i, k]
            row[r] = total
        for r in range(m):
            states[i, r] = row[r]


def wind_rows(states, noise, phi, gain, output, cos_heading, sin_heading, steady, out) -> None:
    """IN PLACE, the wind of n vehicles in one call: the filters step (:func:`filter_rows`), then
    out[i] = the NED turbulence velocity of states[i] (:func:`velocity_rows`) + steady (3, m/s,
    NED: the mean wind and the gusts, every vehicle's the same); ``kernels.flight`` compiles it."""
    filter_rows(states, noise, phi, gain)
    velocity_rows(states, output, cos_heading, sin_heading, out)
    for i in range(out.shape[0]):
        out[i, 0] += steady[0]
        out[i, 1] += steady[1]
        out[i, 2] += steady[2]


def velocity_rows(states, output, cos_heading, sin_heading, out) -> None:
    """out (n, 3) = the NED turbulence velocity (m/s) of each row of states (n, 5): (u, v, w) =
    output states[i], turned by the mean wind's heading (cos, sin); entry by entry (as
    :func:`filter_rows`)."""
    for i in range(states.shape[0]):
        u = v = w = 0.0
        for k in range(states.shape[1]):
            u += output[0, k] * states[i, k]
            v += output[1, k] * states[i, k]
            w += output[2, k] * states[i, k]
        out[i, 0] = cos_heading * u - sin_heading * v
        out[i, 1] = sin_heading * u + cos_heading * v
        out[i, 2] = w


def gust_velocity(time, gusts) -> np.ndarray:
    """(3,) m/s, NED: the sum at `time` s of the (1 - cos) gusts (GustConfig list), each
    amplitude/2 (1 - cos(2 pi (t - start) / duration)) along its normalised direction in
    [start, start + duration], 0 outside."""
    total = np.zeros(3)
    for gust in gusts:
        phase = (time - gust.start) / gust.duration
        if 0.0 <= phase <= 1.0:
            direction = np.asarray(gust.direction, dtype=float)
            total += (
                0.5
                * gust.amplitude
                * (1.0 - math.cos(2.0 * math.pi * phase))
                * direction
                / np.linalg.norm(direction)
            )
    return total


def steady_wind(time, config) -> np.ndarray:
    """(3,) m/s, NED: the mean wind plus the gusts of a WindConfig at `time` s (no turbulence)."""
    return np.asarray(config.mean, dtype=float) + gust_velocity(time, config.gusts)
