"""Watching a run while it goes.

A *watch* is any callable ``watch(time, steps) -> bool`` that a run calls at every row it records,
with the simulated time (s) and the steps taken so far; returning False stops the run there (its
result then ends at that row and says where it stopped). ``TerminalWatch`` is the command line's:
a progress line on a terminal, and Ctrl-C as a request to stop at the next row.
"""

from __future__ import annotations

import signal
import sys
import threading
import time as clock
from typing import Callable

from tqdm import tqdm

__all__ = ["Watch", "TerminalWatch"]

Watch = Callable[[float, int], bool]


class TerminalWatch:
    """Progress of a run to ``stop_time`` (s) on standard error, and Ctrl-C as a request to stop it.

    The line shows the simulated time, the steps, the speed (simulated s per wall s) and the time
    left, updated in place from a second into the run; it is drawn only on a terminal and not with
    ``quiet``, so pipes, logs and CI get no carriage returns. A run that, ``FORECAST_AFTER`` seconds
    in, looks like taking more than ``LONG`` seconds more gets one line (on any stream, unless
    ``quiet``) with the steps and the time it will take at that pace, and ``hint`` (how to get there
    faster). Inside the ``with`` block (on the main thread), the first Ctrl-C stops the run at its next
    recorded row (``interrupted`` is then True); a second one raises KeyboardInterrupt at once, as
    Python does by default.

    Parameters
    ----------
    stop_time : float
        The run's stop time in s.
    label : str, optional
        The line's label (the scenario's name). Default "run".
    quiet : bool, optional
        No progress line and no forecast. Default False.
    hint : str, optional
        How to get there faster, added to the forecast.
    stream : file-like, optional
        Where to write; standard error by default.
    """

    SHOW_AFTER = 1.0  # s of wall time before the line appears
    FORECAST_AFTER = 2.0  # s of wall time
    LONG = 30.0  # s of wall time still to go

    def __init__(self, stop_time: float, label: str = "run", quiet: bool = False, hint: str = "", stream=None):
        self.stop_time = stop_time
        self.label = label
        self.hint = hint
        self.stream = stream or sys.stderr
        self.shown = not quiet and getattr(self.stream, "isatty", lambda: False)()
        self.interrupted = False
        self._bar = None
        self._handler = None
        self._last = 0.0
        self._started = None  # the first call: building and loading the FMUs do not count
        self._forecast_due = not quiet

    def __enter__(self) -> TerminalWatch:
        if threading.current_thread() is threading.main_thread():
            self._handler = signal.signal(signal.SIGINT, self._interrupt)
        return self

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.close()
        if self._handler is not None:
            signal.signal(signal.SIGINT, self._handler)

    def _interrupt(self, number, frame) -> None:
        if self.interrupted:
            raise KeyboardInterrupt
        self.interrupted = True

    def _forecast(self, time: float, steps: int, now: float) -> None:
        """Once, a few seconds in: the steps and the wall time of the whole run at this pace, if long."""
        elapsed = now - self._started
        if elapsed < self.FORECAST_AFTER or time <= 0.0:
            return
        self._forecast_due = False
        total = elapsed * self.stop_time / time
        if total - elapsed > self.LONG:
            line = (f"dsc-fmu: at this pace the run takes about {steps * self.stop_time / time:,.0f} steps and "
                    f"{_duration(total)} in all ({time:.3g} of {self.stop_time:g} s simulated in "
                    f"{_duration(elapsed)}){'; ' + self.hint if self.hint else ''}")
            (self._bar.write if self._bar is not None else print)(line, file=self.stream)

    def __call__(self, time: float, steps: int) -> bool:
        if self._started is None:
            self._started = clock.monotonic()
            if self.shown:
                self._bar = tqdm(total=self.stop_time, desc=self.label, file=self.stream, delay=self.SHOW_AFTER,
                                 leave=False, mininterval=0, dynamic_ncols=True, unit="s",
                                 bar_format="{desc}: t = {n:.3f}/{total:g} s |{bar}| {postfix} [{rate_fmt}, "
                                            "{remaining} left]")
        if self._forecast_due or self._bar is not None:
            now = clock.monotonic()
            if self._forecast_due:
                self._forecast(time, steps, now)
            if self._bar is not None and (now - self._last >= 0.2 or time >= self.stop_time):
                self._last = now
                self._bar.set_postfix_str(f"{steps} steps", refresh=False)
                self._bar.update(time - self._bar.n)
        return not self.interrupted or time <= 0.0  # a stopped run has a row past its start


def _duration(seconds: float) -> str:
    """``seconds`` as a person says it: 45 s, 6.5 min, 2.1 h."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"
