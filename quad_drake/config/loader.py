"""Reading and writing scenario YAML: the only module of the package that touches pydrake
(Drake's ``yaml_load_typed`` / ``yaml_dump_typed``), and PyYAML for the raw data it checks first.
"""

import dataclasses
import re
import warnings
from pathlib import Path

import numpy as np
import yaml
from pydrake.common.yaml import yaml_dump, yaml_dump_typed, yaml_load_typed

from .. import __version__
from ..estimation.registry import DEFAULT_KIND, kind_of
from .deprecated import migrate_ekf7_blocks, migrate_ekf7_override
from .errors import ConfigError, first_line
from .saved import saved_header, warn_of_absent_settings
from .schema import ScenarioConfig
from .validation import check_node, check_scenario


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader reading numbers as people write them.

    PyYAML implements YAML 1.1, where a float needs a dot and a signed exponent: ``1e9``,
    ``-3e2`` or ``1.e3`` load as strings. YAML 1.2 (and Drake's C++ parser) read them as
    numbers; this loader adds the 1.2 exponent forms to the float resolver. A key given twice in
    one mapping is refused (PyYAML keeps the last silently); a merge key (``<<``) may still
    override.
    """

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                    continue
                if key_node.value in seen:
                    raise yaml.constructor.ConstructorError(
                        None,
                        None,
                        f"duplicate key {key_node.value!r} (first at line {seen[key_node.value]})",
                        key_node.start_mark,
                    )
                seen[key_node.value] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)


def _tagged_mapping(loader, tag, node):
    """A ``!Name {...}`` mapping (how ``yaml_dump_typed`` writes a Union member) as a dict with
    ``_tag``, as Drake's ``yaml_load`` reads it; :func:`_check_kind_choice` picks the member."""
    return {**loader.construct_mapping(node, deep=True), "_tag": tag}


_EXPONENT_FLOAT = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$")
"""YAML 1.2's exponent forms of a float (``1e9``, ``-3e2``, ``1.e3``), which YAML 1.1 reads as text."""
_Loader.add_multi_constructor("!", _tagged_mapping)
_Loader.add_implicit_resolver("tag:yaml.org,2002:float", _EXPONENT_FLOAT, list("-+0123456789."))


def load_yaml(text) -> object:
    """Raw YAML data of `text` (merge keys and anchors resolved; 1.2 number forms read as
    numbers); top-level keys starting with ``_`` are dropped (templates for anchors), as
    Drake's ``yaml_load`` does."""
    data = yaml.load(text, Loader=_Loader)  # noqa: S506 (a SafeLoader subclass)
    if isinstance(data, dict):
        data = {k: v for k, v in data.items() if not (isinstance(k, str) and k.startswith("_"))}
    return data


def parse_override(text) -> tuple[list[str], object]:
    """Split ``dotted.key=value`` into (['dotted', 'key'], value parsed as YAML)."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip() or any(not part for part in key.strip().split(".")):
        raise ConfigError(f"--set {text!r}: expected dotted.key=value")
    try:
        value = load_yaml(f"value: {raw}")["value"] if raw.strip() else None
    except yaml.YAMLError as e:
        reason = first_line(e, located=False)
        raise ConfigError(f"--set {text!r}: value is not valid YAML ({reason})") from None
    return key.strip().split("."), value


def apply_override(raw, keys, value, text) -> None:
    """Set raw[k0][k1]... = value in a nested dict/list; list indices are integers."""
    node = raw
    for depth, key in enumerate(keys):
        last = depth == len(keys) - 1
        if isinstance(node, list):
            if not key.isdigit() or int(key) >= len(node):
                raise ConfigError(f"--set {text!r}: {key!r} is not an index of a list of {len(node)}")
            key = int(key)
        elif not isinstance(node, dict):
            raise ConfigError(f"--set {text!r}: {'.'.join(keys[:depth])} is not a mapping")
        if last:
            node[key] = value
        else:
            if isinstance(node, dict) and key not in node:
                node[key] = {}
            node = node[key]


def load_scenario(path, overrides=()) -> ScenarioConfig:
    """ScenarioConfig from a YAML file plus ``dotted.key=value`` overrides; validated.

    Raises ConfigError with one line naming the file and the field.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such scenario file")
    try:
        text = path.read_text()
        raw = load_yaml(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML: {first_line(e)}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: cannot read: {e}") from None
    if raw is None:
        raise ConfigError(f"{path}: the file is empty (a scenario is a mapping of fields)")
    if not isinstance(raw, dict):
        raise ConfigError(f"{path}: expected a mapping of fields at the top level, got {type(raw).__name__}")
    try:
        vehicles = raw.get("vehicles")
        for i, vehicle in enumerate(vehicles if isinstance(vehicles, list) else []):
            if isinstance(vehicle, dict):
                migrate_ekf7_blocks(vehicle, f"vehicles.{i}")
        for text in overrides:
            keys, value = parse_override(text)
            for new_keys, new_value in migrate_ekf7_override(raw, keys, value, holder_depth=2):
                _name_the_default_kind(raw, new_keys)
                apply_override(raw, new_keys, new_value, text)
        _migrate_use_ideal_estimator(raw)
        message = check_node(raw, ScenarioConfig, "")
        if message:
            raise ConfigError(message)
        scenario = yaml_load_typed(schema=ScenarioConfig, data=yaml_dump(raw))
        if not scenario.name:
            scenario.name = path.stem
        for vehicle in scenario.vehicles:
            vehicle.estimator = kind_of(vehicle.estimator).locate(vehicle.estimator, path.parent)
        check_scenario(scenario)
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}{override_hint(str(e), overrides)}") from None
    except (RuntimeError, ValueError, TypeError) as e:
        raise ConfigError(f"{path}: {first_line(e)}") from None
    warn_of_absent_settings(path, text, raw, scenario)
    return scenario


def _name_the_default_kind(raw, keys):
    """Give a vehicle that names no estimator an ``estimator: {kind: <default>}`` block (in
    place) before an override `keys` sets a field inside it (``vehicles.0.estimator.q_yaw_std``):
    the field is the default kind's."""
    if len(keys) < 4 or keys[0] != "vehicles" or keys[2] != "estimator" or not keys[1].isdigit():
        return
    vehicles, index = raw.get("vehicles"), int(keys[1])
    vehicle = vehicles[index] if isinstance(vehicles, list) and index < len(vehicles) else None
    if isinstance(vehicle, dict) and vehicle.get("estimator") is None:
        vehicle["estimator"] = {"kind": DEFAULT_KIND}


def _migrate_use_ideal_estimator(raw):
    """Rewrite each vehicle's deprecated ``use_ideal_estimator`` (raw YAML, in place) into its
    ``flies_on`` (true: truth, false: estimate), with a FutureWarning saying what to write
    instead; ConfigError where both are given and disagree."""
    vehicles = raw.get("vehicles")
    for i, vehicle in enumerate(vehicles if isinstance(vehicles, list) else []):
        if not isinstance(vehicle, dict) or "use_ideal_estimator" not in vehicle:
            continue
        where, ideal = f"vehicles.{i}.use_ideal_estimator", vehicle.pop("use_ideal_estimator")
        if not isinstance(ideal, bool):
            raise ConfigError(f"{where}: expected bool, got {ideal!r}")
        flies_on = "truth" if ideal else "estimate"
        if vehicle.setdefault("flies_on", flies_on) != flies_on:
            raise ConfigError(f"{where}: contradicts vehicles.{i}.flies_on (drop the deprecated field)")
        warnings.warn(
            f"{where} is deprecated: write vehicles.{i}.flies_on: {flies_on}"
            + (" (or estimator: {kind: truth} to run no estimator)" if ideal else ""),
            FutureWarning,
            stacklevel=3,
        )


def override_hint(message, overrides) -> str:
    """`` (--set KEY=VALUE)`` when the field a validation message starts with ("field: ...")
    is, contains or lies in the key of one of the `overrides`, else ``""``: the mistake is on
    the command line, not in the file."""
    field_path = message.split(":", 1)[0]
    for text in reversed(overrides):  # the last override of a key wins
        key = text.partition("=")[0].strip()
        if field_path == key or field_path.startswith(key + ".") or key.startswith(field_path + "."):
            return f" (--set {text})"
    return ""


def dump_scenario(scenario, folder=None) -> str:
    """The resolved scenario as YAML text (loads back to an equal ScenarioConfig); for a file in
    `folder`, the paths it names (a custom estimator's factory file) relative to that folder
    where they can be, so that the folder can move with the files it names."""
    if folder is not None:
        vehicles = [
            dataclasses.replace(v, estimator=kind_of(v.estimator).relative(v.estimator, folder))
            for v in scenario.vehicles
        ]
        scenario = dataclasses.replace(scenario, vehicles=vehicles)
    return dump_resolved(scenario)


class _SavedDumper(yaml.SafeDumper):
    """PyYAML's dumper writing a saved configuration as Drake's ``yaml_dump_typed`` does: block
    mappings in field order, a list of scalars on one line, a Union member's mapping under its
    ``!Name`` tag (the ``_tag`` of :func:`load_yaml`'s data)."""

    def represent_dict(self, data):
        items = [(k, v) for k, v in data.items() if k != "_tag"]
        tag = f"!{data['_tag']}" if "_tag" in data else "tag:yaml.org,2002:map"
        return self.represent_mapping(tag, items, flow_style=False)

    def represent_list(self, data):
        flat = all(not isinstance(item, (dict, list)) for item in data)
        return self.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flat)


