"""The counter-based noise of N runs as a LeafSystem: :class:`NoiseStreamSource`, the
``RandomSource`` of a vehicle built with run seeds (``simulation.build_vehicle(..., seeds=...)``),
thin glue over the pure ``quad_drake.models.random_streams``."""

from pydrake.common import RandomDistribution
from pydrake.systems.framework import LeafSystem

from quad_drake.models.random_streams import GAUSSIAN, UNIFORM, NoiseStreams, sample_index

_DISTRIBUTIONS = {RandomDistribution.kGaussian: GAUSSIAN, RandomDistribution.kUniform: UNIFORM}


class NoiseStreamSource(LeafSystem):
    """Noise of N = len(seeds) vehicles from :class:`~quad_drake.models.random_streams.NoiseStreams`,
    in place of ``RandomSource(distribution, N size, period)``.

    distribution: ``RandomDistribution.kGaussian`` (unit normal) or ``kUniform`` (in [0, 1));
    size: values per vehicle and sample; period (s): the time between samples; seeds: (N,) run
    seeds; name: the streams' name (``"<vehicle name>/<input>"``, ``models.random_streams``).
    Output ``noise`` (N size, vehicle-major) at time t is sample k = floor(t / period) of every
    vehicle's stream, what a RandomSource holds after its redraw at t = k period (applied before
    the discrete updates at t). Unlike RandomSource it has no state and no event: the output is a
    function of the time (cached on Drake's time ticket), so a tick neither copies nor swaps a
    noise state. A block of one simulated second is drawn, into one buffer reused from block to
    block, when a reading first needs a sample of it (``NoiseStreams.block``: in any order)."""

    def __init__(self, distribution, size, period, seeds, name) -> None:
        super().__init__()
        if distribution not in _DISTRIBUTIONS:
            raise ValueError(f"{name}: distribution {distribution} is neither kGaussian nor kUniform")
        self.period = float(period)
        self._per_block = max(1, int(round(1.0 / self.period)))
        self._streams = NoiseStreams(seeds, name, size, _DISTRIBUTIONS[distribution], self._per_block)
        self._block, self._block_index = None, -1
        self.DeclareVectorOutputPort(
            "noise", len(seeds) * int(size), self._calc, prerequisites_of_calc={self.time_ticket()}
        )

    def release_memory(self) -> None:
        """Drop the block in hand (a Python system in a Diagram is never garbage-collected:
        pydrake's C++ side keeps it alive)."""
        self._block, self._block_index = None, -1

    def _calc(self, context, output):
        block, row = divmod(sample_index(context.get_time(), self.period), self._per_block)
        if block != self._block_index:
            self._block = self._streams.block(block, out=self._block)
            self._block_index = block
        n, _, size = self._block.shape
        output.get_mutable_value().reshape(n, size)[:] = self._block[:, row]
