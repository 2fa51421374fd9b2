"""Per-run logs as CSV, for pandas and spreadsheets: one file per vehicle.

Each file has a ``time`` column (s, the 5 ms log samples) and one column per named signal of
that vehicle (``Quad.Pos.X``, ``Quad.Est.E.Yaw`` ..., the names the criteria use), in the
order :func:`quad_drake.judging.signals.vehicle_signals` defines them. A sensor signal that is held
between measurements also gets a ``<name>.fresh`` column (1 on samples carrying a new
measurement, else 0). Numbers are written exactly (shortest round-trip repr; ``nan`` where
a value does not exist yet). ``units.json`` beside them gives each file's column units
({file name: {column: unit}}, ``signals.signal_unit``; "" for flags, counts and NIS).
"""

import csv
from pathlib import Path

from ..config.loader import load_scenario
from ..estimation.registry import vehicle_vocabulary
from ..judging.signals import signal_unit, vehicle_signals
from .jsonio import dump_json
from .results import load_logs

UNITS_FILE = "units.json"


def export_csv(run_dir, out_dir=None) -> list[Path]:
    """Write ``<vehicle>.csv`` per vehicle of the run folder `run_dir` (which holds logs.npz)
    and their columns' units (UNITS_FILE) into `out_dir` (default: ``run_dir/csv``); returns
    the paths written, the units last."""
    times, logs = load_logs(run_dir)
    config = Path(run_dir) / "config.yaml"
    vehicles = {v.name: v for v in load_scenario(config).vehicles} if config.is_file() else {}
    out_dir = Path(run_dir) / "csv" if out_dir is None else Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written, units = [], {}
    for vehicle, vehicle_logs in logs.items():
        header, columns = ["time"], [times]
        path = out_dir / f"{vehicle}.csv"
        column_units = units[path.name] = {"time": "s"}
        vocabulary = vehicle_vocabulary(vehicles[vehicle]) if vehicle in vehicles else None
        for name, signal in vehicle_signals(vehicle, vehicle_logs, vocabulary).items():
            header.append(name)
            columns.append(signal.values)
            column_units[name] = signal_unit(name)
            if not signal.fresh.all():
                header.append(f"{name}.fresh")
                columns.append(signal.fresh.astype(int))
                column_units[f"{name}.fresh"] = ""
        with path.open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(header)
            writer.writerows(zip(*(column.tolist() for column in columns), strict=True))
        written.append(path)
    dump_json(out_dir / UNITS_FILE, units)
    return [*written, out_dir / UNITS_FILE]
