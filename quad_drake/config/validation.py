"""Validation of a scenario: the raw YAML's shape against the schema, each field's value rules
(its metadata), and the rules across fields (:func:`check_scenario`); any problem is one
:class:`~.errors.ConfigError` naming the dotted field path and what is wrong. Pure.
"""

import dataclasses
import math
import re
import typing
from pathlib import Path

from ..conventions import ONBOARD_PERIOD
from ..estimation.measurements import unfused_sensor
from ..estimation.registry import flies_on_estimate, kind_of
from ..models.fidelity import fidelity_from_mode
from .errors import ConfigError, did_you_mean
from .schema import FAULT_KINDS, MAX_SEED, TRAJECTORY_DIR, ScenarioConfig

NAME_PATTERNS = {
    "scenario": (
        re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*"),
        "a letter, digit or _, then letters, digits or _ . + -; default: the file's name",
    ),
    "vehicle": (re.compile(r"[A-Za-z_][A-Za-z0-9_-]*"), "a letter or _, then letters, digits, _ or -"),
}
"""Names that become folders and files (a scenario's results, a vehicle's CSV) and prefixes of
signal names (``Quad.Est.E.Pos``): no path separators, no leading dot, no dot in a vehicle's."""


def check_seed_range(first_seed, runs, what="--seed") -> None:
    """ConfigError unless the seeds first_seed .. first_seed + runs - 1 lie in [0, MAX_SEED]."""
    if first_seed < 0 or first_seed + runs - 1 > MAX_SEED:
        last = f" to {first_seed + runs - 1}" if runs > 1 else ""
        raise ConfigError(f"{what}: seeds must lie in [0, {MAX_SEED}] (2**32 - 1), got {first_seed}{last}")


NOISE_STD_RANGE = (1e-100, 1e100)
"""Allowed magnitudes of a nonzero noise standard deviation (units of its field).

Filters square a std into a covariance (P0, Q, R) and then sum, multiply and invert such
entries: with |std| in this range every square lies in [1e-200, 1e200], so a covariance never
underflows to zero (a singular innovation S = H P H^T + R) nor overflows to inf, with a factor
of 1e100 to spare for P summed over up to 1e8 predict steps and for gains and NIS products.
Outside it no physical quantity of a quadrotor lives. Zero stays allowed where a field is
merely >= 0 (a perfect sensor, a zero Q or P0): R, whose fields are > 0, keeps S invertible.
"""


def _type_name(tp):
    return getattr(tp, "__name__", str(tp))


def check_node(node, tp, path) -> str | None:
    """Shape check of raw YAML `node` against annotation `tp`; returns a message or None."""
    origin = typing.get_origin(tp)
    if origin is typing.Union:
        members = [a for a in typing.get_args(tp) if a is not type(None)]
        if node is None:
            return None
        if len(members) > 1:
            return _check_kind_choice(node, members, path)
        return check_node(node, members[0], path)
    if dataclasses.is_dataclass(tp):
        if not isinstance(node, dict):
            return f"{path or 'the file'}: expected a mapping, got {node!r}"
        names = {f.name: f for f in dataclasses.fields(tp)}
        for key, value in node.items():
            if key == "_tag":  # set by _check_kind_choice, or read from a dumped config
                continue
            sub = f"{path}.{key}" if path else str(key)
            if key not in names:
                return _unspaced_colon(key, value, names, sub) or (
                    f"{sub}: unknown key{did_you_mean(key, names)} (known: {', '.join(names)})"
                )
            message = check_node(value, typing.get_type_hints(tp)[key], sub)
            if message:
                return message
        return None
    if origin in (dict, typing.Dict):
        if not isinstance(node, dict):
            return f"{path}: expected a mapping, got {node!r}"
        key_type, value_type = typing.get_args(tp)
        for key, value in node.items():
            message = check_node(key, key_type, path) or check_node(value, value_type, f"{path}.{key}")
            if message:
                return message
        return None
    if origin in (list, typing.List):
        if not isinstance(node, list):
            return f"{path}: expected a list, got {node!r}"
        (item_type,) = typing.get_args(tp)
        for i, item in enumerate(node):
            message = check_node(item, item_type, f"{path}.{i}")
            if message:
                return message
        return None
    if tp is float:
        ok = isinstance(node, (int, float)) and not isinstance(node, bool)
    elif tp is int:
        ok = isinstance(node, int) and not isinstance(node, bool)
    elif tp is bool:
        ok = isinstance(node, bool)
    else:
        ok = isinstance(node, tp)
    return None if ok else f"{path}: expected {_type_name(tp)}, got {node!r}"


