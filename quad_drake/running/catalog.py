"""The bundled scenarios (``scenarios/`` at the top of the repository, shipped in the wheel as the
package data ``quad_drake/scenarios/``) and how to load one.

A scenario is named either by its bundled name (``01_intro``) or by the path of a YAML file.
This is the library's entry point for loading; the CLI, the notebooks, the benchmarks and the
campaigns all go through it.
"""

from pathlib import Path

from ..config.errors import ConfigError, did_you_mean
from ..config.loader import load_scenario
from ..config.schema import ScenarioConfig
from ..config.validation import check_seed_range
from ..output.outdir import is_result_folder

_PACKAGE = Path(__file__).resolve().parent.parent
SCENARIO_DIR = _PACKAGE / "scenarios" if (_PACKAGE / "scenarios").is_dir() else _PACKAGE.parent / "scenarios"
"""The bundled scenarios' folder: the package data of an installed wheel, else (a checkout, an
editable install) the repository's top-level ``scenarios/``, their one source."""


def bundled_scenarios() -> dict[str, Path]:
    """{name: path} of the bundled scenarios, ordered by name (01_intro first)."""
    return {p.stem: p for p in sorted(SCENARIO_DIR.glob("*.yaml"))}


def resolve(name_or_path) -> Path:
    """Path of a scenario given by bundled name or by a YAML file path; ConfigError if neither."""
    name = str(name_or_path)
    known = bundled_scenarios()
    if name in known:
        return known[name]
    path = Path(name)
    if path.suffix in (".yaml", ".yml") or path.exists():
        if not path.is_file():
            raise ConfigError(f"{name}: no such scenario file")
        return path
    raise ConfigError(f"unknown scenario {name!r}{did_you_mean(name, known)} (known: {', '.join(known)})")


def run_folder_of(name_or_path) -> Path | None:
    """The run folder whose config.yaml `name_or_path` is (reproducing a run from its folder),
    or None for a bundled name or any other file."""
    path = Path(str(name_or_path))
    if path.name == "config.yaml" and path.is_file() and is_result_folder(path.parent):
        return path.resolve().parent
    return None


def load(name_or_path, seed=None, overrides=()) -> ScenarioConfig:
    """Validated ScenarioConfig for a bundled name or a path, with ``dotted.key=value`` overrides.

    ``seed`` (when given, in [0, ``config.MAX_SEED``], else a ConfigError naming ``--seed``) is
    applied as the override ``seed=<seed>`` after the others. The criteria's signal names are checked
    against what the scenario logs, so a misspelt name is reported (with the file) at load
    time, before anything flies.
    """
    from ..judging.verdicts import check_criteria
    from .simulation import available_signals

    path = resolve(name_or_path)
    overrides = list(overrides)
    if seed is not None:
        check_seed_range(seed, 1)
        overrides.append(f"seed={seed}")
    scenario = load_scenario(path, overrides)
    try:
        check_criteria(scenario, available_signals(scenario))
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}") from None
    return scenario
