"""Watching a run while it goes.

A *watch* (``Watch``) is any callable ``watch(time, steps) -> bool`` that a run calls at every row it records,
with the simulated time (s) and the steps so far; returning False stops the run there (its result then ends
at that row and says where it stopped). ``TerminalWatch`` is the command line's; ``ProgressLine`` its line,
which a sweep shows too."""

from __future__ import annotations

import os
import signal
import sys
import threading
import time as clock
from typing import Callable

__all__ = ["Watch"]

Watch = Callable[[float, int], bool]


class TerminalWatch:
    """Progress of a run to ``stop_time`` (s) on standard error, and Ctrl-C as a request to stop it.

    The line (simulated time, steps, speed, time left) is drawn from ``SHOW_AFTER`` s into the run, only on a
    terminal and not with ``quiet``. A run that ``FORECAST_AFTER`` s in looks like taking more than ``LONG`` s
    more gets one line (on any stream, unless ``quiet``) with its steps and duration at that pace, and ``hint``.
    Inside the ``with`` block (on the main thread) the first Ctrl-C stops the run at its next row
    (``interrupted``); a second raises KeyboardInterrupt at once."""

    SHOW_AFTER = 1.0  # s of wall time before the line appears
    FORECAST_AFTER = 2.0  # s of wall time
    LONG = 30.0  # s of wall time still to go

    def __init__(self, stop_time: float, label: str = "run", quiet: bool = False, hint: str = "", stream=None):
        self.stop_time = stop_time
        self.label = label
        self.hint = hint
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.interrupted = False
        self._handler = None
        self._line = None  # made at the first call: building and loading the FMUs do not count
        self._forecast_due = not quiet

    def __enter__(self) -> TerminalWatch:
        if threading.current_thread() is threading.main_thread():
            self._handler = signal.signal(signal.SIGINT, self._interrupt)
        return self

    def __exit__(self, *exc) -> None:
        if self._line is not None:
            self._line.close()
        if self._handler is not None:
            signal.signal(signal.SIGINT, self._handler)

    def _interrupt(self, number, frame) -> None:
        if self.interrupted:
            raise KeyboardInterrupt
        self.interrupted = True

    def _forecast(self, time: float, steps: int, now: float) -> None:
        """Once, a few seconds in: the steps and the wall time of the whole run at this pace, if long."""
        elapsed = now - self._line.started
        if elapsed < self.FORECAST_AFTER or time <= 0.0:
            return
        self._forecast_due = False
        total = elapsed * self.stop_time / time
        if total - elapsed > self.LONG:
            line = (f"dsc-fmu: at this pace the run takes about {steps * self.stop_time / time:,.0f} steps and "
                    f"{_duration(total)} in all ({time:.3g} of {self.stop_time:g} s simulated in "
                    f"{_duration(elapsed)}){'; ' + self.hint if self.hint else ''}")
            self._line.write(line)

    def __call__(self, time: float, steps: int) -> bool:
        if self._line is None:
            self._line = ProgressLine(self.stop_time, self.label, "s", count="t = {done:.3f}/{total:g}",
                                      after=self.SHOW_AFTER, quiet=self.quiet, stream=self.stream)
        if self._forecast_due:
            self._forecast(time, steps, clock.monotonic())
        self._line.update(time - self._line.done, f"{steps} steps")
        return not self.interrupted or time <= 0.0  # a stopped run has a row past its start


class ProgressLine:
    """One line on a terminal, rewritten in place: ``label: done/total unit, note, speed, time left``.

    Drawn only on a terminal and not with ``quiet``, from ``after`` s on, at most every ``EVERY`` s, cut to the
    terminal's width (``COLUMNS`` if it does not say) less ``ROOM``, so that the "^C" a terminal echoes stays on
    the line; closing it clears it, "^C" included. Speed and time left are the average since it was made;
    ``count`` formats ``done`` and ``total``."""

    EVERY = 0.2  # s of wall time between two drawings
    COLUMNS = 80  # the width of a terminal that does not say
    ROOM = 3  # columns left free at the end: "^C" and the cursor

    def __init__(self, total: float, label: str, unit: str, count: str = "{done:.0f}/{total:g}", after: float = 0.0,
                 quiet: bool = False, stream=None):
        self.total, self.label, self.unit, self.count = total, label, unit, count
        self.stream = stream or sys.stderr
        self.shown = not quiet and getattr(self.stream, "isatty", lambda: False)()
        self.done = 0.0
        self.started = clock.monotonic()
        self._due = self.started + after
        self._width = 0  # of the line on the screen

    def __enter__(self) -> ProgressLine:
        self.update(0)
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, advance: float = 1, note: str = "") -> None:
        """Count ``advance`` (in ``unit``) more done and redraw the line, ``note`` after the count, if it is due."""
        self.done += advance
        if not self.shown:
            return
        now = clock.monotonic()
        if now < self._due:
            return
        self._due = now + self.EVERY
        parts = [f"{self.label}: {self.count.format(done=self.done, total=self.total)} {self.unit}"]
        if note:
            parts.append(note)
        if self.done > 0 and now > self.started:
            rate = self.done / (now - self.started)
            parts += [f"{rate:.3g} {self.unit}/s", f"{_duration((self.total - self.done) / rate)} left"]
        self._draw(", ".join(parts)[: self._columns() - self.ROOM])

    def write(self, line: str) -> None:
        """Write ``line`` as a line of its own; the progress line comes back below it at its next update."""
        self.close()
        print(line, file=self.stream, flush=True)
        self._due = min(self._due, clock.monotonic())

    def close(self) -> None:
        """Clear the line (if drawn) and the "^C" a terminal may have echoed after it, cursor at its start."""
        if self._width:
            self._draw(" " * (self._width + self.ROOM - 1))
            self.stream.write("\r")
            self.stream.flush()
            self._width = 0

    def _draw(self, text: str) -> None:
        """``text`` over the line, padded to what was there: ``_width`` is where the cursor stands."""
        text = text.ljust(self._width)
        self.stream.write("\r" + text)
        self.stream.flush()
        self._width = len(text)

    def _columns(self) -> int:
        try:
            return os.get_terminal_size(self.stream.fileno()).columns or self.COLUMNS
        except (AttributeError, ValueError, OSError):  # no file descriptor, or not a terminal
            return self.COLUMNS


def _duration(seconds: float) -> str:
    """``seconds`` as a person says it: 45 s, 6.5 min, 2.1 h."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"
