"""Every scenario example in README.md (a ```yaml block with ``vehicles:``) loads and passes
every criterion at its own seed, as the README presents it."""

import re
from pathlib import Path

import pytest

from quad_drake.cli import main

README = Path(__file__).resolve().parent.parent / "README.md"


def scenario_examples():
    blocks = re.findall(r"```yaml\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.DOTALL)
    return [block for block in blocks if re.search(r"^vehicles:", block, flags=re.MULTILINE)]


def test_the_readme_has_scenario_examples():
    assert len(scenario_examples()) >= 2  # the hover of "Adding a scenario" and the faults one


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(scenario_examples())))
def test_a_readme_scenario_example_passes_at_its_seed(index, tmp_path, capsys):
    path = tmp_path / f"readme_example_{index}.yaml"
    path.write_text(scenario_examples()[index], encoding="utf-8")
    code = main(["run", str(path), "--no-plots", "--out", str(tmp_path / "out")])
    assert code == 0, capsys.readouterr().out
