"""The reference simulator's pass/fail analyzers (SPEC §0.5) over logged samples.

Inputs are the 5 ms analyzer samples (SPEC §0.2): ``times`` (s) and the signal's
``values`` at those times; ``fresh_mask`` marks the samples on which a sensor
signal had a new measurement (the reference's analyzers only see those).

Every analyzer is a *fold*: a small per-run state updated chunk by chunk of samples, for N
runs at once (``update(times (k,), values (k, N), ...)``), and a ``result(j)`` that makes run
j's :class:`CriterionResult`. A run's whole log is one chunk of one run (the functions
``window_threshold`` … below); a fleet batch feeds its samples as they are flown
(``fleet.streaming``), so its verdicts never need the full logs. The rule and its text live
once, in the fold; ``tests/test_evaluation_folds.py`` checks that any split into chunks and
any N give each run the verdict of its own whole log.

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

from ..conventions import PHYSICS_PERIOD
from .safety import SAFETY_SIGNALS, safety_criteria
from .signals import signal_unit

TIME_TOLERANCE = 1e-9
"""s; stretches within this of the window W count as exactly W."""


def _amount(value, signal, spec="g"):
    """`value` (formatted with `spec`) with the unit of the named `signal` ("1 m"; bare when it
    has none), for a criterion's texts."""
    unit = signal_unit(signal)
    return f"{value:{spec}} {unit}" if unit else f"{value:{spec}}"


MEASURED_UNITS = {
    "window": "s",
    "sigma": "s",
    "fleet_sigma": "%",
    "recovery": "s",
    "room": "s",
    "floor": "count",
    "finite": "count",
}
"""Unit of a CriterionResult's ``measured`` by kind ("count": touchdowns, non-finite samples); a
``tracking``, ``bound`` or ``attitude`` verdict measures its signal, in the signal's unit."""


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

    @property
    def measured_unit(self) -> str:
        """The unit of ``measured`` (:data:`MEASURED_UNITS`; the signal's for tracking and bound)."""
        return MEASURED_UNITS.get(self.kind, signal_unit(self.name))

    def to_dict(self) -> dict:
        """The verdict as a dict of plain values, without ``series``, with ``measured_unit`` (for
        summary.json)."""
        values = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "series"}
        return {**values, "measured_unit": self.measured_unit}


def judged_criteria(scenario) -> list:
    """The criteria a run of `scenario` is judged on and a campaign counts, in order: its
    own, then the flight-safety ones of :func:`quad_drake.judging.safety.safety_criteria`."""
    return list(scenario.criteria) + safety_criteria(scenario)


def _one_run(times, values, fresh_mask=None):
    """(times (n,), values (n, 1), fresh (n, 1) bool) of one run's whole log; all fresh when
    `fresh_mask` is None. Raises ValueError when the lengths differ."""
    times = np.asarray(times, dtype=float).reshape(-1)
    values = np.asarray(values, dtype=float).reshape(-1)
    if times.shape != values.shape:
        raise ValueError(f"times {times.shape} and values {values.shape} differ in length")
    if fresh_mask is None:
        return times, values[:, None], np.ones((times.size, 1), dtype=bool)
    mask = np.asarray(fresh_mask, dtype=bool).reshape(-1)
    if mask.shape != times.shape:
        raise ValueError(f"fresh_mask {mask.shape} and times {times.shape} differ in length")
    return times, values[:, None], mask[:, None]


def _column(values, n):
    """A one-run signal as a (n, 1) column (a scalar stays a scalar)."""
    values = np.asarray(values, dtype=float)
    return values if values.ndim == 0 else values.reshape(n, 1)


def _last_index(mask):
    """(N,) index of each run's last true sample of a (k, N) mask (k - 1 where none)."""
    return mask.shape[0] - 1 - np.argmax(mask[::-1], axis=0)


def _at(array, index):
    """(N,) entries array[index[j], j] of a (k, N) array."""
    return array[index, np.arange(array.shape[1])]


def _note_first(first, times, mask):
    """Set first[j] (NaN until then) to the time of run j's first sample with mask true."""
    hit = mask.any(axis=0) & np.isnan(first)
    first[hit] = times[np.argmax(mask, axis=0)[hit]]


def _whole_log(fold, times, **inputs):
    """The verdict of a one-run fold fed a whole log at once, with the plot series of its kind."""
    per_sample = fold.update(times, **inputs)
    return fold.result(0, fold.series(times, per_sample, **inputs))


class _Fold:
    """An analyzer's state for N runs: ``update(times (k,), **inputs)`` folds a chunk of samples,
    ``result(j, series)`` makes run j's CriterionResult; ``series`` the plot arrays of a
    one-run whole log (None: the kind has none)."""

    def series(self, times, per_sample, **inputs):
        return None


def _violations(values, threshold):
    """True where |x| > threshold or x is not finite (as the window analyzer counts a violation)."""
    return ~(np.abs(np.asarray(values, dtype=float)) <= threshold)


