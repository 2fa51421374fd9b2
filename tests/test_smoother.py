"""The fixed-interval RTS smoother (``estimation/smoother.py``): the linear form against the
closed-form posterior of a linear-Gaussian model, the ESKF's error-state form and its ⊖/⊕."""

import numpy as np
import pytest

from quad_drake.estimation import eskf
from quad_drake.estimation.smoother import FilterPass, nominal_difference, rts, smooth_eskf


def constant_velocity_problem(rng, steps=15):
    """A 2-D constant-velocity model (x, y, vx, vy) with a different step dt_k each step (so F_k
    varies: the RTS must use the F of the step from k to k+1), position measured each step."""
    dts = rng.uniform(0.05, 0.5, steps)
    F = np.zeros((steps, 4, 4))
    Q = np.zeros((steps, 4, 4))
    for k, dt in enumerate(dts):
        F[k] = np.eye(4)
        F[k, 0, 2] = F[k, 1, 3] = dt
        block = np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]) * 0.3
        Q[k] = np.kron(block, np.eye(2))[[0, 2, 1, 3]][:, [0, 2, 1, 3]]
    H = np.eye(2, 4)
    R = np.diag([0.4, 0.25])
    m0, P0 = np.array([0.0, 1.0, 0.5, -0.2]), np.diag([1.0, 1.0, 0.5, 0.5])
    z = rng.normal(size=(steps, 2))
    return F, Q, H, R, m0, P0, z


def kalman_pass(F, Q, H, R, m0, P0, z) -> FilterPass:
    """A textbook Kalman filter storing its pairs: x_0|-1 = m0, then predict with F[k] into k."""
    steps = z.shape[0]
    xp, Pp, xu, Pu = (
        np.zeros((steps, 4)),
        np.zeros((steps, 4, 4)),
        np.zeros((steps, 4)),
        np.zeros((steps, 4, 4)),
    )
    x, P = m0, P0
    for k in range(steps):
        if k > 0:
            x, P = F[k] @ x, F[k] @ P @ F[k].T + Q[k]
        xp[k], Pp[k] = x, P
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        x, P = x + K @ (z[k] - H @ x), (np.eye(4) - K @ H) @ P
        xu[k], Pu[k] = x, P
    return FilterPass(xp, Pp, xu, Pu, F)


