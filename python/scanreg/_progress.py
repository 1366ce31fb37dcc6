"""A dependency-free progress bar for long command-line work.

Writes to stderr (stdout stays clean for ``--json``): done/total, items per second, ETA and
caller-supplied counters::

    odometry  42/100 [########------------]  42% 12.3 frames/s ETA 0:05 accepted=41 rejected=1

On a terminal the line is redrawn in place (at most every ``redraw_interval`` seconds); when
the stream is not a terminal (a log file, CI) a plain line is printed every
``line_interval`` seconds and at the end; disabled (``--quiet``, or ``--json`` output), it
writes nothing.

>>> with Progress(total=len(seq), description="odometry", unit="frames") as bar:
...     for frame in seq:
...         ...
...         bar.update(accepted=n_ok, rejected=n_bad)
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import TextIO, TypeVar

T = TypeVar("T")

BAR_WIDTH = 20


def format_duration(seconds: float | None) -> str:
    """``m:ss`` or ``h:mm:ss``; ``?`` when unknown."""
    if seconds is None or seconds != seconds or seconds in (float("inf"), float("-inf")):
        return "?"
    s = max(0, round(seconds))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


def _format_counter(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


class Progress:
    """A progress line on ``stream`` (default: ``sys.stderr`` at construction).

    Parameters
    ----------
    total : int or None
        Number of items; None when unknown (no bar, no ETA).
    description : str
        Shown first.
    unit : str
        Items' name in the rate (``frames/s``).
    enabled : bool
        False: write nothing at all.
    redraw_interval : float
        Seconds between in-place redraws on a terminal.
    line_interval : float
        Seconds between plain lines when the stream is not a terminal.
    clock : callable
        Monotonic seconds (injectable for tests).
    """

    def __init__(
        self,
        total: int | None = None,
        *,
        description: str = "",
        unit: str = "it",
        stream: TextIO | None = None,
        enabled: bool = True,
        redraw_interval: float = 0.1,
        line_interval: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if total is not None and (isinstance(total, bool) or total < 0):
            raise ValueError(f"total: must be None or >= 0, got {total!r}")
        self.total = total
        self.description = description
        self.unit = unit
        self.stream: TextIO = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.redraw_interval = redraw_interval
        self.line_interval = line_interval
        self._clock = clock
        self._start = clock()
        self._last_draw: float | None = None
        self.done = 0
        self.counters: dict[str, object] = {}
        self._closed = False
        self._width = 0
        try:
            self.tty = bool(self.stream.isatty())
        except (AttributeError, ValueError):  # closed or minimal streams
            self.tty = False

    # ----------------------------------------------------------------- state
    @property
    def elapsed(self) -> float:
        return self._clock() - self._start

    @property
    def rate(self) -> float | None:
        """Items per second so far (None before the first item)."""
        elapsed = self.elapsed
        return self.done / elapsed if self.done and elapsed > 0 else None

    @property
    def eta(self) -> float | None:
        """Seconds left at the average rate so far (None when unknown)."""
        rate = self.rate
        if self.total is None or rate is None:
            return None
        return max(self.total - self.done, 0) / rate

    def line(self) -> str:
        """The progress text (without carriage return or newline)."""
        parts = [self.description] if self.description else []
        if self.total:
            frac = min(self.done / self.total, 1.0)
            filled = round(frac * BAR_WIDTH)
            width = len(str(self.total))
            parts.append(f"{self.done:>{width}}/{self.total}")
            parts.append("[" + "#" * filled + "-" * (BAR_WIDTH - filled) + "]")
            parts.append(f"{100 * frac:3.0f}%")
        else:
            parts.append(f"{self.done}" + (f"/{self.total}" if self.total is not None else ""))
        rate = self.rate
        parts.append(f"{rate:.1f} {self.unit}/s" if rate is not None else f"? {self.unit}/s")
        if self._closed:
            parts.append(f"in {format_duration(self.elapsed)}")
        elif self.total is not None:
            parts.append(f"ETA {format_duration(self.eta)}")
        parts.extend(f"{k}={_format_counter(v)}" for k, v in self.counters.items())
        return " ".join(parts)

    # ----------------------------------------------------------------- updates
    def update(self, n: int = 1, **counters: object) -> None:
        """``n`` more items done; ``counters`` (e.g. ``accepted=98``) replace shown values."""
        self.done += n
        self.counters.update(counters)
        self._maybe_draw()

    def set_counters(self, **counters: object) -> None:
        """Change the shown counters without counting an item."""
        self.counters.update(counters)
        self._maybe_draw()

    def _maybe_draw(self) -> None:
        if not self.enabled or self._closed:
            return
        now = self._clock()
        interval = self.redraw_interval if self.tty else self.line_interval
        # first draw immediately on a terminal; a log gets its first line after the interval
        if self._last_draw is None:
            due = self.tty or now - self._start >= interval
        else:
            due = now - self._last_draw >= interval
        if due:
            self._draw()
            self._last_draw = now

    def _draw(self, final: bool = False) -> None:
        text = self.line()
        if self.tty:
            pad = " " * max(self._width - len(text), 0)
            self.stream.write("\r" + text + pad + ("\n" if final else ""))
            self._width = len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        """Draw the final line (once)."""
        if self._closed:
            return
        self._closed = True
        if self.enabled:
            self._draw(final=True)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def track(
    items: Iterable[T],
    *,
    total: int | None = None,
    description: str = "",
    unit: str = "it",
    enabled: bool = True,
    stream: TextIO | None = None,
) -> Iterator[T]:
    """Yield ``items``, counting each on a :class:`Progress` (``total``: ``len(items)`` when
    it has one)."""
    if total is None:
        try:
            total = len(items)  # type: ignore[arg-type]
        except TypeError:
            total = None
    with Progress(total, description=description, unit=unit, enabled=enabled, stream=stream) as bar:
        for item in items:
            yield item
            bar.update()
