"""Pure: the reference's step 1 — standard deviations of logged sensor noise.

At hover the GPS x error (GPS.X − Pos.X) and the accelerometer x reading are pure
noise; their sample standard deviations over fresh samples are the values the
06_sensor_noise criteria need (``MeasuredStdDev_GPSPosXY``, ``MeasuredStdDev_AccelXY``).
"""

import numpy as np

from ..config.errors import ConfigError


def measured_noise_std(signals) -> dict[str, float]:
    """{'<V>.GPS.X': m, '<V>.IMU.AX': m/s^2} sample std devs for every vehicle with those sensors."""
    result = {}
    for name, signal in signals.items():
        vehicle, _, key = name.partition(".")
        if key == "GPS.X":
            fresh = signal.fresh
            error = signal.values[fresh] - signals[f"{vehicle}.Pos.X"].values[fresh]
            result[name] = _std(error, name)
        elif key == "IMU.AX":
            result[name] = _std(signal.values[signal.fresh], name)
    if not result:
        raise ConfigError("noise-std: the run has no GPS or IMU log")
    return result


def _std(samples, name):
    if samples.size < 2:
        raise ConfigError(f"noise-std: {name} has fewer than 2 samples")
    return float(np.std(samples, ddof=1))