def _kind_of(member):
    return next(f.default for f in dataclasses.fields(member) if f.name == "kind")


def _unspaced_colon(key, value, names, path) -> str | None:
    """The message for a key YAML read as "name:value" with no value (``{kind:eskf}``: a flow
    mapping's colon needs a space after it) where name is one of `names`, else None."""
    name, colon, rest = str(key).partition(":")
    if not colon or value is not None or name not in names:
        return None
    return (
        f"{path}: unknown key: YAML reads {str(key)!r} as one key; "
        f"write '{name}: {rest}' (a space after the colon)"
    )


def _check_kind_choice(node, members, path):
    """Check a mapping against the Union member its ``kind`` names; tag it for yaml_load_typed.

    Every member is a dataclass whose ``kind`` field defaults to its own name. A config
    written by :func:`dump_scenario` carries a YAML tag instead of (or besides) the kind.
    """
    if not isinstance(node, dict):
        return f"{path}: expected a mapping, got {node!r}"
    by_kind = {_kind_of(m): m for m in members}
    by_tag = {f"!{m.__name__}": m for m in members}
    if "kind" in node:
        member = by_kind.get(node["kind"])
        if member is None:
            return f"{path}.kind: {node['kind']!r} is not one of {', '.join(by_kind)}"
    elif node.get("_tag") in by_tag:
        member = by_tag[node["_tag"]]
    else:
        for key, value in node.items():
            message = _unspaced_colon(key, value, ("kind",), f"{path}.{key}")
            if message:
                return message
        return f"{path}.kind: missing; one of {', '.join(by_kind)}"
    node["_tag"] = f"!{member.__name__}"
    return check_node(node, member, path)


def validate(config, path="") -> None:
    """Raise ConfigError for the first field of `config` that breaks its metadata rules."""
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        sub = f"{path}.{f.name}" if path else f.name
        if dataclasses.is_dataclass(value):
            validate(value, sub)
            continue
        if isinstance(value, list) and value and dataclasses.is_dataclass(value[0]):
            for i, item in enumerate(value):
                validate(item, f"{sub}.{i}")
            continue
        rules = f.metadata
        if "length" in rules and len(value) != rules["length"]:
            raise ConfigError(f"{sub}: expected {rules['length']} values, got {len(value)}")
        if "pattern" in rules:
            pattern, allowed = NAME_PATTERNS[rules["pattern"]]
            if not pattern.fullmatch(value):
                raise ConfigError(f"{sub}: {value!r} is not a usable name ({allowed})")
        if "choices" in rules and value not in rules["choices"]:
            raise ConfigError(f"{sub}: {value!r} is not one of {', '.join(rules['choices'])}")
        for x in value if isinstance(value, list) else [value]:
            if isinstance(x, float) and not math.isfinite(x):
                raise ConfigError(f"{sub}: must be finite, got {x}")
            if rules.get("positive") and not x > 0:
                raise ConfigError(f"{sub}: must be > 0, got {x}")
            if rules.get("nonnegative") and not x >= 0:
                raise ConfigError(f"{sub}: must be >= 0, got {x}")
            if "minimum" in rules and x < rules["minimum"]:
                raise ConfigError(f"{sub}: must be >= {rules['minimum']}, got {x}")
            if "maximum" in rules and x > rules["maximum"]:
                raise ConfigError(f"{sub}: must be <= {rules['maximum']}, got {x}")
            if rules.get("noise_std") and x and not NOISE_STD_RANGE[0] <= abs(x) <= NOISE_STD_RANGE[1]:
                low, high = NOISE_STD_RANGE
                raise ConfigError(
                    f"{sub}: a noise std must be 0 or within [{low:g}, {high:g}] so that its square "
                    f"is a usable covariance, got {x:g}"
                )
            if "tick_multiple" in rules:
                _check_tick_multiple(x, rules["tick_multiple"], sub)


