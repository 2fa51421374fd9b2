"""The estimators' compiled kernels against the scalar functions, row by row, on seeded random
inputs; an estimator system sized by n against n estimator systems sized by 1 fed the same samples.

Tolerance: |batched - scalar| <= 1e-12 + 1e-12 |scalar| per entry (absolute for small entries,
relative for large ones), TOL below.
"""

import dataclasses
import math

import numpy as np
import pytest
from conftest import as_flight_input
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from quad_drake.config import (
    GpsParams,
    ImuParams,
    MagParams,
    SensorsConfig,
    VehicleConfig,
)
from quad_drake.conventions import GRAVITY, NO_SAMPLE_STAMP, PX4_UPDATE_PERIOD
from quad_drake.estimation import ekf, eskf, gating
from quad_drake.estimation.complementary import complementary_update
from quad_drake.estimation.registry import (
    KINDS,
    AttitudeFilterParams,
    Ekf7EstimatorConfig,
    EskfEstimatorConfig,
    sharing_problem,
    vocabulary_for,
)
from quad_drake.estimation.vocabulary import DIAG, DIAGNOSTICS_SIZE
from quad_drake.kernels import attitude as attitude_kernel
from quad_drake.kernels import ekf7, fusion
from quad_drake.kernels import eskf as eskf_kernel
from quad_drake.kernels.imu_hold import HOLD_SIZE, IMU_HOLD_TIME, initial_hold
from quad_drake.models.fidelity import PHYSICAL, REFERENCE
from quad_drake.models.rotations import quat_from_euler_tuple
from quad_drake.systems.estimators import build_estimator
from quad_drake.systems.faults import GpsDelayCompensator

TOL = {"rtol": 1e-12, "atol": 1e-12}
DT = 0.002
N = 64

SENSORS_GPS_MAG = SensorsConfig(imu=ImuParams(), gps=GpsParams(), mag=MagParams())
"""An IMU, a GPS and a yaw magnetometer: the estimator has their input ports."""


def random_covariances(rng, n, count=N, scale=1.0):
    A = rng.normal(size=(count, n, n)) * scale
    return A @ A.transpose(0, 2, 1) + 1e-3 * np.eye(n)


def random_attitudes(rng, count=N):
    return np.column_stack(
        [rng.uniform(-1.0, 1.0, count), rng.uniform(-1.0, 1.0, count), rng.uniform(-math.pi, math.pi, count)]
    )


def specific_forces(rng, count=N):
    return np.array([0.0, 0.0, -GRAVITY]) + rng.normal(scale=2.0, size=(count, 3))


def gyro_samples(rng, count=N):
    w = rng.normal(scale=1.0, size=(count, 3))
    w[:4] = 0.0  # the rate < 1e-12 branch
    return w


def assert_rows(batched, scalar_rows):
    np.testing.assert_allclose(batched, np.array(scalar_rows, dtype=float), **TOL)


# ----- complementary filter ------------------------------------------------------------------------


@pytest.mark.parametrize("variant", ["nonlinear", "small_angle"])
@pytest.mark.parametrize("reference_accelerometer", [False, True])
def test_complementary_update_matches_the_scalar_filter(variant, reference_accelerometer):
    rng = np.random.default_rng(11)
    attitude, f, w = random_attitudes(rng), specific_forces(rng), gyro_samples(rng)
    batched = attitude_kernel.complementary_update(attitude, f, w, DT, 0.5, variant, reference_accelerometer)
    scalar = [
        complementary_update(*attitude[i], f[i], w[i], DT, 0.5, variant, reference_accelerometer)
        for i in range(N)
    ]
    assert_rows(batched, scalar)
    with pytest.raises(ValueError):
        attitude_kernel.complementary_update(attitude, f, w, DT, 0.5, "euler")


# ----- 7-state EKF ---------------------------------------------------------------------------------


@pytest.mark.parametrize("reference_accelerometer", [False, True])
def test_ekf7_predict_matches_the_scalar_step(reference_accelerometer):
    rng = np.random.default_rng(12)
    params = Ekf7EstimatorConfig()
    Q = ekf.process_noise(params)
    x, P = rng.normal(size=(N, 7)), random_covariances(rng, 7)
    attitude, f = random_attitudes(rng), specific_forces(rng)
    x_new, P_new = ekf7.predict_with_yaw(x, P, attitude, f, DT, Q, reference_accelerometer)
    G = ekf.predict_jacobian(np.zeros(7), 0.0, 0.0, (0.0, 0.0, 0.0), DT)
    for i in range(N):
        x_ref, P_ref = ekf.predict_with_yaw(
            x[i].tolist(), P[i], attitude[i], f[i], DT, Q, G, reference_accelerometer
        )
        np.testing.assert_allclose(x_new[i], x_ref, **TOL)
        np.testing.assert_allclose(P_new[i], P_ref, **TOL)


