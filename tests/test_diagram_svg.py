"""The scenario Diagram rendered to SVG with Graphviz."""

import shutil
import xml.etree.ElementTree as ET

import pytest

from quad_drake.config.errors import ConfigError
from quad_drake.running import catalog
from quad_drake.running.diagram_svg import diagram_dot, write_diagram_svg

needs_dot = pytest.mark.skipif(
    shutil.which("dot") is None, reason="Graphviz 'dot' not installed (apt-get install graphviz)"
)


def _texts(svg_path):
    root = ET.parse(svg_path).getroot()
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    return {"".join(e.itertext()).strip() for e in root.iter("{http://www.w3.org/2000/svg}text")}


@needs_dot
def test_full_depth_shows_every_system_of_every_vehicle(tmp_path):
    path = write_diagram_svg(catalog.load("03_position_control"), tmp_path / "sub" / "diagram.svg")
    texts = _texts(path)
    assert {"name=Quad1", "name=Quad2", "name=plant", "name=controller", "name=trajectory"} <= texts
    assert "motor_thrusts" in texts and "reference" in texts


@needs_dot
def test_depth_one_keeps_vehicles_closed(tmp_path):
    texts = _texts(write_diagram_svg(catalog.load("11_gps_update"), tmp_path / "d.svg", max_depth=1))
    assert "name=Quad" in texts and "name=plant" not in texts
    assert {"state", "ekf_state", "covariance", "gps", "mag"} <= texts  # the vehicle's exported ports


def test_missing_dot_is_a_one_line_config_error(tmp_path, monkeypatch):
    monkeypatch.setattr("quad_drake.running.diagram_svg.shutil.which", lambda name: None)
    with pytest.raises(ConfigError, match=r"^diagram: Graphviz 'dot' not found .*graphviz") as error:
        write_diagram_svg(catalog.load("01_intro"), tmp_path / "d.svg")
    assert "\n" not in str(error.value)
    assert not (tmp_path / "d.svg").exists()


def test_failing_dot_and_bad_depth_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match=r"^diagram: dot failed with exit code 1"):
        write_diagram_svg(catalog.load("01_intro"), tmp_path / "d.svg", dot=shutil.which("false"))
    with pytest.raises(ConfigError, match="depth must be >= 0"):
        diagram_dot(catalog.load("01_intro"), max_depth=-1)
