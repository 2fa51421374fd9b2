"""The README "Fidelity" figures: deviation from the reference binary's golden traces.

For each golden set-up (tests/data/golden/*.yaml, motor noise off) it prints the largest
position (m) and attitude (rad) deviation over every vehicle and 5 ms sample, matched by
index, in both modes and with each item of ``fidelity: reference`` switched back to the
physical behaviour alone (the measured effect of that deviation); then the dead-reckoning
drift of 08 (max |Quad.Est.E.Pos| over 40 s) in both modes, motor noise off and at seed 0.

    python benchmarks/fidelity_table.py
"""

import dataclasses
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from test_golden import CASES, GOLDEN, deviations, load_golden  # noqa: E402

from quad_drake import catalog, simulation  # noqa: E402
from quad_drake.config import load_scenario  # noqa: E402
from quad_drake.fidelity import PHYSICAL, REFERENCE  # noqa: E402

VARIANTS = {"physical": PHYSICAL, "reference": REFERENCE} | {
    f"reference without {f.name}": dataclasses.replace(REFERENCE, **{f.name: False})
    for f in dataclasses.fields(REFERENCE)
    if f.name != "reference_accelerometer"  # it does not touch the truth (ideal estimator)
}


def main():
    build = simulation.fidelity_from_mode
    goldens = {case: load_golden(name) for case, name in CASES.items()}
    for label, fidelity in VARIANTS.items():
        simulation.fidelity_from_mode = lambda mode, fidelity=fidelity: fidelity
        print(f"== {label}")
        for case, golden in goldens.items():
            result = simulation.run(load_scenario(GOLDEN / f"{case}.yaml"))
            worst = deviations(result, golden)
            position = max(p for p, _ in worst.values())
            attitude = max(a for _, a in worst.values())
            print(f"  {case:22s} {position:9.2e} m {attitude:9.2e} rad")
    simulation.fidelity_from_mode = build
    print("== 08_predict_state dead-reckoning drift, max |Quad.Est.E.Pos| over 40 s")
    for mode in ("physical", "reference"):
        for noise in ("vehicles.0.physics.motor_noise=0", "seed=0"):
            result = simulation.run(catalog.load("08_predict_state", overrides=[f"fidelity={mode}", noise]))
            print(f"  {mode:9s} {noise:34s} {result.signals['Quad.Est.E.Pos'].values.max():7.2f} m")


if __name__ == "__main__":
    main()
