"""Benchmark: the CPU of a flight with a user's own estimator (``estimator: {kind: custom}``).

Writes the manual's "Bring your own estimator" example (``docs/guide/04_estimators.md``, the
class ``MyEkf``: a pure-Python 7-state EKF) to a temporary folder and flies 08_predict_state
(40 s) and 11_gps_update (25 s) with it, `--repeats` times each in turn, printing each flight's
CPU time (``time.process_time()``: this process, user + system) and the median per scenario.
Run it on two checkouts one after the other (``PYTHONPATH=<checkout>``) to compare them.

Usage: ``python benchmarks/custom_estimator_cost.py [--repeats 3]``
"""

import argparse
import re
import statistics
import tempfile
import time
from pathlib import Path

from quad_drake.running import catalog
from quad_drake.running.simulation import run

GUIDE = Path(__file__).resolve().parent.parent / "docs" / "guide" / "04_estimators.md"
SCENARIOS = ("08_predict_state", "11_gps_update")


def write_example(folder) -> str:
    """The manual's example written to folder/my_ekf.py; its factory string."""
    section = GUIDE.read_text(encoding="utf-8").split("## Bring your own estimator", 1)[1]
    path = Path(folder) / "my_ekf.py"
    path.write_text(re.search(r"```python\n(.*?)```", section, re.S).group(1), encoding="utf-8")
    return f"{path}:MyEkf"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    repeats = parser.parse_args().repeats
    with tempfile.TemporaryDirectory() as folder:
        factory = write_example(folder)
        override = f'vehicles.0.estimator={{kind: custom, factory: "{factory}"}}'
        seconds = {name: [] for name in SCENARIOS}
        for _ in range(repeats):
            for name in SCENARIOS:
                scenario = catalog.load(name, overrides=[override])
                start = time.process_time()
                run(scenario)
                seconds[name].append(time.process_time() - start)
    for name, values in seconds.items():
        listed = ", ".join(f"{v:.2f}" for v in values)
        print(f"{name}: CPU {listed} s; median {statistics.median(values):.2f} s")


if __name__ == "__main__":
    main()
