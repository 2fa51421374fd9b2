import numpy as np
import pytest

from quad_drake.config.schema import CriterionConfig
from quad_drake.judging.evaluation import (
    bound_threshold,
    evaluate_criterion,
    fleet_sigma_threshold,
    max_abs,
    rms,
    sigma_threshold,
    window_threshold,
)

DT = 0.005


def frames(end_time):
    """Analyzer sample times 0.005, 0.010, ..., end_time (s)."""
    return DT * np.arange(1, round(end_time / DT) + 1)


# ----- WindowThreshold --------------------------------------------------------------


def test_window_latches_on_a_stretch_in_the_middle():
    t = frames(1.0)
    x = np.where((t > 0.1 + 1e-9) & (t < 0.8 - 1e-9), 0.0, 1.0)  # in band for 0.1 < t < 0.8 only
    r = window_threshold(t, x, 0.5, 0.6, name="Quad.Pos.Z")
    assert r.passed
    assert r.measured == pytest.approx(0.695)  # last violation 0.1, last in-band sample 0.795
    assert r.trailing == 0.0
    assert r.line == "PASS: ABS(Quad.Pos.Z) was less than 0.500000 for at least 0.600000 seconds"
    assert not window_threshold(t, x, 0.5, 0.7).passed


def test_window_is_strict():
    t = frames(0.6)
    x = np.zeros_like(t)
    x[t < 0.1 + 1e-9] = 2.0  # last violation at t = 0.1
    exactly = window_threshold(t, x, 1.0, 0.5)  # stretch 0.6 - 0.1 = W exactly
    assert not exactly.passed
    assert exactly.measured == pytest.approx(0.5)
    t2 = frames(0.605)
    x2 = np.append(x, 0.0)
    assert window_threshold(t2, x2, 1.0, 0.5).passed  # W + one sample


def test_window_starts_at_the_first_sample():
    t = frames(1.0)  # 0.005 .. 1.0, never above the threshold
    x = np.full_like(t, 0.1)
    assert not window_threshold(t, x, 0.5, 0.995).passed  # 1.0 - 0.005 is not > 0.995
    assert window_threshold(t, x, 0.5, 0.99).passed
    assert window_threshold(t, x, 0.5, 0.99).measured == pytest.approx(0.995)


def test_window_threshold_equality_is_inside_and_nan_is_a_violation():
    t = frames(1.0)
    assert window_threshold(t, np.full_like(t, -0.5), 0.5, 0.9).passed  # |x| == thr is not above
    x = np.zeros_like(t)
    x[t > 0.5] = np.nan
    r = window_threshold(t, x, 0.5, 0.6)
    assert not r.passed and r.measured == pytest.approx(0.495)


def test_window_fail_line_prints_the_trailing_stretch():
    t = frames(2.0)
    x = np.ones_like(t)
    x[(t > 0.2 + 1e-9) & (t < 0.8 - 1e-9)] = 0.0  # a 0.595 s stretch (0.2 -> 0.795) ...
    x[t > 1.875 + 1e-9] = 0.0  # ... and a trailing 0.125 s one (1.875 -> 2.0)
    r = window_threshold(t, x, 0.5, 0.8, name="Quad.PosFollowErr")
    assert not r.passed
    assert r.measured == pytest.approx(0.595)
    assert r.trailing == pytest.approx(0.125)
    assert r.line == (
        "FAIL: ABS(Quad.PosFollowErr) was less than 0.500000 for 0.125000 seconds, "
        "which was less than 0.800000 seconds"
    )
    assert str(r) == r.line and r.required == 0.8 and r.samples == 400


def test_window_only_sees_fresh_samples():
    t = frames(1.0)
    x = np.zeros_like(t)
    fresh = np.zeros_like(t, dtype=bool)
    fresh[19::20] = True  # every 0.1 s: 0.1, 0.2, ..., 1.0
    x[~fresh] = 9.0  # stale samples would be violations
    r = window_threshold(t, x, 0.5, 0.85, fresh_mask=fresh)
    assert r.passed and r.measured == pytest.approx(0.9) and r.samples == 10


def test_window_without_samples_fails():
    r = window_threshold([], [], 0.5, 1.0, name="Quad.GPS.X")
    assert not r.passed and r.line == "FAIL: ABS(Quad.GPS.X) had no samples"


# ----- SigmaThreshold ----------------------------------------------------------------

GPS_TIMES = 0.105 + 0.1 * np.arange(10)  # 0.105 .. 1.005
PATTERN = np.array([0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 5.0, 0.0, 5.0, 0.0])  # in,in,in,out,in,in,out,in,out,in
# cumulative %: 100 100 100 75 80 83.3 71.4 75 66.7 70 -> with (60, 80): violations up to sample 6 (t=0.605)