def _ekf7_tick(x, P, attitude, imu, gps, mag, diagnostics, book, Q, gains, R_mag, threshold=9.0):
    """ekf7.tick with the scalar EKF's settings; (quiet, healthy)."""
    healthy = np.empty(x.shape[0], dtype=bool)
    filters = fusion.Filters(x, P, diagnostics, book, hold=np.zeros((x.shape[0], HOLD_SIZE)))
    model = ekf7.Model(DT, Q, ekf.gravity_z(False), float(R_mag[0, 0]), float(threshold))
    inputs = (as_flight_input(attitude), as_flight_input(imu), as_flight_input(gps), as_flight_input(mag))
    quiet = ekf7.tick(*filters, *inputs, *model, gains, healthy)
    return quiet, healthy


def test_the_running_mean_of_the_imu_bridges_a_dropout():
    """complementary_tick's hold: the mean of the finite samples with weight dt / (IMU_HOLD_TIME +
    dt), started by the first; over NaN samples the filter integrates the mean and reports a NaN
    rate; a vehicle that never had a finite sample keeps its roll and pitch."""
    rng = np.random.default_rng(21)
    ticks, count = 60, 4
    imu = np.column_stack([specific_forces(rng, ticks * count), gyro_samples(rng, ticks * count)])
    imu = imu.reshape(ticks, count, 6)
    imu[20:35, 1] = math.nan  # vehicle 1: a 30 ms dropout
    imu[:, 2] = math.nan  # vehicle 2: never a finite sample
    attitude, rate = np.zeros((count, 3)), np.zeros((count, 3))
    hold = np.tile(initial_hold(), (count, 1))
    weight = DT / (IMU_HOLD_TIME + DT)
    model = attitude_kernel.model(DT, 0.5, "nonlinear")
    mean = imu[0].copy()
    for k in range(ticks):
        before = attitude.copy()
        no_gps = as_flight_input(np.zeros((count, 7)))
        attitude_kernel.tick(attitude, rate, hold, as_flight_input(imu[k]), no_gps, *model)
        finite = np.isfinite(imu[k]).all(axis=1)
        if k:
            mean[finite] += weight * (imu[k][finite] - mean[finite])
        np.testing.assert_allclose(hold[[0, 1, 3], 0:6], mean[[0, 1, 3]], **TOL)
        if 20 <= k < 35:
            assert np.isnan(rate[1]).all()
            prior = before[1:2].copy()
            prior[0, 2] = 0.0  # the prior yaw is the EKF's
            expected = attitude_kernel.complementary_update(
                prior, mean[1:2, 0:3], mean[1:2, 3:6], DT, 0.5, "nonlinear"
            )
            np.testing.assert_allclose(attitude[1], expected[0], **TOL)
        np.testing.assert_array_equal(rate[[0, 3]], imu[k][[0, 3], 3:6])
    assert hold[2, 6] == 0.0 and np.isnan(rate[2]).all()
    np.testing.assert_array_equal(attitude[2, 0:2], 0.0)


def _never_sampled(width, count=N):
    samples = np.zeros((count, width))
    samples[:, -1] = NO_SAMPLE_STAMP
    return samples


def test_ekf7_tick_with_tilt_noise_matches_the_scalar_step():
    rng = np.random.default_rng(13)
    params = Ekf7EstimatorConfig(tilt_gyro_std=0.5)
    tilt = ekf.TiltNoise.from_params(params, AttitudeFilterParams(), DT)
    Q, t = ekf.process_noise(params), 7.3
    x, P = rng.normal(size=(N, 7)), random_covariances(rng, 7)
    attitude, imu = random_attitudes(rng), np.column_stack([specific_forces(rng), gyro_samples(rng)])
    x_ref, P_ref = x.copy(), P.copy()
    quiet, healthy = _ekf7_tick(
        x, P, attitude, imu, _never_sampled(7), _never_sampled(2), np.zeros((N, DIAGNOSTICS_SIZE)),
        np.zeros((N, fusion.BOOK_SIZE)), Q, tilt.gains(t), ekf.mag_noise(params),
    )  # fmt: skip
    assert quiet and healthy.all()
    G = ekf.predict_jacobian(np.zeros(7), 0.0, 0.0, (0.0, 0.0, 0.0), DT)
    for i in range(N):
        Q_i = tilt.process_noise(t, Q, attitude[i], imu[i, 0:3], imu[i, 3:6])
        x_i, P_i = ekf.predict_with_yaw(x_ref[i].tolist(), P_ref[i], attitude[i], imu[i], DT, Q_i, G)
        np.testing.assert_allclose(x[i], x_i, **TOL)
        np.testing.assert_allclose(P[i], P_i, **TOL)
        assert not np.array_equal(Q_i, Q)


