"""Pure wind models (``quad_drake.models.wind``): the Dryden forms against MIL-F-8785C, the discrete
filters' variance and correlation on a long seeded sample, the (1 - cos) gust, the kernels."""

import math

import numpy as np
import pytest

from quad_drake.config.schema import GustConfig, WindConfig
from quad_drake.kernels import flight as kernels
from quad_drake.models import wind


def test_low_altitude_forms_match_the_spec():
    # MIL-F-8785C low altitude at h = 10, 100 and 1000 ft, W20 = 30 kt (moderate), in ft and ft/s.
    w20 = wind.TURBULENCE_W20["moderate"]
    assert w20 == pytest.approx(30 * 0.514444, rel=1e-6)
    for h_ft in (10.0, 100.0, 1000.0):
        sigmas, lengths = wind.dryden_low_altitude(h_ft * wind.FT, w20)
        base = 0.177 + 0.000823 * h_ft
        assert lengths[2] == pytest.approx(h_ft * wind.FT)
        assert lengths[0] == lengths[1] == pytest.approx(h_ft / base**1.2 * wind.FT)
        assert sigmas[2] == pytest.approx(0.1 * w20)
        assert sigmas[0] == sigmas[1] == pytest.approx(0.1 * w20 / base**0.4)
    # At 1000 ft the turbulence is isotropic: L = 1000 ft, sigma_u = sigma_w.
    sigmas, lengths = wind.dryden_low_altitude(1000 * wind.FT, w20)
    assert lengths[0] == pytest.approx(1000 * wind.FT, rel=1e-3) and sigmas[0] == pytest.approx(
        sigmas[2], rel=1e-3
    )
    # Below 10 ft the 10 ft values are used.
    assert wind.dryden_low_altitude(0.5, w20) == wind.dryden_low_altitude(10 * wind.FT, w20)


def test_levels_and_speed():
    assert wind.turbulence_intensity(WindConfig()) == 0.0
    assert wind.dryden_model(WindConfig(), 0.002) is None
    assert wind.turbulence_intensity(WindConfig(turbulence="light")) == pytest.approx(15 * 1852 / 3600)
    assert wind.turbulence_intensity(WindConfig(turbulence="severe", wind_speed_6m=9.0)) == 9.0
    assert wind.turbulence_speed(WindConfig(mean=[3.0, 4.0, 0.0])) == 5.0
    assert wind.turbulence_speed(WindConfig()) == wind.MIN_TURBULENCE_SPEED
    assert wind.turbulence_speed(WindConfig(airspeed=7.0)) == 7.0


def autocorrelation(x, lag):
    return np.mean(x[:-lag] * x[lag:]) if lag else np.mean(x * x)


@pytest.mark.parametrize("period", [0.002, 0.05])
def test_discrete_filters_have_the_spec_variance_and_correlation(period):
    """A long seeded sample: the variance is sigma^2 and the autocorrelation at the lag L/V is the
    spec's, exp(-1) for u and (1 - 1/2) exp(-1) for v and w, within the sampling error."""
    config = WindConfig(turbulence="moderate", airspeed=10.0, altitude=20.0)
    model = wind.dryden_model(config, period)
    rng = np.random.default_rng(31)
    T = [length / model.speed for length in model.lengths]  # s, the time scales
    samples = int(round(2500 * max(T) / period))  # ~2500 time scales of the slowest component
    samples = min(samples, 400_000)
    noise = rng.standard_normal((samples, 5))
    x = wind.turbulence_start(noise[:1], model)
    states = np.empty((samples, 5))
    for k in range(samples):  # the compiled kernel, one vehicle
        if k:
            kernels.turbulence_filter_rows(x, noise[k : k + 1], model.phi, model.noise_gain)
        states[k] = x[0]
    uvw = states @ model.output.T
    for axis in range(3):
        series = uvw[:, axis]
        sigma = model.sigmas[axis]
        length_in_samples = T[axis] / period
        # relative standard error of a variance over N/(2 tau) independent samples
        tolerance = 4.0 * math.sqrt(2.0 * 2.0 * length_in_samples / samples)
        assert autocorrelation(series, 0) == pytest.approx(sigma**2, rel=tolerance)
        lag = int(round(length_in_samples))
        expected = math.exp(-1.0) if axis == 0 else 0.5 * math.exp(-1.0)
        measured = autocorrelation(series, lag) / sigma**2
        assert measured == pytest.approx(expected, abs=tolerance)


def test_a_stationary_start_and_an_exact_discretisation():
    """Stepping once with period 2 dt equals stepping twice with dt in distribution: Phi(2 dt) =
    Phi(dt)^2 and the covariance is stationary (P = Phi P Phi^T + G G^T)."""
    config = WindConfig(turbulence="light", mean=[2.0, 0.0, 0.0])
    one, two = wind.dryden_model(config, 0.01), wind.dryden_model(config, 0.02)
    np.testing.assert_allclose(one.phi @ one.phi, two.phi, atol=1e-12)
    p = one.initial_gain @ one.initial_gain.T
    np.testing.assert_allclose(one.phi @ p @ one.phi.T + one.noise_gain @ one.noise_gain.T, p, atol=1e-12)
    np.testing.assert_allclose(np.sqrt(np.diag(one.output @ p @ one.output.T)), one.sigmas, rtol=1e-9)


