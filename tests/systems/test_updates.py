"""The measurement-update seam: an estimator's input ports, its NIS columns and the updates it runs
read one list (the kind's measurements the vehicle carries), and a kind that declares a
measurement its system cannot fuse is refused when it is built."""

import dataclasses
import itertools

import pytest

from quad_drake.config import BaroParams, GpsParams, ImuParams, MagParams, SensorsConfig, VehicleConfig
from quad_drake.estimation import registry
from quad_drake.estimation.measurements import MEASUREMENTS, measurements_of
from quad_drake.estimation.registry import (
    Ekf7EstimatorConfig,
    EskfEstimatorConfig,
    fused_measurements,
    nis_sensors,
)
from quad_drake.systems.estimators import build_estimator


def _sensors(gps, mag, baro):
    """SensorsConfig with an IMU, and a GPS / a magnetometer (None, "yaw", "3-axis") / a barometer."""
    return SensorsConfig(
        imu=ImuParams(),
        gps=GpsParams() if gps else None,
        mag=None if mag is None else MagParams(three_axis=mag == "3-axis"),
        baro=BaroParams() if baro else None,
    )


CASES = list(itertools.product((True, False), (None, "yaw", "3-axis"), (True, False)))


@pytest.mark.parametrize("estimator", [Ekf7EstimatorConfig(), EskfEstimatorConfig()], ids=["ekf7", "eskf"])
@pytest.mark.parametrize("gps, mag, baro", CASES)
def test_ports_and_nis_columns_read_the_fused_measurements(estimator, gps, mag, baro):
    vehicle = VehicleConfig(estimator=estimator, sensors=_sensors(gps, mag, baro))
    measurements = fused_measurements(vehicle)
    diagram = build_estimator(vehicle, n=2)
    ports = {
        diagram.get_input_port(i).get_name(): diagram.get_input_port(i).size()
        for i in range(diagram.num_input_ports())
    }
    assert ports == {"imu": 12, **{m.port: 2 * m.width for m in measurements}}
    assert ("gps" in ports) == gps and ("baro" in ports) == baro and ("mag" in ports) == (mag is not None)
    assert set(nis_sensors(vehicle)) == {m.nis for m in measurements}
    if mag == "3-axis":
        assert {"ekf7": "mag", "eskf": "field"}[estimator.kind] in nis_sensors(vehicle)


def test_every_declared_measurement_is_known_and_fusion_orders_yaw_gps_then_aiding():
    for kind in registry.KINDS.values():
        assert set(kind.measurements) <= set(MEASUREMENTS), kind.name
    everything = _sensors(True, "3-axis", True)
    assert [m.name for m in measurements_of(registry.KINDS["ekf7"].measurements, everything)] == [
        "gps",
        "heading",
        "baro",
    ]
    with pytest.raises(ValueError, match="unknown measurement 'sonar'"):
        measurements_of(("gps", "sonar"), everything)


def test_a_kind_declaring_a_measurement_its_system_cannot_fuse_is_refused(monkeypatch):
    # the EKF7's system has no 3-axis field update (it fuses the tilt-compensated heading)
    wrong = dataclasses.replace(registry.KINDS["ekf7"], measurements=("yaw", "gps", "field", "baro"))
    monkeypatch.setitem(registry.KINDS, "ekf7", wrong)
    vehicle = VehicleConfig(sensors=_sensors(True, "3-axis", False))
    with pytest.raises(ValueError, match="declares the 'field' measurement but its system has no update"):
        build_estimator(vehicle)
