"""``quad-drake export``: a run's logs as one CSV per vehicle, exactly what the signals hold."""

import csv
import json
import math

import numpy as np

from quad_drake.output.export import export_csv
from quad_drake.output.results import load_logs, signals_from_logs, variant_name


def read_csv(path):
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], np.array(rows[1:], dtype=float)


def test_one_csv_per_vehicle_time_first_every_signal_exact(gps_run_dir, tmp_path):
    path, units_path = export_csv(gps_run_dir, tmp_path / "csv")
    assert (path.name, units_path.name) == ("Quad.csv", "units.json")
    header, table = read_csv(path)
    times, logs = load_logs(gps_run_dir)
    signals = signals_from_logs(logs)
    assert header[0] == "time" and table.shape == (times.size, len(header))
    np.testing.assert_array_equal(table[:, 0], times)
    assert set(signals) <= set(header)
    for name, signal in signals.items():
        column = table[:, header.index(name)]
        np.testing.assert_array_equal(column, signal.values)  # NaN where no estimate exists: equal
        if name + ".fresh" in header:
            np.testing.assert_array_equal(table[:, header.index(name + ".fresh")], signal.fresh)
        else:
            assert signal.fresh.all()
    # the GPS (10 Hz) is held between samples on the 5 ms log: its fresh column says when it is new
    fresh = table[:, header.index("Quad.GPS.X.fresh")]
    assert 0 < fresh.sum() < 0.1 * fresh.size
    assert math.isclose(table[-1, 0], 3.0)
    units = json.loads(units_path.read_text())["Quad.csv"]
    assert list(units) == header  # every column, in order
    assert (units["time"], units["Quad.Pos.X"], units["Quad.GPS.X.fresh"]) == ("s", "m", "")
    assert (units["Quad.IMU.AX"], units["Quad.IMU.GZ"], units["Quad.Est.E.Yaw"]) == ("m/s^2", "rad/s", "rad")


def test_a_fleet_gets_a_file_per_vehicle(quad_drake_cli, tmp_path):
    out = tmp_path / "out"
    run = quad_drake_cli("run", "09_predict_covariance", "--set", "end_time=0.1", "--no-plots", "--out", out)
    assert run.returncode in (0, 1), run.stderr
    run_dir = out / variant_name("09_predict_covariance", None, ["end_time=0.1"])
    exported = quad_drake_cli("export", run_dir)
    assert exported.returncode == 0, exported.stderr
    paths = exported.stdout.split()
    assert len(paths) == 11 and paths[0].endswith(f"{run_dir.name}/csv/Quad1.csv")
    assert paths[-1].endswith("csv/units.json")
    header, table = read_csv(run_dir / "csv" / "Quad10.csv")
    assert header[:2] == ["time", "Quad10.Pos.X"] and table.shape[0] == 20
