"""Every scenario example in README.md and in the manual's pages (docs/**/*.md: a ```yaml block
with ``vehicles:``) loads and passes every criterion at its own seed, as the page presents it; the
manual's campaign script runs as a user runs it. (The own-estimator example of the estimators
guide is flown by test_custom_estimator.py.)"""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from quad_drake.cli import main

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def scenario_examples():
    """(page, block) for each distinct scenario example, in page order (the same scenario shown on
    two pages, comments aside, flies once)."""
    examples = {}
    for page in PAGES:
        if "_build" in page.parts:
            continue
        blocks = re.findall(r"```yaml\n(.*?)```", page.read_text(encoding="utf-8"), flags=re.DOTALL)
        for block in blocks:
            if re.search(r"^vehicles:", block, flags=re.MULTILINE):
                key = json.dumps(yaml.safe_load(block), sort_keys=True)
                examples.setdefault(key, (page.relative_to(ROOT).as_posix(), block))
    return list(examples.values())


def test_the_readme_and_the_manual_have_scenario_examples():
    pages = [page for page, _ in scenario_examples()]
    assert "README.md" in pages  # the README's hover
    assert "docs/guide/02_scenarios_and_faults.md" in pages  # the hover and the faults example
    assert len(pages) >= 2


@pytest.mark.slow
@pytest.mark.parametrize("example", scenario_examples(), ids=lambda e: f"{e[0]}:{e[1].splitlines()[0][:30]}")
def test_a_scenario_example_passes_at_its_seed(example, tmp_path, capsys):
    page, block = example
    path = tmp_path / "example.yaml"
    path.write_text(block, encoding="utf-8")
    code = main(["run", str(path), "--no-plots", "--out", str(tmp_path / "out")])
    assert code == 0, f"{page}: {capsys.readouterr().out}"


def python_example(page, calls):
    """The ```python block of a manual page that contains `calls`."""
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / page).read_text(encoding="utf-8"), flags=re.DOTALL)
    return next(block for block in blocks if calls in block)


@pytest.mark.slow
def test_the_manual_campaign_script_runs_as_a_plain_script_on_spawned_workers(tmp_path):
    script = tmp_path / "my_campaign.py"
    script.write_text(python_example("docs/guide/05_campaigns.md", "run_campaign("), encoding="utf-8")
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    env = {**os.environ, "PYTHONPATH": path}  # the package of this checkout, as an install would give
    ran = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert ran.returncode == 0, ran.stderr[-3000:]
    assert "criterion" in ran.stdout and (tmp_path / "out" / "my_campaign" / "summary.json").is_file()