def test_turbulence_turns_with_the_mean_wind():
    config = WindConfig(turbulence="light", mean=[0.0, 3.0, 0.0])  # wind towards east: u is east
    model = wind.dryden_model(config, 0.002)
    states = np.zeros((1, 5))
    states[0, 0] = 1.0 / model.output[0, 0]  # u = 1 m/s, v = w = 0
    np.testing.assert_allclose(wind.turbulence_velocity(states, model), [[0.0, 1.0, 0.0]], atol=1e-15)


def test_gust_is_one_minus_cosine():
    gust = GustConfig(start=2.0, duration=1.0, amplitude=4.0, direction=[0.0, 2.0, 0.0])
    assert wind.gust_velocity(1.99, [gust]).tolist() == [0.0, 0.0, 0.0]
    np.testing.assert_allclose(wind.gust_velocity(2.5, [gust]), [0.0, 4.0, 0.0])
    np.testing.assert_allclose(wind.gust_velocity(2.25, [gust]), [0.0, 2.0, 0.0])
    assert wind.gust_velocity(3.01, [gust]).tolist() == [0.0, 0.0, 0.0]
    config = WindConfig(mean=[1.0, 0.0, 0.0], gusts=[gust, gust])
    np.testing.assert_allclose(wind.steady_wind(2.5, config), [1.0, 8.0, 0.0])


def test_kernels_match_the_matrix_forms():
    rng = np.random.default_rng(3101)
    model = wind.dryden_model(WindConfig(turbulence="severe", mean=[1.0, -2.0, 0.0]), 0.002)
    states, noise = rng.normal(size=(50, 5)), rng.normal(size=(50, 5))
    stepped = states.copy()
    kernels.turbulence_filter_rows(stepped, noise, model.phi, model.noise_gain)
    np.testing.assert_allclose(stepped, states @ model.phi.T + noise @ model.noise_gain.T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(wind.turbulence_step(states, noise, model), stepped, rtol=0, atol=1e-12)
    out = np.empty((50, 3))
    kernels.turbulence_velocity_rows(
        stepped, model.output, math.cos(model.heading), math.sin(model.heading), out
    )
    uvw = stepped @ model.output.T
    c, s = math.cos(model.heading), math.sin(model.heading)
    expected = np.stack([c * uvw[:, 0] - s * uvw[:, 1], s * uvw[:, 0] + c * uvw[:, 1], uvw[:, 2]], axis=1)
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-12)


def test_config_checks_of_the_air():
    from quad_drake.config.errors import ConfigError
    from quad_drake.config.validation import ineffective_settings
    from quad_drake.running import catalog

    with pytest.raises(ConfigError, match=r"vehicles\.0\.wind\.gusts\.0\.direction: must not be zero"):
        catalog.load("20_gust_figure_eight", None, ["vehicles.0.wind.gusts.0.direction=[0, 0, 0]"])
    with pytest.raises(ConfigError, match=r"sensors\.imu\.delta_velocity: .*fidelity: physical only"):
        catalog.load("19_windy_hover", None, ["fidelity=reference", "vehicles.0.estimator={kind: ekf7}"])
    with pytest.raises(ConfigError, match=r"wind\.turbulence: 'gale' is not one of"):
        catalog.load("19_windy_hover", None, ["vehicles.0.wind.turbulence=gale"])
    parasitic = catalog.load("19_windy_hover", None, ["vehicles.0.physics.rotor_drag=[0, 0, 0]"])
    assert not ineffective_settings(parasitic)  # the parasitic drag still acts
    still = catalog.load(
        "19_windy_hover",
        None,
        ["vehicles.0.physics.rotor_drag=[0, 0, 0]", "vehicles.0.physics.parasitic_drag=[0, 0, 0]"],
    )
    assert any("vehicles.0.wind: has no effect" in line for line in ineffective_settings(still))


def test_one_tick_kernel_is_the_filter_step_plus_the_steady_wind():
    rng = np.random.default_rng(3102)
    model = wind.dryden_model(WindConfig(turbulence="moderate", mean=[2.0, 1.0, 0.0]), 0.002)
    states, noise, steady = rng.normal(size=(20, 5)), rng.normal(size=(20, 5)), np.array([2.0, 1.0, -0.5])
    expected_states = wind.turbulence_step(states, noise, model)
    expected = wind.turbulence_velocity(expected_states, model) + steady
    c, s = math.cos(model.heading), math.sin(model.heading)
    out = np.empty((20, 3))
    kernels.wind_rows(states, noise, model.phi, model.noise_gain, model.output, c, s, steady, out)
    np.testing.assert_allclose(states, expected_states, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-12)