class WindowFold(_Fold):
    """WindowThreshold(name, threshold, window) of N runs: "ABS(x) < threshold for more than W s",
    latched (:func:`window_threshold` has the rule and the lines)."""

    kind = "window"

    def __init__(self, name, threshold, window, runs):
        self.name, self.threshold, self.window = name, float(threshold), float(window)
        self.last_above = np.full(runs, np.nan)  # s, last violating sample (the first sample until one)
        self.longest = np.full(runs, -np.inf)  # s, longest stretch so far
        self.last_time = np.full(runs, np.nan)  # s, last sample judged
        self.samples = np.zeros(runs, dtype=np.int64)

    def update(self, times, values, fresh) -> dict[str, np.ndarray]:
        """Fold times (k,) s, values (k, N), fresh (k, N) bool (only fresh samples are judged);
        returns {"last_above", "stretch"} (k, N), meaningful on the fresh samples."""
        if times.size == 0:
            return {"last_above": np.zeros(values.shape), "stretch": np.zeros(values.shape)}
        _note_first(self.last_above, times, fresh)
        column = times[:, None]
        above = _violations(values, self.threshold)
        marks = np.where(above & fresh, column, -np.inf)
        last_above = np.maximum(np.maximum.accumulate(marks, axis=0), self.last_above)
        stretch = column - last_above
        self.longest = np.maximum(self.longest, np.where(fresh, stretch, -np.inf).max(axis=0))
        self.last_above = last_above[-1].copy()  # not a view that would keep the chunk's arrays
        self.last_time = np.where(fresh.any(axis=0), times[_last_index(fresh)], self.last_time)
        self.samples += fresh.sum(axis=0)
        return {"last_above": last_above, "stretch": stretch}

    def series(self, times, per_sample, values, fresh) -> dict[str, np.ndarray] | None:
        """Plot arrays of a one-run whole log: the fresh samples' times and stretches, and the
        span (start, end) of the longest stretch; None without samples."""
        if self.samples[0] == 0:
            return None
        mask = fresh[:, 0]
        stretch, last_above = per_sample["stretch"][mask, 0], per_sample["last_above"][mask, 0]
        end = int(np.argmax(stretch))
        t = times[mask]
        return {"times": t, "stretch": stretch, "span": np.array([last_above[end], t[end]])}

    def result(self, j, series=None) -> CriterionResult:
        """Run j's CriterionResult (series: the plot arrays of a whole-log evaluation, or None)."""
        name, threshold, window = self.name, self.threshold, self.window
        text = {
            "description": f"|{name}| < {_amount(threshold, name)} for > {window:g} s",
            "required_text": f"> {window:g} s",
        }
        if self.samples[j] == 0:
            line = f"FAIL: ABS({name}) had no samples"
            return CriterionResult(
                "window", name, False, line, 0.0, window, 0.0, samples=0, measured_text="no samples", **text
            )
        longest = float(self.longest[j])
        trailing = float(self.last_time[j] - self.last_above[j])
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
            window,
            trailing,
            samples=int(self.samples[j]),
            measured_text=f"longest stretch within: {longest:.4g} s",
            series=series,
            **text,
        )


def window_threshold(times, values, threshold, window, name="x", fresh_mask=None) -> CriterionResult:
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
    times, values, fresh = _one_run(times, values, fresh_mask)
    return _whole_log(WindowFold(name, threshold, window, 1), times, values=values, fresh=fresh)


def _label(label, value):
    if label:
        return label
    if np.ndim(value) != 0:
        raise ValueError("a signal-valued ref or sigma needs a label for the report line")
    return f"{float(value):f}"