def batch_posterior(F, Q, H, R, m0, P0, z):
    """The smoothing distribution in closed form: the joint Gaussian of all states and all
    measurements, conditioned on the measurements (no recursion)."""
    steps = z.shape[0]
    # x = A w, w = (x_0 - m0, noise_1, ..., noise_{T-1}) ~ N(0, blockdiag(P0, Q_1, ...)) plus the mean
    A = np.zeros((4 * steps, 4 * steps))
    mean = np.zeros(4 * steps)
    W = np.zeros((4 * steps, 4 * steps))
    W[0:4, 0:4] = P0
    mean[0:4] = m0
    for k in range(1, steps):
        W[4 * k : 4 * k + 4, 4 * k : 4 * k + 4] = Q[k]
        mean[4 * k : 4 * k + 4] = F[k] @ mean[4 * k - 4 : 4 * k]
    for k in range(steps):
        block = np.eye(4)
        for j in range(k, -1, -1):
            A[4 * k : 4 * k + 4, 4 * j : 4 * j + 4] = block
            block = block @ F[j]
    Sxx = A @ W @ A.T
    Hbig = np.kron(np.eye(steps), H)
    Szz = Hbig @ Sxx @ Hbig.T + np.kron(np.eye(steps), R)
    gain = np.linalg.solve(Szz, Hbig @ Sxx).T
    x = mean + gain @ (z.ravel() - Hbig @ mean)
    P = Sxx - gain @ Hbig @ Sxx
    return x.reshape(steps, 4), np.array([P[4 * k : 4 * k + 4, 4 * k : 4 * k + 4] for k in range(steps)])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_linear_rts_equals_the_closed_form_posterior_with_time_varying_transitions(seed):
    problem = constant_velocity_problem(np.random.default_rng(seed))
    smoothed = rts(kalman_pass(*problem))
    x, P = batch_posterior(*problem)
    np.testing.assert_allclose(smoothed.x, x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(smoothed.P, P, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(smoothed.sigma()[-1], np.sqrt(np.diag(kalman_pass(*problem).P_updated[-1])))


def test_a_fixed_transition_is_not_the_smoother_of_a_time_varying_model():
    """The FilterPy #278 error (the transition of the wrong step) moves the result: the test above
    can tell."""
    problem = constant_velocity_problem(np.random.default_rng(3))
    filtered = kalman_pass(*problem)
    f = filtered
    wrong = FilterPass(f.x_predicted, f.P_predicted, f.x_updated, f.P_updated, np.roll(f.F, 1, axis=0))
    x, _ = batch_posterior(*problem)
    assert np.abs(rts(wrong).x - x).max() > 1e-3


def random_nominal(rng):
    q = rng.normal(size=4)
    return eskf.initial_nominal(rng.normal(size=3), rng.normal(size=3), q / np.linalg.norm(q),
                                rng.normal(size=3) * 0.1, rng.normal(size=3) * 0.01)  # fmt: skip


@pytest.mark.parametrize("n", [9, 15])
def test_nominal_difference_inverts_the_injection(n):
    rng = np.random.default_rng(n)
    for _ in range(20):
        x, dx = random_nominal(rng), rng.normal(size=n) * 0.3
        injected, _ = eskf.inject(x, np.eye(n), dx)
        np.testing.assert_allclose(nominal_difference(injected, x, n), dx, rtol=0, atol=1e-12)


@pytest.mark.parametrize("n", [9, 15])
def test_the_eskf_smoother_is_the_linear_one_where_no_attitude_moves(n):
    """With the nominals all identity attitude and no attitude correlation (P's attitude block
    decoupled and F not coupling into it) the error-state smoother is the linear RTS on the
    error state: same gains, smoothed position/velocity equal to 1e-12."""
    rng = np.random.default_rng(10 + n)
    steps = 12
    F = np.tile(np.eye(n), (steps, 1, 1))
    for k in range(steps):
        F[k, 0:3, 3:6] = np.eye(3) * rng.uniform(0.01, 0.1)
    xp, xu = np.zeros((steps, 16)), np.zeros((steps, 16))
    xp[:, 6] = xu[:, 6] = 1.0
    xp[:, 0:6], xu[:, 0:6] = rng.normal(size=(steps, 6)), rng.normal(size=(steps, 6))
    Pp, Pu = np.zeros((steps, n, n)), np.zeros((steps, n, n))
    for k in range(steps):  # a filter's pairs: P_k|k-1 = F_k P_k-1|k-1 F_kᵀ + Q, P_k|k <= P_k|k-1
        Pp[k] = np.eye(n) * 0.1 if k == 0 else F[k] @ Pu[k - 1] @ F[k].T + np.eye(n) * 0.01
        M = rng.normal(size=(6, 6)) * 0.05
        Pu[k] = Pp[k]
        Pu[k, 0:6, 0:6] = np.linalg.inv(np.linalg.inv(Pp[k, 0:6, 0:6]) + M @ M.T)
    smoothed = smooth_eskf(FilterPass(xp, Pp, xu, Pu, F))
    linear = rts(FilterPass(xp[:, 0:6], Pp[:, 0:6, 0:6], xu[:, 0:6], Pu[:, 0:6, 0:6], F[:, 0:6, 0:6]))
    np.testing.assert_allclose(smoothed.x[:, 0:6], linear.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(smoothed.P[:, 0:6, 0:6], linear.P, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(smoothed.x[:, 6:10], xu[:, 6:10])
