"""Progress of long steps: a tqdm bar on a terminal, plain periodic log lines otherwise.

One helper for every long loop outside training (world rendering, the evaluate stage's pairs,
``cmal-lcd match``): when stderr is a terminal, a tqdm bar (shown only after ``delay`` seconds,
so short loops stay silent, and removed when done); when it is not (``dvc repro``, a queued
experiment, a log file), an INFO line on the caller's logger at most every ``interval`` seconds
(one line, wrapped here)::

    INFO cmal_lcd.data.world.dataset: render route1/foggy: 320/600 frames (53%),
        41.2 frames/s, about 7 s left

Use as a context manager::

    with Progress(total=len(frames), desc="render", unit="frame", logger=logger) as bar:
        for batch in batches:
            ...
            bar.update(len(batch))
"""

from __future__ import annotations

import logging
import sys
import time
from typing import IO, Callable

#: Seconds between two plain log lines when stderr is not a terminal.
LOG_INTERVAL_S = 30.0
#: Seconds before a terminal bar appears (shorter loops show nothing).
BAR_DELAY_S = 2.0


def stderr_is_terminal(stream: IO | None = None) -> bool:
    """Whether ``stream`` (default ``sys.stderr``) is an interactive terminal."""
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # closed or replaced by an object without isatty
        return False


class Progress:
    """Progress of one loop of ``total`` units.

    Parameters
    ----------
    total : int
        Units of work (frames, pairs, queries).
    desc : str
        What is being done, first on the bar or log line.
    unit : str
        Name of one unit, plural in the log lines (``"frame"`` -> ``"frames"``).
    logger : logging.Logger, optional
        Where the plain lines go (default ``cmal_lcd.progress``).
    terminal : bool, optional
        Force the bar (True) or the log lines (False); default: whether stderr is a terminal.
    interval : float
        Seconds between two log lines.
    clock : callable, optional
        Monotonic clock in seconds (tests pass a fake one).
    """

    def __init__(self, total: int, *, desc: str, unit: str = "it",
                 logger: logging.Logger | None = None, terminal: bool | None = None,
                 interval: float = LOG_INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.total = max(0, int(total))
        self.desc = desc
        self.unit = unit
        self.n = 0
        self._logger = logger or logging.getLogger(__name__)
        self._interval = float(interval)
        self._clock = clock
        self._start = clock()
        self._last_log = self._start
        self._bar = None
        if stderr_is_terminal() if terminal is None else terminal:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=self.total, desc=desc, unit=unit, file=sys.stderr,
                             leave=False, delay=BAR_DELAY_S, dynamic_ncols=True)

    def update(self, n: int = 1) -> None:
        """Count ``n`` more units done; logs a line when ``interval`` has passed since the last."""
        self.n += int(n)
        if self._bar is not None:
            self._bar.update(n)
            return
        now = self._clock()
        if now - self._last_log >= self._interval:
            self._last_log = now
            self._logger.info("%s", self.line(now))

    def line(self, now: float | None = None) -> str:
        """The plain progress line: done/total, percentage, rate and time left."""
        now = self._clock() if now is None else now
        elapsed = max(now - self._start, 1e-9)
        rate = self.n / elapsed
        units = self.unit if self.unit.endswith("s") else f"{self.unit}s"
        text = f"{self.desc}: {self.n}/{self.total} {units}"
        if self.total:
            text += f" ({100.0 * self.n / self.total:.0f}%)"
        text += f", {rate:.3g} {units}/s"
        if rate > 0 and self.total > self.n:
            text += f", about {_duration((self.total - self.n) / rate)} left"
        return text

    def close(self) -> None:
        """Remove the bar (the caller logs its own summary)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"