def test_ekf7_tick_fuses_the_magnetometer_only_on_a_quiet_tick():
    """Quiet (no fresh GPS, P healthy): the prediction then :func:`ekf7_mag_tick`; a fresh GPS
    sample (or an unhealthy P) leaves the mag step, the repair and the GPS to the caller."""
    rng = np.random.default_rng(16)
    params = Ekf7EstimatorConfig()
    Q, R_mag = ekf.process_noise(params), ekf.mag_noise(params)
    x, P = rng.normal(size=(N, 7)), random_covariances(rng, 7, scale=0.1)
    attitude, imu = random_attitudes(rng), np.column_stack([specific_forces(rng), gyro_samples(rng)])
    mag = np.column_stack([x[:, 6] + rng.normal(scale=0.3, size=N), np.full(N, 0.01)])
    mag[::3, 1] = NO_SAMPLE_STAMP  # a third without a sample
    gps = _never_sampled(7)

    def tick(gps, P_start=P):
        x_new, P_new = x.copy(), P_start.copy()
        diagnostics, book = np.zeros((N, DIAGNOSTICS_SIZE)), np.zeros((N, fusion.BOOK_SIZE))
        quiet, healthy = _ekf7_tick(
            x_new, P_new, attitude, imu, gps, mag, diagnostics, book, Q, ekf7.NO_TILT, R_mag
        )
        return quiet, healthy, x_new, P_new, diagnostics, book

    quiet, healthy, x_new, P_new, diagnostics, book = tick(gps)
    x_ref, P_ref = x.copy(), P.copy()
    diagnostics_ref, book_ref = np.zeros((N, DIAGNOSTICS_SIZE)), np.zeros((N, fusion.BOOK_SIZE))
    _ekf7_tick(
        x_ref,
        P_ref,
        attitude,
        imu,
        gps,
        _never_sampled(2),
        diagnostics_ref,
        book_ref,
        Q,
        ekf7.NO_TILT,
        R_mag,
    )
    reference = fusion.Filters(x_ref, P_ref, diagnostics_ref, book_ref, None)
    ekf7.mag_tick(reference, as_flight_input(mag), R_mag, 9.0)
    assert quiet and healthy.all()
    np.testing.assert_array_equal(x_new, x_ref)
    np.testing.assert_array_equal(P_new, P_ref)
    np.testing.assert_array_equal(diagnostics, diagnostics_ref)
    np.testing.assert_array_equal(book, book_ref)
    assert (book[:, fusion.MAG_SLOT] == 0.01).sum() == N - len(range(0, N, 3))
    assert diagnostics[:, DIAG["mag_gated"]].sum() > 0  # the gate was exercised

    gps[5] = [0.0] * 6 + [0.1]  # one fresh GPS sample
    unhealthy = P.copy()
    unhealthy[7, 2, 2] = -1.0
    for gps_case, P_case, flagged in ((gps, P, None), (_never_sampled(7), unhealthy, 7)):
        quiet, healthy, x_new, P_new, diagnostics, book = tick(gps_case, P_case)
        assert not quiet
        assert healthy.tolist() == [i != flagged for i in range(N)]
        assert (book == 0.0).all() and not diagnostics[:, DIAG["mag_gated"]].any()  # no mag step


def _check_update(batched, scalar, x, P, z, R):
    x_new, P_new, nis = batched(x, P, z, R)
    for i in range(x.shape[0]):
        x_ref, P_ref, nis_ref = scalar(x[i].copy(), P[i].copy(), z[i], R)
        np.testing.assert_allclose(x_new[i], x_ref, **TOL)
        np.testing.assert_allclose(P_new[i], P_ref, **TOL)
        if math.isnan(nis_ref):
            assert math.isnan(nis[i])
        else:
            np.testing.assert_allclose(nis[i], nis_ref, **TOL)


def test_ekf7_gps_and_mag_updates_match_the_scalar_updates():
    rng = np.random.default_rng(13)
    params = Ekf7EstimatorConfig()
    x, P = rng.normal(size=(N, 7)), random_covariances(rng, 7, scale=0.5)
    x[:, 6] = rng.uniform(-math.pi, math.pi, N)
    gps = x[:, 0:6] + rng.normal(size=(N, 6))
    gps[5, 2] = math.nan
    gps[6, 0] = math.inf
    _check_update(ekf7.gps_update, ekf.gps_update, x, P, gps, ekf.gps_noise(params))
    yaw = rng.uniform(-math.pi, math.pi, N)
    yaw[7] = math.nan
    _check_update(ekf7.mag_update, ekf.mag_update, x, P, yaw, ekf.mag_noise(params))


# ----- gating and covariance health ----------------------------------------------------------------


