"""The reference simulator's pass/fail analyzers (SPEC §0.5) over logged samples.

Inputs are the 5 ms analyzer samples (SPEC §0.2): ``times`` (s) and the signal's
``values`` at those times; ``fresh_mask`` marks the samples on which a sensor
signal had a new measurement (the reference's analyzers only see those).

Times are treated as exact multiples of the log period: a stretch is compared
with the window W with a tolerance of :data:`TIME_TOLERANCE`, so a stretch of
exactly W counts as W (not longer) whatever the floating-point rounding of the
sample times. A non-finite sample counts as a violation (the reference's
``fabs(NaN) > thr`` is false; a diverged run must not pass).
"""

import math
from dataclasses import dataclass, field, fields
from typing import Optional

import numpy as np

from .conventions import PHYSICS_PERIOD
from .safety import SAFETY_SIGNALS, safety_criteria

TIME_TOLERANCE = 1e-9
"""s; stretches within this of the window W count as exactly W."""


@dataclass(frozen=True)
class CriterionResult:
    """Verdict of one analyzer, with the text every reader (console, report, campaign) prints.

    kind: "window", "sigma", "fleet_sigma" or a safety kind ("floor", "room", "finite",
        "tracking"; see the safety analyzers below for their measured/required; their
        ``trailing`` and ``percent`` are None).
    line: the reference-style PASS/FAIL line.
    measured: window: s, the longest stretch, ending at a sample, with every sample
        |x| <= threshold (passed iff measured > required); sigma: s, the final stretch
        lastSampleTime - lastViolation (passed iff >= required); fleet_sigma: %, the share
        of the fleet's fresh samples inside the band.
    required: window, sigma: s, the window W; fleet_sigma: %, the lowest share accepted.
    trailing: window, sigma: s, lastSampleTime - (last violation), what the window FAIL
        line prints; None for fleet_sigma.
    percent: sigma: final cumulative share of fresh samples in the band, %; fleet_sigma: the
        share, %; None for window.
    samples: number of samples the analyzer counted (fresh ones for sigma and fleet_sigma).
    description: what is judged, e.g. ``|Quad.Est.E.Pos| < 1 for > 20 s``.
    measured_text, required_text: the measured value and the requirement, in words.
    series: the arrays the verdict was computed from, for plots (not compared, not saved):
        window: ``times`` (s, the samples judged), ``stretch`` (s since the last violation)
        and ``span`` ((2,) s, start and end of the longest stretch); sigma: ``times`` (s, the
        fresh samples) and ``percent`` (the cumulative share in the band, %).
    """

    kind: str
    name: str
    passed: bool
    line: str
    measured: float
    required: float
    trailing: Optional[float]
    percent: Optional[float] = None
    samples: int = 0
    description: str = ""
    measured_text: str = ""
    required_text: str = ""
    series: Optional[dict] = field(default=None, compare=False, repr=False)

    def __str__(self):
        return self.line

    def to_dict(self):
        """The verdict as a dict of plain values, without ``series`` (for summary.json)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "series"}


def judged_criteria(scenario):
    """The criteria a run of `scenario` is judged on and a campaign counts, in order: its
    own, then the flight-safety ones of :func:`quad_drake.safety.safety_criteria`."""
    return list(scenario.criteria) + safety_criteria(scenario)


def _select(times, values, fresh_mask):
    times = np.asarray(times, dtype=float).reshape(-1)
    values = np.asarray(values, dtype=float).reshape(-1)
    if times.shape != values.shape:
        raise ValueError(f"times {times.shape} and values {values.shape} differ in length")
    if fresh_mask is None:
        return times, values, None
    mask = np.asarray(fresh_mask, dtype=bool).reshape(-1)
    if mask.shape != times.shape:
        raise ValueError(f"fresh_mask {mask.shape} and times {times.shape} differ in length")
    return times[mask], values[mask], mask


def window_threshold(times, values, threshold, window, name="x", fresh_mask=None):
    """WindowThreshold(name, threshold, window): "ABS(x) < threshold for more than W s", latched.

    SPEC §0.5: lastAbove starts at the first sample time; at each sample t,
    |x| > threshold sets lastAbove = t; t - lastAbove > W (strict) latches PASS.
    So the run passes iff some stretch longer than W, ending at a sample and
    counted from the last violating sample (or the first sample), had every
    sample within the threshold; it need not reach the end of the run.

    Lines (printf ``%lf``, as the reference):
      ``PASS: ABS(name) was less than <thr> for at least <W> seconds``
      ``FAIL: ABS(name) was less than <thr> for <trailing> seconds, which was less than <W> seconds``
    where <trailing> = last sample time - last violating sample time, which is what
    the reference prints (not the longest stretch; that is ``measured``).
    """
    times, values, _ = _select(times, values, fresh_mask)
    text = {
        "description": f"|{name}| < {threshold:g} for > {window:g} s",
        "required_text": f"> {window:g} s",
    }
    if times.size == 0:
        return CriterionResult(
            "window",
            name,
            False,
            f"FAIL: ABS({name}) had no samples",
            0.0,
            float(window),
            0.0,
            samples=0,
            measured_text="no samples",
            **text,
        )
    above = ~(np.abs(values) <= threshold)  # NaN counts as above
    last_above = np.maximum.accumulate(np.where(above, times, times[0]))
    stretches = times - last_above
    end = int(np.argmax(stretches))
    longest = float(stretches[end])
    trailing = float(stretches[-1])
    passed = longest > window + TIME_TOLERANCE
    if passed:
        line = f"PASS: ABS({name}) was less than {threshold:f} for at least {window:f} seconds"
    else:
        line = (
            f"FAIL: ABS({name}) was less than {threshold:f} for {trailing:f} seconds, "
            f"which was less than {window:f} seconds"
        )
    return CriterionResult(
        "window",
        name,
        bool(passed),
        line,
        longest,
        float(window),
        trailing,
        samples=int(times.size),
        measured_text=f"longest stretch within: {longest:.4g} s",
        series={"times": times, "stretch": stretches, "span": np.array([last_above[end], times[end]])},
        **text,
    )


def _label(label, value):
    if label:
        return label
    if np.ndim(value) != 0:
        raise ValueError("a signal-valued ref or sigma needs a label for the report line")
    return f"{float(value):f}"


def sigma_threshold(
    times,
    values,
    fresh_mask,
    ref_values,
    sigma_values,
    min_percent,
    max_percent,
    window,
    name="x",
    ref_label="",
    sigma_label="",
):
    """SigmaThreshold(name, ref, sigma, minP, maxP, W) (SPEC §0.5).

    Only fresh samples count (``fresh_mask`` None: all). ``ref_values`` and
    ``sigma_values`` are scalars or arrays over all samples (live signals read at
    the same sample time). At each fresh sample t: "in" iff ref - sigma <= x <=
    ref + sigma (inclusive); per = 100 in / (in + out), cumulative since the
    start; per <= minP or per >= maxP sets lastViolation = t. lastViolation
    starts at the first fresh sample time (the reference analyzer's first
    update). PASS iff lastSampleTime - lastViolation >= W (non-strict), i.e. the
    cumulative percentage stayed strictly inside (minP, maxP) for the last W s.

    Line (as the reference; labels default to the numbers printed with ``%lf``,
    P is the final percentage rounded to an integer):
      ``PASS: ABS(name-ref) was less than sigma for P% of the time`` (or ``FAIL: ...``)
    """
    all_times = np.asarray(times, dtype=float).reshape(-1)
    times, values, mask = _select(all_times, values, fresh_mask)
    ref = np.broadcast_to(np.asarray(ref_values, dtype=float), all_times.shape)
    sigma = np.broadcast_to(np.asarray(sigma_values, dtype=float), all_times.shape)
    if mask is not None:
        ref, sigma = ref[mask], sigma[mask]
    head = f"ABS({name}-{_label(ref_label, ref_values)}) was less than {_label(sigma_label, sigma_values)}"
    short_ref = ref_label or f"{float(np.asarray(ref_values).flat[0]):g}"
    short_sigma = sigma_label or f"{float(np.asarray(sigma_values).flat[0]):g}"
    text = {
        "description": (
            f"|{name} - {short_ref}| <= {short_sigma}: {min_percent:g}-{max_percent:g} % (last {window:g} s)"
        ),
        "required_text": f"share in ({min_percent:g} %, {max_percent:g} %) for the last >= {window:g} s",
    }
    if times.size == 0:
        return CriterionResult(
            "sigma",
            name,
            False,
            f"FAIL: {head}: no fresh samples",
            0.0,
            float(window),
            0.0,
            samples=0,
            measured_text="no fresh samples",
            **text,
        )
    inside = (values >= ref - sigma) & (values <= ref + sigma)
    percent = 100.0 * np.cumsum(inside) / np.arange(1, times.size + 1)
    violation = (percent <= min_percent) | (percent >= max_percent)
    last_violation = times[np.flatnonzero(violation)[-1]] if violation.any() else times[0]
    stretch = float(times[-1] - last_violation)
    passed = stretch >= window - TIME_TOLERANCE
    final = float(percent[-1])
    line = f"{'PASS' if passed else 'FAIL'}: {head} for {final:.0f}% of the time"
    return CriterionResult(
        "sigma",
        name,
        bool(passed),
        line,
        stretch,
        float(window),
        stretch,
        percent=final,
        samples=int(times.size),
        measured_text=(
            f"{final:.3g} % of {times.size} samples within; "
            f"share inside the limits for the last {stretch:.4g} s"
        ),
        series={"times": times, "percent": percent},
        **text,
    )


def evaluate_criterion(criterion, times, signal):
    """Run one window, sigma or safety :class:`~quad_drake.config.CriterionConfig` on logged samples.

    ``signal(name) -> (values, fresh_mask)`` returns a named signal over ``times``
    (``fresh_mask`` None when every sample is fresh).
    """
    values, fresh = signal(criterion.signal)
    if criterion.kind == "bound":
        return bound_threshold(
            times, values, criterion.threshold, criterion.start, criterion.end, criterion.signal
        )
    if criterion.kind == "recovery":
        return recovery_threshold(
            times, values, criterion.threshold, criterion.start, criterion.window, criterion.signal
        )
    vehicle = criterion.signal.split(".", 1)[0]
    if criterion.kind == "floor":
        contact = signal(f"{vehicle}.FloorContact")[0]
        return floor_touchdowns(times, values, contact, vehicle, criterion.landing_time, criterion.signal)
    if criterion.kind == "room":
        return room_contacts(times, values, vehicle, criterion.signal)
    if criterion.kind == "finite":
        return state_finite(times, values, vehicle, criterion.signal)
    if criterion.kind == "tracking":
        return tracking_bound(times, values, criterion.threshold, criterion.signal)
    if criterion.kind == "window":
        return window_threshold(
            times, values, criterion.threshold, criterion.window, name=criterion.signal, fresh_mask=fresh
        )
    ref = signal(criterion.ref_signal)[0] if criterion.ref_signal else criterion.ref
    sigma = signal(criterion.sigma_signal)[0] if criterion.sigma_signal else criterion.sigma
    return sigma_threshold(
        times,
        values,
        fresh,
        ref,
        sigma,
        criterion.min_percent,
        criterion.max_percent,
        criterion.window,
        name=criterion.signal,
        ref_label=criterion.ref_signal,
        sigma_label=criterion.sigma_signal,
    )


def sigma_share(errors, sigmas, multiple=1.0):
    """(inside, total): how many samples have |error| <= multiple * sigma, of how many.

    errors, sigmas: arrays of one shape (or sequences of such arrays, e.g. one per vehicle);
    a non-finite sample counts as outside. A consistent Gaussian estimate has a share
    inside / total of 0.683 at 1 sigma and 0.954 at 2 sigma.
    """
    if isinstance(errors, (list, tuple)):
        counts = [sigma_share(e, s, multiple) for e, s in zip(errors, sigmas, strict=True)]
        return sum(c[0] for c in counts), sum(c[1] for c in counts)
    errors = np.asarray(errors, dtype=float)
    sigmas = np.asarray(sigmas, dtype=float)
    return int(np.count_nonzero(np.abs(errors) <= multiple * sigmas)), int(errors.size)


def fleet_sigma_threshold(errors, sigmas, name, sigma_name, multiple, min_percent, max_percent):
    """Verdict on the share of a fleet's fresh samples with |error| <= multiple * sigma.

    errors, sigmas: one array per vehicle of its fresh samples of ``V.<name>`` and the
    matching ``V.<sigma_name>``. Passes iff min_percent <= share <= max_percent (%);
    ``samples`` is the number of (vehicle, fresh sample) pairs counted.
    """
    inside, total = sigma_share(list(errors), list(sigmas), multiple)
    percent = 100.0 * inside / total if total else math.nan
    passed = bool(min_percent <= percent <= max_percent)
    line = (
        f"{'PASS' if passed else 'FAIL'}: {percent:.0f}% of fleet {name} samples within "
        f"{multiple:g} x {sigma_name} (required {min_percent:g}% to {max_percent:g}%)"
    )
    return CriterionResult(
        kind="fleet_sigma",
        name=name,
        passed=passed,
        line=line,
        measured=percent,
        required=float(min_percent),
        trailing=None,
        percent=percent,
        samples=total,
        description=(
            f"fleet |V.{name}| <= {multiple:g} V.{sigma_name}: {min_percent:g}-{max_percent:g} % "
            f"({len(errors)} vehicles V)"
        ),
        measured_text=f"{percent:.3g} % of {total} samples within" if total else "no samples",
        required_text=f"share in [{min_percent:g} %, {max_percent:g} %]",
    )


def _first_time(times, mask):
    """Time (s) of the first sample where mask is true, or None."""
    hits = np.flatnonzero(mask)
    return float(times[hits[0]]) if hits.size else None


def _times_word(n):
    return "1 time" if n == 1 else f"{n} times"


def _safety_verdict(kind, name, passed, line, measured, required, samples, **text):
    """CriterionResult of a safety analyzer (no ``trailing`` or ``percent``); text: the
    ``description``, ``measured_text`` and ``required_text``."""
    return CriterionResult(
        kind, name, passed, line, float(measured), float(required), None, samples=samples, **text
    )


def _safety_name(kind, vehicle, name):
    """The signal name a safety verdict reports: `name`, else ``vehicle.<its safety signal>``."""
    return name or f"{vehicle}.{SAFETY_SIGNALS[kind]}"


def floor_touchdowns(times, touchdowns, contact, vehicle, landing_time=None, name=""):
    """Safety verdict "never touched the floor after take-off" (``floor``).

    touchdowns: the cumulative touchdown count per sample (``V.FloorTouchdowns``, counted by
    the plant every 1 ms step); contact: 1 while on the floor (``V.FloorContact``).
    landing_time (s) or None: touchdowns counted at samples from then on are a documented
    landing and pass. A vehicle on the floor at every sample never took off and fails.
    measured: the number of touchdowns before the landing time; required: 0.
    Lines: ``PASS: Quad never touched the floor after take-off``,
    ``FAIL: Quad touched the floor 3 times (first at 2.345 s)``,
    ``FAIL: Quad never took off (on the floor at every sample)``.
    """
    times = np.asarray(times, dtype=float)
    touchdowns = np.asarray(touchdowns, dtype=float)
    judged = times < landing_time if landing_time is not None else np.ones(times.shape, dtype=bool)
    count = int(touchdowns[judged].max()) if judged.any() else 0
    grounded = times.size > 0 and bool(np.all(np.asarray(contact) >= 1.0))
    landing = f" before its landing at {landing_time:g} s" if landing_time is not None else ""
    if grounded:
        passed, line = False, f"FAIL: {vehicle} never took off (on the floor at every sample)"
    elif count == 0:
        passed, line = True, f"PASS: {vehicle} never touched the floor after take-off{landing}"
    else:
        first = _first_time(times, touchdowns > 0)
        passed = False
        line = f"FAIL: {vehicle} touched the floor {_times_word(count)}{landing} (first at {first:.3f} s)"
    return _safety_verdict(
        "floor",
        _safety_name("floor", vehicle, name),
        passed,
        line,
        count,
        0.0,
        int(times.size),
        description=f"{vehicle}: no floor touchdown after take-off{landing}",
        measured_text="on the floor at every sample" if grounded else f"{count} touchdown(s)",
        required_text="0 touchdowns, off the floor at some sample",
    )


def room_contacts(times, wall_steps, vehicle, name=""):
    """Safety verdict "stayed inside the room" (``room``): never stopped at a wall or the ceiling.

    wall_steps: the cumulative count of 1 ms physics steps stopped at a room bound per sample
    (``V.WallContactSteps``). measured: the time at a bound, s (steps x PHYSICS_PERIOD);
    required: 0. Lines: ``PASS: Quad stayed inside the room``,
    ``FAIL: Quad was stopped by a wall or the ceiling for 0.350 s (first at 12.345 s)``.
    """
    times = np.asarray(times, dtype=float)
    wall_steps = np.asarray(wall_steps, dtype=float)
    steps = int(wall_steps.max()) if wall_steps.size else 0
    seconds = steps * PHYSICS_PERIOD
    if steps == 0:
        passed, line = True, f"PASS: {vehicle} stayed inside the room"
    else:
        first = _first_time(times, wall_steps > 0)
        passed = False
        line = (
            f"FAIL: {vehicle} was stopped by a wall or the ceiling for {seconds:.3f} s "
            f"(first at {first:.3f} s)"
        )
    return _safety_verdict(
        "room",
        _safety_name("room", vehicle, name),
        passed,
        line,
        seconds,
        0.0,
        int(times.size),
        description=f"{vehicle}: never stopped by a wall or the ceiling",
        measured_text=f"{seconds:.3f} s at a wall or the ceiling",
        required_text="0 s",
    )


def state_finite(times, finite, vehicle, name=""):
    """Safety verdict "the true state stayed finite" (``finite``).

    finite: 1 at samples where every true state entry is finite (``V.StateFinite``).
    measured: the number of non-finite samples; required: 0. Lines:
    ``PASS: the true state of Quad stayed finite``,
    ``FAIL: the true state of Quad became non-finite at 3.210 s``.
    """
    times = np.asarray(times, dtype=float)
    bad = ~(np.asarray(finite, dtype=float) >= 1.0)
    if not bad.any():
        passed, line = True, f"PASS: the true state of {vehicle} stayed finite"
    else:
        passed = False
        line = f"FAIL: the true state of {vehicle} became non-finite at {_first_time(times, bad):.3f} s"
    return _safety_verdict(
        "finite",
        _safety_name("finite", vehicle, name),
        passed,
        line,
        bad.sum(),
        0.0,
        int(times.size),
        description=f"{vehicle}: true state finite at every sample",
        measured_text=f"{int(bad.sum())} non-finite sample(s) of {times.size}",
        required_text="0 non-finite samples",
    )


def tracking_bound(times, error, bound, name="x"):
    """Safety verdict "the true tracking error stayed bounded" (``tracking``): |x| <= bound at
    every sample (a non-finite sample violates).

    measured: max |x| (inf when a sample is non-finite); required: the bound. Lines (``%lf``):
    ``PASS: ABS(name) stayed below <bound> (max 3.580 at 13.000 s)``,
    ``FAIL: ABS(name) reached 7.123 at 3.450 s, above <bound>`` (the first violating sample).
    """
    times = np.asarray(times, dtype=float)
    magnitude = np.abs(np.asarray(error, dtype=float))
    magnitude = np.where(np.isfinite(magnitude), magnitude, math.inf)
    text = {"description": f"|{name}| <= {bound:g} at every sample", "required_text": f"max <= {bound:g}"}
    if magnitude.size == 0:
        return _safety_verdict(
            "tracking",
            name,
            False,
            f"FAIL: ABS({name}) had no samples",
            0.0,
            bound,
            0,
            measured_text="no samples",
            **text,
        )
    worst = int(np.argmax(magnitude))
    above = magnitude > bound
    if not above.any():
        passed = True
        line = (
            f"PASS: ABS({name}) stayed below {bound:f} (max {magnitude[worst]:.3f} at {times[worst]:.3f} s)"
        )
    else:
        first = int(np.flatnonzero(above)[0])
        passed = False
        line = f"FAIL: ABS({name}) reached {magnitude[first]:.3f} at {times[first]:.3f} s, above {bound:f}"
    return _safety_verdict(
        "tracking",
        name,
        passed,
        line,
        magnitude[worst],
        bound,
        int(times.size),
        measured_text=f"max {magnitude[worst]:.4g} at {times[worst]:.3f} s",
        **text,
    )


def rms(values):
    """Root mean square of the samples (NaN propagates)."""
    values = np.asarray(values, dtype=float)
    return float(np.sqrt(np.mean(values * values)))


def max_abs(values):
    """Largest |value| (NaN propagates)."""
    return float(np.max(np.abs(np.asarray(values, dtype=float))))


def _violations(values, threshold):
    """True where |x| > threshold or x is not finite (as the window analyzer counts a violation)."""
    return ~(np.abs(np.asarray(values, dtype=float)) <= threshold)


def bound_threshold(times, values, threshold, start, end, name="x"):
    """ "ABS(x) < threshold in [start, end) s": every sample in the interval within the threshold.

    A non-finite sample counts as a violation. measured: the largest |x| in the interval
    (inf if a sample is not finite); required: the threshold; trailing: s, time of the first
    violating sample (None if none). Lines:
      ``PASS: ABS(name) was less than <thr> from <start> to <end> seconds (max <m>)``
      ``FAIL: ABS(name) was <m> at <t> seconds, not less than <thr> from <start> to <end> seconds``
    """
    times = np.asarray(times, dtype=float).reshape(-1)
    values = np.asarray(values, dtype=float).reshape(-1)
    inside = (times >= start - TIME_TOLERANCE) & (times < end - TIME_TOLERANCE)
    span = f"from {start:f} to {end:f} seconds"
    text = {
        "description": f"|{name}| < {threshold:g} in [{start:g}, {end:g}) s",
        "required_text": f"< {threshold:g} on every sample",
    }
    if not inside.any():
        line = f"FAIL: ABS({name}) had no samples {span}"
        return CriterionResult(
            "bound", name, False, line, math.nan, float(threshold), None, measured_text="no samples", **text
        )
    t, x = times[inside], np.abs(values[inside])
    bad = _violations(x, threshold)
    worst = float(np.max(np.where(np.isfinite(x), x, math.inf)))
    first_time = None
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        first_time = float(t[first])
        line = (
            f"FAIL: ABS({name}) was {x[first]:f} at {first_time:f} seconds, "
            f"not less than {threshold:f} {span}"
        )
        measured_text = f"max {worst:.4g}; first above at {first_time:.4g} s"
    else:
        line = f"PASS: ABS({name}) was less than {threshold:f} {span} (max {worst:f})"
        measured_text = f"max {worst:.4g}"
    return CriterionResult(
        "bound",
        name,
        not bad.any(),
        line,
        worst,
        float(threshold),
        first_time,
        samples=int(t.size),
        measured_text=measured_text,
        series={"times": t, "values": x},
        **text,
    )


def recovery_threshold(times, values, threshold, start, within, name="x"):
    """ "ABS(x) < threshold within W s after start": from start + W to the end every sample within.

    The recovery time is (first sample after the last violation at or after `start`) - start,
    0 if no sample from `start` on violates, inf if the last sample violates; the run passes
    iff it is <= W and the run has samples at or after start + W. measured: the recovery time
    (s); required: W (s); trailing: s, time of the last violation (None if none). Lines:
      ``PASS: ABS(name) was less than <thr> <r> seconds after <start> seconds (allowed <W>)``
      ``FAIL: ABS(name) was not less than <thr> within <W> seconds after <start> seconds (<r>)``
    """
    times = np.asarray(times, dtype=float).reshape(-1)
    values = np.asarray(values, dtype=float).reshape(-1)
    after = times >= start - TIME_TOLERANCE
    t, bad = times[after], _violations(values[after], threshold)
    text = {
        "description": f"|{name}| < {threshold:g} within {within:g} s after {start:g} s",
        "required_text": f"back under within {within:g} s, and staying",
    }
    if t.size == 0 or t[-1] < start + within - TIME_TOLERANCE:
        line = f"FAIL: ABS({name}) had no samples {within:f} seconds after {start:f} seconds"
        return CriterionResult(
            "recovery", name, False, line, math.inf, float(within), None, measured_text="no samples", **text
        )
    last_bad = None
    recovery = 0.0
    if bad.any():
        last = int(np.flatnonzero(bad)[-1])
        last_bad = float(t[last])
        recovery = float(t[last + 1] - start) if last + 1 < t.size else math.inf
    passed = recovery <= within + TIME_TOLERANCE
    if passed:
        line = (
            f"PASS: ABS({name}) was less than {threshold:f} {recovery:f} seconds after {start:f} seconds "
            f"(allowed {within:f})"
        )
    else:
        shown = "never" if math.isinf(recovery) else f"after {recovery:f} seconds"
        line = (
            f"FAIL: ABS({name}) was not less than {threshold:f} within {within:f} seconds after "
            f"{start:f} seconds ({shown})"
        )
    measured_text = "never back under" if math.isinf(recovery) else f"back under {recovery:.4g} s after"
    return CriterionResult(
        "recovery",
        name,
        bool(passed),
        line,
        recovery,
        float(within),
        last_bad,
        samples=int(t.size),
        measured_text=measured_text,
        series={"times": t, "values": np.abs(values[after])},
        **text,
    )
