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

TIME_TOLERANCE = 1e-9
"""s; stretches within this of the window W count as exactly W."""


@dataclass(frozen=True)
class CriterionResult:
    """Verdict of one analyzer, with the text every reader (console, report, campaign) prints.

    kind: "window", "sigma" or "fleet_sigma".
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
    """The criteria a run of `scenario` is judged on and a campaign counts, in order."""
    return list(scenario.criteria)


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
    """Run one window or sigma :class:`~quad_drake.config.CriterionConfig` on logged samples.

    ``signal(name) -> (values, fresh_mask)`` returns a named signal over ``times``
    (``fresh_mask`` None when every sample is fresh).
    """
    values, fresh = signal(criterion.signal)
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


def rms(values):
    """Root mean square of the samples (NaN propagates)."""
    values = np.asarray(values, dtype=float)
    return float(np.sqrt(np.mean(values * values)))


def max_abs(values):
    """Largest |value| (NaN propagates)."""
    return float(np.max(np.abs(np.asarray(values, dtype=float))))