class SigmaFold(_Fold):
    """SigmaThreshold(name, ref, sigma, minP, maxP, W) of N runs (:func:`sigma_threshold` has the
    rule). ref_label / sigma_label name the live signals ref and sigma are read from ("" : the
    numbers ref_value / sigma_value, printed with ``%lf``)."""

    kind = "sigma"

    def __init__(
        self, name, ref_label, ref_value, sigma_label, sigma_value, min_percent, max_percent, window, runs
    ):
        self.name, self.window = name, float(window)
        self.min_percent, self.max_percent = float(min_percent), float(max_percent)
        self.head = (
            f"ABS({name}-{_label(ref_label, ref_value)}) was less than {_label(sigma_label, sigma_value)}"
        )
        short_ref = ref_label or f"{float(np.asarray(ref_value).flat[0]):g}"
        short_sigma = sigma_label or f"{float(np.asarray(sigma_value).flat[0]):g}"
        self.text = {
            "description": (
                f"|{name} - {short_ref}| <= {short_sigma}: "
                f"{min_percent:g}-{max_percent:g} % (last {window:g} s)"
            ),
            "required_text": f"share in ({min_percent:g} %, {max_percent:g} %) for the last >= {window:g} s",
        }
        self.inside = np.zeros(runs, dtype=np.int64)  # fresh samples in the band so far
        self.counted = np.zeros(runs, dtype=np.int64)  # fresh samples so far
        self.percent = np.full(runs, np.nan)  # %, cumulative share at the last fresh sample
        self.last_violation = np.full(runs, np.nan)  # s (the first fresh sample until one)
        self.last_time = np.full(runs, np.nan)  # s, last fresh sample

    def update(self, times, values, fresh, ref, sigma) -> dict[str, np.ndarray]:
        """Fold times (k,) s, values (k, N), fresh (k, N) bool, ref and sigma ((k, N) or scalars);
        returns {"percent"} (k, N), the cumulative share, meaningful on the fresh samples."""
        if times.size == 0:
            return {"percent": np.zeros(values.shape)}
        _note_first(self.last_violation, times, fresh)
        inside = (values >= ref - sigma) & (values <= ref + sigma) & fresh
        within = self.inside + np.cumsum(inside, axis=0)
        counted = self.counted + np.cumsum(fresh, axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            percent = 100.0 * within / counted
        violation = fresh & ((percent <= self.min_percent) | (percent >= self.max_percent))
        self.last_violation = np.where(
            violation.any(axis=0), times[_last_index(violation)], self.last_violation
        )
        last, seen = _last_index(fresh), fresh.any(axis=0)
        self.percent = np.where(seen, _at(percent, last), self.percent)
        self.last_time = np.where(seen, times[last], self.last_time)
        self.inside, self.counted = within[-1].copy(), counted[-1].copy()
        return {"percent": percent}

    def series(self, times, per_sample, fresh, **_) -> dict[str, np.ndarray] | None:
        """Plot arrays of a one-run whole log: the fresh samples' times and cumulative share (%)."""
        mask = fresh[:, 0]
        return {"times": times[mask], "percent": per_sample["percent"][mask, 0]} if mask.any() else None

    def result(self, j, series=None) -> CriterionResult:
        """Run j's CriterionResult (series: the plot arrays of a whole-log evaluation, or None)."""
        name, window, count = self.name, self.window, int(self.counted[j])
        if count == 0:
            line = f"FAIL: {self.head}: no fresh samples"
            return CriterionResult(
                "sigma",
                name,
                False,
                line,
                0.0,
                window,
                0.0,
                samples=0,
                measured_text="no fresh samples",
                **self.text,
            )
        stretch = float(self.last_time[j] - self.last_violation[j])
        passed = stretch >= window - TIME_TOLERANCE
        final = float(self.percent[j])
        return CriterionResult(
            "sigma",
            name,
            bool(passed),
            f"{'PASS' if passed else 'FAIL'}: {self.head} for {final:.0f}% of the time",
            stretch,
            window,
            stretch,
            percent=final,
            samples=count,
            measured_text=(
                f"{final:.3g} % of {count} samples within; "
                f"share inside the limits for the last {stretch:.4g} s"
            ),
            series=series,
            **self.text,
        )


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
) -> CriterionResult:
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
    times, values, fresh = _one_run(times, values, fresh_mask)
    n = times.size
    ref = np.broadcast_to(_column(ref_values, n), values.shape)
    sigma = np.broadcast_to(_column(sigma_values, n), values.shape)
    fold = SigmaFold(
        name, ref_label, ref_values, sigma_label, sigma_values, min_percent, max_percent, window, 1
    )
    return _whole_log(fold, times, values=values, fresh=fresh, ref=ref, sigma=sigma)


def _within(errors, sigmas, multiple):
    """True where |error| <= multiple * sigma (a non-finite sample is outside)."""
    return np.abs(errors) <= multiple * sigmas


def sigma_share(errors, sigmas, multiple=1.0) -> tuple[int, int]:
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
    return int(np.count_nonzero(_within(errors, sigmas, multiple))), int(errors.size)


class PooledSigmaFold(_Fold):
    """The share of a scenario's vehicles' fresh samples with |error| <= multiple * sigma, for N
    runs (:func:`fleet_sigma_threshold` has the rule); vehicles: how many vehicles are pooled."""

    kind = "fleet_sigma"

    def __init__(self, name, sigma_name, multiple, min_percent, max_percent, vehicles, runs):
        self.name, self.sigma_name, self.multiple = name, sigma_name, float(multiple)
        self.min_percent, self.max_percent, self.vehicles = float(min_percent), float(max_percent), vehicles
        self.inside = np.zeros(runs, dtype=np.int64)
        self.total = np.zeros(runs, dtype=np.int64)

    def update(self, times, errors, sigmas, fresh) -> None:
        """Fold one (k, N) error, sigma and fresh mask per vehicle (lists; times unused: the
        vehicles' samples are pooled whatever their times)."""
        for error, sigma, mask in zip(errors, sigmas, fresh, strict=True):
            self.inside += np.count_nonzero(_within(error, sigma, self.multiple) & mask, axis=0)
            self.total += mask.sum(axis=0)

    def result(self, j, series=None) -> CriterionResult:
        total = int(self.total[j])
        percent = 100.0 * int(self.inside[j]) / total if total else math.nan
        passed = bool(self.min_percent <= percent <= self.max_percent)
        name, multiple, low, high = self.name, self.multiple, self.min_percent, self.max_percent
        line = (
            f"{'PASS' if passed else 'FAIL'}: {percent:.0f}% of fleet {name} samples within "
            f"{multiple:g} x {self.sigma_name} (required {low:g}% to {high:g}%)"
        )
        return CriterionResult(
            kind="fleet_sigma",
            name=name,
            passed=passed,
            line=line,
            measured=percent,
            required=low,
            trailing=None,
            percent=percent,
            samples=total,
            description=(
                f"fleet |V.{name}| <= {multiple:g} V.{self.sigma_name}: {low:g}-{high:g} % "
                f"({self.vehicles} vehicles V)"
            ),
            measured_text=f"{percent:.3g} % of {total} samples within" if total else "no samples",
            required_text=f"share in [{low:g} %, {high:g} %]",
        )


