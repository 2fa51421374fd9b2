"""Counter-based noise streams: one Philox generator per (run seed, noise name).

Vehicle j of a batch of N runs (``simulation.build_vehicle`` with ``seeds``) flies run seed
``seeds[j]`` (a campaign's run i has seed S + i, as on the process pool). Each of its noise
inputs, named ``"<vehicle name>/<input>"`` (e.g. ``Quad/imu``), draws from its own Philox
generator whose 128-bit key is derived by ``numpy.random.SeedSequence(run seed,
spawn_key=(crc32(name),))``. A stream depends on nothing else, so run i gives the same noise,
and so the same result, whatever the batch it is flown in, its position there and the number
of workers.

The draws are taken in blocks of one simulated second (``samples_per_block`` samples of
``size`` values), so the per-vehicle loop runs once per second, not per tick. Sample k of
a stream (k = 0, 1, ... at t = k period) is row k % samples_per_block of block
k // samples_per_block; every block is the next ``samples_per_block * size`` draws of the
generator, in C order. A block is stored run-major, (N, samples, size): each generator draws
straight into its vehicle's contiguous (samples, size) part, with no copy (a time-major block
cost as much again as the drawing, in strided copies); reading one sample of the N vehicles is
a gather of N rows of ``size`` values.

These streams differ from Drake's ``RandomSource`` (which ``build_vehicle`` wires without
``seeds``): a fleet run and ``quad-drake run NAME --seed S`` see different noise and agree only
statistically (README "Fleet mode"). ``systems.noise.NoiseStreamSource`` is their LeafSystem.
Pure: numpy only.
"""

import math
import zlib

import numpy as np

GAUSSIAN = "gaussian"
UNIFORM = "uniform"
DISTRIBUTIONS = (GAUSSIAN, UNIFORM)


SAMPLE_TIME_TOLERANCE = 1e-7
"""Samples (fractions of a noise period) by which a reading may fall short of its sample time and
still see that sample: the rounding of t / period (about 1e-9 of a sample at 10,000 s of 2 ms
samples); every consumer reads at or after the sample time (``conventions``' offsets)."""


def sample_index(time, period) -> int:
    """The index k of the noise sample held at `time` s: the last redraw at k period <= time."""
    return math.floor(time / period + SAMPLE_TIME_TOLERANCE)


def stream_key(run_seed, name) -> np.ndarray:
    """(2,) uint64 Philox key of the noise named `name` of the run with seed `run_seed` (>= 0)."""
    sequence = np.random.SeedSequence(int(run_seed), spawn_key=(zlib.crc32(name.encode()),))
    return sequence.generate_state(2, np.uint64)


def stream_generator(run_seed, name) -> np.random.Generator:
    """A fresh numpy Generator at the start of the stream (run_seed, name)."""
    return np.random.Generator(np.random.Philox(key=stream_key(run_seed, name)))


class NoiseStreams:
    """The noise of one input of N vehicles, drawn a block at a time.

    seeds: (N,) run seeds; name: the noise name (same for every vehicle of the fleet);
    size: values per sample; distribution: ``"gaussian"`` (unit normal) or ``"uniform"``
    (in [0, 1)); samples_per_block: samples per block (one simulated second of the input).
    """

    def __init__(self, seeds, name, size, distribution, samples_per_block):
        if distribution not in DISTRIBUTIONS:
            raise ValueError(f"distribution {distribution!r} is not one of {DISTRIBUTIONS}")
        self.seeds = [int(s) for s in seeds]
        self.name, self.size, self.distribution = name, int(size), distribution
        self.samples_per_block = int(samples_per_block)
        self._generators = None
        self._next_block = 0  # the block the generators draw next

    @property
    def n(self) -> int:
        return len(self.seeds)

    def block(self, index, out=None) -> np.ndarray:
        """(N, samples_per_block, size) draws of block `index` ([j, k]: sample k of the block of
        vehicle j), written into `out` (a C-contiguous float array of that shape, reused from
        block to block) when given.

        Blocks may come in any order: the generators are sequential, so a later block draws
        the ones it skips, and an earlier one restarts the streams (a re-initialised
        simulation) and draws up to it.
        """
        if index < 0:
            raise ValueError(f"{self.name}: block {index} asked for")
        if self._generators is None or index < self._next_block:
            self._generators = [stream_generator(s, self.name) for s in self.seeds]
            self._next_block = 0
        if out is None:
            out = np.empty((self.n, self.samples_per_block, self.size))
        generator_type = np.random.Generator
        draw = generator_type.standard_normal if self.distribution == GAUSSIAN else generator_type.random
        for j, generator in enumerate(self._generators):
            for _ in range(self._next_block, index + 1):
                draw(generator, out=out[j])
        self._next_block = index + 1
        return out
