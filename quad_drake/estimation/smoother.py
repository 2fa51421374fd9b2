"""Fixed-interval Rauch–Tung–Striebel smoothing of a Kalman filter's stored pass, and of the ESKF's.

A forward filter pass is stored per tick k = 0 .. T-1 as :class:`FilterPass`: the predicted pair
(x_k|k-1, P_k|k-1) (the prediction of tick k from the updated pair of tick k-1), the updated pair
(x_k|k, P_k|k) after every measurement of tick k, and F_k, the transition of the prediction step
from tick k-1 to tick k. The backward pass (Rauch, Tung & Striebel 1965; Särkkä, *Bayesian
Filtering and Smoothing*, 2013, Thm. 8.2) runs k = T-2 .. 0:

    C_k  = P_k|k F_(k+1)ᵀ P_(k+1|k)⁻¹                 smoother gain
    x_k|T = x_k|k + C_k (x_(k+1)|T - x_(k+1)|k)
    P_k|T = P_k|k + C_k (P_(k+1)|T - P_(k+1)|k) C_kᵀ

with F_(k+1) the transition of the step FROM k TO k+1: the one that produced P_(k+1)|k from
P_k|k. (Using a fixed F, or F_k of the step into k, is the error FilterPy #278 reports for
time-varying models.) :func:`rts` is this linear form.

The error-state EKF (``estimation/eskf.py``, ``kernels/eskf.py``) keeps a nominal state x = (p_N
m, v_N m/s, q_NB wxyz, b_a m/s², b_g rad/s) and a covariance P of the error dx = (dp, dv,
dtheta (rad, WORLD axes: R_true = Exp(dtheta) R_hat), db_a, db_g) (n = 15; 9 without biases).
:func:`smooth_eskf` runs the same backward pass on the error state:

    e_(k+1) = x_(k+1)|T ⊖ x_(k+1)|k       (dp, dv, Log(R_s R_predᵀ) world axes, db): the smoothed
                                           nominal's error relative to the predicted nominal
    dx_k    = C_k e_(k+1),   x_k|T = x_k|k ⊕ dx_k    (``eskf.inject``: q = Exp(dtheta) ⊗ q)
    P_k|T   = G(dx_k) [P_k|k + C_k (G(e)⁻¹ P_(k+1)|T G(e)⁻ᵀ - P_(k+1)|k) C_kᵀ] G(dx_k)ᵀ

where G(d) = I with attitude block I + [dtheta]x / 2 is the filter's own covariance reset
Jacobian (``eskf.reset_jacobian``): P_(k+1)|T is the covariance about the smoothed nominal, so
it is moved to the tangent space of the predicted nominal (G(e)⁻¹) before it meets P_(k+1)|k,
and the result about x_k|k to the tangent space of x_k|T (G(dx_k)), as the filter moves its P
after each injection. Pure numpy, no pydrake; no I/O.
"""

from dataclasses import dataclass

import numpy as np

from quad_drake.estimation import eskf


@dataclass(frozen=True)
class FilterPass:
    """One forward pass stored per tick k = 0 .. T-1 (module docstring).

    x_predicted, x_updated: (T, m) states (the ESKF's nominal, m = 16); P_predicted, P_updated:
    (T, n, n) covariances; F: (T, n, n), F[k] the transition of the prediction from tick k-1 to
    tick k (F[0] is not used). Units and frames as the filter's.
    """

    x_predicted: np.ndarray
    P_predicted: np.ndarray
    x_updated: np.ndarray
    P_updated: np.ndarray
    F: np.ndarray


@dataclass(frozen=True)
class Smoothed:
    """The smoothed states x (T, m) and covariances P (T, n, n); gains C (T, n, n), C[T-1] = 0."""

    x: np.ndarray
    P: np.ndarray
    C: np.ndarray

    def sigma(self) -> np.ndarray:
        """(T, n) standard deviations, the square roots of P's diagonal (the filter's units)."""
        return np.sqrt(np.maximum(np.diagonal(self.P, axis1=1, axis2=2), 0.0))


def smoother_gain(P_updated, F_next, P_predicted_next) -> np.ndarray:
    """C = P_k|k F_(k+1)ᵀ P_(k+1)|k⁻¹ (n x n) by a linear solve (P symmetric positive definite)."""
    return np.linalg.solve(P_predicted_next, F_next @ P_updated).T


def rts(filtered: FilterPass) -> Smoothed:
    """The linear fixed-interval RTS smoother of a stored Kalman filter pass (module docstring)."""
    f = filtered
    x, P = np.array(f.x_updated, dtype=float), np.array(f.P_updated, dtype=float)
    C = np.zeros_like(P)
    for k in range(x.shape[0] - 2, -1, -1):
        C[k] = smoother_gain(f.P_updated[k], f.F[k + 1], f.P_predicted[k + 1])
        x[k] = f.x_updated[k] + C[k] @ (x[k + 1] - f.x_predicted[k + 1])
        P[k] = f.P_updated[k] + C[k] @ (P[k + 1] - f.P_predicted[k + 1]) @ C[k].T
        P[k] = 0.5 * (P[k] + P[k].T)
    return Smoothed(x, P, C)


def nominal_difference(x, x_reference, n) -> np.ndarray:
    """x ⊖ x_reference (n,): the error dx with x = x_reference ⊕ dx for two ESKF nominals (16,):
    position and velocity differences (m, m/s), dtheta = Log(R(q) R(q_ref)ᵀ) (rad, world axes)
    and, when n = 15, the bias differences."""
    d = np.empty(n)
    d[0:6] = x[0:6] - x_reference[0:6]
    d[6:9] = eskf.attitude_errors(x[None, eskf.Q_IDX], x_reference[None, eskf.Q_IDX])[0]
    if n == eskf.ERROR_SIZE_WITH_BIASES:
        d[9:15] = x[10:16] - x_reference[10:16]
    return d


def smooth_eskf(filtered: FilterPass) -> Smoothed:
    """The RTS smoother of an ESKF pass (module docstring): nominals (T, 16) and error
    covariances (T, n, n) about them."""
    f = filtered
    n = f.P_updated.shape[1]
    x, P = np.array(f.x_updated, dtype=float), np.array(f.P_updated, dtype=float)
    C = np.zeros_like(P)
    for k in range(x.shape[0] - 2, -1, -1):
        C[k] = smoother_gain(f.P_updated[k], f.F[k + 1], f.P_predicted[k + 1])
        e = nominal_difference(x[k + 1], f.x_predicted[k + 1], n)
        G_inverse = np.linalg.inv(eskf.reset_jacobian(e[6:9], n))
        P_next = G_inverse @ P[k + 1] @ G_inverse.T
        dx = C[k] @ e
        x_k, P_k = eskf.inject(
            f.x_updated[k], f.P_updated[k] + C[k] @ (P_next - f.P_predicted[k + 1]) @ C[k].T, dx
        )
        x[k], P[k] = x_k, 0.5 * (P_k + P_k.T)
    return Smoothed(x, P, C)
