"""Whole-process CPU of ``quad-drake run 11_gps_update --no-plots``: this tree against a git revision.

The figure of issue 37's import-time guard: one process costs no more CPU (user + system,
``resource.getrusage(RUSAGE_CHILDREN)``) than it did at the revision (default ``daa41b3``).
The revision is checked out once as a detached git worktree under the temporary directory
(``<tmp>/quad_drake-rev-<revision>``, kept for the next call). Each round runs the two
processes back to back, alternating which goes first, so a busy machine slows both alike;
every process gets the tree it measures on ``PYTHONPATH`` and writes into a throwaway folder.
One warm-up run per tree first (numba compiles its kernels into that tree's cache once).
Printed: each side's median CPU over the rounds, and the ratio of the medians (this tree over
the revision; <= 1.0 is the guard held). ``--imports`` times instead a process that only imports
what such a run imports before it flies (the command line and the simulation module, wherever
the tree keeps it): the import share of the figure.

    python benchmarks/bench_process_cpu.py [--rev daa41b3] [--rounds 7] [--scenario 11_gps_update] [--imports]
"""

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent


def checkout(revision):
    """Folder of a detached worktree of `revision` (created once, under the temporary directory)."""
    folder = Path(tempfile.gettempdir()) / f"quad_drake-rev-{revision}"
    if not (folder / "quad_drake").is_dir():
        subprocess.run(
            ["git", "-C", str(HERE), "worktree", "add", "--detach", str(folder), revision],
            check=True,
            capture_output=True,
        )
    return folder


IMPORTS_ONLY = """
import importlib, quad_drake.cli
for name in ("quad_drake.running.simulation", "quad_drake.simulation"):
    try:
        importlib.import_module(name)
        break
    except ModuleNotFoundError:
        pass
"""
"""What a run imports before it flies, in a tree before or after the modules moved (issue 37)."""


def process_cpu(tree, scenario, out, imports_only=False):
    """CPU s (user + system) of one ``python -m quad_drake run <scenario> --no-plots`` of `tree`
    (or, `imports_only`, of a process importing what that run imports before it flies)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env |= {"PYTHONPATH": str(tree), "MPLBACKEND": "Agg"}
    command = [sys.executable, "-m", "quad_drake", "run", scenario, "--no-plots", "--out", str(out)]
    if imports_only:
        command = [sys.executable, "-c", IMPORTS_ONLY]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in (0, 1):
        raise SystemExit(f"{tree}: exit {done.returncode}: {done.stderr.strip()[-500:]}")
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rev", default="daa41b3", help="git revision to compare with (default daa41b3)")
    parser.add_argument("--rounds", type=int, default=7, help="paired rounds, >= 1 (default 7)")
    parser.add_argument("--scenario", default="11_gps_update")
    parser.add_argument("--imports", action="store_true", help="time only what the run imports")
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error("--rounds must be >= 1")
    trees = {"this tree": HERE, args.rev: checkout(args.rev)}
    cpu = {name: [] for name in trees}
    with tempfile.TemporaryDirectory() as out:
        for tree in trees.values():
            process_cpu(tree, args.scenario, out)  # warm-up: numba's cache, bytecode
        for i in range(args.rounds):
            order = list(trees) if i % 2 == 0 else list(trees)[::-1]
            for name in order:
                cpu[name].append(process_cpu(trees[name], args.scenario, out, args.imports))
    median = {name: statistics.median(values) for name, values in cpu.items()}
    for name, values in cpu.items():
        rounds = " ".join(f"{v:.2f}" for v in values)
        print(f"{name:>12}: median {median[name]:.3f} s CPU over {args.rounds} rounds ({rounds})")
    ratio = median["this tree"] / median[args.rev]
    print(f"ratio (this tree / {args.rev}): {ratio:.3f}")


if __name__ == "__main__":
    main()
