"""How much the RTS smoother CAN gain over the ESKF on 11_gps_update_eskf: the ratio its model allows.

A smoother's error is smaller than its filter's by what its own model predicts, the ratio of the
smoothed to the filtered σ; no smoother of the same model and measurements does better. Three
parts, each printed as a table:

1. **One axis in closed form.** The position of one axis as the ESKF models it without the attitude
   (a double integrator driven by the accelerometer's white noise of ``accel_std`` per 2 ms sample,
   GPS position and velocity of ``pos_std`` and ``vel_std`` every 0.1 s: the scenario's sensors),
   a linear Kalman filter and ``estimation.smoother.rts`` over 60 s: the σ ratio of position in
   the steady middle third, for the horizontal and the vertical axis, and with the GPS velocity
   left out (then the position is no longer a random walk pinned by an accurate velocity).
2. **The ESKF's own linearised model, simulated.** One run of the scenario (a seed given, not a
   reporting seed) gives the filter's transitions F_k, its process noise Q_k (``eskf.process_noise``
   at the nominal attitude before each step) and each tick's measurement information
   P_k|k⁻¹ - P_k|k-1⁻¹ (GPS and magnetometer as fused, gates included). `--trajectories` truths are
   drawn from that linear model with white noise, filtered by a linear Kalman filter of the same
   model and smoothed by ``estimation.smoother.rts``: the Monte Carlo RMSE ratio (95 % bootstrap
   interval over trajectories) against the σ ratio the model predicts, and that model's filter σ
   against the ESKF's (the reconstruction is the filter's model when they agree).
3. The ESKF run itself: its σ ratio (``smooth_eskf``'s P against the filter's).

Parts 2 and 3 also give the ratios over the middle third of the flight alone: the time mean over a
whole flight counts its start (P0 near zero: the filter's σ still growing) and its end (the
smoother has no future left there; its last tick IS the filter's).

    PYTHONPATH=$PWD python benchmarks/smoother_bound.py --seed 3000 --trajectories 64
    PYTHONPATH=$PWD python benchmarks/smoother_bound.py --seed 3000 --set end_time=75
"""

import argparse
import tempfile
import time

import numpy as np
from scipy.stats import bootstrap

from quad_drake.config.schema import GpsParams, ImuParams
from quad_drake.conventions import ONBOARD_PERIOD
from quad_drake.estimation import eskf
from quad_drake.estimation.smoother import FilterPass, rts
from quad_drake.flightlogs.recording import smooth_run
from quad_drake.models.rotations import rotation_from_quat
from quad_drake.running import catalog

GPS_TICKS = 50  # 0.1 s of 2 ms ticks


def kalman(F, Q_root, information, P0, rng, trajectories):
    """A linear Kalman filter over truths drawn from x_k = F_k x_k-1 + Q_root_k w (w white), with the
    measurements y = L_kᵀ x + e (e white, unit) of information L_k L_kᵀ = information[k]. Returns
    (FilterPass with states (T, n, trajectories), truth (T, n, trajectories))."""
    steps, n = F.shape[0], F.shape[1]
    xp, xu, truth = (np.zeros((steps, n, trajectories)) for _ in range(3))
    Pp, Pu = np.zeros((steps, n, n)), np.zeros((steps, n, n))
    P0_root = np.linalg.cholesky(P0)
    x_true, x, P = P0_root @ rng.normal(size=(n, trajectories)), np.zeros((n, trajectories)), P0
    for k in range(steps):
        if k > 0:
            x_true = F[k] @ x_true + Q_root[k] @ rng.normal(size=(Q_root.shape[2], trajectories))
            x, P = F[k] @ x, F[k] @ P @ F[k].T + Q_root[k] @ Q_root[k].T
        xp[k], Pp[k], truth[k] = x, P, x_true
        values, vectors = np.linalg.eigh(information[k])
        keep = values > 1e-9 * max(values.max(), 1e-300)
        if keep.any():
            L = vectors[:, keep] * np.sqrt(values[keep])  # information = L Lᵀ
            y = L.T @ x_true + rng.normal(size=(L.shape[1], trajectories))
            S = L.T @ P @ L + np.eye(L.shape[1])
            K = np.linalg.solve(S, L.T @ P).T
            x = x + K @ (y - L.T @ x)
            I_KH = np.eye(n) - K @ L.T
            P = I_KH @ P @ I_KH.T + K @ K.T
        xu[k], Pu[k] = x, 0.5 * (P + P.T)
    return FilterPass(xp, Pp, xu, Pu, F), truth