def fleet_sigma_threshold(
    errors, sigmas, name, sigma_name, multiple, min_percent, max_percent
) -> CriterionResult:
    """Verdict on the share of a fleet's fresh samples with |error| <= multiple * sigma.

    errors, sigmas: one array per vehicle of its fresh samples of ``V.<name>`` and the
    matching ``V.<sigma_name>``. Passes iff min_percent <= share <= max_percent (%);
    ``samples`` is the number of (vehicle, fresh sample) pairs counted.
    """
    errors = [np.asarray(e, dtype=float).reshape(-1, 1) for e in errors]
    sigmas = [np.asarray(s, dtype=float).reshape(-1, 1) for s in sigmas]
    fold = PooledSigmaFold(name, sigma_name, multiple, min_percent, max_percent, len(errors), 1)
    return _whole_log(
        fold, None, errors=errors, sigmas=sigmas, fresh=[np.ones(e.shape, dtype=bool) for e in errors]
    )


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


class FloorFold(_Fold):
    """ "Never touched the floor after take-off" of N runs (:func:`floor_touchdowns` has the rule)."""

    kind = "floor"

    def __init__(self, vehicle, landing_time, name, runs):
        self.vehicle, self.landing_time, self.name = (
            vehicle,
            landing_time,
            _safety_name("floor", vehicle, name),
        )
        self.judged_max = np.full(runs, -np.inf)  # most touchdowns counted before the landing time
        self.grounded = np.ones(runs, dtype=bool)  # on the floor at every sample so far
        self.first_touch = np.full(runs, np.nan)  # s
        self.samples = 0

    def update(self, times, touchdowns, contact) -> None:
        """Fold times (k,) s, the cumulative touchdowns and the floor contact (k, N)."""
        if times.size == 0:
            return
        judged = times < self.landing_time if self.landing_time is not None else np.ones(times.shape, bool)
        self.judged_max = np.maximum(
            self.judged_max, np.where(judged[:, None], touchdowns, -np.inf).max(axis=0)
        )
        self.grounded &= (contact >= 1.0).all(axis=0)
        _note_first(self.first_touch, times, touchdowns > 0)
        self.samples += times.size

    def result(self, j, series=None) -> CriterionResult:
        vehicle, landing_time = self.vehicle, self.landing_time
        count = int(self.judged_max[j]) if self.judged_max[j] > -np.inf else 0
        grounded = self.samples > 0 and bool(self.grounded[j])
        landing = f" before its landing at {landing_time:g} s" if landing_time is not None else ""
        if grounded:
            passed, line = False, f"FAIL: {vehicle} never took off (on the floor at every sample)"
        elif count == 0:
            passed, line = True, f"PASS: {vehicle} never touched the floor after take-off{landing}"
        else:
            passed = False
            line = (
                f"FAIL: {vehicle} touched the floor {_times_word(count)}{landing} "
                f"(first at {self.first_touch[j]:.3f} s)"
            )
        return _safety_verdict(
            "floor",
            self.name,
            passed,
            line,
            count,
            0.0,
            self.samples,
            description=f"{vehicle}: no floor touchdown after take-off{landing}",
            measured_text="on the floor at every sample" if grounded else f"{count} touchdown(s)",
            required_text="0 touchdowns, off the floor at some sample",
        )


def floor_touchdowns(times, touchdowns, contact, vehicle, landing_time=None, name="") -> CriterionResult:
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
    times, touchdowns, _ = _one_run(times, touchdowns)
    fold = FloorFold(vehicle, landing_time, name, 1)
    return _whole_log(fold, times, touchdowns=touchdowns, contact=_column(contact, times.size))


