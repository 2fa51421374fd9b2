"""Pure: the EKF7's parameters at their pre-0.3 places, rewritten into its estimator config.

Before 0.3 the EKF7's parameters were a vehicle's (or a replay's) ``ekf:`` and
``attitude_filter:`` blocks; they are now fields of its ``estimator: {kind: ekf7, ...}``
(``estimation.registry.Ekf7EstimatorConfig``): ``ekf.q_yaw_std`` is ``estimator.q_yaw_std`` and
``attitude_filter.tau`` is ``estimator.attitude_filter.tau``. The loaders
(``config.loader``, ``flightlogs.settings``) rewrite the old places with a FutureWarning, in a
file (:func:`migrate_ekf7_blocks`) and in a ``--set`` key (:func:`migrate_ekf7_override`);
``quad-drake tune`` rewrites a ``--params`` key (:func:`current_field_path`).
"""

import warnings

from ..estimation.registry import DEFAULT_KIND, KINDS, Ekf7EstimatorConfig
from .errors import ConfigError

EKF7_BLOCKS = {"ekf": (), "attitude_filter": ("attitude_filter",)}
"""{the old block of a vehicle: its path below the vehicle's ``estimator``}."""
EKF7_KIND = Ekf7EstimatorConfig().kind


def current_field_path(parts) -> tuple:
    """The field path (below a vehicle) that the dotted path `parts` names today: an old
    ``ekf.X`` / ``attitude_filter.X`` moved under ``estimator``, else `parts` unchanged."""
    parts = tuple(parts)
    if parts and parts[0] in EKF7_BLOCKS:
        return ("estimator", *EKF7_BLOCKS[parts[0]], *parts[1:])
    return parts


def _raw_kind(estimator, where) -> str:
    """The kind a raw ``estimator`` mapping (named `where`) names: its ``kind``, or the tag a
    dumped config carries; the default kind when there is no block. ConfigError when it is not a
    mapping."""
    if estimator is None:
        return DEFAULT_KIND
    if not isinstance(estimator, dict):
        raise ConfigError(f"{where}: expected a mapping, got {estimator!r}")
    if "kind" in estimator:
        return estimator["kind"]
    by_tag = {f"!{kind.config_type.__name__}": name for name, kind in KINDS.items()}
    return by_tag.get(estimator.get("_tag"), DEFAULT_KIND)


def _merge(target, block, where, new_where) -> None:
    """Merge the mapping `block` into the mapping `target` (in place, recursively); ConfigError
    where a value both give differs."""
    for key, value in block.items():
        if isinstance(value, dict) and isinstance(target.get(key), dict):
            _merge(target[key], value, f"{where}.{key}", f"{new_where}.{key}")
        elif key in target and target[key] != value:
            raise ConfigError(f"{where}.{key}: contradicts {new_where}.{key} (drop the deprecated field)")
        else:
            target[key] = value


def migrate_ekf7_blocks(holder, where) -> None:
    """Rewrite the old ``ekf`` / ``attitude_filter`` blocks of the raw mapping `holder` (a
    vehicle's or a replay's, named `where`: ``vehicles.0``, or ``""`` for a replay) into its
    ``estimator`` (in place), with a FutureWarning saying what to write instead. An estimator of
    another kind never read them: they are dropped, and the warning says so. ConfigError where a
    block is not a mapping, or where it and the estimator give a field different values."""
    prefix = f"{where}." if where else ""
    for block, below in EKF7_BLOCKS.items():
        if block not in holder:
            continue
        value = holder.pop(block)
        old = f"{prefix}{block}"
        if value is None:
            value = {}
        if not isinstance(value, dict):
            raise ConfigError(f"{old}: expected a mapping, got {value!r}")
        kind = _raw_kind(holder.get("estimator"), f"{prefix}estimator")
        if kind != EKF7_KIND:
            warnings.warn(
                f"{old} is deprecated and ignored: it holds ekf7 parameters and {prefix}estimator is {kind}",
                FutureWarning,
                stacklevel=3,
            )
            continue
        estimator = holder.setdefault("estimator", {"kind": EKF7_KIND})
        if estimator is None:
            estimator = holder["estimator"] = {"kind": EKF7_KIND}
        target = estimator
        for key in below:
            target = target.setdefault(key, {})
        new = ".".join([f"{prefix}estimator", *below])
        _merge(target, value, old, new)
        warnings.warn(
            f"{old} is deprecated: write its fields in {new} ({prefix}estimator: {{kind: ekf7, ...}})",
            FutureWarning,
            stacklevel=3,
        )


def migrate_ekf7_override(raw, keys, value, holder_depth) -> list:
    """The ``(keys, value)`` overrides that a ``--set keys=value`` means today: keys naming an old
    block (``vehicles.N.ekf.X`` for a scenario, `holder_depth` 2; ``ekf.X`` for a replay, 0)
    move under the holder's ``estimator`` (a whole ``ekf`` mapping sets each of its fields), with
    a FutureWarning; an old key of a holder whose estimator is of another kind is dropped (it was
    never read), with a FutureWarning saying so; any other key is kept. `raw` is the raw
    scenario (or replay) mapping, read to find the holder's estimator kind."""
    keys = list(keys)
    if len(keys) <= holder_depth or keys[holder_depth] not in EKF7_BLOCKS:
        return [(keys, value)]
    holder = raw
    for key in keys[:holder_depth]:
        if isinstance(holder, list) and key.isdigit() and int(key) < len(holder):
            holder = holder[int(key)]
        elif isinstance(holder, dict):
            holder = holder.get(key, {})
        else:
            return [(keys, value)]  # apply_override says what is wrong
    head, old = keys[:holder_depth], ".".join(keys)
    where = ".".join([*head, "estimator"])
    kind = _raw_kind(holder.get("estimator") if isinstance(holder, dict) else None, where)
    if kind != EKF7_KIND:
        warnings.warn(
            f"--set {old}: deprecated and ignored: it sets an ekf7 parameter and the estimator is {kind}",
            FutureWarning,
            stacklevel=3,
        )
        return []
    new = [*head, *current_field_path(keys[holder_depth:])]
    warnings.warn(f"--set {old} is deprecated: write --set {'.'.join(new)}", FutureWarning, stacklevel=3)
    if keys[holder_depth] == "ekf" and len(keys) == holder_depth + 1:
        if not isinstance(value, dict):
            raise ConfigError(f"--set {old}: expected a mapping of ekf7 parameters, got {value!r}")
        return [([*new, key], item) for key, item in value.items()]
    return [(new, value)]
