"""The Drake Diagram of a scenario as an SVG picture (Graphviz ``dot``)."""

import shutil
import subprocess
from pathlib import Path

from ..config.errors import ConfigError
from .simulation import build_diagram


def diagram_dot(scenario, max_depth=None) -> str:
    """Graphviz source of the scenario's Diagram; max_depth None expands every sub-Diagram,
    1 shows each vehicle as one box, 0 the whole scenario as one."""
    if max_depth is not None and max_depth < 0:
        raise ConfigError(f"diagram: depth must be >= 0, got {max_depth}")
    diagram, _ = build_diagram(scenario)
    return diagram.GetGraphvizString(max_depth=max_depth)


def write_diagram_svg(scenario, path, max_depth=None, dot=None) -> Path:
    """Render the scenario's Diagram to an SVG file with `dot -Tsvg`; -> path.

    Raises ConfigError (one line) when Graphviz is missing or fails.
    """
    dot = dot or shutil.which("dot")
    if dot is None:
        raise ConfigError(
            "diagram: Graphviz 'dot' not found on PATH (install graphviz, e.g. apt-get install graphviz)"
        )
    path = Path(path)
    process = subprocess.run(
        [dot, "-Tsvg"], input=diagram_dot(scenario, max_depth), capture_output=True, text=True, check=False
    )
    if process.returncode != 0:
        message = (process.stderr.strip().splitlines() or ["no message"])[0]
        raise ConfigError(f"diagram: dot failed with exit code {process.returncode}: {message}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(process.stdout, encoding="utf-8")
    return path
