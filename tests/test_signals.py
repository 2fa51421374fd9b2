"""The reference's named signals derived from logged arrays (pure)."""

import math

import numpy as np
import pytest

from quad_drake.estimation.vocabulary import DIAG, DIAGNOSTICS_SIZE, EKF7, ESKF15
from quad_drake.judging.signals import (
    LOG_WIDTHS,
    Signal,
    Signals,
    empty_logs,
    euler_from_quats,
    key_unit,
    signal_unit,
    stamp_fresh,
    vehicle_signals,
    wrap_angles,
)
from quad_drake.models.rotations import euler_from_quat, quat_from_euler, yaw_from_quats


def test_stamp_fresh_marks_only_new_samples():
    stamps = np.array([-1.0, -1.0, 0.1, 0.1, 0.1, 0.2, 0.2, 0.3])
    np.testing.assert_array_equal(stamp_fresh(stamps), [0, 0, 1, 0, 0, 1, 0, 1])


def test_euler_from_quats_matches_the_scalar_version():
    rng = np.random.default_rng(4)
    angles = rng.uniform([-3, -1.5, -3], [3, 1.5, 3], size=(50, 3))
    quats = np.array([quat_from_euler(*a) for a in angles])
    roll, pitch, yaw = euler_from_quats(quats)
    expected = np.array([euler_from_quat(q) for q in quats])
    np.testing.assert_allclose(np.column_stack([roll, pitch, yaw]), expected, atol=1e-12)
    np.testing.assert_array_equal(yaw_from_quats(quats), yaw)
    strided = np.zeros((50, 2, 13))
    strided[:, 1, 3:7] = quats  # a (50,) view of a batch's state log, as the EKF7 errors read it
    np.testing.assert_array_equal(yaw_from_quats(strided[:, 1, 3:7]), yaw)


def test_merged_signals_are_derived_once_and_later_names_win():
    calls = []

    def maker(value):
        return lambda: calls.append(value) or Signal(np.array([value]), np.array([True]))

    a = Signals({"A.x": maker(1.0), "shared": maker(2.0)})
    assert a["A.x"].values[0] == 1.0 and calls == [1.0]
    merged = a.merged(Signals({"B.x": maker(3.0)}), Signals({"shared": maker(4.0)}))
    assert list(merged) == ["A.x", "shared", "B.x"]
    assert merged["A.x"].values[0] == 1.0 and calls == [1.0]  # derived before the merge: kept
    assert merged["shared"].values[0] == 4.0 and "B.y" not in merged and len(merged) == 3


def test_wrap_angles_into_minus_pi_pi():
    np.testing.assert_allclose(
        wrap_angles(np.array([3.5, -3.5, 0.2, 2 * math.pi])),
        [3.5 - 2 * math.pi, 2 * math.pi - 3.5, 0.2, 0.0],
        atol=1e-12,
    )


def test_names_follow_the_logs_present():
    truth_only = vehicle_signals(
        "Q", empty_logs({k: LOG_WIDTHS[k] for k in ("state", "reference", "motor_forces")})
    )
    assert {"Q.Pos.X", "Q.Roll", "Q.Omega.Z", "Q.PosFollowErr", "Q.Thrust.D"} <= set(truth_only)
    assert not any(".Est." in n or ".GPS." in n for n in truth_only)
    for vocabulary, own in ((EKF7, {"Q.Est.S.Yaw"}), (ESKF15, {"Q.Est.S.AttD", "Q.Est.E.BGZ", "Q.Est.BAX"})):
        widths = dict(LOG_WIDTHS, **vocabulary.log_widths())
        full = vehicle_signals("Q", empty_logs(widths), vocabulary)
        common = {"Q.IMU.AX", "Q.GPS.VZ", "Q.MagYaw", "Q.Est.E.MaxEuler", "Q.Est.E.Roll", "Q.Est.E.Pos"}
        counters = {"Q.Est.GpsGated", "Q.Est.CovRepairs", "Q.Est.GpsNIS"}
        assert common | own | counters <= set(full)
        assert {f"Q.Est.S.{name}" for name in vocabulary.state_names} <= set(full)


