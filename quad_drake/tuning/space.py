"""Pure: the search space of ``quad-drake tune`` — which config fields are searched and how.

A :class:`Parameter` is one dotted config key (``estimator.q_vel_xy_std``, ``estimator.accel_std``,
or ``vehicles.0.estimator.q_yaw_std`` for one vehicle; a pre-0.3 ``ekf.X`` key is read as
``estimator.X``, with a FutureWarning). The search moves its log10 *multiplier* x
of the starting value: the field becomes ``start * 10**x`` with x in [-SEARCH_DECADES,
SEARCH_DECADES]. So a scalar and a vector field (scaled as a whole, keeping the ratios of its
axes) are searched alike, in log space, where noise standard deviations live; x = 0 is the
scenario as given. A key without a ``vehicles.N.`` prefix applies to every tuned vehicle
(those carrying the first estimator's kind), so a multi-vehicle scenario keeps one tuning.
"""

import copy
import dataclasses
import warnings
from dataclasses import dataclass

from ..config.deprecated import current_field_path
from ..config.errors import ConfigError, did_you_mean
from ..config.schema import ScenarioConfig
from ..config.validation import validate
from ..estimation.registry import kind_of, vehicle_vocabulary

SEARCH_DECADES = 1.0
"""Each parameter is searched from 1/10 to 10 times its starting value."""


@dataclass(frozen=True)
class Parameter:
    """One searched key: the (vehicle index, field path) targets it sets and their start values."""

    key: str  # as the user gave it (or the default), e.g. "estimator.q_vel_xy_std"
    targets: tuple  # ((vehicle index, ("estimator", "q_vel_xy_std")), ...)
    starts: tuple  # start value per target: a float or a tuple of floats (a vector field)

    def values(self, x) -> tuple:
        """Field value per target at log10 multiplier x."""
        scale = 10.0**x
        return tuple(
            tuple(v * scale for v in start) if isinstance(start, tuple) else start * scale
            for start in self.starts
        )

    def label(self, x) -> str:
        """The first target's value at x, as text (a vector as [a, b, c])."""
        value = self.values(x)[0]
        if isinstance(value, tuple):
            return "[" + ", ".join(f"{v:.4g}" for v in value) + "]"
        return f"{value:.4g}"


def tuned_vehicles(scenario) -> list[int]:
    """Indices of the vehicles a relative key tunes: those with an estimator of the first one's kind."""
    kinds = [(i, vehicle_vocabulary(v)) for i, v in enumerate(scenario.vehicles)]
    kinds = [(i, v.kind) for i, v in kinds if v is not None]
    if not kinds:
        raise ConfigError(f"tune: {scenario.name} has no estimator to tune (no vehicle carries an IMU)")
    return [i for i, kind in kinds if kind == kinds[0][1]]


def _field_value(node, parts, key, where):
    """Value at `parts` below `node` (a dataclass, dict or list); ConfigError naming the unknown part."""
    for depth, part in enumerate(parts):
        here = ".".join([where, *parts[:depth]]).strip(".") or "the scenario"
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise ConfigError(f"--params {key}: {part!r} is not an index of {here} (0..{len(node) - 1})")
            node = node[int(part)]
        elif isinstance(node, dict):  # a custom estimator's params
            if part not in node:
                raise ConfigError(
                    f"--params {key}: unknown key {part!r} in {here}{did_you_mean(part, node)} "
                    f"(known: {', '.join(node) or 'none'})"
                )
            node = node[part]
        elif dataclasses.is_dataclass(node):
            names = [f.name for f in dataclasses.fields(node)]
            if part not in names:
                raise ConfigError(
                    f"--params {key}: unknown field {part!r} in {here}{did_you_mean(part, names)} "
                    f"(known: {', '.join(names)})"
                )
            node = getattr(node, part)
        else:
            raise ConfigError(f"--params {key}: {here} is not a mapping or a list")
    return node


def _start(value, key):
    """The start value of a searchable field: a float > 0, or a list of floats >= 0 not all 0."""
    if isinstance(value, float):
        if not value > 0:
            raise ConfigError(
                f"--params {key}: starts at {value:g}; the log-space search scales the start, "
                "so give it a positive value first (--set)"
            )
        return value
    if isinstance(value, list) and value and all(isinstance(v, float) for v in value):
        if not all(v >= 0 for v in value) or not any(v > 0 for v in value):
            raise ConfigError(f"--params {key}: starts at {value}; needs values >= 0, not all 0")
        return tuple(value)
    raise ConfigError(f"--params {key}: not a number or a list of numbers (got {value!r})")


