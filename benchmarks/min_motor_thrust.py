"""How far the golden set-ups move from the reference binary when physics.min_motor_thrust is
not the 0.1 N the binary always uses (it reads the key without its dot, SPEC §3): README
"Fidelity".

    python benchmarks/min_motor_thrust.py [--values 0 0.2]
"""

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_golden import CASES, GOLDEN, deviations, load_golden  # noqa: E402

from quad_drake.config import load_scenario  # noqa: E402
from quad_drake.running.simulation import run  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--values", type=float, nargs="*", default=[0.0, 0.1, 0.2])
    args = parser.parse_args(argv)
    for case, trace in CASES.items():
        path = GOLDEN / f"{case}.yaml"
        vehicles = len(load_scenario(path).vehicles)
        for value in args.values:
            overrides = [f"vehicles.{i}.physics.min_motor_thrust={value}" for i in range(vehicles)]
            worst = deviations(run(load_scenario(path, overrides)), load_golden(trace))
            position = max(p for p, _ in worst.values())
            attitude = max(a for _, a in worst.values())
            print(f"{case} min_motor_thrust={value:g} N: {position:.2g} m / {attitude:.2g} rad")


if __name__ == "__main__":
    main()