_SavedDumper.add_representer(dict, _SavedDumper.represent_dict)
_SavedDumper.add_representer(list, _SavedDumper.represent_list)
_SavedDumper.add_representer(tuple, _SavedDumper.represent_list)
# A numpy scalar a computation left in a field (a tuned value) is written as the Python number it is.
_SavedDumper.add_multi_representer(np.generic, lambda dumper, data: dumper.represent_data(data.item()))
# A text such as "1e3" is quoted, as :class:`_Loader` would read it unquoted as a number.
_SavedDumper.add_implicit_resolver("tag:yaml.org,2002:float", _EXPONENT_FLOAT, list("-+0123456789."))


def dump_resolved(config) -> str:
    """`config` (a scenario's or a replay's dataclass) as the text of a saved configuration
    (``config.saved``): the mark naming this version, then every setting in field order. Drake's
    ``yaml_dump_typed`` leaves out a field whose value is None; here it is written ``null``, so
    that a later quad_drake can tell a setting saved as None from one added since. Drake's text
    gives only the structure (which mappings carry a Union member's tag); the values are the
    dataclass's own, so that a text such as ``1e3``, which Drake writes unquoted and
    :func:`load_yaml` would read as a number, is written quoted."""
    data = _saved_data(load_yaml(yaml_dump_typed(config)), config)
    body = yaml.dump(data, Dumper=_SavedDumper, sort_keys=False, allow_unicode=True, width=100)
    return saved_header(__version__) + body


def _saved_data(raw, config):
    """The data of the dataclass `config` as a mapping in field order: each field's own value
    (None included), a nested dataclass (alone or in a list) as such a mapping under the
    ``_tag`` that `raw`, Drake's dump of it read back, gives it."""
    data = {"_tag": raw["_tag"]} if "_tag" in raw else {}
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if dataclasses.is_dataclass(value):
            value = _saved_data(raw[field.name], value)
        elif isinstance(value, list):
            value = [
                _saved_data(g, v) if dataclasses.is_dataclass(v) else v
                for v, g in zip(value, raw[field.name], strict=True)
            ]
        data[field.name] = value
    return data
