"""Estimator systems: tick timing, freshness by stamp, NaN rejection, the CF/EKF yaw hand-off."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from quad_drake.config import (
    BaroParams,
    GpsParams,
    ImuParams,
    MagParams,
    SensorsConfig,
    VehicleConfig,
)
from quad_drake.conventions import ATTITUDE_FILTER_OFFSET, GRAVITY, NO_SAMPLE_STAMP, ONBOARD_PERIOD
from quad_drake.estimation import ekf, eskf, gating
from quad_drake.estimation.complementary import complementary_update
from quad_drake.estimation.registry import (
    AttitudeFilterParams,
    Ekf7EstimatorConfig,
    EskfEstimatorConfig,
    vocabulary_for,
)
from quad_drake.estimation.vocabulary import DIAG, DIAGNOSTICS_SIZE, initial_diagnostics
from quad_drake.models.fidelity import PHYSICAL, REFERENCE
from quad_drake.models.rotations import quat_from_euler
from quad_drake.systems.estimators import (
    ComplementaryFilter,
    Ekf,
    Eskf,
    EstimatedStateAssembler,
    build_estimator,
)

DT = ONBOARD_PERIOD
LEVEL_IMU = [0.0, 0.0, -GRAVITY, 0.0, 0.0, 0.0]
NO_GPS = [0.0] * 6 + [NO_SAMPLE_STAMP]
NO_MAG = [0.0, NO_SAMPLE_STAMP]

SENSORS_GPS_MAG = SensorsConfig(imu=ImuParams(), gps=GpsParams(), mag=MagParams())
"""An IMU, a GPS and a yaw magnetometer: the estimator has their input ports."""


def ticks_end(n):
    """A time after the n-th onboard tick (ticks at k DT + offsets < 1e-5 s) and before the next."""
    return (n - 1) * DT + 0.5 * DT


class EkfFixture:
    def __init__(
        self, params=None, imu=LEVEL_IMU, attitude=(0.0, 0.0, 0.0), gps=NO_GPS, mag=NO_MAG, fidelity=PHYSICAL
    ):
        self.params = params or Ekf7EstimatorConfig()
        self.dut = Ekf(self.params, fidelity)
        self.context = self.dut.CreateDefaultContext()
        self.ports = {name: self.dut.GetInputPort(name) for name in ("imu", "attitude", "gps", "mag")}
        self.fix(imu=imu, attitude=attitude, gps=gps, mag=mag)
        self.simulator = Simulator(self.dut, self.context)
        self.ticks = 0

    def fix(self, **values):
        for name, value in values.items():
            self.ports[name].FixValue(self.context, np.asarray(value, dtype=float))

    def tick(self, n=1):
        self.ticks += n
        self.simulator.AdvanceTo(ticks_end(self.ticks))

    def output(self, name):
        return self.dut.GetOutputPort(name).Eval(self.context).copy()


class Replay:
    """The pure-function sequence the EKF system should perform."""

    def __init__(self, params, imu=LEVEL_IMU, attitude=(0.0, 0.0, 0.0)):
        self.Q, self.R_gps = ekf.process_noise(params), ekf.gps_noise(params)
        self.R_mag = ekf.mag_noise(params)
        self.x, self.P = ekf.initial_state(params), ekf.initial_covariance(params)
        self.imu, self.attitude = np.asarray(imu, dtype=float), attitude

    def predict(self, n=1):
        for _ in range(n):
            self.x[6] = self.attitude[2]
            roll, pitch = self.attitude[0], self.attitude[1]
            self.x, self.P = ekf.predict(self.x, self.P, roll, pitch, self.imu[:3], DT, self.Q)

    def gps(self, z):
        self.x, self.P, nis = ekf.gps_update(self.x, self.P, z, self.R_gps)
        return nis

    def mag(self, yaw):
        self.x, self.P, nis = ekf.mag_update(self.x, self.P, yaw, self.R_mag)
        return nis


def assert_matches(fixture, replay):
    np.testing.assert_allclose(fixture.output("ekf_state"), replay.x, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fixture.output("covariance"), replay.P.ravel(), rtol=0, atol=1e-15)


# ----- ComplementaryFilter -----------------------------------------------------


def make_cf(imu, ekf_yaw, params=None, initial_attitude=(0.0, 0.0, 0.0)):
    dut = ComplementaryFilter(params or AttitudeFilterParams(), initial_attitude)
    context = dut.CreateDefaultContext()
    dut.GetInputPort("imu").FixValue(context, np.asarray(imu, dtype=float))
    dut.GetInputPort("ekf_state").FixValue(context, np.array([9.0] * 6 + [ekf_yaw]))
    return dut, context, Simulator(dut, context)


def test_cf_ticks_at_its_offset_and_integrates_from_the_ekf_yaw():
    imu = [0.5, -1.0, -9.7, 0.3, -0.2, 0.8]
    params = AttitudeFilterParams(variant="nonlinear", tau=0.5)
    dut, context, simulator = make_cf(imu, ekf_yaw=0.4, params=params, initial_attitude=(0.1, -0.05, 2.0))
    simulator.AdvanceTo(ATTITUDE_FILTER_OFFSET - 0.5e-6)
    np.testing.assert_array_equal(dut.GetOutputPort("attitude").Eval(context), [0.1, -0.05, 2.0])
    simulator.AdvanceTo(ATTITUDE_FILTER_OFFSET + 0.5e-6)
    expected = complementary_update(0.1, -0.05, 0.4, imu[:3], imu[3:], DT, 0.5, "nonlinear")
    np.testing.assert_allclose(dut.GetOutputPort("attitude").Eval(context), expected, rtol=0, atol=1e-15)
    simulator.AdvanceTo(ticks_end(2))
    expected = complementary_update(*expected[:2], 0.4, imu[:3], imu[3:], DT, 0.5, "nonlinear")
    np.testing.assert_allclose(dut.GetOutputPort("attitude").Eval(context), expected, rtol=0, atol=1e-15)


def test_cf_small_angle_variant_is_selected_by_params():
    imu = [0.0, 0.0, -GRAVITY, 0.0, 0.0, 1.0]
    dut, context, simulator = make_cf(imu, 0.0, AttitudeFilterParams(variant="small_angle"), (0.5, 0.0, 0.0))
    simulator.AdvanceTo(ticks_end(1))
    roll, pitch, yaw = dut.GetOutputPort("attitude").Eval(context)
    assert pitch == pytest.approx(0.0, abs=1e-15)  # the nonlinear variant would give -r sin(roll) dt
    assert yaw == pytest.approx(DT, abs=1e-15)
    assert roll == pytest.approx(0.5 * 100.0 / (100.0 + DT), abs=1e-15)


def test_cf_holds_its_attitude_on_a_non_finite_imu_sample():
    dut, context, simulator = make_cf(
        [0.0, math.nan, -GRAVITY, 0.0, 0.0, 1.0], ekf_yaw=-0.3, initial_attitude=(0.1, 0.2, 0.0)
    )
    simulator.AdvanceTo(ticks_end(3))
    np.testing.assert_array_equal(dut.GetOutputPort("attitude").Eval(context), [0.1, 0.2, -0.3])


def test_cf_rejects_an_unknown_variant():
    with pytest.raises(ValueError, match="variant"):
        ComplementaryFilter(AttitudeFilterParams(variant="linear"))


# ----- Ekf ---------------------------------------------------------------------


def test_ekf_port_sizes():
    dut = Ekf(Ekf7EstimatorConfig())
    assert [dut.GetInputPort(n).size() for n in ("imu", "gps", "mag", "attitude")] == [6, 7, 2, 3]
    sizes = [dut.GetOutputPort(n).size() for n in ("ekf_state", "covariance", "diagnostics")]
    assert sizes == [7, 49, DIAGNOSTICS_SIZE]


def test_ekf_stationary_ticks_grow_covariance_by_q():
    f = EkfFixture()
    p = f.params
    P0, Q = ekf.initial_covariance(p), ekf.process_noise(p)
    G = ekf.predict_jacobian(ekf.initial_state(p), 0.0, 0.0, LEVEL_IMU[:3], DT)
    P = P0
    for k in range(1, 6):
        f.tick()
        P = G @ P @ G.T + Q
        got = f.output("covariance").reshape(7, 7)
        # velocity and yaw do not depend on the other states: P = P0 + k Q exactly
        np.testing.assert_allclose(got[3:7, 3:7], P0[3:7, 3:7] + k * Q[3:7, 3:7], rtol=1e-14, atol=0)
        np.testing.assert_allclose(got, P, rtol=1e-14, atol=1e-18)
        assert got[0, 3] == pytest.approx(k * DT * P0[3, 3] + DT * Q[3, 3] * k * (k - 1) / 2, rel=1e-12)
        np.testing.assert_array_equal(f.output("ekf_state"), p.init_state)
    diagnostics = f.output("diagnostics")
    assert math.isnan(diagnostics[0]) and math.isnan(diagnostics[2])
    np.testing.assert_array_equal(diagnostics[[1, 3, 4]], [NO_SAMPLE_STAMP, NO_SAMPLE_STAMP, 0.0])


def test_ekf_takes_the_attitude_yaw_and_predicts_with_its_tilt():
    imu = [0.3, -0.2, -9.9, 0.0, 0.0, 0.0]
    attitude = (0.1, -0.2, 0.7)
    f, r = EkfFixture(imu=imu, attitude=attitude), Replay(Ekf7EstimatorConfig(), imu, attitude)
    f.tick(3)
    r.predict(3)
    assert_matches(f, r)
    assert f.output("ekf_state")[6] == 0.7
    assert abs(f.output("ekf_state")[3:6]).max() > 1e-3


def test_ekf_fuses_a_fresh_gps_stamp_exactly_once():
    z = [0.5, -0.3, -1.4, 0.2, 0.1, -0.1]
    f, r = EkfFixture(gps=z + [0.1]), Replay(Ekf7EstimatorConfig())
    f.tick()
    r.predict()
    nis = r.gps(z)
    assert_matches(f, r)
    np.testing.assert_allclose(f.output("diagnostics")[[0, 1, 4]], [nis, 0.1, 0.0], rtol=1e-12)
    f.tick(4)  # same stamp: no further update
    r.predict(4)
    assert_matches(f, r)
    f.fix(gps=z + [0.2])  # fresh stamp: one more update
    f.tick(2)
    r.predict()
    nis = r.gps(z)
    r.predict()
    assert_matches(f, r)
    np.testing.assert_allclose(f.output("diagnostics")[[0, 1]], [nis, 0.2], rtol=1e-12)


def test_ekf_fuses_mag_and_gps_samples_of_one_tick():
    # A horizontal specific force correlates yaw with velocity, so both updates move all states.
    # (Two linear updates of independent measurements commute; the mag-then-GPS order only
    # matters through the yaw wrap.)
    z, yaw = [0.5, -0.3, -1.4, 0.2, 0.1, -0.1], 0.3
    imu, attitude = [2.0, -1.0, -9.6, 0.0, 0.0, 0.0], (0.1, 0.05, 0.2)
    f, r = EkfFixture(imu=imu, attitude=attitude), Replay(Ekf7EstimatorConfig(), imu, attitude)
    f.tick(10)
    r.predict(10)
    f.fix(gps=z + [0.1], mag=[yaw, 0.008])
    f.tick()
    r.predict()
    mag_nis = r.mag(yaw)
    gps_nis = r.gps(z)
    assert_matches(f, r)
    expected = [gps_nis, 0.1, mag_nis, 0.008] + list(initial_diagnostics()[4:])  # no baro, no field
    np.testing.assert_allclose(f.output("diagnostics"), expected, rtol=1e-12)
    assert abs(r.P[3, 6]) > 1e-6


def test_ekf_skips_and_counts_non_finite_samples():
    z = [0.5, -0.3, -1.4, 0.2, 0.1, -0.1]
    f, r = EkfFixture(gps=[math.nan] + z[1:] + [0.1], mag=[math.inf, 0.008]), Replay(Ekf7EstimatorConfig())
    f.tick(3)  # each stamp counted once
    r.predict(3)
    assert_matches(f, r)
    assert f.output("diagnostics")[4] == 2.0
    assert math.isnan(f.output("diagnostics")[0]) and math.isnan(f.output("diagnostics")[2])
    f.fix(gps=z + [math.nan])  # a NaN stamp is rejected too
    f.tick()
    r.predict()
    assert_matches(f, r)
    assert f.output("diagnostics")[4] == 3.0
    f.fix(gps=NO_GPS, imu=[0.0, 0.0, math.nan, 0.0, 0.0, 0.0])  # a bad IMU sample: predicted with
    f.tick(2)  # the running mean of the finite ones, all LEVEL_IMU here
    r.predict(2)
    assert_matches(f, r)
    assert f.output("diagnostics")[4] == 5.0
    f.fix(imu=LEVEL_IMU, attitude=(0.0, math.inf, 0.0))
    f.tick()
    assert_matches(f, r)
    assert f.output("diagnostics")[4] == 6.0


def test_ekf_mag_update_wraps_the_posterior_yaw():
    f = EkfFixture(attitude=(0.0, 0.0, -3.1), mag=[3.1, 0.008])
    f.tick()
    r = Replay(Ekf7EstimatorConfig(), attitude=(0.0, 0.0, -3.1))
    r.predict()
    r.mag(3.1)
    assert_matches(f, r)
    assert -math.pi <= f.output("ekf_state")[6] < -3.1


# ----- EstimatedStateAssembler and the closed estimator loop ------------------


def test_assembler_layout_uses_the_ekf_yaw_and_the_held_body_rate():
    dut = EstimatedStateAssembler()
    context = dut.CreateDefaultContext()
    dut.GetInputPort("attitude").FixValue(context, [0.1, -0.2, 9.0])
    dut.GetInputPort("ekf_state").FixValue(context, [1.0, 2.0, -3.0, 0.4, 0.5, 0.6, 0.7])
    dut.GetInputPort("body_rate").FixValue(context, [-0.1, 0.2, -0.3])
    got = dut.GetOutputPort("estimated_state").Eval(context)
    expected = np.concatenate(
        [[1.0, 2.0, -3.0], quat_from_euler(0.1, -0.2, 0.7), [0.4, 0.5, 0.6], [-0.1, 0.2, -0.3]]
    )
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-15)


def build_estimators(imu, gps=NO_GPS, mag=NO_MAG, estimator=None):
    """The estimator sub-Diagram of a vehicle (default: ekf7) fed by constant sensor samples.

    Returns (diagram, {sensor: ConstantVectorSource}) so a test can change the samples.
    """
    vehicle = VehicleConfig(sensors=SENSORS_GPS_MAG, estimator=estimator or Ekf7EstimatorConfig())
    builder = DiagramBuilder()
    dut = builder.AddSystem(build_estimator(vehicle))
    sources = {
        name: builder.AddSystem(ConstantVectorSource(np.asarray(v, dtype=float)))
        for name, v in (("imu", imu), ("gps", gps), ("mag", mag))
    }
    for name in ("imu", "gps", "mag"):
        builder.Connect(sources[name].get_output_port(), dut.GetInputPort(name))
    for name in vocabulary_for(vehicle.estimator).log_widths():
        builder.ExportOutput(dut.GetOutputPort(name), name)
    return builder.Build(), sources


def test_yaw_hand_off_between_filter_and_ekf_integrates_the_gyro_once_per_tick():
    diagram, _ = build_estimators(imu=[0.0, 0.0, -GRAVITY, 0.0, 0.0, 0.5])
    context = diagram.CreateDefaultContext()
    Simulator(diagram, context).AdvanceTo(ticks_end(500))
    assert diagram.GetOutputPort("ekf_state").Eval(context)[6] == pytest.approx(500 * DT * 0.5, abs=1e-12)
    estimated = diagram.GetOutputPort("estimated_state").Eval(context)
    np.testing.assert_allclose(estimated[3:7], quat_from_euler(0.0, 0.0, 0.5), atol=1e-12)
    np.testing.assert_array_equal(estimated[10:13], [0.0, 0.0, 0.5])


# ----- non-finite IMU samples, gating, GPS reset, covariance health -------------

BURST_IMU = [0.0, 0.0, -GRAVITY, 0.1, -0.2, 0.3]


@pytest.mark.parametrize("estimator", [Ekf7EstimatorConfig(), EskfEstimatorConfig()], ids=["ekf7", "eskf"])
def test_an_imu_dropout_is_dead_reckoned_on_the_running_mean_and_its_rate_reported_unknown(estimator):
    # 0.2 s of NaN IMU samples (100 ticks) after a constant IMU: the estimators predict with the
    # running mean of the finite samples (here exactly the constant), so p, q and v are those of
    # a run without the dropout; the body rate is NaN (not measured) until the IMU is back, and
    # every missing sample is counted.
    runs = {}
    for dropout in (False, True):
        diagram, sources = build_estimators(imu=BURST_IMU, estimator=estimator)
        context = diagram.CreateDefaultContext()
        simulator = Simulator(diagram, context)
        simulator.AdvanceTo(ticks_end(10))
        source_context = sources["imu"].GetMyContextFromRoot(context)
        if dropout:
            sources["imu"].get_mutable_source_value(source_context).set_value(np.full(6, math.nan))
        simulator.AdvanceTo(ticks_end(110))
        runs[dropout] = diagram.GetOutputPort("estimated_state").Eval(context).copy()
        assert (
            diagram.GetOutputPort("diagnostics").Eval(context)[DIAG["nonfinite_samples"]] == 100.0 * dropout
        )
        sources["imu"].get_mutable_source_value(source_context).set_value(np.array(BURST_IMU))
        simulator.AdvanceTo(ticks_end(111))
        np.testing.assert_allclose(
            diagram.GetOutputPort("estimated_state").Eval(context)[10:13], BURST_IMU[3:6], atol=1e-3
        )  # measured again (the ESKF subtracts its gyro bias)
    np.testing.assert_allclose(runs[True][0:10], runs[False][0:10], rtol=0, atol=1e-12)
    assert np.isnan(runs[True][10:13]).all()
    assert np.isfinite(runs[False]).all()


def test_ekf_gates_a_50_m_outlier_and_resets_the_horizontal_position_after_the_timeout():
    params = Ekf7EstimatorConfig(gps_reset_timeout=0.25)
    z = [50.0, 0.0, -1.0, 0.0, 0.0, 0.0]
    f = EkfFixture(params=params, gps=z + [0.1])
    f.tick()
    diagnostics = f.output("diagnostics")
    assert diagnostics[DIAG["gps_gated"]] == 1.0
    assert diagnostics[DIAG["gps_nis"]] > gating.gate_threshold(6, 5.0)  # the NIS of the gated sample
    np.testing.assert_allclose(f.output("ekf_state")[0:2], [0.0, 0.0], atol=1e-6)  # prior kept
    for k, stamp in enumerate((0.2, 0.3), start=2):
        f.fix(gps=z + [stamp])
        f.tick()
        assert f.output("diagnostics")[DIAG["gps_gated"]] == k
    assert f.output("diagnostics")[DIAG["gps_resets"]] == 0.0
    f.fix(gps=z + [0.4])  # >= 0.25 s of continuous rejection: reset the horizontal position
    f.tick()
    assert f.output("diagnostics")[DIAG["gps_resets"]] == 1.0
    np.testing.assert_allclose(f.output("ekf_state")[0:2], z[0:2], atol=1e-12)
    P = f.output("covariance").reshape(7, 7)
    np.testing.assert_allclose(P[0:2, 0:2], ekf.gps_noise(params)[0:2, 0:2], atol=1e-15)
    np.testing.assert_array_equal(P[0:2, 2:], 0.0)
    f.fix(gps=z + [0.5])  # consistent with the new estimate: fused
    f.tick()
    assert f.output("diagnostics")[DIAG["gps_gated"]] == 4.0


@pytest.mark.parametrize("kind", ["ekf7", "eskf"])
@pytest.mark.parametrize("restart", [True, False])
def test_a_gps_sample_after_a_gap_resets_the_height_and_the_barometer_keeps_it(kind, restart):
    # the GPS the height reference (gps_height_restart): a fix 2 s after the last (beyond PX4's
    # 1 s GNSS height timeout) 2 m above the estimate resets the height to it although its gate
    # accepts it, and the baro bias moves with it: the next baro samples (same height as before)
    # leave it there. Off: the fix is fused, the height moves part of the way.
    sensors = SensorsConfig(imu=ImuParams(), gps=GpsParams(), mag=MagParams(), baro=BaroParams())
    if kind == "ekf7":
        dut = Ekf(Ekf7EstimatorConfig(gps_height_restart=restart), sensors=sensors)
    else:
        dut = Eskf(EskfEstimatorConfig(gps_height_restart=restart), sensors=sensors)
    context = dut.CreateDefaultContext()
    ports = {port.get_name(): port for port in (dut.get_input_port(i) for i in range(dut.num_input_ports()))}
    ports["imu"].FixValue(context, LEVEL_IMU)
    if "attitude" in ports:
        ports["attitude"].FixValue(context, [0.0, 0.0, 0.0])
    ports["mag"].FixValue(context, NO_MAG)
    simulator = Simulator(dut, context)
    state = "ekf_state" if kind == "ekf7" else "estimated_state"
    for stamp in np.arange(1, 11) * 0.1:  # 1 s of 10 Hz fixes and 50 Hz baro at 1 m
        ports["gps"].FixValue(context, [0.0, 0.0, -1.0, 0.0, 0.0, 0.0, stamp])
        for k in range(5):
            ports["baro"].FixValue(context, [1.0, stamp - 0.08 + 0.02 * k])
            simulator.AdvanceTo(stamp - 0.08 + 0.02 * k + 0.5 * DT)
    before = dut.GetOutputPort(state).Eval(context)[2]
    bias = dut.GetOutputPort("diagnostics").Eval(context)[DIAG["baro_bias"]]
    ports["gps"].FixValue(context, [0.0, 0.0, -3.0, 0.0, 0.0, 0.0, 3.0])  # 2 s later, 2 m up
    simulator.AdvanceTo(3.0 + 0.5 * DT)
    after = dut.GetOutputPort(state).Eval(context)[2]
    diagnostics = dut.GetOutputPort("diagnostics").Eval(context)
    assert diagnostics[DIAG["gps_gated"]] == 0.0  # the gate accepts it
    assert diagnostics[DIAG["gps_resets"]] == 0.0  # a restart, not a filter that lost the GPS
    if not restart:
        assert after > -2.9 and diagnostics[DIAG["gps_height_restarts"]] == 0.0
        return
    assert after == -3.0 and diagnostics[DIAG["gps_height_restarts"]] == 1.0
    assert diagnostics[DIAG["baro_bias"]] == pytest.approx(bias + (-3.0 - before), abs=1e-12)  # PX4's
    for k in range(1, 26):  # 0.5 s more of the barometer at 1 m
        ports["baro"].FixValue(context, [1.0, 3.0 + 0.02 * k])
        simulator.AdvanceTo(3.0 + 0.02 * k + 0.5 * DT)
    assert dut.GetOutputPort(state).Eval(context)[2] == pytest.approx(-3.0, abs=0.05)


def test_the_reference_estimator_fuses_every_sample_as_the_binary_does():
    # fidelity: reference runs the reference's EKF: no gate, so a 50 m outlier is fused
    z = [50.0, 0.0, -1.0, 0.0, 0.0, 0.0]
    gated = EkfFixture(gps=z + [0.1])
    reference = EkfFixture(gps=z + [0.1], imu=[0.0, 0.0, GRAVITY, 0.0, 0.0, 0.0], fidelity=REFERENCE)
    for f in (gated, reference):
        f.tick()
    assert gated.output("diagnostics")[DIAG["gps_gated"]] == 1.0
    assert reference.output("diagnostics")[DIAG["gps_gated"]] == 0.0
    assert reference.output("ekf_state")[0] > 0.4  # fused: gain P / (P + R) = 0.01 of 50 m
    assert abs(gated.output("ekf_state")[0]) < 1e-6


def test_a_wrong_velocity_never_makes_the_ekf_refuse_a_good_position():
    # The graze the IMU missed: the EKF believes 5 m/s, the GPS says the vehicle stopped where the
    # EKF thinks it is. The velocity group is gated, the position fused (the joint 6-dof gate
    # refused both for 5 s); after gps_vel_reset_timeout s of rejection the velocity is reset.
    params = Ekf7EstimatorConfig(
        init_state=[0.0, 0.0, -1.0, 5.0, 0.0, 0.0, 0.0], init_std=[2.0] * 3 + [0.1] * 3 + [0.05]
    )
    z = [0.0, 0.0, -1.0, 0.0, 0.0, 0.0]
    f = EkfFixture(params=params, gps=z + [0.002])
    P_before = ekf.initial_covariance(params)
    f.tick()
    assert f.output("diagnostics")[DIAG["gps_gated"]] == 1.0
    P = f.output("covariance").reshape(7, 7)
    assert P[0, 0] < 0.5 * P_before[0, 0]  # the position was fused
    assert f.output("ekf_state")[3] > 4.0  # the velocity was not
    for k in range(1, 6):  # 10 Hz samples: rejected until 0.5 s after the first
        f.fix(gps=z + [0.002 + 0.1 * k])
        f.tick(50)
    assert f.output("diagnostics")[DIAG["gps_resets"]] == 1.0
    np.testing.assert_allclose(f.output("ekf_state")[3:6], 0.0, atol=0.05)


@pytest.mark.filterwarnings("ignore:invalid value encountered")
def test_ekf_repairs_a_non_finite_covariance_and_counts_it():
    f = EkfFixture()
    f.context.get_mutable_discrete_state(1).SetFromVector(np.full(49, math.inf))
    f.tick()
    P = f.output("covariance").reshape(7, 7)
    assert np.isfinite(P).all()
    np.testing.assert_allclose(P, ekf.initial_covariance(f.params), rtol=1e-12)
    assert f.output("diagnostics")[DIAG["covariance_repairs"]] == 1.0
    f.tick(3)
    assert f.output("diagnostics")[DIAG["covariance_repairs"]] == 1.0


def test_eskf_matches_its_pure_functions_tick_by_tick():
    params = EskfEstimatorConfig()
    imu = [0.3, -0.2, -9.7, 0.05, -0.02, 0.1]
    z = [0.2, -0.1, -1.1, 0.05, 0.0, 0.02]
    dut = Eskf(params)
    context = dut.CreateDefaultContext()
    for name, value in (("imu", imu), ("gps", z + [0.006]), ("mag", [0.02, 0.004])):
        dut.GetInputPort(name).FixValue(context, np.asarray(value, dtype=float))
    Simulator(dut, context).AdvanceTo(ticks_end(3))
    noise = eskf.NoiseModel.from_params(params)
    x = eskf.initial_nominal(params.init_position, params.init_velocity, [1.0, 0.0, 0.0, 0.0])
    P = eskf.initial_covariance(params)
    x, P = eskf.predict(x, P, imu[0:3], imu[3:6], DT, noise)
    x, P, mag_nis = eskf.mag_update(x, P, 0.02, eskf.mag_noise(params))
    x, P, gps_nis = eskf.gps_update(x, P, z, eskf.gps_noise(params))
    for _ in range(2):
        x, P = eskf.predict(x, P, imu[0:3], imu[3:6], DT, noise)
    estimated = dut.GetOutputPort("estimated_state").Eval(context)
    np.testing.assert_allclose(estimated[0:3], x[0:3], atol=1e-13)
    np.testing.assert_allclose(estimated[3:7], x[6:10], atol=1e-13)
    np.testing.assert_allclose(estimated[7:10], x[3:6], atol=1e-13)
    np.testing.assert_allclose(estimated[10:13], np.array(imu[3:6]) - x[13:16], atol=1e-13)
    np.testing.assert_allclose(dut.GetOutputPort("covariance").Eval(context), P.ravel(), atol=1e-15)
    np.testing.assert_allclose(dut.GetOutputPort("imu_bias").Eval(context), x[10:16], atol=1e-15)
    diagnostics = dut.GetOutputPort("diagnostics").Eval(context)
    np.testing.assert_allclose(diagnostics[0:4], [gps_nis, 0.006, mag_nis, 0.004], rtol=1e-10)
    assert dut.GetOutputPort("covariance").size() == 225
    assert Eskf(EskfEstimatorConfig(estimate_biases=False)).GetOutputPort("covariance").size() == 81


def _eskf_roll_after(params, gps, seconds=1.0):
    """The roll (rad) of an ESKF started level, after `seconds` of the IMU of a vehicle standing
    still rolled 0.1 rad, with the GPS input fixed at `gps`."""
    from quad_drake.models.rotations import euler_from_quats, rotation_from_quat

    f_B = rotation_from_quat(quat_from_euler(0.1, 0.0, 0.0)).T @ [0.0, 0.0, -GRAVITY]
    dut = Eskf(params)
    context = dut.CreateDefaultContext()
    for name, value in (("imu", list(f_B) + [0.0] * 3), ("gps", gps), ("mag", NO_MAG)):
        dut.GetInputPort(name).FixValue(context, np.asarray(value, dtype=float))
    Simulator(dut, context).AdvanceTo(ticks_end(round(seconds / DT)))
    return float(euler_from_quats(dut.GetOutputPort("estimated_state").Eval(context)[3:7])[0])


def test_the_eskf_fuses_the_gravity_vector_while_no_gps_aids_it():
    """PX4's gravity fusion (``gravity_std``, EKF2_IMU_CTRL bit 2): unaided, a level start (tilt
    sigma 0.05 rad) on a still vehicle rolled 0.1 rad moves toward the accelerometer's tilt, by
    the share of information the prior predicts (100 updates/s of PX4's variance 1 against the
    prior's 400: 0.1 x 100 / 500 = 0.02 rad in 1 s; more than twice that by 3 s, as the gyro's
    process noise keeps the tilt's variance from shrinking as fast), where without it nothing
    observes the tilt and it stays where it started; with a GPS sample seen within
    ``gravity_aiding_timeout`` it is not fused: the run equals the one without it bit for bit."""
    plain = EskfEstimatorConfig(init_att_std=[0.05, 0.05, 0.05])
    gravity = EskfEstimatorConfig(init_att_std=[0.05, 0.05, 0.05], gravity_std=1.0)
    assert abs(_eskf_roll_after(plain, NO_GPS)) < 1e-3
    after_1s = _eskf_roll_after(gravity, NO_GPS)
    assert after_1s == pytest.approx(0.02, rel=0.15)
    assert 2.0 * after_1s < _eskf_roll_after(gravity, NO_GPS, seconds=3.0) < 0.1
    aided = [0.0] * 6 + [0.001]
    assert _eskf_roll_after(gravity, aided) == _eskf_roll_after(plain, aided)