class RoomFold(_Fold):
    """ "Stayed inside the room" of N runs (:func:`room_contacts` has the rule)."""

    kind = "room"

    def __init__(self, vehicle, name, runs):
        self.vehicle, self.name = vehicle, _safety_name("room", vehicle, name)
        self.steps = np.full(runs, -np.inf)  # most wall steps counted so far
        self.first = np.full(runs, np.nan)  # s, first sample at a bound
        self.samples = 0

    def update(self, times, wall_steps) -> None:
        """Fold times (k,) s and the cumulative wall-contact steps (k, N)."""
        if times.size == 0:
            return
        self.steps = np.maximum(self.steps, wall_steps.max(axis=0))
        _note_first(self.first, times, wall_steps > 0)
        self.samples += times.size

    def result(self, j, series=None) -> CriterionResult:
        vehicle = self.vehicle
        steps = int(self.steps[j]) if self.samples else 0
        seconds = steps * PHYSICS_PERIOD
        if steps == 0:
            passed, line = True, f"PASS: {vehicle} stayed inside the room"
        else:
            passed = False
            line = (
                f"FAIL: {vehicle} was stopped by a wall or the ceiling for {seconds:.3f} s "
                f"(first at {self.first[j]:.3f} s)"
            )
        return _safety_verdict(
            "room",
            self.name,
            passed,
            line,
            seconds,
            0.0,
            self.samples,
            description=f"{vehicle}: never stopped by a wall or the ceiling",
            measured_text=f"{seconds:.3f} s at a wall or the ceiling",
            required_text="0 s",
        )


def room_contacts(times, wall_steps, vehicle, name="") -> CriterionResult:
    """Safety verdict "stayed inside the room" (``room``): never stopped at a wall or the ceiling.

    wall_steps: the cumulative count of 1 ms physics steps stopped at a room bound per sample
    (``V.WallContactSteps``). measured: the time at a bound, s (steps x PHYSICS_PERIOD);
    required: 0. Lines: ``PASS: Quad stayed inside the room``,
    ``FAIL: Quad was stopped by a wall or the ceiling for 0.350 s (first at 12.345 s)``.
    """
    times, wall_steps, _ = _one_run(times, wall_steps)
    return _whole_log(RoomFold(vehicle, name, 1), times, wall_steps=wall_steps)


class FiniteFold(_Fold):
    """ "The true state stayed finite" of N runs (:func:`state_finite` has the rule)."""

    kind = "finite"

    def __init__(self, vehicle, name, runs):
        self.vehicle, self.name = vehicle, _safety_name("finite", vehicle, name)
        self.bad = np.zeros(runs, dtype=np.int64)  # non-finite samples so far
        self.first = np.full(runs, np.nan)  # s, first non-finite sample
        self.samples = 0

    def update(self, times, finite) -> None:
        """Fold times (k,) s and the StateFinite flags (k, N)."""
        if times.size == 0:
            return
        bad = ~(finite >= 1.0)
        self.bad += bad.sum(axis=0)
        _note_first(self.first, times, bad)
        self.samples += times.size

    def result(self, j, series=None) -> CriterionResult:
        vehicle, bad = self.vehicle, int(self.bad[j])
        if bad == 0:
            passed, line = True, f"PASS: the true state of {vehicle} stayed finite"
        else:
            passed = False
            line = f"FAIL: the true state of {vehicle} became non-finite at {self.first[j]:.3f} s"
        return _safety_verdict(
            "finite",
            self.name,
            passed,
            line,
            bad,
            0.0,
            self.samples,
            description=f"{vehicle}: true state finite at every sample",
            measured_text=f"{bad} non-finite sample(s) of {self.samples}",
            required_text="0 non-finite samples",
        )


def state_finite(times, finite, vehicle, name="") -> CriterionResult:
    """Safety verdict "the true state stayed finite" (``finite``).

    finite: 1 at samples where every true state entry is finite (``V.StateFinite``).
    measured: the number of non-finite samples; required: 0. Lines:
    ``PASS: the true state of Quad stayed finite``,
    ``FAIL: the true state of Quad became non-finite at 3.210 s``.
    """
    times, finite, _ = _one_run(times, finite)
    return _whole_log(FiniteFold(vehicle, name, 1), times, finite=finite)


class TrackingFold(_Fold):
    """ "The true tracking error stayed bounded" of N runs (:func:`tracking_bound` has the rule)."""

    kind = "tracking"

    def __init__(self, name, bound, runs):
        self.name, self.bound = name, float(bound)
        self.worst = np.full(runs, -np.inf)  # largest |x| so far (inf: a non-finite sample)
        self.worst_time = np.full(runs, np.nan)  # s, its first sample
        self.first_above = np.full(runs, np.nan)  # |x| at the first violating sample
        self.first_above_time = np.full(runs, np.nan)  # s
        self.samples = 0

    def update(self, times, error) -> None:
        """Fold times (k,) s and the tracking error (k, N)."""
        if times.size == 0:
            return
        magnitude = np.abs(error)
        magnitude = np.where(np.isfinite(magnitude), magnitude, math.inf)
        worst = np.argmax(magnitude, axis=0)
        larger = _at(magnitude, worst) > self.worst  # strictly: the first sample of the maximum stays
        self.worst = np.where(larger, _at(magnitude, worst), self.worst)
        self.worst_time = np.where(larger, times[worst], self.worst_time)
        above = magnitude > self.bound
        new = above.any(axis=0) & np.isnan(self.first_above_time)
        first = np.argmax(above, axis=0)
        self.first_above = np.where(new, _at(magnitude, first), self.first_above)
        self.first_above_time = np.where(new, times[first], self.first_above_time)
        self.samples += times.size

    def result(self, j, series=None) -> CriterionResult:
        name, bound = self.name, self.bound
        limit = _amount(bound, name)
        text = {"description": f"|{name}| <= {limit} at every sample", "required_text": f"max <= {limit}"}
        if self.samples == 0:
            line = f"FAIL: ABS({name}) had no samples"
            return _safety_verdict(
                "tracking", name, False, line, 0.0, bound, 0, measured_text="no samples", **text
            )
        worst, worst_time = float(self.worst[j]), float(self.worst_time[j])
        passed = bool(np.isnan(self.first_above_time[j]))
        if passed:
            line = f"PASS: ABS({name}) stayed below {bound:f} (max {worst:.3f} at {worst_time:.3f} s)"
        else:
            line = (
                f"FAIL: ABS({name}) reached {self.first_above[j]:.3f} at {self.first_above_time[j]:.3f} s, "
                f"above {bound:f}"
            )
        return _safety_verdict(
            "tracking",
            name,
            passed,
            line,
            worst,
            bound,
            self.samples,
            measured_text=f"max {_amount(worst, name, '.4g')} at {worst_time:.3f} s",
            **text,
        )