def axis_ratio(accel_std, pos_std, vel_std=None, seconds=60.0):
    """σ ratio (smoother / filter) of position on one axis in the steady middle third (part 1)."""
    dt, steps = ONBOARD_PERIOD, int(round(seconds / ONBOARD_PERIOD))
    F = np.tile(np.array([[1.0, dt], [0.0, 1.0]]), (steps, 1, 1))
    Q_root = np.tile(np.array([[0.5 * dt * dt], [dt]]) * accel_std, (steps, 1, 1))
    measured = np.diag([pos_std**-2, 0.0 if vel_std is None else vel_std**-2])
    information = np.zeros((steps, 2, 2))
    information[GPS_TICKS - 1 :: GPS_TICKS] = measured
    filtered, _ = kalman(F, Q_root, information, np.diag([pos_std**2, 1.0]), np.random.default_rng(0), 1)
    smoothed = rts(filtered)
    middle = slice(steps // 3, 2 * steps // 3)
    ratio = np.sqrt(smoothed.P[middle, 0, 0].mean() / filtered.P_updated[middle, 0, 0].mean())
    return float(ratio), float(np.sqrt(filtered.P_updated[middle, 0, 0].mean()))


def linearised_model(run, estimator):
    """(F, Q_root, information, P0) of an ESKF run's stored pass (part 2)."""
    f = run.filtered
    steps, n = f.P_updated.shape[0], f.P_updated.shape[1]
    noise = eskf.NoiseModel.from_params(estimator)
    Q = np.zeros((steps, n, n))
    for k in range(1, steps):
        R = rotation_from_quat(f.x_updated[k - 1, eskf.Q_IDX])
        Q[k] = eskf.process_noise(R, noise, ONBOARD_PERIOD, n)
    values, vectors = np.linalg.eigh(Q)
    Q_root = vectors * np.sqrt(np.maximum(values, 0.0))[:, None, :]
    fused = np.any(f.P_updated != f.P_predicted, axis=(1, 2))
    information = np.zeros_like(f.P_updated)
    information[fused] = np.linalg.inv(f.P_updated[fused]) - np.linalg.inv(f.P_predicted[fused])
    information = 0.5 * (information + np.swapaxes(information, 1, 2))
    return f.F, Q_root, information, f.P_predicted[0]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="11_gps_update_eskf")
    parser.add_argument("--seed", type=int, default=3000)
    parser.add_argument("--trajectories", type=int, default=64)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    started = time.process_time()
    imu, gps = ImuParams(), GpsParams()
    print("1. one axis, double integrator, GPS every 0.1 s (σ ratio of position, steady state)\n")
    print("| axis | accel σ per 2 ms | GPS position σ | GPS velocity σ | filter σ | σ ratio |")
    print("|---|---|---|---|---|---|")
    for axis, a, p, v in (
        ("horizontal", imu.accel_std[0], gps.pos_std[0], gps.vel_std[0]),
        ("vertical", imu.accel_std[2], gps.pos_std[2], gps.vel_std[2]),
    ):
        for velocity in (v, None):
            ratio, sigma = axis_ratio(a, p, velocity)
            shown = "not fused" if velocity is None else f"{velocity:g} m/s"
            print(f"| {axis} | {a:g} m/s² | {p:g} m | {shown} | {sigma:.4f} m | {ratio:.3f} |")

    scenario = catalog.load(args.scenario, seed=args.seed, overrides=args.set)
    with tempfile.TemporaryDirectory() as directory:
        run = smooth_run(scenario, directory)
    estimator = scenario.vehicles[0].estimator
    F, Q_root, information, P0 = linearised_model(run, estimator)
    filtered, truth = kalman(F, Q_root, information, P0, np.random.default_rng(args.seed), args.trajectories)
    smoothed = rts(filtered)
    eskf_sigma = np.sqrt(np.diagonal(run.filtered.P_updated, axis1=1, axis2=2)[:, 0:3])
    linear_sigma = np.sqrt(np.diagonal(filtered.P_updated, axis1=1, axis2=2)[:, 0:3])
    print(
        f"\n2. the ESKF's linearised model of {args.scenario} seed {args.seed} ({F.shape[0]} ticks), "
        f"{args.trajectories} white-noise trajectories; the linear filter's position σ against the "
        f"ESKF's: largest relative difference {np.max(np.abs(linear_sigma / eskf_sigma - 1)):.2e}\n"
    )
    print("| state | RMSE filter | RMSE smoother | ratio [95 % CI] | σ ratio of the model "
          "| NEES/dof smoother | middle third: ratio, σ ratio |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    steps = F.shape[0]
    middle = slice(steps // 3, 2 * steps // 3)
    for name, states in (("position", slice(0, 3)), ("velocity", slice(3, 6)), ("attitude", slice(6, 9))):
        e_f, e_s = filtered.x_updated[:, states] - truth[:, states], smoothed.x[:, states] - truth[:, states]
        per_trajectory = (np.mean(np.sum(e_f**2, axis=1), axis=0), np.mean(np.sum(e_s**2, axis=1), axis=0))
        ci = bootstrap(
            per_trajectory,
            lambda f, s, axis=-1: np.sqrt(s.mean(axis=axis) / f.mean(axis=axis)),
            paired=True,
            random_state=0,
            vectorized=True,
        ).confidence_interval
        rmse = [float(np.sqrt(m.mean())) for m in per_trajectory]
        var_f = np.trace(filtered.P_updated[:, states, states], axis1=1, axis2=2).mean()
        var_s = np.trace(smoothed.P[:, states, states], axis1=1, axis2=2).mean()
        solved = np.linalg.solve(smoothed.P[:, states, states], e_s)
        nees = np.mean(np.sum(e_s * solved, axis=1)) / 3
        mid_ratio = np.sqrt(np.mean(e_s[middle] ** 2) / np.mean(e_f[middle] ** 2))
        mid_var = [
            np.trace(p[middle, states, states], axis1=1, axis2=2).mean()
            for p in (filtered.P_updated, smoothed.P)
        ]
        print(
            f"| {name} | {rmse[0]:.4g} | {rmse[1]:.4g} "
            f"| {rmse[1] / rmse[0]:.3f} [{ci.low:.3f}, {ci.high:.3f}] "
            f"| {np.sqrt(var_s / var_f):.3f} | {nees:.3f} "
            f"| {mid_ratio:.3f}, {np.sqrt(mid_var[1] / mid_var[0]):.3f} |"
        )
    print(f"\n3. the ESKF run itself (smooth_eskf), position σ ratio over {scenario.end_time:g} s:")
    edge = int(round(2.0 / ONBOARD_PERIOD))
    for name, ticks in (
        ("the whole flight", slice(None)),
        ("its middle third", middle),
        ("its first 2 s", slice(0, edge)),
        ("its last 2 s", slice(steps - edge, steps)),
    ):
        var_f = np.diagonal(run.filtered.P_updated[ticks], axis1=1, axis2=2)[:, 0:3].mean(axis=0)
        var_s = np.diagonal(run.smoothed.P[ticks], axis1=1, axis2=2)[:, 0:3].mean(axis=0)
        print(
            f"- {name}: {np.sqrt(var_s.sum() / var_f.sum()):.3f} "
            f"(N, E, D: {np.array2string(np.sqrt(var_s / var_f), precision=3)}; "
            f"filter σ {np.array2string(np.sqrt(var_f), precision=4)} m)"
        )
    print(f"\nCPU {time.process_time() - started:.0f} s (user+sys)")


if __name__ == "__main__":
    main()
