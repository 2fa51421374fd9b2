"""Progress of one long flight on stderr: a tqdm bar over the simulated seconds on a terminal,
elsewhere (a log, a pipe) a plain line every tenth of the flight, so no ``\\r`` lands in logs.
``simulation.run(scenario, progress=FlightProgress(...))`` calls it as the flight advances."""

import sys
import time

LONG_FLIGHT_S = 60.0
"""s of simulated time from which the command line shows a single run's progress."""


class FlightProgress:
    """Callable progress(t) of a flight of `end_time` s (t: simulated s)."""

    def __init__(self, label, end_time, stream=None):
        self.label, self.end_time = label, float(end_time)
        self.stream = stream or sys.stderr
        self.start = time.perf_counter()
        terminal = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.bar = None
        if terminal:
            from tqdm import tqdm  # only a terminal draws a bar: a run without one never loads tqdm

            self.bar = tqdm(total=self.end_time, desc=label, unit="sim s", file=self.stream, bar_format=None)
        self.shown = 0.0  # s, simulated time at the last update
        self.tenths = 0

    def __call__(self, t):
        if self.bar is not None:
            self.bar.update(t - self.shown)
        elif int(10 * t / self.end_time) > self.tenths:
            self.tenths = int(10 * t / self.end_time)
            elapsed = time.perf_counter() - self.start
            eta = elapsed / t * (self.end_time - t) if t > 0 else float("nan")
            self.stream.write(
                f"{self.label}: {t:.0f} of {self.end_time:g} s simulated, {elapsed:.0f} s, ETA {eta:.0f} s\n"
            )
            self.stream.flush()
        self.shown = t

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