def tracking_bound(times, error, bound, name="x") -> CriterionResult:
    """Safety verdict "the true tracking error stayed bounded" (``tracking``): |x| <= bound at
    every sample (a non-finite sample violates).

    measured: max |x| (inf when a sample is non-finite); required: the bound. Lines (``%lf``):
    ``PASS: ABS(name) stayed below <bound> (max 3.580 at 13.000 s)``,
    ``FAIL: ABS(name) reached 7.123 at 3.450 s, above <bound>`` (the first violating sample).
    """
    times, error, _ = _one_run(times, error)
    return _whole_log(TrackingFold(name, bound, 1), times, error=error)


def rms(values) -> float:
    """Root mean square of the samples (NaN propagates)."""
    values = np.asarray(values, dtype=float)
    return float(np.sqrt(np.mean(values * values)))


def max_abs(values) -> float:
    """Largest |value| (NaN propagates)."""
    return float(np.max(np.abs(np.asarray(values, dtype=float))))


class BoundFold(_Fold):
    """ "ABS(x) < threshold in [start, end) s" of N runs (:func:`bound_threshold` has the rule)."""

    kind = "bound"

    def __init__(self, name, threshold, start, end, runs):
        self.name, self.threshold, self.start, self.end = name, float(threshold), float(start), float(end)
        self.worst = np.full(runs, -np.inf)  # largest |x| in the interval (inf: a non-finite sample)
        self.first_bad = np.full(runs, np.nan)  # |x| at the first violating sample
        self.first_bad_time = np.full(runs, np.nan)  # s
        self.samples = 0

    def update(self, times, values) -> tuple[np.ndarray, np.ndarray]:
        """Fold times (k,) s and values (k, N); returns (times, |x|) of the samples in the interval."""
        inside = (times >= self.start - TIME_TOLERANCE) & (times < self.end - TIME_TOLERANCE)
        t, x = times[inside], np.abs(values[inside])
        if t.size == 0:
            return t, x
        self.worst = np.maximum(self.worst, np.where(np.isfinite(x), x, math.inf).max(axis=0))
        bad = _violations(x, self.threshold)
        new = bad.any(axis=0) & np.isnan(self.first_bad_time)
        first = np.argmax(bad, axis=0)
        self.first_bad = np.where(new, _at(x, first), self.first_bad)
        self.first_bad_time = np.where(new, t[first], self.first_bad_time)
        self.samples += t.size
        return t, x

    def series(self, times, per_sample, **_) -> dict[str, np.ndarray]:
        """Plot arrays of a one-run whole log: the judged samples' times and |x|."""
        t, x = per_sample
        return {"times": t, "values": x[:, 0]}

    def result(self, j, series=None) -> CriterionResult:
        name, threshold, start, end = self.name, self.threshold, self.start, self.end
        span = f"from {start:f} to {end:f} seconds"
        text = {
            "description": f"|{name}| < {_amount(threshold, name)} in [{start:g}, {end:g}) s",
            "required_text": f"< {_amount(threshold, name)} on every sample",
        }
        if self.samples == 0:
            line = f"FAIL: ABS({name}) had no samples {span}"
            return CriterionResult(
                self.kind, name, False, line, math.nan, threshold, None, measured_text="no samples", **text
            )
        worst = float(self.worst[j])
        first_time = None if np.isnan(self.first_bad_time[j]) else float(self.first_bad_time[j])
        if first_time is not None:
            line = (
                f"FAIL: ABS({name}) was {self.first_bad[j]:f} at {first_time:f} seconds, "
                f"not less than {threshold:f} {span}"
            )
            measured_text = f"max {_amount(worst, name, '.4g')}; first above at {first_time:.4g} s"
        else:
            line = f"PASS: ABS({name}) was less than {threshold:f} {span} (max {worst:f})"
            measured_text = f"max {_amount(worst, name, '.4g')}"
        return CriterionResult(
            self.kind,
            name,
            first_time is None,
            line,
            worst,
            threshold,
            first_time,
            samples=self.samples,
            measured_text=measured_text,
            series=series,
            **text,
        )


