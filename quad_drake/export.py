"""Per-run logs as CSV, for pandas and spreadsheets: one file per vehicle.

Each file has a ``time`` column (s, the 5 ms log samples) and one column per named signal of
that vehicle (``Quad.Pos.X``, ``Quad.Est.E.Yaw`` ..., the names the criteria use), in the
order :func:`quad_drake.signals.vehicle_signals` defines them. A sensor signal that is held
between measurements also gets a ``<name>.fresh`` column (1 on samples carrying a new
measurement, else 0). Numbers are written exactly (shortest round-trip repr; ``nan`` where
a value does not exist yet).
"""

import csv
from pathlib import Path

from .config import load_scenario
from .estimation.vocabulary import vehicle_vocabulary
from .results import load_logs
from .signals import vehicle_signals


def export_csv(run_dir, out_dir=None):
    """Write ``<vehicle>.csv`` per vehicle of the run folder `run_dir` (which holds logs.npz)
    into `out_dir` (default: ``run_dir/csv``); returns the paths written."""
    times, logs = load_logs(run_dir)
    config = Path(run_dir) / "config.yaml"
    vehicles = {v.name: v for v in load_scenario(config).vehicles} if config.is_file() else {}
    out_dir = Path(run_dir) / "csv" if out_dir is None else Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for vehicle, vehicle_logs in logs.items():
        header, columns = ["time"], [times]
        vocabulary = vehicle_vocabulary(vehicles[vehicle]) if vehicle in vehicles else None
        for name, signal in vehicle_signals(vehicle, vehicle_logs, vocabulary).items():
            header.append(name)
            columns.append(signal.values)
            if not signal.fresh.all():
                header.append(f"{name}.fresh")
                columns.append(signal.fresh.astype(int))
        path = out_dir / f"{vehicle}.csv"
        with path.open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(header)
            writer.writerows(zip(*(column.tolist() for column in columns), strict=True))
        written.append(path)
    return written
