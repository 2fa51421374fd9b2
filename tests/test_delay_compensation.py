"""Delay compensation on hand-made estimates: the odometry leaves GPS corrections out, samples move by it;
one vehicle's vectors and N vehicles' rows give the same numbers."""

import math

import numpy as np
import pytest

from quad_drake.estimation import delay_compensation as dc

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
    np.testing.assert_array_equal(dc.compensated_gps(sample, [3.9] + row[1:], now), sample)  # ring moved on
    np.testing.assert_array_equal(dc.compensated_gps(sample, [math.nan] * 7, now), sample)  # no row


def test_rows_of_n_vehicles_are_each_vehicle_alone():
    rng = np.random.default_rng(19)
    n = 20
    odometry, estimate, previous = rng.normal(size=(3, n, 6))
    step, fused = rng.normal(size=(n, 3)), rng.uniform(size=n) < 0.3
    new, dv = dc.odometry_step(odometry, estimate, previous, step, fused, DT)
    velocity = rng.normal(size=(n, 3))
    ahead = dc.predicted_odometry(odometry, velocity, step, DT)
    sample = np.column_stack([rng.normal(size=(n, 6)), rng.uniform(0.0, 10.0, n)])
    rows = np.column_stack([sample[:, 6] + rng.choice([0.0, 1e-10, 0.002], n), rng.normal(size=(n, 6))])
    rows[:5, 0] = math.nan
    shifted = dc.compensated_gps(sample, rows, ahead)
    assert fused.any() and not fused.all()
    for i in range(n):
        one, one_dv = dc.odometry_step(odometry[i], estimate[i], previous[i], step[i], fused[i], DT)
        np.testing.assert_allclose(new[i], one, rtol=0, atol=1e-12)
        np.testing.assert_allclose(dv[i], one_dv, rtol=0, atol=1e-12)
        np.testing.assert_allclose(
            ahead[i], dc.predicted_odometry(odometry[i], velocity[i], step[i], DT), atol=1e-12
        )
        np.testing.assert_allclose(shifted[i], dc.compensated_gps(sample[i], rows[i], ahead[i]), atol=1e-12)
    np.testing.assert_array_equal(shifted[:5], sample[:5])
