"""Fleet vs per-vehicle noise: every noisy system puts the same noise into its output on both paths.

The two paths share every LeafSystem (sized by n) and differ only in where the noise comes from:
one vehicle's ``RandomSource`` (seeded by ``SetRandomContext``) against the fleet's
``NoiseStreamSource`` (Philox streams of the run seeds), both wired by ``simulation._add_noise``
as ``build_vehicle`` wires them. The noiseless fleet is bit-identical to the per-vehicle Diagram
(tests/test_fleet.py), so what remains to compare is the noise: here each noisy system (IMU white
noise and bias walk, GPS white noise and random walk, yaw and 3-axis magnetometer, barometer
height noise and bias walk, Dryden turbulence, motor noise) is driven by a fixed truth, once with
n = 1 on a RandomSource for SAMPLES samples and once with n = FLEET vehicles on the streams for
SAMPLES / FLEET samples each, and the increments of each output channel (sample k+1 minus sample
k: white noise as 2 sigma^2, a walk as its step's sigma^2, a filter's as its gain) are compared:
their distributions (two-sample Kolmogorov-Smirnov), their variances (Brown-Forsythe), their
lag-1 autocorrelation and the correlations between channels (z of the difference), and in the
fleet the vehicles' increments must be uncorrelated. Each noise term is tested alone (the others
set to zero), so a wrong sigma of any one term changes its channel's increments by its full
ratio: a 1.3x sigma in one sensor of the fleet path fails the variance test at p = 6e-50
(planted in ``Magnetometer._sample`` for n > 1, 2026-12-06), and two vehicles drawing one stream
fail the independence test (correlation 1.0 against a standard error below 0.1). Both tests
pass at 20 other seeds (1-20, the fleet's from 100 times the seed).

One end-to-end campaign pair (tests/test_fleet_equivalence.py) checks the wiring of whole
vehicles (estimator, magnetometer and GPS) on top.
"""

import numpy as np
import pytest
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput
from scipy.stats import ks_2samp, levene

from quad_drake.config.schema import BaroParams, GpsParams, ImuParams, MagParams, PhysicsParams, WindConfig
from quad_drake.running.simulation import _add_noise
from quad_drake.systems.plant import QuadrotorPlant
from quad_drake.systems.sensors import Barometer, Gps, Imu, Magnetometer
from quad_drake.systems.wind import Wind

SEED = 7100  # per-vehicle seed; the fleet flies run seeds SEED .. SEED + FLEET - 1
SAMPLES = 4000  # per path and channel
FLEET = 20
MIN_P_VALUE = 1e-4  # per test; 68 of them (34 channels, 2 tests each): a false alarm below 1 %
MAX_Z = 4.5  # lag and cross correlations: |difference| / its standard error
MAX_INDEPENDENT_SE = 6.0  # two vehicles' correlation / its standard error (190 pairs)