def test_sigma_cumulative_percentage_and_non_strict_window():
    r = sigma_threshold(GPS_TIMES, PATTERN, None, 0.0, 1.0, 60.0, 80.0, 0.4, name="Quad.Est.E.X")
    assert r.passed
    assert r.percent == pytest.approx(70.0)
    assert r.measured == pytest.approx(0.4)  # 1.005 - 0.605, >= W passes
    assert r.line == "PASS: ABS(Quad.Est.E.X-0.000000) was less than 1.000000 for 70% of the time"
    failed = sigma_threshold(GPS_TIMES, PATTERN, None, 0.0, 1.0, 60.0, 80.0, 0.41, name="Quad.Est.E.X")
    assert not failed.passed
    assert failed.line == "FAIL: ABS(Quad.Est.E.X-0.000000) was less than 1.000000 for 70% of the time"


def test_sigma_percent_equal_to_a_limit_is_a_violation():
    # 80% at sample 5 (t=0.505) is a violation with maxP = 80, not with maxP = 80.5.
    assert sigma_threshold(GPS_TIMES, PATTERN, None, 0.0, 1.0, 60.0, 80.5, 0.45).passed is False
    assert sigma_threshold(GPS_TIMES, PATTERN, None, 0.0, 1.0, 60.0, 83.5, 0.5).passed  # last viol. 0.505


def test_sigma_band_is_inclusive():
    x = np.array([1.5, 0.5, 1.5, 0.5])
    r = sigma_threshold(GPS_TIMES[:4], x, None, 1.0, 0.5, 50.0, 100.0, 0.0)
    assert r.percent == 100.0
    r = sigma_threshold(GPS_TIMES[:4], np.nextafter(x, [9, -9, 9, -9]), None, 1.0, 0.5, -1.0, 100.0, 0.0)
    assert r.percent == 0.0


def test_sigma_leaving_the_band_during_the_last_window_fails():
    t = 0.105 + 0.1 * np.arange(100)
    x = np.where(np.arange(100) % 10 < 7, 0.0, 3.0)  # 70 % inside ...
    assert sigma_threshold(t, x, None, 0.0, 1.0, 60.0, 80.0, 5.0).passed
    x[-20:] = 0.0  # ... the last 2 s raise the cumulative share to 76 %: still inside
    assert sigma_threshold(t, x, None, 0.0, 1.0, 60.0, 80.0, 5.0).passed
    x[-40:] = 0.0  # 82 % at the end: violation at the last sample
    r = sigma_threshold(t, x, None, 0.0, 1.0, 60.0, 80.0, 5.0)
    assert not r.passed and r.measured == 0.0 and r.percent == pytest.approx(82.0)


def test_sigma_starts_at_the_first_fresh_sample_and_ignores_stale_ones():
    t = frames(1.005)
    fresh = np.isin(np.round(t / DT).astype(int), np.round(GPS_TIMES / DT).astype(int))
    assert fresh.sum() == 10
    x = np.where(fresh, 0.0, 100.0)  # stale samples would all be outside
    # all fresh samples inside: 100% never >= 100.5, so no violation; stretch 1.005 - 0.105 = 0.9
    r = sigma_threshold(t, x, fresh, 0.0, 1.0, 50.0, 100.5, 0.9)
    assert r.passed and r.measured == pytest.approx(0.9) and r.samples == 10
    assert not sigma_threshold(t, x, fresh, 0.0, 1.0, 50.0, 100.5, 0.95).passed


def test_sigma_with_signal_reference_and_sigma():
    t = GPS_TIMES[:4]
    truth = np.array([1.0, 2.0, 3.0, 4.0])
    sigma = np.array([0.1, 0.1, 0.5, 0.5])
    measured = truth + np.array([0.05, -0.2, 0.4, -0.5])  # in, out, in, in (boundary)
    r = sigma_threshold(
        t,
        measured,
        None,
        truth,
        sigma,
        50.0,
        80.0,
        0.0,
        name="Quad.GPS.X",
        ref_label="Quad.Pos.X",
        sigma_label="Quad.Est.S.X",
    )
    assert r.percent == pytest.approx(75.0)
    assert r.line == "PASS: ABS(Quad.GPS.X-Quad.Pos.X) was less than Quad.Est.S.X for 75% of the time"
    with pytest.raises(ValueError, match="label"):
        sigma_threshold(t, measured, None, truth, 0.5, 50.0, 80.0, 0.0)


def test_sigma_without_fresh_samples_fails():
    r = sigma_threshold(GPS_TIMES, PATTERN, np.zeros(10, bool), 0.0, 1.0, 60.0, 80.0, 0.0, name="G")
    assert not r.passed and r.samples == 0


# ----- from config, metrics ------------------------------------------------------------


