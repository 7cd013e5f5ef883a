"""Progress of a long analysis on a terminal: simulated time, steps, rate, ETA.

The contract between an analysis and whoever runs it (the CLI) is one optional callable:

1. An analysis accepts ``options["progress"]``: ``None`` (the default, nothing happens) or a
   callable ``progress(t, t_end)``, ``t`` the simulated time just reached (s) and ``t_end`` the
   end time of the run (s).
2. The analysis takes the callable out of its options (``opt.pop("progress", None)``) before
   it stores them in ``Result.settings``: a callable is not a setting and has no place in the
   HDF5 file.
3. It calls ``progress(t, t_end)`` once after each *output* step has been recorded (not per
   internal integrator step or Newton iteration), with non-decreasing ``t``; the first call
   may be at ``t_start``. It ignores the return value. The callable is cheap (it rate-limits
   its own writing), so calling it every output step costs nothing measurable.
4. An exception raised by the callable propagates, except ``KeyboardInterrupt`` (Ctrl-C on
   the terminal): the kinematic, inverse and dynamic analyses end the run there as
   ``incomplete`` and return what they recorded, as they do on a Ctrl-C anywhere in the loop.
5. The analysis never prints: drawing, rate limiting and cleaning up the line are the
   callable's business, and the caller closes it when the analysis returns.

:class:`Progress` is the terminal implementation the CLI uses; :func:`terminal_progress`
decides whether to show one at all (only when the stream is a terminal, unless forced).
"""

from __future__ import annotations

import sys
import time
from typing import Callable, TextIO

TTY_INTERVAL = 0.2  # s between updates on a terminal (at most 5 updates a second)
LINE_INTERVAL = 5.0  # s between lines when forced onto a stream that is not a terminal


def format_duration(seconds: float) -> str:
    """``m:ss`` below an hour, ``h:mm:ss`` above; ``--:--`` when unknown."""
    if not seconds >= 0 or seconds == float("inf"):
        return "--:--"
    s = int(round(seconds))
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class Progress:
    """A ``progress(t, t_end)`` callable that draws one status line on `stream`.

    The line reads ``kinematic  t = 0.42 / 1 s  42%  85 steps  170 steps/s  ETA 0:01``:
    simulated time, fraction done, output steps so far, output steps per wall-clock second
    and the estimated time left, ``(wall time since the first call) x (t_end - t) /
    (t - t_first)`` (the rate so far, in simulated seconds, holds for the rest).

    On a terminal (``tty``) each update overwrites the line with a carriage return, at most
    one every `min_interval` seconds; :meth:`close` blanks the line so that what the caller
    prints next starts clean. Otherwise each update is its own line.

    Parameters
    ----------
    stream : text stream written to (the CLI passes ``sys.stderr``).
    label : text in front of the line, e.g. the analysis mode.
    tty : carriage-return updates (default: ``stream.isatty()``).
    min_interval : s between updates (default 0.2 on a terminal, 5 otherwise).
    clock : monotonic clock in seconds (tests pass a fake one).
    """

    def __init__(self, stream: TextIO, label: str = "", tty: bool | None = None,
                 min_interval: float | None = None,
                 clock: Callable[[], float] = time.monotonic):  # fmt: skip
        self.stream = stream
        self.label = label
        self.tty = _isatty(stream) if tty is None else bool(tty)
        self.min_interval = (TTY_INTERVAL if self.tty else LINE_INTERVAL) \
            if min_interval is None else float(min_interval)
        self.clock = clock
        self.steps = 0  # calls so far (output steps)
        self.t_first: float | None = None  # simulated time of the first call, s
        self.wall_first = 0.0  # clock at the first call, s
        self.last_write: float | None = None  # clock at the last update written, s
        self.width = 0  # length of the line on screen (tty), to blank it
        self.updates = 0  # updates written

    def __call__(self, t: float, t_end: float) -> None:
        now = self.clock()
        self.steps += 1
        if self.t_first is None:
            self.t_first, self.wall_first = float(t), now
            return
        since = now - (self.wall_first if self.last_write is None else self.last_write)
        if since < self.min_interval:
            return  # rate limit; a run shorter than min_interval draws nothing
        self.last_write = now
        self._write(self.line(float(t), float(t_end), now))

    def line(self, t: float, t_end: float, now: float) -> str:
        """The status text for simulated time `t` of `t_end` at clock `now`."""
        elapsed = now - self.wall_first
        done = t - (self.t_first or 0.0)
        span = t_end - (self.t_first or 0.0)
        frac = min(max(done / span, 0.0), 1.0) if span > 0 else 1.0
        rate = (self.steps - 1) / elapsed if elapsed > 0 else float("nan")
        eta = elapsed * (t_end - t) / done if done > 0 else float("nan")
        head = f"{self.label}  " if self.label else ""
        return (f"{head}t = {t:.4g} / {t_end:.4g} s  {100 * frac:3.0f}%  {self.steps} steps  "
                f"{rate:.3g} steps/s  ETA {format_duration(eta)}")

    def _write(self, text: str) -> None:
        if self.tty:
            pad = " " * max(self.width - len(text), 0)
            self.stream.write("\r" + text + pad)
            self.width = len(text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
        self.updates += 1

    def close(self) -> None:
        """Blank the status line (terminal); safe to call more than once."""
        if self.tty and self.width:
            self.stream.write("\r" + " " * self.width + "\r")
            self.stream.flush()
            self.width = 0


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


def terminal_progress(stream: TextIO | None = None, enabled: bool | None = None,
                      label: str = "") -> Progress | None:  # fmt: skip
    """A :class:`Progress` for `stream` (default ``sys.stderr``), or None for no progress.

    `enabled` None (automatic) shows progress only when `stream` is a terminal; False never;
    True always (a stream that is not a terminal gets a plain line every few seconds).
    """
    stream = sys.stderr if stream is None else stream
    if enabled is False or (enabled is None and not _isatty(stream)):
        return None
    return Progress(stream, label=label)


__all__ = ["Progress", "format_duration", "terminal_progress"]