def test_gps_updates_of_any_component_subset_match_the_textbook_update():
    """The GPS groups a gate accepts are fused alone: H = those rows of [I6 0] (ekf.kalman_update;
    eskf.joseph_update then eskf.inject), each vehicle with its own subset, none = prior kept."""
    rng = np.random.default_rng(14)
    R = np.diag(rng.uniform(0.01, 1.0, 6))
    mask = rng.uniform(size=(N, 6)) < 0.6
    mask[0] = True
    mask[1] = False
    z = rng.normal(size=(N, 6))
    x7, P7 = rng.normal(size=(N, 7)), random_covariances(rng, 7)
    x_new, P_new, nis = ekf7.gps_update(x7, P7, z, R, mask)
    for i in range(N):
        rows = np.flatnonzero(mask[i])
        if not len(rows):
            np.testing.assert_array_equal(x_new[i], x7[i])
            assert math.isnan(nis[i])
            continue
        H = np.eye(7)[rows]
        x_ref, P_ref, nis_ref = ekf.kalman_update(
            x7[i], P7[i], z[i, rows], H, R[np.ix_(rows, rows)], x7[i, rows]
        )
        np.testing.assert_allclose(x_new[i], x_ref, **TOL)
        np.testing.assert_allclose(P_new[i], P_ref, **TOL)
        assert nis[i] == pytest.approx(nis_ref, rel=1e-12)
    x15 = random_nominal(rng)
    P15 = random_covariances(rng, 15, scale=0.1)
    x_new, P_new, nis = eskf_kernel.gps_update(x15, P15, z, R, mask)
    for i in np.flatnonzero(mask.any(axis=1)):
        rows = np.flatnonzero(mask[i])
        dx, P_ref, nis_ref = eskf.joseph_update(
            P15[i], np.eye(15)[rows], R[np.ix_(rows, rows)], z[i, rows] - x15[i, rows]
        )
        x_ref, P_ref = eskf.inject(x15[i], P_ref, dx)
        np.testing.assert_allclose(x_new[i], x_ref, **TOL)
        np.testing.assert_allclose(P_new[i], P_ref, **TOL)
        assert nis[i] == pytest.approx(nis_ref, rel=1e-12)


@pytest.mark.parametrize("n", [7, 15])
def test_covariance_health_matches_the_scalar_checks(n):
    rng = np.random.default_rng(15)
    P = random_covariances(rng, n)
    P[1, 2, 2] = -0.5  # negative variance
    P[2, 0, 3] = math.nan
    P[3, 4, 4] = math.inf
    vectors = np.linalg.qr(rng.normal(size=(n, n)))[0]
    P[4] = (vectors * np.r_[-1e-3, np.ones(n - 1)]) @ vectors.T  # indefinite, positive diagonal
    P[5] = (vectors * np.r_[0.0, np.ones(n - 1)]) @ vectors.T  # singular PSD
    P[6] = P[4] + 1e-9 * rng.normal(size=(n, n))  # indefinite and asymmetric
    healthy = fusion.covariance_looks_healthy(P)
    assert healthy.tolist() == [gating.covariance_looks_healthy(P[i]) for i in range(N)]
    assert not healthy[1:4].any() and healthy[4:].all()
    large = P[4:7].copy()
    large[0, 0, 1] = large[0, 1, 0] = 1e308  # finite entries, an infinite sum
    large[1, 0, 1] = large[1, 1, 0] = 1e301  # large finite entries, a finite sum
    large[2, 1, 2] = -math.inf
    with np.errstate(over="ignore"):
        expected = [gating.covariance_looks_healthy(P_i) for P_i in large]
    assert fusion.covariance_looks_healthy(large).tolist() == expected == [False, True, False]
    fallback = np.diag(rng.uniform(0.1, 1.0, n))
    P_new, outcomes = fusion.repaired_covariance(P, fallback)
    for i in range(N):
        P_ref, outcome = gating.repaired_covariance(P[i], fallback)
        assert outcomes[i] == outcome
        np.testing.assert_allclose(P_new[i], P_ref, **TOL)
    assert outcomes[[2, 3, 4, 6]].tolist() == [gating.COVARIANCE_RESET] * 2 + [gating.COVARIANCE_REPAIRED] * 2
    in_place, check = P.copy(), np.arange(N) % 2 == 0
    outcomes = fusion.repair_covariances(in_place, check, fallback)
    np.testing.assert_array_equal(in_place[check], P_new[check])
    np.testing.assert_array_equal(in_place[~check], P[~check])
    assert (outcomes[~check] == gating.COVARIANCE_OK).all()


# ----- error-state EKF -----------------------------------------------------------------------------