def parameter(scenario, key) -> Parameter:
    """The Parameter of dotted `key` in `scenario`; ConfigError (one line) when it cannot be searched."""
    parts = key.split(".")
    if not key or any(not p for p in parts):
        raise ConfigError(f"--params {key!r}: expected a dotted config key such as estimator.q_vel_xy_std")
    key, parts = _current_key(key, parts)
    if parts[0] == "vehicles":
        if len(parts) < 3 or not parts[1].isdigit() or int(parts[1]) >= len(scenario.vehicles):
            raise ConfigError(
                f"--params {key}: expected vehicles.N.<field> with N in 0..{len(scenario.vehicles) - 1}"
            )
        indices, path = [int(parts[1])], tuple(parts[2:])
    else:
        indices, path = tuned_vehicles(scenario), tuple(parts)
    starts = []
    for i in indices:
        where = f"vehicles.{i}"
        starts.append(_start(_field_value(scenario.vehicles[i], list(path), key, where), key))
    return Parameter(key, tuple((i, path) for i in indices), tuple(starts))


def _current_key(key: str, parts: list) -> tuple[str, list]:
    """(key, parts) as written today: a pre-0.3 ``ekf.X`` / ``attitude_filter.X`` (or
    ``vehicles.N.`` ones) read as ``estimator.X`` (``config.deprecated``), with a FutureWarning."""
    head = parts[:2] if parts[0] == "vehicles" else []
    current = [*head, *current_field_path(parts[len(head) :])]
    if current == parts:
        return key, parts
    new_key = ".".join(current)
    warnings.warn(f"--params {key} is deprecated: write {new_key}", FutureWarning, stacklevel=3)
    return new_key, current


def default_keys(scenario) -> list[str]:
    """The default space: the tuned estimator kind's tuning keys (``estimation/registry.py``)
    whose start is not zero (a zero field, e.g. 11's q_pos_xy_std = 0, is switched off and cannot
    be scaled), less the measurement noise of a sensor the
    vehicle does not have (10 has no GPS: its ``gps_*`` fields have no effect)."""
    first = scenario.vehicles[tuned_vehicles(scenario)[0]]
    keys = kind_of(first.estimator).tuning_keys(first.estimator)
    for sensor in ("gps", "mag"):
        if getattr(first.sensors, sensor) is None:
            keys = [k for k in keys if not k.split(".")[-1].startswith(f"{sensor}_")]
    return [k for k in keys if _is_on(_field_value(first, k.split("."), k, "vehicle"))]


def _is_on(value):
    return any(v > 0 for v in value) if isinstance(value, list) else value > 0


def search_space(scenario, keys=None) -> list[Parameter]:
    """[Parameter] of `keys` (default: :func:`default_keys`); checks every key before any work."""
    keys = list(keys) if keys else default_keys(scenario)
    if len(set(keys)) != len(keys):
        raise ConfigError(f"--params: a key is given twice ({', '.join(keys)})")
    space = [parameter(scenario, key) for key in keys]
    seen = {}
    for p in space:
        for target in p.targets:
            if target in seen:
                raise ConfigError(f"--params {p.key}: sets the same field as {seen[target]}")
            seen[target] = p.key
    return space


def overrides(space, x) -> list[str]:
    """The ``--set`` texts that give a scenario the values of `space` at x (what :func:`apply`
    sets): ``vehicles.I.PATH=VALUE`` per target, VALUE a number or a ``[...]`` list."""
    texts = []
    for p, xi in zip(space, x, strict=True):
        for (i, path), value in zip(p.targets, p.values(float(xi)), strict=True):
            shown = (
                f"[{', '.join(repr(float(v)) for v in value)}]"
                if isinstance(value, tuple | list)
                else repr(float(value))
            )
            texts.append(f"vehicles.{i}.{'.'.join(map(str, path))}={shown}")
    return texts


def apply(scenario, space, x) -> ScenarioConfig:
    """A validated copy of `scenario` with every Parameter of `space` at its log10 multiplier in x."""
    candidate = copy.deepcopy(scenario)
    for p, xi in zip(space, x, strict=True):
        for (i, path), value in zip(p.targets, p.values(float(xi)), strict=True):
            node = _field_value(candidate.vehicles[i], list(path[:-1]), p.key, f"vehicles.{i}")
            value = list(value) if isinstance(value, tuple) else value
            if isinstance(node, list):
                node[int(path[-1])] = value
            elif isinstance(node, dict):
                node[path[-1]] = value
            else:
                setattr(node, path[-1], value)
    validate(candidate)
    return candidate
