"""The air's velocity around n vehicles: :class:`Wind`, thin glue over the pure ``quad_drake.models.wind``."""

import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import LeafSystem

from quad_drake.conventions import ONBOARD_PERIOD, SENSOR_OFFSET
from quad_drake.kernels import flight as kernels
from quad_drake.models import wind
from quad_drake.systems._io import discrete_group, row_reader


class Wind(LeafSystem):
    """The wind of n vehicles (default 1): constant + (1 - cos) gusts + Dryden turbulence
    (``quad_drake.models.wind``), updated every ONBOARD_PERIOD from t = SENSOR_OFFSET = 0 and held in
    between (the plant's two 1 ms steps of a tick read the same value).

    Constructor: config (WindConfig, shared by the n vehicles; each draws its own turbulence),
    n (vehicles). Ports carry the n per-vehicle vectors concatenated vehicle-major.
    Input ``noise`` (5, unit Gaussian, random kGaussian; only with turbulence): the Dryden
    filters' draws (u 1, v 2, w 2); the first sample (t = 0) draws the filters' stationary start.
    Wire ``RandomSource(kGaussian, n 5, ONBOARD_PERIOD)`` or a ``systems.noise.NoiseStreamSource``.
    Output ``wind`` (3, m/s, NED; a state output port): the air's velocity wind_N; before the
    first update the mean wind. Without gusts and turbulence the output is the constant mean
    and the system has no event.
    """

    noise_size = wind.TURBULENCE_STATES
    noise_period = ONBOARD_PERIOD
    noise_distribution = RandomDistribution.kGaussian

    def __init__(self, config, n=1) -> None:
        super().__init__()
        self._config, self._n = config, n
        self._model = model = wind.dryden_model(config, ONBOARD_PERIOD)
        self._mean = np.asarray(config.mean, dtype=float)
        if model is not None:
            self._heading = (float(np.cos(model.heading)), float(np.sin(model.heading)))
            self._no_phi = np.zeros_like(model.phi)
        self._output = discrete_group(self, np.tile(np.asarray(config.mean, dtype=float), n), "wind")
        if self._model is not None:
            port = self.DeclareVectorInputPort(
                "noise", n * self.noise_size, random_type=self.noise_distribution
            )
            self._read_noise = row_reader(port, n)
            self._turbulence = discrete_group(self, n * self.noise_size)
            self._started = discrete_group(self, 1)
        if self._model is not None or config.gusts:
            self.DeclarePeriodicDiscreteUpdateEvent(ONBOARD_PERIOD, SENSOR_OFFSET, self._update)

    @property
    def model(self) -> wind.DrydenModel | None:
        """The :class:`~quad_drake.models.wind.DrydenModel`, or None without turbulence."""
        return self._model

    def _update(self, context, discrete_state):
        out = discrete_state.get_mutable_value(self._output).reshape(self._n, 3)
        config, model = self._config, self._model
        steady = wind.steady_wind(context.get_time(), config) if config.gusts else self._mean
        if model is None:
            out[:] = steady
            return
        states = discrete_state.get_mutable_value(self._turbulence).reshape(self._n, self.noise_size)
        started = discrete_state.get_mutable_value(self._started)
        if started[0]:  # x = Phi x + G n (quad_drake.models.wind.turbulence_step)
            phi, gain = model.phi, model.noise_gain
        else:  # the stationary start x = P^(1/2) n (quad_drake.models.wind.turbulence_start)
            phi, gain = self._no_phi, model.initial_gain
            started[0] = 1.0
        kernels.wind_rows(
            states, self._read_noise(context), phi, gain, model.output, *self._heading, steady, out
        )