def test_estimation_errors_sigmas_and_freshness():
    yaw_true, yaw_est = 3.1, -3.1
    state = np.zeros((2, 13))
    state[:, 3:7] = quat_from_euler(0.0, 0.0, yaw_true)
    state[:, 0:3] = [1.0, 2.0, -1.0]
    ekf_state = np.zeros((2, 7))
    ekf_state[:, 0:3] = [1.3, 2.4, -1.0]
    ekf_state[:, 6] = yaw_est
    covariance = np.tile(np.diag([0.01, 0.04, 0.09, 1, 1, 1, 0.25]).ravel(), (2, 1))
    attitude = np.array([[0.02, -0.01, yaw_est]] * 2)
    gps = np.array([[0, 0, 0, 0, 0, 0, -1.0], [1, 2, -1, 0, 0, 0, 0.1]])
    estimated_state = np.zeros((2, 13))
    estimated_state[:, 0:3] = ekf_state[:, 0:3]
    estimated_state[:, 3:7] = quat_from_euler(0.02, -0.01, yaw_est)
    diagnostics = np.zeros((2, DIAGNOSTICS_SIZE))
    diagnostics[:, DIAG["gps_gated"]] = [0, 1]
    logs = {
        "state": state,
        "estimated_state": estimated_state,
        "ekf_state": ekf_state,
        "covariance": covariance,
        "attitude": attitude,
        "diagnostics": diagnostics,
        "gps": gps,
    }
    signals = vehicle_signals("Q", logs, EKF7)
    np.testing.assert_allclose(signals["Q.Est.E.Roll"].values, 0.02, atol=1e-12)
    np.testing.assert_array_equal(signals["Q.Est.GpsGated"].values, [0, 1])
    np.testing.assert_allclose(signals["Q.Est.E.Yaw"].values, 2 * math.pi - 6.2, atol=1e-9)  # short way
    np.testing.assert_allclose(signals["Q.Est.S.Y"].values, 0.2)
    np.testing.assert_allclose(signals["Q.Est.E.Pos"].values, 0.5)
    np.testing.assert_allclose(signals["Q.Est.E.MaxEuler"].values, 2 * math.pi - 6.2, atol=1e-9)
    np.testing.assert_array_equal(signals["Q.GPS.X"].fresh, [False, True])
    assert signals["Q.Pos.X"].fresh.all()


@pytest.mark.parametrize(
    "name, unit",
    [
        ("Quad.Pos.X", "m"),
        ("Quad.Vel.Z", "m/s"),
        ("Quad.Omega.X", "rad/s"),
        ("Quad.Roll", "rad"),
        ("Quad.Ref.Yaw", "rad"),
        ("Quad.PosFollowErr", "m"),
        ("Quad.GPS.X", "m"),
        ("Quad.GPS.VX", "m/s"),
        ("Quad.IMU.AX", "m/s^2"),
        ("Quad.IMU.GZ", "rad/s"),
        ("Quad.MagYaw", "rad"),
        ("Quad.Thrust.B", "N"),
        ("Quad2.Est.E.Yaw", "rad"),
        ("Quad.Est.S.Z", "m"),
        ("Quad.Est.E.VX", "m/s"),
        ("Quad.Est.E.Pos", "m"),
        ("Quad.Est.E.Vel", "m/s"),
        ("Quad.Est.E.MaxEuler", "rad"),
        ("Quad.Est.Roll", "rad"),
        ("Quad.Unknown", ""),
    ],
)
def test_signal_unit(name, unit):
    assert signal_unit(name) == unit


@pytest.mark.parametrize(
    "key, unit",
    [
        ("Est.E.AttN", "rad"),
        ("Est.E.BAX", "m/s^2"),
        ("Est.E.BGZ", "rad/s"),
        ("Est.E.X", "m"),
        ("PosFollowErr", "m"),
    ],
)
def test_a_signal_named_without_its_vehicle_has_the_same_unit(key, unit):
    assert key_unit(key) == signal_unit(f"Quad.{key}") == unit
