"""Progress of the long commands (``areasearch run``, ``render``, ``eval``, ``train``) on stderr.

On a terminal, :class:`Progress` keeps one self-overwriting line (carriage returns): a bar, done /
total, the rate and the ETA. Anywhere else (``2> log``, a pipe, a batch system's log file) it writes
plain lines, no carriage return: one at most every ``interval_s`` seconds (10) and one at the end,
so a log holds a readable record rather than thousands of frames.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TextIO

BAR_WIDTH = 24


class Progress:
    """Progress of ``total`` units of work, ``done`` of them finished before this reporter started.

    ``stream`` None reports nothing. ``interval_s`` is the least time between two plain lines;
    ``clock`` gives seconds (tests pass a fake one). Rate and ETA count the units done since the
    start of this reporter, so a resumed run's ETA is that of the rest.
    """

    def __init__(
        self,
        label: str,
        total: int,
        unit: str,
        stream: TextIO | None,
        *,
        done: int = 0,
        rate_unit: str | None = None,
        interval_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.label, self.total, self.unit = label, total, unit
        self.rate_unit = rate_unit or f"{unit}/s"
        self.done = self.start_done = done
        self.stream = stream
        self.terminal = _is_terminal(stream)
        self.interval_s = interval_s
        self.clock = clock
        self.t0 = self._last = clock()
        self._closed = False
        self._width = 0  # of the longest terminal frame so far
        self._lined: int | None = None  # units done at the last plain line
        if self.terminal:
            self._frame()

    def advance(self, n: int = 1) -> None:
        """``n`` more units are done."""
        self.update(self.done + n)

    def update(self, done: int) -> None:
        """``done`` units are done in all; on a terminal redraw the line, else a line when one is due."""
        self.done = done
        if self.stream is None or self._closed:
            return
        if self.terminal:
            self._frame()
        elif self.clock() - self._last >= self.interval_s:
            self._line()

    def clear(self) -> None:
        """On a terminal, blank the line (before other output goes to the same terminal)."""
        if self.stream is not None and self.terminal and not self._closed:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()

    def close(self) -> None:
        """The last report: the final state, ending the terminal line, or a final plain line."""
        if self.stream is None or self._closed:
            return
        if self.terminal:
            self._frame()
            self.stream.write("\n")
            self.stream.flush()
        elif self._lined != self.done:  # unless the last plain line said as much
            self._line()
        self._closed = True

    def text(self) -> str:
        """The report without bar: done / total, rate, elapsed time, ETA."""
        elapsed = self.clock() - self.t0
        ran = self.done - self.start_done
        rate = ran / elapsed if elapsed > 0 and ran > 0 else 0.0
        eta = duration((self.total - self.done) / rate) if rate else "?"
        shown = f"{rate:.1f}" if rate >= 10 else f"{rate:.2f}"
        return (
            f"{self.done:,}/{self.total:,} {self.unit}  {shown} {self.rate_unit}  "
            f"elapsed {duration(elapsed)}  ETA {eta}"
        )

    def _frame(self) -> None:
        assert self.stream is not None
        filled = int(BAR_WIDTH * min(self.done, self.total) / max(1, self.total))
        bar = "#" * filled + "." * (BAR_WIDTH - filled)
        frame = f"{self.label} [{bar}] {self.text()}"
        self._width = max(self._width, len(frame))
        self.stream.write("\r" + frame.ljust(self._width))  # padded over a longer earlier frame
        self.stream.flush()

    def _line(self) -> None:
        assert self.stream is not None
        percent = 100.0 * self.done / max(1, self.total)
        self.stream.write(f"{self.label}: {self.text()}  ({percent:.0f} %)\n")
        self.stream.flush()
        self._last, self._lined = self.clock(), self.done


def _is_terminal(stream: TextIO | None) -> bool:
    if stream is None:
        return False
    try:
        return bool(stream.isatty())
    except (ValueError, AttributeError):  # a closed stream, or an object without isatty
        return False


def duration(seconds: float, *, hours: bool = False) -> str:
    """``1h02m03s`` / ``2m03s``: a duration for people; ``hours`` shows them also when 0 (``0h02m03s``,
    the fixed width of ``areasearch train``'s line per iteration)."""
    seconds = int(round(max(0.0, seconds)))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h or hours else f"{m}m{s:02d}s"
