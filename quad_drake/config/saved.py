"""Pure: a saved configuration, and the settings a file saved by an earlier quad_drake lacks.

Every run and replay writes its resolved configuration into its folder as ``config.yaml``
(``config.loader.dump_resolved``): every setting with its value, ``null`` included, under a first
line :data:`SAVED_MARK` naming the version that wrote it; ``quad-drake run config.yaml`` (or
``replay``) flies it again. A setting added to quad_drake after the file was written is absent
from it, and loading the file gives that setting today's default, which may fly otherwise than
the saved run did (an IMU gap bridge added to the replay after a replay folder was written
changes what replaying that folder gives). The loaders name those settings
(:func:`absent_settings`) in one :class:`SavedConfigWarning` line instead of flying silently
otherwise. A hand-written scenario leaves settings out on purpose and is not judged so: only a
file that carries the mark, or a run folder's ``config.yaml`` written before the mark existed
(a ``summary.json`` beside it), is a saved configuration.
"""

import dataclasses
import warnings
from pathlib import Path

SAVED_MARK = "# written by quad_drake"
"""The start of a saved configuration's first line: ``# written by quad_drake <version>: ...``."""
SHOWN_SETTINGS = 6
"""How many absent settings the warning names before it counts the rest."""


class SavedConfigWarning(UserWarning):
    """A saved configuration lacks settings that quad_drake has today (:func:`absent_settings`)."""


def saved_header(version) -> str:
    """The first line of a saved configuration written by quad_drake `version` (newline ended)."""
    return f"{SAVED_MARK} {version}: every setting, resolved (run or replay this file to fly it again)\n"


def has_saved_mark(text) -> bool:
    """True when one of the leading comment lines of the YAML `text` starts with :data:`SAVED_MARK`
    (a ``tuned.yaml`` puts the tuner's comments first)."""
    for line in text.splitlines():
        if not line.startswith("#"):
            return False
        if line.startswith(SAVED_MARK):
            return True
    return False


def is_saved_config(path, text) -> bool:
    """True when the YAML `text` of the file `path` is a saved configuration (module docstring):
    it carries the mark (:func:`has_saved_mark`), or it is a ``config.yaml`` with a
    ``summary.json`` beside it (a result folder's, written before the mark existed)."""
    path = Path(path)
    return has_saved_mark(text) or (path.name == "config.yaml" and (path.parent / "summary.json").is_file())


def absent_settings(raw, config, nulls_written=True, prefix="") -> list[str]:
    """The dotted paths (``vehicles.0.estimator.gravity_std``) of the dataclass fields of the
    loaded `config` that the raw mapping `raw` (the file's YAML data, after ``--set``) does not
    give, in field order; a nested dataclass (or a list of them) the file gives is searched field
    by field, one the file lacks is named once. `config` is the object loaded from `raw`, so a
    Union field (an estimator of some kind) is searched as the kind it loaded as.
    nulls_written: False for a file written before the mark, by Drake's ``yaml_dump_typed``,
    which leaves out every field whose value is None: there a field that loaded as None is not
    named (it was None when saved, or did not exist and is None, off, today)."""
    absent = []
    for field in dataclasses.fields(config):
        path, value = f"{prefix}{field.name}", getattr(config, field.name)
        if not isinstance(raw, dict) or field.name not in raw:
            if nulls_written or value is not None:
                absent.append(path)
            continue
        given = raw[field.name]
        if dataclasses.is_dataclass(value):
            absent += absent_settings(given, value, nulls_written, f"{path}.")
        elif isinstance(value, list) and isinstance(given, list):
            for i, (item, item_given) in enumerate(zip(value, given, strict=False)):
                if dataclasses.is_dataclass(item):
                    absent += absent_settings(item_given, item, nulls_written, f"{path}.{i}.")
    return absent


def absent_settings_line(path, absent) -> str:
    """One line saying that the saved configuration `path` lacks the settings `absent` (dotted
    paths, at least one) and what loading it does with them."""
    shown = ", ".join(absent[:SHOWN_SETTINGS])
    more = f" and {len(absent) - SHOWN_SETTINGS} more" if len(absent) > SHOWN_SETTINGS else ""
    return (
        f"{path}: saved by an earlier quad_drake (or edited): {len(absent)} setting(s) it does not give "
        f"take today's defaults, so it may not fly as the saved run did: {shown}{more}"
    )


def warn_of_absent_settings(path, text, raw, config) -> None:
    """A SavedConfigWarning (one line) when the file `path` (its YAML `text`) is a saved
    configuration and its data `raw` (after ``--set``) leaves out settings of the `config` loaded
    from it: they took today's defaults. The loaders call it once a file has loaded."""
    if is_saved_config(path, text):
        absent = absent_settings(raw, config, nulls_written=has_saved_mark(text))
        if absent:
            warnings.warn(absent_settings_line(path, absent), SavedConfigWarning, stacklevel=3)
