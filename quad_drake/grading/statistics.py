"""Pure: the numbers the grading criteria judge, one per run, from a :class:`flights.Flight`'s
signals (values (samples, N) per signal; all N runs at once).

06: ``gps_sigma_ratio``, ``accel_sigma_ratio``: the student's MEASURED_STD_DEV_* over the RMS
    of the run's own samples (GPS x and y minus the true position, m; accelerometer x and y
    about 0, m/s^2), pooled over both axes.
07: ``max_euler_error``: rad, the largest of |roll|, |pitch|, |yaw| errors over the run.
08: ``max_position_error``: m, largest ``Est.E.Pos`` over the run.
09: ``position_nees``, ``velocity_nees``: the mean over the samples, the ten vehicles and the
    x and y axes of (error / predicted sigma)^2 (1 when the predicted covariance matches the
    fleet's spread).
10: ``max_yaw_error``: rad, largest |``Est.E.Yaw``|; ``yaw_nees``: the mean of
    (yaw error / sigma)^2 over the run.
11: ``position_window``: s, the longest stretch with ``Est.E.Pos`` <= POSITION_BAND (the
    reference's window rule, ``evaluation.WindowFold``); ``max_position_error``: m, as 08;
    ``max_velocity_error``: m/s, largest ``Est.E.Vel``; ``rms_velocity_error``: m/s, its RMS
    over the run; ``position_nees``: the mean over samples and x y z of (error / sigma)^2.
"""

import numpy as np

from quad_drake.judging.evaluation import WindowFold

POSITION_BAND = 1.0
"""m: 11's band, the reference's (``WindowThreshold(Quad.Est.E.Pos, 1, 20)``)."""


def _rms(values, fresh):
    """(N,) root mean square of `values` (k, N) over the samples where `fresh` (k, N)."""
    squares = np.where(fresh, np.square(values), 0.0).sum(axis=0)
    return np.sqrt(squares / np.maximum(fresh.sum(axis=0), 1))


def _nonfinite_as_inf(values):
    return np.where(np.isfinite(values), values, np.inf)


def sensor_noise(flight, gps_sigma, accel_sigma) -> dict[str, np.ndarray]:
    """06's {statistic: (N,)} of the student's sigmas (m, m/s^2)."""
    gps = [flight.values(f"Quad.GPS.{a}") - flight.values(f"Quad.Pos.{a}") for a in "XY"]
    fresh_gps = [flight.fresh(f"Quad.GPS.{a}") for a in "XY"]
    accel = [flight.values(f"Quad.IMU.A{a}") for a in "XY"]
    fresh_accel = [flight.fresh(f"Quad.IMU.A{a}") for a in "XY"]
    return {
        "gps_sigma_ratio": gps_sigma / _rms(np.concatenate(gps), np.concatenate(fresh_gps)),
        "accel_sigma_ratio": accel_sigma / _rms(np.concatenate(accel), np.concatenate(fresh_accel)),
    }


def _max_abs(values):
    return _nonfinite_as_inf(np.abs(values)).max(axis=0)


def _nees(errors, sigmas):
    """(N,) mean of (e / s)^2 over samples and the listed (errors, sigmas) pairs (k, N) each;
    inf for a non-finite or zero sigma."""
    ratios = [np.square(e / np.where(s > 0, s, np.nan)) for e, s in zip(errors, sigmas, strict=True)]
    return _nonfinite_as_inf(np.concatenate(ratios).mean(axis=0))


def attitude(flight) -> dict[str, np.ndarray]:
    """07's {statistic: (N,)}."""
    return {"max_euler_error": _max_abs(flight.values("Quad.Est.E.MaxEuler"))}


def dead_reckoning(flight) -> dict[str, np.ndarray]:
    """08's {statistic: (N,)}."""
    return {"max_position_error": _max_abs(flight.values("Quad.Est.E.Pos"))}


def covariance(flight) -> dict[str, np.ndarray]:
    """09's {statistic: (N,)} pooled over its vehicles."""
    vehicles = [v.name for v in flight.scenario.vehicles]
    out = {}
    for key, axes in (("position_nees", ("X", "Y")), ("velocity_nees", ("VX", "VY"))):
        errors = [flight.values(f"{v}.Est.E.{a}") for v in vehicles for a in axes]
        sigmas = [flight.values(f"{v}.Est.S.{a}") for v in vehicles for a in axes]
        out[key] = _nees(errors, sigmas)
    return out


def magnetometer(flight) -> dict[str, np.ndarray]:
    """10's {statistic: (N,)}."""
    error = flight.values("Quad.Est.E.Yaw")
    return {"max_yaw_error": _max_abs(error), "yaw_nees": _nees([error], [flight.values("Quad.Est.S.Yaw")])}


def gps(flight) -> dict[str, np.ndarray]:
    """11's {statistic: (N,)}."""
    errors = [flight.values(f"Quad.Est.E.{a}") for a in "XYZ"]
    sigmas = [flight.values(f"Quad.Est.S.{a}") for a in "XYZ"]
    position_error = flight.values("Quad.Est.E.Pos")
    window = WindowFold("Quad.Est.E.Pos", POSITION_BAND, 0.0, position_error.shape[1])
    window.update(flight.times, position_error, np.ones(position_error.shape, dtype=bool))
    return {
        "position_window": window.longest,
        "max_position_error": _max_abs(position_error),
        "max_velocity_error": _max_abs(flight.values("Quad.Est.E.Vel")),
        "rms_velocity_error": _nonfinite_as_inf(
            np.sqrt(np.mean(np.square(flight.values("Quad.Est.E.Vel")), axis=0))
        ),
        "position_nees": _nees(errors, sigmas),
    }