def _check_tick_multiple(seconds, min_ticks, where):
    """ConfigError unless `seconds` is a whole number >= min_ticks of 2 ms onboard ticks
    (to 1e-9 of a tick: what a decimal such as 0.1 s rounds to)."""
    ticks = seconds / ONBOARD_PERIOD
    if round(ticks) < min_ticks or abs(ticks - round(ticks)) > 1e-9 * max(1.0, ticks):
        tick_ms = f"{ONBOARD_PERIOD * 1e3:g} ms"
        least = f", at least {min_ticks * ONBOARD_PERIOD:g} s" if min_ticks else ""
        raise ConfigError(
            f"{where}: must be a whole multiple of the {tick_ms} onboard tick{least}, got {seconds:g}"
        )


def check_scenario(scenario) -> None:
    """Raise ConfigError (one line, the field's dotted path) for a ScenarioConfig that breaks a
    rule of :func:`load_scenario`: what every entry point (``simulation.run``, ``run_fleet``,
    ``run_campaign``) checks, so a config built or changed in Python is judged as a file is."""
    if not isinstance(scenario, ScenarioConfig):
        raise ConfigError(f"expected a ScenarioConfig, got {type(scenario).__name__}")
    try:
        validate(dataclasses.replace(scenario, name=scenario.name or "scenario"))  # a name comes later
        _check_semantics(scenario)
    except (TypeError, AttributeError) as e:  # e.g. a string where a number belongs
        raise ConfigError(f"{scenario.name or 'scenario'}: a field has the wrong type ({e})") from None


def ineffective_settings(scenario) -> list[str]:
    """Lines naming the criteria and faults that cannot matter for a flight of ``end_time`` s:
    a window (window, sigma) not shorter than the flight, a bound interval or a recovery that
    starts at or after its end (judged on no samples), a fault that starts after the flight.
    Not errors (a short trial run may mean it); the command line prints them as warnings."""
    end, lines = scenario.end_time, []
    for i, c in enumerate(scenario.criteria):
        where = f"criteria.{i} ({c.kind} on {c.signal})"
        if c.kind in ("window", "sigma") and c.window >= end:
            lines.append(f"{where}: its {c.window:g} s window is not shorter than the {end:g} s flight")
        if c.kind == "bound" and c.start >= end:
            lines.append(f"{where}: [{c.start:g}, {c.end:g}) s starts after the {end:g} s flight")
        if c.kind == "recovery" and c.start + c.window > end:
            lines.append(
                f"{where}: judged from {c.start + c.window:g} s (start + window), after the {end:g} s flight"
            )
    for i, v in enumerate(scenario.vehicles):
        if v.wind is not None and not any(v.physics.rotor_drag + v.physics.parasitic_drag):
            lines.append(f"vehicles.{i}.wind: has no effect, physics.rotor_drag and parasitic_drag are 0")
        for j, fault in enumerate(v.faults):
            begins = fault.time if fault.kind == "gps_outlier" else fault.start
            if fault.kind != "gps_delay" and begins >= end:
                where = f"vehicles.{i}.faults.{j} ({fault.kind})"
                lines.append(f"{where}: starts at {begins:g} s, after the {end:g} s flight")
    return lines


