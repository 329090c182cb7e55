"""Progress of long work, one interface for every command and function.

The ``progress=`` argument of the front door's functions (:mod:`orchestration.api`:
``simulate``, ``stability``, ``design``, ``sweep``, ``build_fmus``) takes, everywhere:

* ``False`` (the default) or ``None``: silent;
* ``True``: a bar on stderr (:class:`Progress`);
* a callable ``progress(fraction, label)``: ``fraction`` is the share of the whole call's work
  done, a float from 0 to 1 that never decreases and whose last value is 1.0 when the work
  completes; ``label`` a str naming what is being done now (``"flexible_pd: stiffened rung
  (3 of 4)"``, ``"building PDLowPass (native, FMI 2.0): compiling linux64"``).

Anything else is a TypeError naming the argument (:func:`sink_for`).

Work without a natural fraction is counted in parts (:class:`Steps`: the rungs of a climb, the
FMUs of a build, the models compared), each part reporting its own fraction within its share.

On a terminal a bar redraws one line (a new line when its label changes); otherwise it prints a
line at each quarter and one whenever its label changes. A bar shows only once the work has
lasted :func:`delay_seconds` (1 s; the environment variable ``FLEXPEND_PROGRESS_DELAY`` sets
another, ``0`` shows every bar at once). :func:`~orchestration.notes.quiet` silences every bar
and every note (``flexpend --quiet``); errors and warnings are not progress and are not
silenced."""
from __future__ import annotations

import inspect
import math
import os
import shutil
import sys
import time

from ..notes import is_quiet, note, quiet

__all__ = ["Progress", "Steps", "sink_for", "check_progress", "delay_seconds", "quiet",
           "is_quiet", "note", "DELAY_ENV"]

#: The environment variable of the seconds a bar waits before it shows.
DELAY_ENV = "FLEXPEND_PROGRESS_DELAY"

#: The delay when the environment does not set one (s).
DEFAULT_DELAY = 1.0

def delay_seconds() -> float:
    """The seconds a bar waits before it shows: ``FLEXPEND_PROGRESS_DELAY`` when it is a finite
    number >= 0, else 1."""
    text = os.environ.get(DELAY_ENV)
    try:
        value = float(text) if text is not None else DEFAULT_DELAY
    except ValueError:
        return DEFAULT_DELAY
    return value if math.isfinite(value) and value >= 0 else DEFAULT_DELAY


class Progress:
    """A progress bar on stderr, shown once the work has lasted ``delay`` seconds (default
    :func:`delay_seconds`), silent within :func:`quiet`. Called as ``bar(fraction,
    label=None)``: a label changes the bar's.

    On a terminal it redraws one line, and starts a new one when its label changes; otherwise
    it prints a line at each quarter and one when its label changes."""

    def __init__(self, label: str, stream=None, delay: float | None = None):
        self.label, self.stream = label, stream or sys.stderr
        self.delay = delay_seconds() if delay is None else delay
        self.start = time.perf_counter()
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.shown = False             # a terminal line is open
        self.said = None               # the label of the last line written (not a terminal)
        self.last_quarter = 0
        self.width = 0
        self._last = -math.inf
        self.complete = False          # 100 % shown

    def close(self):
        """End the bar's line early (a run that stopped before the end)."""
        if self.tty and self.shown:
            self.stream.write("\n")
            self.stream.flush()
            self.shown = False

    def _line(self, fraction: float, elapsed: float, columns: int) -> str:
        """The terminal's line, within ``columns``: the label first (the rung, the model), then
        the bar, the percentage, the time and the time left, the bar narrowed, then the time
        left dropped, then the label cut, as the width asks."""
        eta = elapsed * (1 - fraction) / max(fraction, 1e-9)
        left = f", ~{eta:.1f} s left" if 0.01 <= fraction < 1.0 else ""
        for width, time_left in ((30, left), (20, left), (10, left), (10, "")):
            n = int(width * fraction)
            tail = (f" [{'#' * n}{'.' * (width - n)}] {100 * fraction:5.1f} % {elapsed:.1f} s"
                    f"{time_left} ")
            if len(self.label) + len(tail) <= columns:
                return self.label + tail
        room = max(columns - len(tail), 4)
        return self.label[:room - 3] + "..." + tail

    def __call__(self, fraction: float, label: str | None = None):
        if is_quiet():
            return
        changed = label is not None and label != self.label
        if changed:
            self.label = label
        elapsed = time.perf_counter() - self.start
        if elapsed < self.delay or self.complete:     # after 100 %: nothing more to show
            return
        fraction = min(max(float(fraction), 0.0), 1.0)
        self.complete = fraction >= 1.0
        if self.tty:
            if changed and self.shown:
                self.stream.write("\n")
                self.shown, self.width = False, 0
            if fraction < 1.0 and not changed and elapsed - self._last < 0.1:
                return
            self._last = elapsed
            text = self._line(fraction, elapsed, shutil.get_terminal_size().columns - 1)
            self.stream.write("\r" + text + " " * max(0, self.width - len(text)))
            self.width = len(text)
            self.shown = True
            if fraction >= 1.0:
                self.stream.write("\n")
                self.shown, self.width = False, 0
            self.stream.flush()
        else:
            quarter = int(fraction * 4)
            if quarter > self.last_quarter:
                self.last_quarter = quarter
                self.stream.write(f"{self.label}: {25 * quarter} % after {elapsed:.1f} s\n")
                self.said = self.label
            elif self.label != self.said:
                self.stream.write(f"{self.label}: {int(100 * fraction)} % after "
                                  f"{elapsed:.1f} s\n")
                self.said = self.label
            else:
                return
            self.stream.flush()


