"""The ESKF's baro bias as an error state (``estimation/baro.py``): with it the filter's height and
vertical velocity stay honest with a barometer, through a GPS outage too.

A fleet of ESKFs (``build_estimator``, n vehicles in one system) hovers at a known truth, fed
IMU, GPS and barometer samples drawn from the noise the filter assumes, and each baro with its
own bias (a random walk of the assumed rate from a random datum); the GPS is out for the last
4 s. Over the vehicles and the sampled times, the mean e^2/P of the height (Z) and the vertical
velocity (VZ) must be that of a consistent filter. The scalar bias filter beside the ESKF with
its height-variance floor (the model before the bias became a state) gave, in this test, Z 1.49
on the pinned seed (seeds 1-3: 1.40-1.61): over-confident; its VZ, 0.92-1.04, passed (in a hover
the floor's dilution of the vertical velocity, which 23's flights show, does not).
"""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from quad_drake.config import BaroParams, GpsParams, ImuParams, SensorsConfig, VehicleConfig
from quad_drake.conventions import GRAVITY, NO_SAMPLE_STAMP, ONBOARD_PERIOD
from quad_drake.estimation.registry import EskfEstimatorConfig
from quad_drake.systems.estimators import build_estimator

VEHICLES, SECONDS, OUTAGE_START = 100, 12.0, 8.0
GPS_EVERY, BARO_EVERY = 50, 10  # ticks: 10 Hz, 50 Hz
HEIGHT = 1.0  # m above the datum (NED z = -1)


def hover_errors(seed):
    """(times (T,), Z and VZ e^2/P (T, VEHICLES) each) of the hovering fleet, sampled every 0.1 s
    from 2 s on."""
    rng = np.random.default_rng(seed)
    estimator = EskfEstimatorConfig(
        estimate_biases=False, init_position=[0.0, 0.0, -HEIGHT], init_pos_std=[0.001] * 3,
        init_vel_std=[0.001] * 3, init_att_std=[0.001] * 3,
    )  # fmt: skip
    vehicle = VehicleConfig(
        sensors=SensorsConfig(imu=ImuParams(), gps=GpsParams(), baro=BaroParams()), estimator=estimator
    )
    diagram = build_estimator(vehicle, n=VEHICLES)
    context = diagram.CreateDefaultContext()
    simulator = Simulator(diagram, context)
    ports = {name: diagram.GetInputPort(name) for name in ("imu", "gps", "baro")}
    state, covariance = diagram.GetOutputPort("estimated_state"), diagram.GetOutputPort("covariance")
    accel_std, gyro_std = np.array(estimator.accel_std), np.array(estimator.gyro_std)
    gps_std = np.r_[estimator.gps_pos_std, estimator.gps_vel_std]
    bias = rng.normal(0.0, 0.5, VEHICLES)  # each baro's datum offset, m
    gps = np.tile([0.0, 0.0, -HEIGHT, 0.0, 0.0, 0.0, NO_SAMPLE_STAMP], (VEHICLES, 1))
    baro = np.tile([0.0, NO_SAMPLE_STAMP], (VEHICLES, 1))
    times, z_ratio, vz_ratio = [], [], []
    for k in range(1, round(SECONDS / ONBOARD_PERIOD) + 1):
        t = k * ONBOARD_PERIOD
        imu = np.column_stack(
            (rng.normal(0.0, accel_std, (VEHICLES, 3)), rng.normal(0.0, gyro_std, (VEHICLES, 3)))
        )
        imu[:, 2] -= GRAVITY  # the specific force of a hover, body FRD
        if k % BARO_EVERY == 0:
            bias += BaroParams().bias_walk_std * rng.normal(size=VEHICLES)
            baro = np.column_stack((HEIGHT + bias + rng.normal(0.0, 0.1, VEHICLES), np.full(VEHICLES, t)))
        if k % GPS_EVERY == 0 and t < OUTAGE_START:
            noise = rng.normal(0.0, gps_std, (VEHICLES, 6))
            gps = np.column_stack((noise + [0.0, 0.0, -HEIGHT, 0.0, 0.0, 0.0], np.full(VEHICLES, t)))
        for name, value in (("imu", imu), ("gps", gps), ("baro", baro)):
            ports[name].FixValue(context, value.ravel())
        simulator.AdvanceTo(t)
        if k % 50 == 0 and t >= 2.0:
            x = state.Eval(context).reshape(VEHICLES, -1)
            P = covariance.Eval(context).reshape(VEHICLES, 9, 9)
            times.append(t)
            z_ratio.append((x[:, 2] + HEIGHT) ** 2 / P[:, 2, 2])
            vz_ratio.append(x[:, 9] ** 2 / P[:, 5, 5])
    return np.array(times), np.array(z_ratio), np.array(vz_ratio)


@pytest.mark.slow
def test_height_and_vertical_velocity_are_consistent_with_a_barometer_through_an_outage():
    # seed 0 pinned (Z 1.05, VZ 1.01); seeds 1-20 give Z 0.89-1.16 and VZ 0.96-1.05 over the
    # flight, 0.85-1.21 and 0.93-1.09 in the outage; the earlier model's Z, 1.40-1.61, fails
    times, z_ratio, vz_ratio = hover_errors(0)
    outage = times >= OUTAGE_START
    for ratio in (z_ratio, vz_ratio):
        assert 0.8 < ratio.mean() < 1.25
        assert 0.7 < ratio[outage].mean() < 1.4  # the GPS out: the height on the barometer alone