def random_nominal(rng, count=N, baro=False):
    """(count, 16) nominals, or (count, 17) with a baro bias."""
    q = rng.normal(size=(count, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    x = np.column_stack([rng.normal(size=(count, 6)), q, rng.normal(scale=0.05, size=(count, 6))])
    return np.column_stack([x, rng.normal(size=count)]) if baro else x


def eskf_params(estimate_biases, isotropic_gyro=True):
    gyro = [0.5, 0.5, 0.5] if isotropic_gyro else [0.3, 0.5, 0.7]
    return EskfEstimatorConfig(estimate_biases=estimate_biases, gyro_std=gyro)


@pytest.mark.parametrize(
    "estimate_biases, isotropic_gyro, baro",
    [
        (True, True, False),
        (False, True, False),
        (True, False, False),
        (True, True, True),
        (False, True, True),
    ],
    ids=["15", "9", "15-aniso", "16-baro", "10-baro"],
)
def test_eskf_predict_matches_the_scalar_step(estimate_biases, isotropic_gyro, baro):
    rng = np.random.default_rng(16)
    params = eskf_params(estimate_biases, isotropic_gyro)
    noise = eskf.NoiseModel.from_params(params)
    n = eskf.initial_covariance(params, baro).shape[0]
    x, P = random_nominal(rng, baro=baro), random_covariances(rng, n, scale=0.3)
    f, w = specific_forces(rng), gyro_samples(rng)
    x_new, P_new = eskf_kernel.predict(
        x, P, f, w, eskf_kernel.model(noise, eskf.noise_buffer(n, noise, DT), DT)
    )
    for i in range(N):
        x_ref, P_ref = eskf.predict(x[i], P[i], f[i], w[i], DT, noise)
        np.testing.assert_allclose(x_new[i], x_ref, **TOL)
        np.testing.assert_allclose(P_new[i], P_ref, **TOL)


@pytest.mark.parametrize(
    "estimate_biases, baro",
    [(True, False), (False, False), (True, True), (False, True)],
    ids=["15", "9", "16-baro", "10-baro"],
)
def test_eskf_updates_and_injection_match_the_scalar_functions(estimate_biases, baro):
    rng = np.random.default_rng(17)
    params = eskf_params(estimate_biases)
    n = eskf.initial_covariance(params, baro).shape[0]
    x, P = random_nominal(rng, baro=baro), random_covariances(rng, n, scale=0.2)
    dx = rng.normal(scale=0.1, size=(N, n))
    dx[:3, 6:9] = 1e-14  # the small-angle branch of quat_exp
    x_new, P_new = eskf_kernel.inject(x, P, dx)
    for i in range(N):
        x_ref, P_ref = eskf.inject(x[i], P[i], dx[i])
        np.testing.assert_allclose(x_new[i], x_ref, **TOL)
        np.testing.assert_allclose(P_new[i], P_ref, **TOL)
    gps = x[:, 0:6] + rng.normal(size=(N, 6))
    gps[8, 4] = math.nan
    _check_update(eskf_kernel.gps_update, eskf.gps_update, x, P, gps, eskf.gps_noise(params))
    yaw = rng.uniform(-math.pi, math.pi, N)
    yaw[9] = math.nan
    _check_update(eskf_kernel.mag_update, eskf.mag_update, x, P, yaw, eskf.mag_noise(params))


@pytest.mark.parametrize("n, baro", [(15, False), (9, False), (16, True)], ids=["15", "9", "16-baro"])
def test_eskf_gravity_fusion_matches_the_scalar_update(n, baro):
    """``kernels.eskf.gravity_tick`` against ``eskf.gravity_fusion_active`` (which vehicles) then
    ``eskf.gravity_update`` and ``eskf.inject`` row by row: near-level attitudes and forces (some
    beyond the gate: rejected, x and P kept); rows left out by each of the conditions (aided by a
    recent GPS sample, the peak-held force out of the band or NaN, a non-finite sample) untouched,
    rows whose GPS sample is older than the timeout or never came fused."""
    rng = np.random.default_rng(23)
    x = random_nominal(rng, baro=baro)
    for i in range(N):
        roll, pitch = rng.normal(scale=0.1, size=2)
        x[i, 6:10] = quat_from_euler_tuple(roll, pitch, rng.uniform(-math.pi, math.pi))
    P = random_covariances(rng, n, scale=0.05)
    imu = np.column_stack([specific_forces(rng), gyro_samples(rng)])
    now, timeout, band = 30.0, 5.0, eskf.GRAVITY_ACCEL_BAND
    book = np.tile(fusion.initial_book(), (N, 1))  # every vehicle: no GPS sample yet
    book[1, fusion.GPS_SLOT] = now - 1.0  # aided
    book[2, fusion.GPS_SLOT] = now - timeout - 0.5  # its GPS lost: unaided
    book[3, fusion.GPS_SLOT] = now - timeout  # just aided (PX4: more than the timeout)
    levels = np.column_stack([rng.uniform(0.0, 1.0, N), np.full(N, GRAVITY)])
    levels[4, 1], levels[5, 1], levels[6, 1] = 1.2 * GRAVITY, band[0], math.nan  # out, on the edge, NaN
    imu[7, 1] = math.nan
    active = eskf.gravity_fusion_active(
        book[:, fusion.GPS_SLOT], now, timeout, levels[:, 1], band, imu[:, 0:3]
    )
    assert not active[[1, 3, 4, 5, 6, 7]].any() and active[[0, 2]].all()
    x_new, P_new = x.copy(), P.copy()
    fused = eskf_kernel.gravity_tick(
        x_new, P_new, imu, levels, book, now, timeout, *band, 5.0, 1.0, eskf.GRAVITY_GATE
    )
    assert 0 < fused.sum() < active.sum() and not fused[~active].any()
    for i in range(N):
        if not active[i]:
            np.testing.assert_array_equal(x_new[i], x[i])
            np.testing.assert_array_equal(P_new[i], P[i])
            continue
        dx, P_ref, ok = eskf.gravity_update(x[i : i + 1], P[i : i + 1], imu[i : i + 1, 0:3], 5.0, 1.0)
        assert ok[0] == fused[i]
        x_ref, P_ref = eskf.inject(x[i], P_ref[0], dx[0])
        np.testing.assert_allclose(x_new[i], x_ref, **TOL)
        np.testing.assert_allclose(P_new[i], P_ref, **TOL)


def test_eskf_manoeuvre_levels_compiled_match_the_scalar_levels():
    """``kernels.eskf.manoeuvre_tick`` against ``eskf.manoeuvre_levels`` over 40 ticks of random
    samples, one vehicle's with a non-finite sample."""
    rng = np.random.default_rng(29)
    state, reference = np.zeros((N, eskf.MANOEUVRE_SIZE)), np.zeros((N, eskf.MANOEUVRE_SIZE))
    for tick in range(40):
        imu = np.column_stack([specific_forces(rng), gyro_samples(rng)])
        if tick == 7:
            imu[3, 4] = math.nan
        eskf_kernel.manoeuvre_tick(state, imu, DT, PX4_UPDATE_PERIOD, eskf.ACCEL_BIAS_LEARNING_TAU)
        eskf.manoeuvre_levels(reference, imu, DT)
        np.testing.assert_allclose(state, reference, **TOL)
    assert (state[:, 1] > 0.0).all() and (state[4:, 0] > 0.0).all()  # gyro_samples: rows 0-3 still


def test_gps_updates_on_a_singular_innovation_covariance_behave_as_the_scalar_ones():
    rng = np.random.default_rng(18)
    x, P = random_nominal(rng, 3), random_covariances(rng, 9, count=3)
    R = np.zeros((6, 6))
    P[1, 0:6, :] = 0.0
    P[1, :, 0:6] = 0.0
    gps = x[:, 0:6] + 0.1
    _check_update(eskf_kernel.gps_update, eskf.gps_update, x, P, gps, R)
    assert math.isnan(eskf_kernel.gps_update(x, P, gps, R)[2][1])
    x7, P7 = rng.normal(size=(3, 7)), P[:, 0:7, 0:7].copy()  # the EKF7's update raises, as its scalar one
    with pytest.raises(np.linalg.LinAlgError):
        ekf.gps_update(x7[1], P7[1], gps[1], R)
    with pytest.raises(np.linalg.LinAlgError):
        ekf7.gps_update(x7, P7, gps, R)


def test_ekf7_estimated_state_matches_the_scalar_assembly():
    rng = np.random.default_rng(20)
    attitude, x, rate = (
        as_flight_input(a) for a in (random_attitudes(rng), rng.normal(size=(N, 7)), rng.normal(size=(N, 3)))
    )
    estimate = ekf7.estimated_state(attitude, x, rate)
    for i in range(N):
        q = quat_from_euler_tuple(attitude[i, 0], attitude[i, 1], x[i, 6])
        np.testing.assert_allclose(estimate[i], np.r_[x[i, 0:3], q, x[i, 3:6], rate[i]], **TOL)
    out = np.full((N, 13), np.nan)
    assert ekf7.estimated_state(attitude, x, rate, out=out) is out
    np.testing.assert_array_equal(out, estimate)  # written in place, every entry


# ----- an estimator sized by n against n sized by 1 ----------------------------------------------------

TICKS = 300
GPS_EVERY, MAG_EVERY = 25, 5
RESET_TIMEOUT = 0.09  # s: the third of three rejected samples 0.05 s apart resets to the GPS
SENSORS = {"imu": 6, "gps": 7, "mag": 2}


def sensor_sequences(vehicle, reference_accelerometer):
    """{sensor: (TICKS, size)} samples of one vehicle (seed = vehicle index), with its faults.

    Vehicle 0: a 10-tick NaN IMU burst and a NaN GPS position; 1: a 50 m GPS outlier and a NaN
    mag yaw; 2: a 40 m GPS step to the end (rejected, then reset to) and a 2 rad mag outlier;
    3: its GPS 10 ticks later than the others' and one NaN GPS stamp.
    """
    rng = np.random.default_rng(100 + vehicle)
    level = [0.0, 0.0, GRAVITY if reference_accelerometer else -GRAVITY, 0.0, 0.0, 0.0]
    imu = level + rng.normal(scale=[0.3, 0.3, 0.3, 0.05, 0.05, 0.05], size=(TICKS, 6))
    gps = np.tile([0.0] * 6 + [NO_SAMPLE_STAMP], (TICKS, 1))
    mag = np.tile([0.0, NO_SAMPLE_STAMP], (TICKS, 1))
    shift = 10 if vehicle == 3 else 0
    for k in range(1, TICKS):
        gps[k], mag[k] = gps[k - 1], mag[k - 1]
        if (k - shift) % GPS_EVERY == 0 and k > shift:
            p = [0.0, 0.0, -1.0] + rng.normal(scale=[0.7, 0.7, 2.0])
            gps[k] = np.r_[p, rng.normal(scale=[0.1, 0.1, 0.3]), k * DT]
        if k % MAG_EVERY == 0:
            mag[k] = [rng.normal(scale=0.1), k * DT]
    if vehicle == 0:
        imu[120:130] = math.nan
        gps[200:225, 0] = math.nan
    elif vehicle == 1:
        gps[100:125, 0] += 50.0
        mag[150:155, 0] = math.nan
    elif vehicle == 2:
        gps[175:, 0:3] += 40.0
        mag[100:105, 0] += 2.0
    else:
        gps[260:285, 6] = math.nan
    return {"imu": imu, "gps": gps, "mag": mag}


def fleet_and_scalar_estimators(vehicle, n, fidelity, own=None):
    """One Diagram holding the fleet estimator and n scalar ones, every input and output exported;
    own: n VehicleConfigs, one per vehicle (the fleet's built of them, each scalar of its own)."""
    builder = DiagramBuilder()
    systems = {"fleet": build_estimator(own, fidelity) if own else build_estimator(vehicle, fidelity, n=n)}
    systems.update({f"scalar{i}": build_estimator((own or [vehicle] * n)[i], fidelity) for i in range(n)})
    for tag, system in systems.items():
        system.set_name(tag)
        builder.AddSystem(system)
        for name in SENSORS:
            builder.ExportInput(system.GetInputPort(name), f"{tag}.{name}")
        for name in vocabulary_for(vehicle.estimator).log_widths():
            builder.ExportOutput(system.GetOutputPort(name), f"{tag}.{name}")
    return builder.Build()


VEHICLES = {
    "ekf7": (
        VehicleConfig(
            sensors=SENSORS_GPS_MAG, estimator=Ekf7EstimatorConfig(gps_reset_timeout=RESET_TIMEOUT)
        ),
        PHYSICAL,
    ),
    "ekf7-reference-small-angle": (
        VehicleConfig(
            sensors=SENSORS_GPS_MAG,
            estimator=Ekf7EstimatorConfig(
                gps_reset_timeout=RESET_TIMEOUT,
                attitude_filter=AttitudeFilterParams(variant="small_angle", tau=0.5),
            ),
        ),
        REFERENCE,
    ),
    "ekf7-tilt": (
        VehicleConfig(
            sensors=SENSORS_GPS_MAG,
            estimator=Ekf7EstimatorConfig(gps_reset_timeout=RESET_TIMEOUT, tilt_gyro_std=0.5),
        ),
        PHYSICAL,
    ),
    "eskf15": (
        VehicleConfig(
            sensors=SENSORS_GPS_MAG, estimator=EskfEstimatorConfig(gps_reset_timeout=RESET_TIMEOUT)
        ),
        PHYSICAL,
    ),
    "eskf9": (
        VehicleConfig(
            sensors=SENSORS_GPS_MAG,
            estimator=EskfEstimatorConfig(gps_reset_timeout=RESET_TIMEOUT, estimate_biases=False),
        ),
        PHYSICAL,
    ),
}


@pytest.mark.parametrize("case", list(VEHICLES))
def test_an_estimator_sized_by_n_matches_n_sized_by_one_tick_by_tick(case):
    vehicle, fidelity = VEHICLES[case]
    n = 4
    diagram = fleet_and_scalar_estimators(vehicle, n, fidelity)
    diagnostics = _fly_fleet_and_scalars(diagram, vehicle, n, fidelity)
    assert diagnostics[0, DIAG["nonfinite_samples"]] >= 11  # the IMU burst and the NaN GPS sample
    assert diagnostics[1, DIAG["nonfinite_samples"]] >= 1
    if fidelity.reference_estimator:  # the reference's EKF: every sample fused, nothing reset
        assert (diagnostics[:, [DIAG["gps_gated"], DIAG["mag_gated"], DIAG["gps_resets"]]] == 0).all()
    else:
        assert diagnostics[1, DIAG["gps_gated"]] >= 1
        assert diagnostics[2, DIAG["gps_resets"]] == 1
        assert diagnostics[2, DIAG["mag_gated"]] == 1
    assert diagnostics[3, DIAG["nonfinite_samples"]] >= 25  # a NaN stamp is fresh on every tick


@pytest.mark.parametrize("case", ["ekf7", "eskf15"])
def test_an_estimator_of_vehicles_each_with_its_own_settings_matches_each_alone(case):
    """n replayed logs in one estimator: each vehicle's start and GPS noise its own (the settings
    ``registry.EstimatorKind.per_vehicle`` names), each equal tick by tick to its own alone."""
    vehicle, fidelity = VEHICLES[case]
    kind = KINDS[vehicle.estimator.kind]
    own = []
    for i in range(4):
        estimator = kind.started_from_log(vehicle.estimator, 0.0, 0.0, 0.4 * i - 0.6)
        if i % 2:
            estimator = kind.assuming_gps_noise(estimator, 1.0 + i, 0.2 * i)
        own.append(dataclasses.replace(vehicle, estimator=estimator))
    assert sharing_problem(own) is None and len({repr(v) for v in own}) == 4
    diagram = fleet_and_scalar_estimators(vehicle, 4, fidelity, own)
    diagnostics = _fly_fleet_and_scalars(diagram, vehicle, 4, fidelity)
    assert diagnostics[2, DIAG["gps_resets"]] == 1


def _fly_fleet_and_scalars(diagram, vehicle, n, fidelity):
    """Feed ``fleet_and_scalar_estimators``'s Diagram the n vehicles' sensor sequences tick by
    tick, asserting the fleet's outputs equal the scalars' every tick; the fleet's final
    diagnostics (n, width)."""
    context = diagram.CreateDefaultContext()
    simulator = Simulator(diagram, context)
    sequences = [sensor_sequences(i, fidelity.reference_accelerometer) for i in range(n)]
    widths = vocabulary_for(vehicle.estimator).log_widths()
    for k in range(TICKS):
        for name in SENSORS:
            samples = [sequences[i][name][k] for i in range(n)]
            diagram.GetInputPort(f"fleet.{name}").FixValue(context, np.concatenate(samples))
            for i in range(n):
                diagram.GetInputPort(f"scalar{i}.{name}").FixValue(context, samples[i])
        simulator.AdvanceTo((k + 0.5) * DT)
        for name, width in widths.items():
            fleet = diagram.GetOutputPort(f"fleet.{name}").Eval(context).reshape(n, width)
            for i in range(n):
                scalar = diagram.GetOutputPort(f"scalar{i}.{name}").Eval(context)
                np.testing.assert_allclose(fleet[i], scalar, **TOL, err_msg=f"tick {k}, vehicle {i}, {name}")
    return diagram.GetOutputPort("fleet.diagnostics").Eval(context).reshape(n, -1)


def test_estimator_port_sizes_sized_by_n_follow_the_vocabulary():
    for estimator in (Ekf7EstimatorConfig(), EskfEstimatorConfig()):
        vehicle = VehicleConfig(sensors=SENSORS_GPS_MAG, estimator=estimator)
        diagram = build_estimator(vehicle, n=5)
        assert diagram.get_name() == "estimator"
        for name, size in SENSORS.items():
            assert diagram.GetInputPort(name).size() == 5 * size
        for name, width in vocabulary_for(estimator).log_widths().items():
            assert diagram.GetOutputPort(name).size() == 5 * width
    with pytest.raises(ValueError, match="at least one vehicle"):
        build_estimator(
            VehicleConfig(
                sensors=SENSORS_GPS_MAG,
            ),
            n=0,
        )


def test_gps_delay_compensator_sized_by_n_matches_n_sized_by_one_tick_by_tick():
    """Late GPS samples (0.1 s, one vehicle 0.3 s: past the 0.2 s history) on random-walk estimates."""
    n, max_lag, ticks = 3, 0.2, 250
    builder = DiagramBuilder()
    systems = {"fleet": GpsDelayCompensator(max_lag, n)}
    systems.update({f"scalar{i}": GpsDelayCompensator(max_lag) for i in range(n)})
    for tag, system in systems.items():
        system.set_name(tag)
        builder.AddSystem(system)
        for name in ("gps", "estimated_state"):
            builder.ExportInput(system.GetInputPort(name), f"{tag}.{name}")
        builder.ExportOutput(system.GetOutputPort("gps"), f"{tag}.gps")
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    simulator = Simulator(diagram, context)
    rng = np.random.default_rng(7)
    estimates = np.cumsum(rng.normal(scale=0.01, size=(n, ticks, 13)), axis=1)
    gps = np.tile([0.0] * 6 + [NO_SAMPLE_STAMP], (n, 1))
    lag = [50, 50, 150]  # ticks
    for k in range(ticks):
        for i in range(n):
            measured = k - lag[i]
            if measured >= 0 and measured % 25 == 0:
                gps[i] = np.r_[rng.normal(size=6), measured * DT]
        diagram.GetInputPort("fleet.gps").FixValue(context, gps.ravel())
        diagram.GetInputPort("fleet.estimated_state").FixValue(context, estimates[:, k].ravel())
        for i in range(n):
            diagram.GetInputPort(f"scalar{i}.gps").FixValue(context, gps[i])
            diagram.GetInputPort(f"scalar{i}.estimated_state").FixValue(context, estimates[i, k])
        simulator.AdvanceTo((k + 0.5) * DT)
        fleet = diagram.GetOutputPort("fleet.gps").Eval(context).reshape(n, 7)
        for i in range(n):
            scalar = diagram.GetOutputPort(f"scalar{i}.gps").Eval(context)
            np.testing.assert_allclose(fleet[i], scalar, **TOL, err_msg=f"tick {k}, vehicle {i}")
    shifted = diagram.GetOutputPort("fleet.gps").Eval(context).reshape(n, 7)
    assert not np.array_equal(shifted[0], gps[0])  # compensated
    assert np.array_equal(shifted[2], gps[2])  # older than the history: unchanged
