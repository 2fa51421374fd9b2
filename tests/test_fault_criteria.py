"""Fault criteria on hand-made signals: a bound over a time interval, recovery within T s after a time."""

import math

import numpy as np
import pytest

from quad_drake.judging.evaluation import bound_threshold, recovery_threshold

TIMES = 0.005 * np.arange(1, 2001)  # 10 s of 5 ms analyzer samples


def bump(level, start, end, base=0.2):
    """base everywhere, `level` on samples in [start, end)."""
    values = np.full(TIMES.shape, base)
    values[(TIMES >= start - 1e-9) & (TIMES < end - 1e-9)] = level
    return values


def test_bound_judges_only_its_interval():
    values = bump(3.0, 2.0, 3.0)
    inside = bound_threshold(TIMES, values, 1.0, 4.0, 6.0, "Quad.X")
    assert inside.passed and inside.kind == "bound"
    assert inside.measured == pytest.approx(0.2) and inside.required == 1.0
    assert inside.samples == 400 and inside.trailing is None
    assert (
        inside.line
        == "PASS: ABS(Quad.X) was less than 1.000000 from 4.000000 to 6.000000 seconds (max 0.200000)"
    )
    over = bound_threshold(TIMES, values, 1.0, 1.0, 5.0, "Quad.X")
    assert not over.passed and over.measured == pytest.approx(3.0) and over.trailing == pytest.approx(2.0)
    assert over.line.startswith("FAIL: ABS(Quad.X) was 3.000000 at 2.000000 seconds, not less than 1.000000")
    # [start, end) is half-open: the violation starting at 2.0 s is outside [1, 2)
    assert bound_threshold(TIMES, values, 1.0, 1.0, 2.0).passed


def test_bound_counts_non_finite_samples_and_an_empty_interval_as_failures():
    values = bump(math.nan, 5.0, 5.1)
    result = bound_threshold(TIMES, values, 1.0, 4.0, 6.0)
    assert not result.passed and math.isinf(result.measured) and result.trailing == pytest.approx(5.0)
    empty = bound_threshold(TIMES, values, 1.0, 20.0, 30.0)
    assert not empty.passed and empty.samples == 0 and "had no samples" in empty.line
    assert empty.measured_text == "no samples"


def test_bound_and_recovery_fill_the_criterion_texts():
    values = bump(2.0, 4.0, 6.5)
    bound = bound_threshold(TIMES, values, 1.0, 4.0, 6.0, "Quad.Est.E.Pos")
    assert bound.description == "|Quad.Est.E.Pos| < 1 m in [4, 6) s"
    assert bound.required_text == "< 1 m on every sample"
    assert bound.measured_text == "max 2 m; first above at 4 s"
    recovery = recovery_threshold(TIMES, values, 1.0, 6.0, 1.0, "Quad.Est.E.Pos")
    assert recovery.description == "|Quad.Est.E.Pos| < 1 m within 1 s after 6 s"
    assert recovery.required_text == "back under within 1 s, and staying"
    assert recovery.measured_text == "back under 0.5 s after 6 s"
    calm = recovery_threshold(TIMES, np.zeros_like(values), 1.0, 6.0, 1.0, "Quad.Est.E.Pos")
    assert calm.passed and calm.measured == 0.0
    assert calm.measured_text == "under 1 m from 6 s on (never above)"  # not "back under 0 s after"


def test_recovery_time_is_measured_from_start_to_the_first_sample_after_the_last_violation():
    values = bump(2.0, 4.0, 6.5)  # a fault from 4 s to 6 s, the signal back at 6.5 s
    result = recovery_threshold(TIMES, values, 1.0, 6.0, 1.0, "Quad.Est.E.Pos")
    assert result.passed and result.kind == "recovery"
    assert result.measured == pytest.approx(0.5) and result.trailing == pytest.approx(6.495)
    assert result.line == (
        "PASS: ABS(Quad.Est.E.Pos) was less than 1.000000 0.500000 seconds after 6.000000 seconds "
        "(allowed 1.000000)"
    )
    late = recovery_threshold(TIMES, values, 1.0, 6.0, 0.4, "Quad.Est.E.Pos")
    assert not late.passed and late.measured == pytest.approx(0.5)
    assert "within 0.400000 seconds after 6.000000 seconds (after 0.500000 seconds)" in late.line


def test_recovery_needs_to_stay_recovered_and_samples_after_the_allowed_time():
    values = bump(2.0, 4.0, 6.5)
    values[TIMES > 9.0] = 5.0  # a relapse after recovering counts
    relapse = recovery_threshold(TIMES, values, 1.0, 6.0, 1.0)
    assert not relapse.passed and math.isinf(relapse.measured) and "(never)" in relapse.line
    assert recovery_threshold(TIMES, bump(0.0, 0.0, 0.0), 1.0, 2.0, 0.0).measured == 0.0
    short = recovery_threshold(TIMES, bump(0.0, 0.0, 0.0), 1.0, 9.5, 1.0)
    assert not short.passed and "had no samples" in short.line
