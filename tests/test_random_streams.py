"""Counter-based noise streams: run i draws the same noise whatever its batch."""

import numpy as np
import pytest
from pydrake.common import RandomDistribution

from quad_drake.models.random_streams import NoiseStreams, stream_generator
from quad_drake.systems.noise import NoiseStreamSource


def test_a_run_draws_the_same_noise_in_any_batch():
    alone = NoiseStreams([107], "Quad/imu", 6, "gaussian", 500)
    batch = NoiseStreams([103, 104, 107, 990], "Quad/imu", 6, "gaussian", 500)
    for block in range(3):
        np.testing.assert_array_equal(alone.block(block)[0], batch.block(block)[2])


def test_blocks_are_the_stream_in_order():
    streams = NoiseStreams([7, 8], "Quad/motor_noise", 8, "uniform", 500)
    blocks = np.concatenate([streams.block(b) for b in range(2)], axis=1)  # (2, 1000, 8): run-major
    expected = stream_generator(8, "Quad/motor_noise").random((1000, 8))
    np.testing.assert_array_equal(blocks[1], expected)
    assert blocks.min() >= 0.0 and blocks.max() < 1.0


def test_names_and_seeds_give_independent_streams():
    a = NoiseStreams([1, 2], "Quad/gps", 9, "gaussian", 10).block(0)
    b = NoiseStreams([1, 2], "Quad/mag", 9, "gaussian", 10).block(0)
    c = NoiseStreams([1, 2], "Quad2/gps", 9, "gaussian", 10).block(0)
    assert not np.array_equal(a, b) and not np.array_equal(a, c)
    assert not np.array_equal(a[0], a[1])
    # unit normal: 2 x 10 x 9 draws, mean and std well inside their sampling error (5 sigma)
    draws = NoiseStreams(range(50), "Quad/imu", 6, "gaussian", 500).block(0)
    assert abs(draws.mean()) < 5 / np.sqrt(draws.size)
    assert abs(draws.std() - 1.0) < 5 / np.sqrt(2 * draws.size)


def test_blocks_in_any_order_are_the_stream_s_blocks():
    streams = NoiseStreams([3, 9], "Quad/imu", 6, "gaussian", 50)
    in_order = [streams.block(b) for b in range(4)]
    any_order = NoiseStreams([3, 9], "Quad/imu", 6, "gaussian", 50)
    for b in (2, 3, 0, 1, 3, 2):  # skipped blocks, then back in time (a restart)
        np.testing.assert_array_equal(any_order.block(b), in_order[b])
    with pytest.raises(ValueError, match="block -1 asked for"):
        any_order.block(-1)


def test_a_block_drawn_into_a_buffer_is_the_block():
    fresh = NoiseStreams([5, 6], "Quad/imu", 6, "gaussian", 500)
    reused = NoiseStreams([5, 6], "Quad/imu", 6, "gaussian", 500)
    buffer = np.full((2, 500, 6), np.nan)
    for block in range(2):
        assert reused.block(block, out=buffer) is buffer
        np.testing.assert_array_equal(buffer, fresh.block(block))


def _noise_at(source, context, time):
    context.SetTime(time)
    return source.GetOutputPort("noise").Eval(context).reshape(2, 3)


def test_the_noise_source_holds_sample_k_from_its_redraw_at_k_period():
    period = 0.1  # 10 samples per block
    source = NoiseStreamSource(RandomDistribution.kGaussian, 3, period, [4, 11], "Quad/gps")
    context = source.CreateDefaultContext()
    assert context.num_total_states() == 0  # a function of the time: no state to copy in a tick
    streams = [stream_generator(s, "Quad/gps").standard_normal((40, 3)) for s in (4, 11)]
    for k in (0, 1, 9, 10, 27, 3, 35):  # within a block, the next, one skipped, back in time
        for offset in (0.0, 1e-6, 0.5 * period, period - 1e-6):
            expected = [stream[k] for stream in streams]
            np.testing.assert_array_equal(_noise_at(source, context, k * period + offset), expected)
    # a sample time computed with rounding below k period still reads sample k
    np.testing.assert_array_equal(_noise_at(source, context, 3 * period - 1e-15), [s[3] for s in streams])
