"""Guard for refactors: fly every bundled scenario at its default seed and save every log, then
compare two such files bit for bit.

    python benchmarks/logs_guard.py before.npz          # on the old tree
    python benchmarks/logs_guard.py after.npz           # on the new tree
    python benchmarks/logs_guard.py --compare before.npz after.npz

Prints each scenario's verdict while flying; the comparison prints every array that differs (its
largest absolute difference) and "bit-identical" when none does; exit 1 on a difference.
"""

import argparse
import sys

import numpy as np


def dump(out: str) -> None:
    """Fly every bundled scenario at its default seed; every log array into the npz `out`."""
    from quad_drake.running.catalog import bundled_scenarios, load
    from quad_drake.running.simulation import run

    arrays, verdicts = {}, {}
    for name in bundled_scenarios():
        result = run(load(name))
        arrays[f"{name}/times"] = result.times
        for vehicle, logs in result.logs.items():
            for log, values in logs.items():
                arrays[f"{name}/{vehicle}/{log}"] = np.asarray(values)
        verdicts[name] = [(c.line, bool(c.passed)) for c in result.criteria]
        print(name, "PASS" if result.passed else "FAIL", flush=True)
    arrays["__verdicts__"] = np.array(repr(verdicts))
    np.savez_compressed(out, **arrays)


def compare(before: str, after: str) -> int:
    """The number of arrays that differ between two npz files of :func:`dump` (each printed)."""
    a, b = np.load(before), np.load(after)
    differences = 0
    for key in sorted(set(a.files) | set(b.files)):
        if key not in a.files or key not in b.files:
            print("only in one file:", key)
            differences += 1
        elif a[key].shape != b[key].shape:
            print(f"shape {key}: {a[key].shape} vs {b[key].shape}")
            differences += 1
        elif not np.array_equal(a[key], b[key], equal_nan=a[key].dtype.kind in "fc"):
            gap = np.nanmax(np.abs(a[key] - b[key])) if a[key].dtype.kind in "fc" else float("nan")
            print(f"differs {key}: max |difference| {gap:.3e}")
            differences += 1
    print("bit-identical" if differences == 0 else f"{differences} arrays differ")
    return differences


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", help="OUT.npz, or with --compare BEFORE.npz AFTER.npz")
    parser.add_argument("--compare", action="store_true")
    args = parser.parse_args()
    if args.compare:
        if len(args.files) != 2:
            parser.error("--compare takes two files")
        sys.exit(1 if compare(*args.files) else 0)
    dump(args.files[0])
