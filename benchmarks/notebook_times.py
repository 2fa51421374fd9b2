"""What executing each notebook of notebooks/ costs, cell by cell: wall and CPU seconds.

Each notebook is executed as the tests and the manual execute it (``docs/_ext/executed_notebooks.py``:
nbclient, this interpreter's ``python3`` kernel, in a new empty folder, this checkout first on
PYTHONPATH), in its quick mode (``QUAD_DRAKE_QUICK=1``) unless ``--full``. Printed per code
cell: its wall time and the CPU time (user + system) of the kernel and of every process under it
(pool workers) while it ran, from psutil; per notebook: its wall time and the CPU time of every
process it started, ended ones included (``getrusage`` of this script's children). CPU is the
figure to compare on a shared machine; alternate old and new executions, the machine varies.

    python benchmarks/notebook_times.py                       # every notebook, quick mode
    python benchmarks/notebook_times.py notebooks/03_write_your_own_ekf.ipynb --full
"""

import argparse
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import nbclient
import nbformat
import psutil

ROOT = Path(__file__).resolve().parent.parent


def _cpu_under(process):
    """CPU s (user + system) of `process` and its living descendants, with their waited-for children."""
    total = 0.0
    for member in [process, *process.children(recursive=True)]:
        try:
            times = member.cpu_times()
        except psutil.Error:  # ended meanwhile
            continue
        total += times.user + times.system + times.children_user + times.children_system
    return total


def _children_cpu():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def execute(path):
    """(rows, wall s, CPU s) of one execution of the notebook at `path`; rows: (cell index,
    wall s, CPU s, first line) per code cell. Raises nbclient's CellExecutionError on a failing
    cell."""
    node = nbformat.read(path, as_version=4)
    rows, marks = [], {}
    with tempfile.TemporaryDirectory(prefix="notebook_") as folder:
        client = nbclient.NotebookClient(
            node, timeout=1800, kernel_name="python3", resources={"metadata": {"path": folder}}
        )

        def started(cell, cell_index):
            marks["kernel"] = marks.get("kernel") or psutil.Process(client.km.provisioner.process.pid)
            marks["wall"], marks["cpu"] = time.perf_counter(), _cpu_under(marks["kernel"])

        def finished(cell, cell_index, execute_reply):
            cpu = _cpu_under(marks["kernel"]) - marks["cpu"]
            rows.append((cell_index, time.perf_counter() - marks["wall"], cpu, cell.source.split("\n")[0]))

        client.on_cell_execute, client.on_cell_executed = started, finished
        wall, cpu = time.perf_counter(), _children_cpu()
        client.execute()
        return rows, time.perf_counter() - wall, _children_cpu() - cpu


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("notebooks", nargs="*", type=Path, help="default: every notebook of notebooks/")
    parser.add_argument("--full", action="store_true", help="the user's mode, not the quick mode")
    args = parser.parse_args(argv)
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    if args.full:
        os.environ.pop("QUAD_DRAKE_QUICK", None)
    else:
        os.environ["QUAD_DRAKE_QUICK"] = "1"
    totals = []
    for path in args.notebooks or sorted((ROOT / "notebooks").glob("*.ipynb")):
        rows, wall, cpu = execute(path)
        print(f"{path.stem} ({'full' if args.full else 'quick'} mode)")
        for index, cell_wall, cell_cpu, line in rows:
            print(f"  cell {index:2d}  wall {cell_wall:6.1f} s  CPU {cell_cpu:6.1f} s  {line[:60]}")
        print(f"  the whole notebook: wall {wall:.1f} s, CPU {cpu:.1f} s (kernel, workers, start-up)")
        totals.append(cpu)
    if len(totals) > 1:
        print(f"all {len(totals)}: CPU {sum(totals):.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