HOVER = np.array([0.0, 0.0, -20.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # 20 m up, level
IN_THE_AIR = {"state": HOVER, "acceleration": np.zeros(3)}


def _imu(**params):
    return lambda n: Imu(ImuParams(**params), n=n)


def _walk_only(**walk):
    zeros = {"accel_std": [0.0] * 3, "gyro_std": [0.0] * 3}
    return _imu(**zeros, **walk)


# name: (system of n vehicles, {input: per-vehicle value}, output, {noise input: stream name},
#        channels of the output that carry noise)
CASES = {
    "imu_white": (_imu(), IN_THE_AIR, "imu", {"noise": "imu"}, slice(0, 6)),
    "imu_bias_walk": (
        _walk_only(accel_bias_walk_std=[0.02, 0.03, 0.04], gyro_bias_walk_std=[0.01, 0.02, 0.03]),
        IN_THE_AIR,
        "imu",
        {"noise": "imu", "bias_noise": "imu_bias"},
        slice(0, 6),
    ),
    "gps_white": (
        lambda n: Gps(GpsParams(period=0.01), n=n),
        {"state": HOVER},
        "gps",
        {"noise": "gps"},
        slice(0, 6),
    ),
    "gps_random_walk": (
        lambda n: Gps(
            GpsParams(pos_std=[0.0] * 3, vel_std=[0.0] * 3, pos_random_walk_std=[0.1, 0.2, 0.3], period=0.01),
            n=n,
        ),
        {"state": HOVER},
        "gps",
        {"noise": "gps"},
        slice(0, 3),
    ),
    "mag_yaw": (
        lambda n: Magnetometer(MagParams(), n=n),
        {"state": HOVER},
        "mag",
        {"noise": "mag"},
        slice(0, 1),
    ),
    "mag_three_axis": (
        lambda n: Magnetometer(MagParams(three_axis=True, field_std=[0.005, 0.01, 0.02]), n=n),
        {"state": HOVER},
        "mag",
        {"noise": "mag"},
        slice(0, 3),
    ),
    "baro_height": (
        lambda n: Barometer(BaroParams(bias_walk_std=0.0, period=0.01), n=n),
        {"state": HOVER},
        "baro",
        {"noise": "baro"},
        slice(0, 1),
    ),
    "baro_bias_walk": (
        lambda n: Barometer(BaroParams(height_std=0.0, bias_walk_std=0.01, period=0.01), n=n),
        {"state": HOVER},
        "baro",
        {"noise": "baro"},
        slice(0, 1),
    ),
    "turbulence": (
        lambda n: Wind(WindConfig(mean=[3.0, 1.0, 0.0], turbulence="moderate"), n),
        {},
        "wind",
        {"noise": "wind"},
        slice(0, 3),
    ),
    "motor_noise": (
        lambda n: QuadrotorPlant(PhysicsParams(motor_noise=0.25), HOVER, n=n),
        {"motor_thrusts": np.full(4, 1.2)},
        "motor_forces",
        {"motor_noise": "motor_noise"},
        slice(0, 4),
    ),
}


def samples_of(case, seeds, samples):
    """(vehicles, samples, channels) of the case's output, one row per new sample: n = 1 on a
    RandomSource seeded `seeds` (an int), or n = len(seeds) vehicles on the streams of `seeds`."""
    make, inputs, output, noise, channels = CASES[case]
    n = 1 if isinstance(seeds, int) else len(seeds)
    builder = DiagramBuilder()
    system = builder.AddNamedSystem(case, make(n))
    for port, value in inputs.items():
        source = builder.AddSystem(ConstantVectorSource(np.tile(value, n)))
        builder.Connect(source.get_output_port(0), system.GetInputPort(port))
    for port, stream in noise.items():
        _add_noise(builder, system, port, None if n == 1 else seeds, f"Quad/{stream}")
    period = system.noise_period
    logger = LogVectorOutput(system.GetOutputPort(output), builder, period)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    if n == 1:
        diagram.SetRandomContext(simulator.get_mutable_context(), RandomGenerator(seeds))
    simulator.AdvanceTo((samples + 3) * period)
    data = (
        logger.FindLog(simulator.get_context())
        .data()
        .T.reshape(-1, n, system.GetOutputPort(output).size() // n)
    )
    data = data[3:]  # before the first sample, and a stationary start's
    if output in ("gps", "mag", "baro"):  # one row per stamp
        _, first = np.unique(data[:, 0, -1], return_index=True)
        data = data[np.sort(first)]
    return np.swapaxes(data[:samples, :, channels], 0, 1)


def lag1(x):
    """Lag-1 autocorrelation of each column of the (vehicles, samples, channels) `x`, pooled."""
    x = x - x.mean(axis=1, keepdims=True)
    return (x[:, 1:] * x[:, :-1]).sum(axis=(0, 1)) / (x * x).sum(axis=(0, 1))


@pytest.fixture(scope="module", params=list(CASES))
def both_paths(request):
    """(case, per-vehicle increments (1, SAMPLES - 1, k), fleet increments (FLEET, SAMPLES/FLEET - 1, k))."""
    case = request.param
    single = np.diff(samples_of(case, SEED, SAMPLES), axis=1)
    fleet = np.diff(samples_of(case, list(range(SEED, SEED + FLEET)), SAMPLES // FLEET), axis=1)
    return case, single, fleet


def test_each_channel_gets_the_same_noise_on_both_paths(both_paths):
    case, single, fleet = both_paths
    assert np.all(single.std(axis=1) > 0) and np.all(fleet.std(axis=1) > 0), (
        f"{case}: a channel without noise"
    )
    for k in range(single.shape[2]):
        a, b = single[..., k].ravel(), fleet[..., k].ravel()
        ks, spread = ks_2samp(a, b).pvalue, levene(a, b, center="median").pvalue
        print(
            f"{case}[{k}]: std {a.std():.4g} vs {b.std():.4g}, KS p {ks:.2g}, Brown-Forsythe p {spread:.2g}"
        )
        assert ks >= MIN_P_VALUE and spread >= MIN_P_VALUE, (case, k, a.std(), b.std(), ks, spread)
    se = np.sqrt(1 / single[..., 0].size + 1 / fleet[..., 0].size)
    assert np.all(np.abs(lag1(single) - lag1(fleet)) <= MAX_Z * se), (case, lag1(single), lag1(fleet))
    corr_single, corr_fleet = (
        np.atleast_2d(np.corrcoef(x.reshape(-1, x.shape[2]).T)) for x in (single, fleet)
    )
    assert np.all(np.abs(corr_single - corr_fleet) <= MAX_Z * se), (case, corr_single, corr_fleet)


def off_diagonal_correlations(x):
    """The correlations between the vehicles' (rows') series of the (vehicles, samples) `x`."""
    r = np.corrcoef(x)
    return r[~np.eye(len(r), dtype=bool)]


def test_the_fleets_vehicles_draw_independent_noise(both_paths):
    """No two vehicles of the fleet share noise: every correlation between two vehicles' increments
    within MAX_INDEPENDENT_SE standard errors of zero, the standard error measured on the
    per-vehicle series cut into FLEET pieces of the same length (independent draws with the same
    autocorrelation, which widens a correlation's spread: white noise's increments by 1.5x in
    variance)."""
    case, single, fleet = both_paths
    vehicles, samples, channels = fleet.shape
    pieces = single[0, : vehicles * samples].reshape(vehicles, samples, channels)
    for k in range(channels):
        se = off_diagonal_correlations(pieces[..., k]).std()
        largest = np.abs(off_diagonal_correlations(fleet[..., k])).max()
        assert largest <= MAX_INDEPENDENT_SE * se, (case, k, largest, se)
