"""The ESKF's forward pass over a flight log, stored tick by tick, and its RTS smoothing.

The pass is THE filter's: the replay Diagram (``replay._playback_diagram``) is flown with one more
``VectorLogSink`` per estimator output every ONBOARD_PERIOD (``tick_sinks``): ``estimated_state``
(p, q_NB, v), ``imu_bias`` (b_a, b_g) and ``covariance`` after each tick's update, and the IMU
sample the estimator read that tick (the playback's ``imu``). A sink publishes at t_(k+1) (offset
0) what the update of tick k (at t_k + EKF_OFFSET) wrote, so sample k+1 is tick k's updated pair
and sample 0 the initial one.

The predicted pair of tick k is the prediction of the updated pair of tick k-1 with the IMU
sample of tick k, by the filter's own compiled step (``kernels.eskf.predict``, over a non-finite
sample the filter's running IMU mean, ``kernels.imu_hold``), and F_k the transition of that step
(``eskf.transition`` at the nominal before it): on a tick that fuses nothing the prediction IS the
updated pair (tested). :func:`smooth_pass` then runs ``estimation.smoother.smooth_eskf``.
"""

from dataclasses import dataclass

import numpy as np
from pydrake.systems.primitives import LogVectorOutput

from quad_drake.conventions import ONBOARD_PERIOD
from quad_drake.estimation import eskf
from quad_drake.estimation.smoother import FilterPass, Smoothed, smooth_eskf

TICK_OUTPUTS = ("estimated_state", "covariance", "imu_bias")
"""The ESKF outputs logged every tick for the smoother: together the nominal state and P."""


@dataclass(frozen=True)
class TickLogs:
    """Per tick k = 0 .. T-1 (times (T,) s): nominal x (T + 1, 16) and P (T + 1, n, n) after tick
    k's update at index k + 1 (index 0: the initial pair), imu (T, 6) the sample read at tick k."""

    times: np.ndarray
    x: np.ndarray
    P: np.ndarray
    imu: np.ndarray


def tick_sinks(builder, estimator, playback) -> dict:
    """Add the per-tick sinks of the module docstring to a DiagramBuilder; {name: sink}."""
    ports = {name: estimator.GetOutputPort(name) for name in TICK_OUTPUTS}
    ports["imu"] = playback.GetOutputPort("imu")
    return {
        name: LogVectorOutput(port, builder, publish_period=ONBOARD_PERIOD) for name, port in ports.items()
    }


def read_tick_sinks(sinks, context) -> TickLogs:
    """TickLogs of the sinks of :func:`tick_sinks` after a simulation."""
    data = {name: sink.FindLog(context).data().T for name, sink in sinks.items()}
    times = sinks["imu"].FindLog(context).sample_times()[:-1].copy()
    state = data["estimated_state"]
    x = np.column_stack([state[:, 0:3], state[:, 7:10], state[:, 3:7], data["imu_bias"]])
    n = int(round(np.sqrt(data["covariance"].shape[1])))
    return TickLogs(times, x, data["covariance"].reshape(-1, n, n).copy(), data["imu"][1:].copy())


def eskf_pass(ticks: TickLogs, estimator) -> FilterPass:
    """The FilterPass (predicted and updated pairs, F_k) of an ESKF's TickLogs; estimator: its
    EskfEstimatorConfig (the noise it assumes)."""
    from quad_drake.kernels import eskf as eskf_kernel
    from quad_drake.kernels.imu_hold import IMU_FINITE, IMU_MISSING, bridge_imu_row, hold_weight, initial_hold

    noise = eskf.NoiseModel.from_params(estimator)
    n = ticks.P.shape[1]
    model = eskf_kernel.model(noise, eskf.noise_buffer(n, noise, ONBOARD_PERIOD), ONBOARD_PERIOD)
    count = ticks.imu.shape[0]
    x_updated, P_updated = ticks.x[1:], ticks.P[1:]
    x_predicted, P_predicted = np.empty_like(x_updated), np.empty_like(P_updated)
    F = np.tile(np.eye(n), (count, 1, 1))
    hold, weight = initial_hold()[None, :], hold_weight(ONBOARD_PERIOD)
    for k in range(count):
        status = bridge_imu_row(ticks.imu[k : k + 1], hold, 0, weight)
        prior_x, prior_P = ticks.x[k], ticks.P[k]
        if status == IMU_MISSING:
            x_predicted[k], P_predicted[k] = prior_x, prior_P
            continue
        sample = ticks.imu[k] if status == IMU_FINITE else hold[0, :6]
        f_B, w_B = sample[None, 0:3], sample[None, 3:6]
        x_new, P_new = eskf_kernel.predict(prior_x[None], prior_P[None], f_B, w_B, model)
        x_predicted[k], P_predicted[k] = x_new[0], P_new[0]
        _, R, R_next, u_N = eskf.predict_nominal(prior_x, f_B[0], w_B[0], ONBOARD_PERIOD)
        F[k] = eskf.transition(R, R_next, u_N, ONBOARD_PERIOD, n)
    return FilterPass(x_predicted, P_predicted, x_updated.copy(), P_updated.copy(), F)


def smooth_pass(ticks: TickLogs, estimator) -> Smoothed:
    """The RTS-smoothed nominals and covariances of an ESKF's TickLogs (module docstring)."""
    return smooth_eskf(eskf_pass(ticks, estimator))


def log_ticks(tick_times, times) -> np.ndarray:
    """Index of the tick whose update a log sample at each of `times` (s) shows: the last tick k
    with t_k < t (a log publishes before the updates of its own time; log and tick times differ
    by whole milliseconds)."""
    index = np.searchsorted(tick_times, np.asarray(times) - 0.25 * ONBOARD_PERIOD) - 1
    return np.clip(index, 0, len(tick_times) - 1)


def smoothed_logs(ticks: TickLogs, smoothed: Smoothed, times) -> dict:
    """{``smoothed_state``: (m, 16) nominal (p, v, q_NB, b_a, b_g), ``smoothed_sigma``: (m, n): dp
    m, dv m/s, dtheta rad[, db_a m/s², db_g rad/s]} sampled at the log times `times` (s)."""
    index = log_ticks(ticks.times, times)
    return {"smoothed_state": smoothed.x[index], "smoothed_sigma": smoothed.sigma()[index]}
