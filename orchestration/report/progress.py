"""Progress on the terminal: a bar for one long computation (a run, a design, a model choice)."""
from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """A progress bar on stderr, shown once a run has lasted a second.

    On a terminal it redraws one line; otherwise it prints a line at each quarter."""

    def __init__(self, label: str, stream=None, delay: float = 1.0):
        self.label, self.stream, self.delay = label, stream or sys.stderr, delay
        self.start = time.perf_counter()
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.shown = False
        self.last_quarter = 0

    def close(self):
        """End the bar's line early (a run that stopped before the end)."""
        if self.tty and self.shown:
            self.stream.write("\n")
            self.stream.flush()
            self.shown = False

    def __call__(self, fraction: float):
        elapsed = time.perf_counter() - self.start
        if elapsed < self.delay:
            return
        if self.tty:
            if fraction < 1.0 and elapsed - getattr(self, "_last", 0.0) < 0.1:
                return
            self._last = elapsed
            n = int(30 * fraction)
            eta = elapsed * (1 - fraction) / max(fraction, 1e-9)
            self.stream.write(f"\r{self.label} [{'#' * n}{'.' * (30 - n)}] {100 * fraction:5.1f} % "
                              f"{elapsed:6.1f} s, ~{eta:5.1f} s left ")
            self.shown = True
            if fraction >= 1.0:
                self.stream.write("\n")
                self.shown = False
            self.stream.flush()
        else:
            quarter = int(fraction * 4)
            if quarter > self.last_quarter:
                self.last_quarter = quarter
                self.stream.write(f"{self.label}: {25 * quarter} % after {elapsed:.1f} s\n")
                self.stream.flush()