class _Sink:
    """What :func:`sink_for` gives: ``sink(fraction, label=None)`` passes the fraction on to
    ``target(fraction, label)``, never less than before and at most 1, with the label of the
    last call that named one; calls that change less than 0.1 % are not passed on."""

    def __init__(self, target, label: str):
        self.target, self.label = target, label
        self.fraction, self.sent = 0.0, None

    def __call__(self, fraction: float, label: str | None = None):
        f = float(fraction)
        f = self.fraction if math.isnan(f) else min(max(f, self.fraction), 1.0)
        if label is not None:
            self.label = label
        self.fraction = f
        if self.sent is not None:
            sent_f, sent_label = self.sent
            if sent_label == self.label and (f == sent_f or (f < 1.0 and f - sent_f < 1e-3)):
                return
        self.sent = (f, self.label)
        self.target(f, self.label)

    def finish(self, label: str | None = None):
        """The work is done: 1.0."""
        self(1.0, label)

    def close(self):
        """End a bar's line early (work that stopped before its end)."""
        close = getattr(self.target, "close", None)
        if close is not None:
            close()


def _takes_two(fn) -> bool:
    """Whether ``fn`` can be called as ``fn(fraction, label)`` (True when Python cannot tell)."""
    try:
        inspect.signature(fn).bind(0.0, "")
    except TypeError:
        return False
    except ValueError:
        return True
    return True


def check_progress(progress, argument: str = "progress") -> None:
    """A TypeError naming ``argument`` unless ``progress`` is ``True``, ``False``, ``None`` or a
    callable ``progress(fraction, label)`` (see the module's docstring)."""
    if progress is None or isinstance(progress, (bool, _Sink)):
        return
    if not callable(progress) or not _takes_two(progress):
        raise TypeError(f"{argument} must be True, False or a callable progress(fraction, "
                        f"label), got {progress!r}")


def sink_for(progress, label: str, argument: str = "progress"):
    """What reports the progress of a call: ``None`` for ``False``/``None`` (silent), a sink
    that draws a :class:`Progress` bar labelled ``label`` for ``True``, or one that calls the
    callable ``progress(fraction, label)`` (see the module's docstring). A sink is called as
    ``sink(fraction, label=None)`` and has ``finish()`` and ``close()``; a sink given is
    returned as it is. A TypeError naming ``argument`` for anything else."""
    check_progress(progress, argument)
    if progress is None or progress is False:
        return None
    if isinstance(progress, _Sink):
        return progress
    if progress is True:
        return _Sink(Progress(label), label)
    return _Sink(progress, label)


class Steps:
    """One long computation in parts, reported to ``parent`` (``None``: nothing): a sink
    (:func:`sink_for`) or another part's callback, called as ``parent(fraction, label)``.

    ``total``: the parts' expected weight (e.g. the number of runs). :meth:`part` starts the
    next part and gives its callback, ``callback(fraction, label=None)``, that reports the
    fraction of that part done as its share of the whole, under the part's label or the label
    given (what a part's own parts name). Parts that are skipped (a climb that stops early)
    leave their share, which :meth:`finish` covers."""

    def __init__(self, parent, total: float):
        self.parent, self.total, self.done = parent, max(float(total), 1e-12), 0.0

    def part(self, weight: float, label: str):
        """The callback of the next part, of ``weight`` (None without a parent)."""
        start = min(self.done, self.total)
        self.done += weight
        if self.parent is None:
            return None
        parent, total = self.parent, self.total
        span = max(0.0, min(weight, total - start))
        parent(start / total, label)

        def report(fraction, label_now=None):
            f = float(fraction)
            f = 0.0 if math.isnan(f) else min(max(f, 0.0), 1.0)
            parent((start + f * span) / total, label_now or label)
        return report

    def finish(self, label: str | None = None):
        """The whole is done: 1.0."""
        if self.parent is not None:
            self.parent(1.0, label) if label is not None else self.parent(1.0)
