"""Delay compensation on hand-made estimates: the odometry leaves GPS corrections out, samples move by it."""

import pytest

from quad_drake import delay_compensation as dc

DT = 0.002


def test_history_reaches_the_longest_lag_in_a_ring():
    capacity = dc.history_capacity(0.2, DT)
    assert capacity == 102
    assert dc.history_slot(0.0, DT, capacity) == 0
    assert dc.history_slot(0.2, DT, capacity) == 100
    assert dc.history_slot(0.204, DT, capacity) == 0  # 102 ticks later: the same slot, overwritten


def test_odometry_follows_the_estimate_but_not_its_gps_corrections():
    odometry, step = [0.0] * 6, [0.0] * 3
    previous = [0.0, 0.0, -1.0, 1.0, 0.0, 0.0]
    moved = [0.002, 0.0, -1.0, 1.01, 0.0, 0.0]  # one predicted tick: p += v dt, v += 0.01
    odometry, step = dc.odometry_step(odometry, moved, previous, step, False, DT)
    assert odometry == pytest.approx([0.002, 0, 0, 0.01, 0, 0]) and step == pytest.approx([0.01, 0, 0])
    corrected = [0.5, 0.3, -1.0, 1.3, 0.0, 0.0]  # a GPS correction jumped the estimate
    odometry, step = dc.odometry_step(odometry, corrected, moved, step, True, DT)
    assert odometry == pytest.approx([0.002 + 1.01 * DT, 0, 0, 0.02, 0, 0])  # kinematic increment only
    assert step == pytest.approx([0.01, 0, 0])
    assert dc.predicted_odometry(odometry, [2.0, 0, 0], step, DT) == pytest.approx(
        [0.002 + 1.01 * DT + 2.0 * DT, 0, 0, 0.03, 0, 0]
    )


def test_a_late_sample_moves_by_the_odometry_since_its_stamp_and_keeps_it():
    sample = [1.0, 2.0, -3.0, 0.5, 0.0, 0.0, 4.0]
    row = [4.0, 10.0, 0.0, 0.0, 1.0, 0.0, 0.0]
    now = [10.1, 0.0, 0.0, 1.0, 0.2, 0.0]
    assert dc.compensated_gps(sample, row, now) == pytest.approx([1.1, 2.0, -3.0, 0.5, 0.2, 0.0, 4.0])
    assert dc.compensated_gps(sample, [3.9] + row[1:], now) == sample  # the ring no longer holds 4.0 s
    assert dc.compensated_gps(sample, None, now) == sample
    assert dc.compensated_gps(sample, [float("nan")] * 7, now) == sample
