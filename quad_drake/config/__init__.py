"""Scenario configuration, a pure floor: every module here but :mod:`.loader` is pydrake-free.

- :mod:`.errors`: :class:`ConfigError` (a user's mistake, one line) and the did-you-mean hint;
- :mod:`.fields`: the field constructors whose metadata carries the value rules;
- :mod:`.schema`: the scenario dataclasses (defaults, units), nothing else;
- :mod:`.deprecated`: the EKF7's pre-0.3 ``ekf:`` / ``attitude_filter:`` blocks, rewritten into
  its estimator config;
- :mod:`.validation`: the raw YAML's shape, the field rules, the rules across fields;
- :mod:`.saved`: a saved configuration (a run's ``config.yaml``) and the settings it lacks;
- :mod:`.loader`: YAML in and out, the only module that touches pydrake (Drake's typed YAML).

``from quad_drake.config import load_scenario`` keeps working: this package re-exports its
modules' names lazily (module ``__getattr__``), so importing :mod:`quad_drake.config.errors`
(or this package) loads only what is asked for. Inside the package, import from the module
that defines a name.
"""

import importlib

_EXPORTS = {
    "errors": (
        "ConfigError",
        "did_you_mean",
        "first_line",
    ),
    "fields": (
        "vector",
        "number",
        "noise_stds",
    ),
    "schema": (
        "PACKAGE_DIR",
        "TRAJECTORY_DIR",
        "MAX_SEED",
        "PhysicsParams",
        "ControllerParams",
        "ImuParams",
        "GpsParams",
        "MagParams",
        "BaroParams",
        "SensorsConfig",
        "FAULT_KINDS",
        "FaultConfig",
        "TURBULENCE_LEVELS",
        "GustConfig",
        "WindConfig",
        "TRAJECTORY_KINDS",
        "TrajectoryConfig",
        "FLIES_ON",
        "VehicleConfig",
        "SAFETY_KINDS",
        "CRITERION_KINDS",
        "CriterionConfig",
        "SafetyConfig",
        "ScenarioConfig",
    ),
    "deprecated": (
        "EKF7_BLOCKS",
        "current_field_path",
        "migrate_ekf7_blocks",
        "migrate_ekf7_override",
    ),
    "validation": (
        "NAME_PATTERNS",
        "check_seed_range",
        "NOISE_STD_RANGE",
        "check_node",
        "validate",
        "check_scenario",
        "ineffective_settings",
        "FAULT_OFFSET_LENGTHS",
        "WINDOW_FAULT_KINDS",
        "MAG_MODEL_FAULTS",
        "resolve_trajectory_file",
    ),
    "loader": (
        "load_yaml",
        "parse_override",
        "apply_override",
        "load_scenario",
        "override_hint",
        "dump_scenario",
        "dump_resolved",
    ),
    "saved": (
        "SAVED_MARK",
        "SavedConfigWarning",
        "saved_header",
        "has_saved_mark",
        "is_saved_config",
        "absent_settings",
        "absent_settings_line",
        "warn_of_absent_settings",
    ),
}
"""{module: the public names it defines}, re-exported here on first use."""
_HOME = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_HOME)


def __getattr__(name):
    module = _HOME.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_HOME))