class AttitudeFold(BoundFold):
    """The attitude safety criterion of N runs: a :class:`BoundFold` on ``V.Tilt`` (rad) over the
    flight (``judging.safety.attitude_criterion``), its verdicts of kind ``attitude``."""

    kind = "attitude"


def bound_threshold(times, values, threshold, start, end, name="x") -> CriterionResult:
    """ "ABS(x) < threshold in [start, end) s": every sample in the interval within the threshold.

    A non-finite sample counts as a violation. measured: the largest |x| in the interval
    (inf if a sample is not finite); required: the threshold; trailing: s, time of the first
    violating sample (None if none). Lines:
      ``PASS: ABS(name) was less than <thr> from <start> to <end> seconds (max <m>)``
      ``FAIL: ABS(name) was <m> at <t> seconds, not less than <thr> from <start> to <end> seconds``
    """
    times, values, _ = _one_run(times, values)
    return _whole_log(BoundFold(name, threshold, start, end, 1), times, values=values)


class RecoveryFold(_Fold):
    """ "ABS(x) < threshold within W s after start" of N runs (:func:`recovery_threshold` has the rule)."""

    kind = "recovery"

    def __init__(self, name, threshold, start, within, runs):
        self.name, self.threshold, self.start, self.within = (
            name,
            float(threshold),
            float(start),
            float(within),
        )
        self.last_bad = np.full(runs, np.nan)  # s, last violating sample from start on
        self.next_after = np.full(runs, np.nan)  # s, the sample after it
        self.pending = np.zeros(runs, dtype=bool)  # the last sample so far violates (no sample after it yet)
        self.last_time = math.nan  # s, last sample from start on
        self.samples = 0

    def update(self, times, values) -> tuple[np.ndarray, np.ndarray]:
        """Fold times (k,) s and values (k, N); returns (times, |x|) of the samples from start on."""
        after = times >= self.start - TIME_TOLERANCE
        t, x = times[after], values[after]
        if t.size == 0:
            return t, np.abs(x)
        bad = _violations(x, self.threshold)
        hit = bad.any(axis=0)
        self.next_after = np.where(self.pending & ~hit, t[0], self.next_after)
        last = _last_index(bad)
        followed = last + 1 < t.size
        self.last_bad = np.where(hit, t[last], self.last_bad)
        self.next_after = np.where(hit & followed, t[np.minimum(last + 1, t.size - 1)], self.next_after)
        self.pending = hit & ~followed
        self.last_time = float(t[-1])
        self.samples += t.size
        return t, np.abs(x)

    def series(self, times, per_sample, **_) -> dict[str, np.ndarray]:
        """Plot arrays of a one-run whole log: the samples' times from start on and |x|."""
        t, x = per_sample
        return {"times": t, "values": x[:, 0]}

    def result(self, j, series=None) -> CriterionResult:
        name, threshold, start, within = self.name, self.threshold, self.start, self.within
        text = {
            "description": f"|{name}| < {_amount(threshold, name)} within {within:g} s after {start:g} s",
            "required_text": f"back under within {within:g} s, and staying",
        }
        if self.samples == 0 or self.last_time < start + within - TIME_TOLERANCE:
            line = f"FAIL: ABS({name}) had no samples {within:f} seconds after {start:f} seconds"
            return CriterionResult(
                "recovery", name, False, line, math.inf, within, None, measured_text="no samples", **text
            )
        last_bad = None if np.isnan(self.last_bad[j]) else float(self.last_bad[j])
        if last_bad is None:
            recovery = 0.0
        elif self.pending[j]:
            recovery = math.inf
        else:
            recovery = float(self.next_after[j] - start)
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
        return CriterionResult(
            "recovery",
            name,
            bool(passed),
            line,
            recovery,
            within,
            last_bad,
            samples=self.samples,
            measured_text=_recovery_text(recovery, last_bad, start, _amount(threshold, name)),
            series=series,
            **text,
        )


def _recovery_text(recovery, last_bad, start, threshold):
    """The measured value of a recovery verdict in words: ``back under 1.2 s after 12 s``,
    ``never back under`` or, when no sample from `start` on was above, ``under 0.5 m from
    12 s on (never above)``."""
    if math.isinf(recovery):
        return "never back under"
    if last_bad is None:
        return f"under {threshold} from {start:g} s on (never above)"
    return f"back under {recovery:.4g} s after {start:g} s"


def recovery_threshold(times, values, threshold, start, within, name="x") -> CriterionResult:
    """ "ABS(x) < threshold within W s after start": from start + W to the end every sample within.

    The recovery time is (first sample after the last violation at or after `start`) - start,
    0 if no sample from `start` on violates, inf if the last sample violates; the run passes
    iff it is <= W and the run has samples at or after start + W. measured: the recovery time
    (s); required: W (s); trailing: s, time of the last violation (None if none). Lines:
      ``PASS: ABS(name) was less than <thr> <r> seconds after <start> seconds (allowed <W>)``
      ``FAIL: ABS(name) was not less than <thr> within <W> seconds after <start> seconds (<r>)``
    """
    times, values, _ = _one_run(times, values)
    return _whole_log(RecoveryFold(name, threshold, start, within, 1), times, values=values)