def _check_semantics(scenario):
    names = [v.name for v in scenario.vehicles]
    if not names:
        raise ConfigError("vehicles: at least one vehicle is needed")
    if len(set(names)) != len(names):
        raise ConfigError(f"vehicles: names must be unique, got {names}")
    for i, v in enumerate(scenario.vehicles):
        p = v.physics
        if p.min_motor_thrust >= p.max_motor_thrust:
            raise ConfigError(f"vehicles.{i}.physics: min_motor_thrust must be < max_motor_thrust")
        for axis, bounds in enumerate((p.x_bounds, p.y_bounds, p.z_bounds)):
            where = f"vehicles.{i}.physics.{'xyz'[axis]}_bounds"
            if not bounds[0] < bounds[1]:
                raise ConfigError(f"{where}: must be [min, max] with min < max, got {bounds}")
            if not bounds[0] <= v.initial_position[axis] <= bounds[1]:
                raise ConfigError(
                    f"vehicles.{i}.initial_position: {'xyz'[axis]} = {v.initial_position[axis]:g} m is "
                    f"outside the room ({where} {bounds}; NED, z = {p.z_bounds[1]:g} is the floor)"
                )
        if v.trajectory.kind == "file":
            resolve_trajectory_file(v.trajectory.file, f"vehicles.{i}.trajectory.file")
        kind = kind_of(v.estimator)
        gsf = getattr(v.estimator, "gsf", None)
        gsf_on = gsf is not None and gsf.enabled
        if gsf_on and not v.sensors.gps:
            raise ConfigError(f"vehicles.{i}.estimator.gsf: enabled needs a gps sensor (its velocity)")
        if v.flies_on == "estimate" and kind.builder is not None:
            if not (v.sensors.imu and v.sensors.gps and (v.sensors.mag or gsf_on)):
                raise ConfigError(
                    f"vehicles.{i}.flies_on: estimate needs imu, gps and mag sensors "
                    "(or, without a magnetometer, the estimator's gsf enabled)"
                )
        if v.sensors.gps_accuracy:
            raise ConfigError(
                f"vehicles.{i}.sensors.gps_accuracy: only a flight log's replay supplies a GPS "
                "receiver's reported accuracy (quad-drake replay); a simulated GPS reports none"
            )
        if v.sensors.no_aid:
            raise ConfigError(
                f"vehicles.{i}.sensors.no_aid: only a flight log's replay supplies no-aiding samples "
                "(quad-drake replay); a simulated vehicle has none"
            )
        if kind.builder and unfused_sensor(kind.measurements, v.sensors) == "mag":
            raise ConfigError(
                f"vehicles.{i}.sensors.mag.three_axis: estimator kind {kind.name!r} takes the yaw "
                "magnetometer only (ekf7 and eskf fuse a 3-axis one)"
            )
        problem = kind.fidelity_problem(fidelity_from_mode(scenario.fidelity)) or kind.problem(v.estimator)
        if problem:
            raise ConfigError(f"vehicles.{i}.estimator: {problem}")
        if v.failsafe is not None and not flies_on_estimate(v):
            raise ConfigError(f"vehicles.{i}.failsafe: needs flies_on: estimate (it supervises the estimate)")
        if v.gps_delay_compensation > 0 and not (v.sensors.imu and v.sensors.gps):
            raise ConfigError(f"vehicles.{i}.gps_delay_compensation: needs imu and gps sensors")
        for j, fault in enumerate(v.faults):
            _check_fault(fault, v.sensors, f"vehicles.{i}.faults.{j}")
        if sum(f.kind == "gps_delay" for f in v.faults) > 1:
            raise ConfigError(f"vehicles.{i}.faults: at most one gps_delay per vehicle")
        _check_air(v, scenario.fidelity, f"vehicles.{i}")
    for i, c in enumerate(scenario.criteria):
        if not c.signal:
            raise ConfigError(f"criteria.{i}.signal: must name a signal")
        if c.kind == "fleet_sigma" and not c.sigma_signal:
            raise ConfigError(f"criteria.{i}.sigma_signal: fleet_sigma needs a sigma signal suffix")
        if c.kind == "bound" and not c.end > c.start:
            raise ConfigError(f"criteria.{i}.end: must be > start ({c.start}), got {c.end}")
        if c.kind in ("sigma", "fleet_sigma") and c.min_percent >= c.max_percent:
            raise ConfigError(f"criteria.{i}: min_percent must be < max_percent")
        if c.landing_time is not None and not c.landing_time >= 0:
            raise ConfigError(f"criteria.{i}.landing_time: must be >= 0, got {c.landing_time}")
    landing = scenario.safety.landing_time
    if landing is not None and not landing >= 0:
        raise ConfigError(f"safety.landing_time: must be >= 0, got {landing}")


