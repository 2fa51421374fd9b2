"""CPU time of a run's plots (``plots.write_plots``): the figures of a 25 s flight of 11.

Usage: python benchmarks/bench_plots.py [--scenario 11_gps_update] [--repeats 3]

Flies the scenario once, then writes its plots `repeats` times into a temporary folder and prints
the CPU time of each (``time.process_time``, this process). About 1 s per set on the 2-core
machine; a time above 5 s is a regression worth a look (this was an assertion of
``tests/test_plots.py`` until issue 28 moved timing out of the test suite).
"""

import argparse
import tempfile
import time
from pathlib import Path

from quad_drake.output import plots
from quad_drake.running import catalog
from quad_drake.running.simulation import run


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="11_gps_update")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    result = run(catalog.load(args.scenario))
    with tempfile.TemporaryDirectory() as folder:
        for i in range(args.repeats):
            start = time.process_time()
            written = plots.write_plots(result, Path(folder) / str(i))
            print(f"{args.scenario}: {len(written)} plots in {time.process_time() - start:.2f} s CPU")


if __name__ == "__main__":
    main()