def test_evaluate_criterion_dispatches_on_kind():
    t = frames(1.0)
    fresh = np.zeros_like(t, dtype=bool)
    fresh[::20] = True
    signals = {
        "Quad.Pos.Z": (np.zeros_like(t), None),
        "Quad.GPS.Z": (np.full_like(t, 0.3), fresh),
        "Quad.Est.S.Z": (np.full_like(t, 0.5), None),
    }
    window = evaluate_criterion(
        CriterionConfig(kind="window", signal="Quad.Pos.Z", threshold=0.1, window=0.5), t, signals.__getitem__
    )
    assert window.passed and window.kind == "window"
    sigma = evaluate_criterion(
        CriterionConfig(
            kind="sigma",
            signal="Quad.GPS.Z",
            sigma_signal="Quad.Est.S.Z",
            min_percent=50.0,
            max_percent=100.0,
            window=0.1,
        ),
        t,
        signals.__getitem__,
    )
    assert sigma.samples == 10 and sigma.percent == 100.0 and not sigma.passed  # 100 >= maxP at the end
    assert sigma.line == "FAIL: ABS(Quad.GPS.Z-0.000000) was less than Quad.Est.S.Z for 100% of the time"


def test_metrics():
    assert rms([3.0, -4.0]) == pytest.approx(np.sqrt(12.5))
    assert max_abs([1.0, -7.5, 2.0]) == 7.5


# ----- what the plots and the report draw ------------------------------------------------------


def test_window_series_locate_the_longest_credited_stretch():
    t = frames(2.0)  # 0.005 .. 2.0 s
    x = np.zeros_like(t)
    x[[39, 199]] = 1.0  # violations at t = 0.2 and 1.0 s
    r = window_threshold(t, x, 0.5, 0.9, name="Quad.Pos.Z")
    assert r.series["span"] == pytest.approx([1.0, 2.0], abs=1e-12)  # 1.0 s after the last violation
    assert r.measured == pytest.approx(1.0, abs=1e-12) and r.passed
    x[359] = 1.0  # and at 1.8 s: 0.2 -> 1.0 (0.8 s) wins
    r = window_threshold(t, x, 0.5, 0.9, name="Quad.Pos.Z")
    assert r.series["span"] == pytest.approx([0.2, 0.995], abs=1e-12)
    np.testing.assert_allclose(r.series["stretch"][-1], r.trailing)
    assert (r.description, r.required_text) == ("|Quad.Pos.Z| < 0.5 m for > 0.9 s", "> 0.9 s")
    assert r.measured_text == "longest stretch within: 0.795 s" and not r.passed


def test_sigma_series_is_the_cumulative_share_of_fresh_samples():
    t = frames(0.1)  # 20 samples, every other one fresh
    fresh = np.arange(t.size) % 2 == 0
    x = np.where(np.arange(t.size) % 4 == 0, 0.0, 5.0)  # fresh: in, out, in, out, ...
    r = sigma_threshold(t, x, fresh, 0.0, 1.0, 40.0, 60.0, 0.05, name="Quad.GPS.X")
    np.testing.assert_array_equal(r.series["times"], t[fresh])
    np.testing.assert_allclose(r.series["percent"][:4], [100.0, 50.0, 100 * 2 / 3, 50.0])
    assert r.series["percent"][-1] == r.percent == 50.0 and r.samples == 10
    assert r.description == "|Quad.GPS.X - 0| <= 1: 40-60 % (last 0.05 s)"
    assert r.measured_text.startswith("50 % of 10 samples within")


def test_fleet_sigma_counts_what_it_judged_and_writes_no_nan():
    errors = [np.array([0.1, 0.5, np.nan]), np.array([2.0])]
    sigmas = [np.array([1.0, 1.0, 1.0]), np.array([1.0])]
    r = fleet_sigma_threshold(errors, sigmas, "Est.E.X", "Est.S.X", 1.0, 40.0, 60.0)
    assert (r.samples, r.percent, r.passed, r.trailing) == (4, 50.0, True, None)
    assert r.description == "fleet |V.Est.E.X| <= 1 V.Est.S.X: 40-60 % (2 vehicles V)"
    assert (r.measured_text, r.required_text) == ("50 % of 4 samples within", "share in [40 %, 60 %]")
    assert "series" not in r.to_dict() and r.to_dict()["samples"] == 4
    assert r.measured_unit == r.to_dict()["measured_unit"] == "%"


def test_the_measured_unit_follows_the_kind_or_the_signal():
    t = frames(0.1)
    assert window_threshold(t, np.zeros(t.size), 0.5, 0.05, name="Quad.Pos.Z").measured_unit == "s"
    bound = bound_threshold(t, np.zeros(t.size), 0.1, 0.0, 0.1, name="Quad.Est.E.Vel")
    assert (bound.measured_unit, bound.to_dict()["measured_unit"]) == ("m/s", "m/s")
    assert bound_threshold(t, np.zeros(t.size), 0.1, 0.0, 0.1, name="x").measured_unit == ""