def _check_air(vehicle, fidelity, where):
    """One-line ConfigError for a wind gust without a direction, or a delta-velocity IMU under the
    reference's accelerometer (``fidelity: reference``)."""
    for j, gust in enumerate(vehicle.wind.gusts if vehicle.wind is not None else ()):
        if not any(gust.direction):
            raise ConfigError(f"{where}.wind.gusts.{j}.direction: must not be zero")
    imu = vehicle.sensors.imu
    if imu is not None and imu.delta_velocity and fidelity_from_mode(fidelity).reference_accelerometer:
        raise ConfigError(
            f"{where}.sensors.imu.delta_velocity: the reference's accelerometer reads the last step "
            "(fidelity: physical only)"
        )


FAULT_OFFSET_LENGTHS = {"gps_outlier": 3, "gps_step": 3, "mag_bias": 1, "mag_disturbance": 3, "baro_step": 1}
"""Number of ``offset`` values each fault kind takes (the others take none)."""
WINDOW_FAULT_KINDS = tuple(kind for kind in FAULT_KINDS if kind not in ("gps_outlier", "gps_delay"))
"""The faults that act over a [start, end) window (gps_outlier acts at ``time``, gps_delay always)."""
MAG_MODEL_FAULTS = {"mag_bias": False, "mag_disturbance": True}
"""The magnetometer faults that need one model: False the yaw model, True ``three_axis``."""


def _check_fault(fault, sensors, where):
    """One-line ConfigError for a fault the vehicle cannot have or whose fields do not fit its kind."""
    sensor = fault.kind.split("_")[0]
    if getattr(sensors, sensor) is None:
        raise ConfigError(f"{where}.kind: {fault.kind} needs a {sensor} sensor on the vehicle")
    if fault.kind in MAG_MODEL_FAULTS and sensors.mag.three_axis != MAG_MODEL_FAULTS[fault.kind]:
        model = "a 3-axis (three_axis: true)" if MAG_MODEL_FAULTS[fault.kind] else "a yaw (three_axis: false)"
        raise ConfigError(f"{where}.kind: {fault.kind} needs {model} magnetometer")
    if fault.kind in WINDOW_FAULT_KINDS and not fault.end > fault.start:
        raise ConfigError(f"{where}.end: must be > start ({fault.start}), got {fault.end}")
    expected = FAULT_OFFSET_LENGTHS.get(fault.kind, 0)
    if len(fault.offset) != expected:
        raise ConfigError(f"{where}.offset: {fault.kind} takes {expected} values, got {len(fault.offset)}")
    if fault.kind == "gps_delay":
        ticks = fault.delay / ONBOARD_PERIOD
        if not fault.delay > 0 or abs(ticks - round(ticks)) > 1e-6:
            raise ConfigError(
                f"{where}.delay: must be a positive multiple of {ONBOARD_PERIOD} s, got {fault.delay}"
            )


def resolve_trajectory_file(name, where="trajectory.file") -> Path:
    """Path of a trajectory file: a packaged name (e.g. ``Square.txt``) or a path."""
    if not name:
        raise ConfigError(f"{where}: kind 'file' needs a file name")
    for candidate in (Path(name), TRAJECTORY_DIR / name):
        if candidate.is_file():
            return candidate
    raise ConfigError(f"{where}: no such trajectory file {name!r}")
