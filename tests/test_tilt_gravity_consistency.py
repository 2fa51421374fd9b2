"""benchmarks/tilt_gravity_consistency.py: the tilt it reads from a mean specific force is the
vehicle's roll and pitch where that force points away from gravity (the sensor model's at rest),
whatever the yaw."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from quad_drake.models import sensor_models
from quad_drake.models.rotations import quat_from_euler

SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "tilt_gravity_consistency.py"


@pytest.mark.parametrize(
    "roll, pitch, yaw", [(0.0, 0.0, 0.0), (0.02, -0.03, 1.0), (-0.4, 0.25, -2.5), (1.0, -0.7, 3.0)]
)
def test_the_accelerometer_tilt_is_the_attitude_of_a_vehicle_at_rest(roll, pitch, yaw):
    spec = importlib.util.spec_from_file_location("tilt_gravity_consistency", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    force = sensor_models.specific_force(quat_from_euler(roll, pitch, yaw), [0.0, 0.0, 0.0])
    np.testing.assert_allclose(module.accelerometer_tilt(force), (roll, pitch), atol=1e-12)