def _criterion_fold(criterion, runs, vehicles):
    """The fold of a :class:`~quad_drake.config.CriterionConfig` for N = `runs` runs; vehicles:
    the scenario's vehicle names (a fleet_sigma criterion pools them)."""
    kind, name = criterion.kind, criterion.signal
    vehicle = name.split(".", 1)[0]
    if kind == "window":
        return WindowFold(name, criterion.threshold, criterion.window, runs)
    if kind == "sigma":
        return SigmaFold(
            name,
            criterion.ref_signal,
            criterion.ref,
            criterion.sigma_signal,
            criterion.sigma,
            criterion.min_percent,
            criterion.max_percent,
            criterion.window,
            runs,
        )
    if kind == "fleet_sigma":
        return PooledSigmaFold(
            name,
            criterion.sigma_signal,
            criterion.sigma_multiple,
            criterion.min_percent,
            criterion.max_percent,
            len(vehicles),
            runs,
        )
    if kind in ("bound", "attitude"):
        fold = BoundFold if kind == "bound" else AttitudeFold
        return fold(name, criterion.threshold, criterion.start, criterion.end, runs)
    if kind == "recovery":
        return RecoveryFold(name, criterion.threshold, criterion.start, criterion.window, runs)
    if kind == "floor":
        return FloorFold(vehicle, criterion.landing_time, name, runs)
    if kind == "room":
        return RoomFold(vehicle, name, runs)
    if kind == "finite":
        return FiniteFold(vehicle, name, runs)
    if kind == "tracking":
        return TrackingFold(name, criterion.threshold, runs)
    raise ValueError(f"unknown criterion kind {kind!r}")


def _criterion_inputs(criterion, signal, vehicles):
    """The keyword arguments of the criterion's fold ``update`` after the times, read with
    ``signal(name) -> (values (k, N), fresh (k, N) bool)``."""
    kind, name = criterion.kind, criterion.signal
    if kind == "fleet_sigma":
        pairs = [(signal(f"{v}.{name}"), signal(f"{v}.{criterion.sigma_signal}")[0]) for v in vehicles]
        return {
            "errors": [e for (e, _), _ in pairs],
            "sigmas": [s for _, s in pairs],
            "fresh": [f for (_, f), _ in pairs],
        }
    values, fresh = signal(name)
    if kind == "window":
        return {"values": values, "fresh": fresh}
    if kind == "sigma":
        ref = signal(criterion.ref_signal)[0] if criterion.ref_signal else criterion.ref
        sigma = signal(criterion.sigma_signal)[0] if criterion.sigma_signal else criterion.sigma
        return {"values": values, "fresh": fresh, "ref": ref, "sigma": sigma}
    if kind == "floor":
        return {"touchdowns": values, "contact": signal(f"{name.split('.', 1)[0]}.FloorContact")[0]}
    if kind == "room":
        return {"wall_steps": values}
    if kind == "finite":
        return {"finite": values}
    if kind == "tracking":
        return {"error": values}
    return {"values": values}  # bound, recovery


def evaluate_criterion(criterion, times, signal, vehicles=()) -> CriterionResult:
    """Run one :class:`~quad_drake.config.CriterionConfig` on one run's logged samples.

    ``signal(name) -> (values, fresh_mask)`` returns a named signal over ``times``
    (``fresh_mask`` None when every sample is fresh); vehicles: the scenario's vehicle names
    (what a fleet_sigma criterion pools). The verdict carries the plot series of its kind.
    """
    times = np.asarray(times, dtype=float).reshape(-1)

    def column(name):
        values, fresh = signal(name)
        mask = np.ones(times.size, dtype=bool) if fresh is None else np.asarray(fresh, dtype=bool)
        return _column(values, times.size), mask.reshape(-1, 1)

    fold = _criterion_fold(criterion, 1, vehicles)
    return _whole_log(fold, times, **_criterion_inputs(criterion, column, vehicles))


class CriterionStream:
    """One judged criterion folded over N runs' signals chunk by chunk (a fleet batch's verdicts
    without its full logs): ``update(times (k,), signal)`` with ``signal(name) -> (values (k, N),
    fresh (k, N))``, then ``result(j)``, run j's CriterionResult (without plot series)."""

    def __init__(self, criterion, runs, vehicles):
        self.criterion, self.vehicles = criterion, tuple(vehicles)
        self.fold = _criterion_fold(criterion, runs, self.vehicles)

    def update(self, times, signal) -> None:
        self.fold.update(
            np.asarray(times, dtype=float), **_criterion_inputs(self.criterion, signal, self.vehicles)
        )

    def result(self, j) -> CriterionResult:
        return self.fold.result(j)
