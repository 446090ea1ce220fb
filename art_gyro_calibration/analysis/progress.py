"""Progress of long work on a terminal: one line on stderr, rewritten in place; nothing in scripts.

A line is shown only when its stream is a terminal (``isatty``), so pipes, logs and tests see
nothing. :class:`Progress` follows work whose amount is known (a bar and the time left) or counted;
:class:`Ticker` shows the time spent on work that reports nothing, once it has lasted a few seconds.
Anything else written to the stream meanwhile goes through :func:`clear` first, so that it starts a line.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import TextIO

# Rewrites at most this often (s), and a ticker appears only after its work has taken this long.
UPDATE_S = 0.5
TICKER_AFTER_S = 2.0
_CLEAR_LINE = '\r\x1b[K'
# The streams a progress line is on now, and whose line it is: a Progress's line is not overwritten by a Ticker's
# (``calibrate fit --still`` shows the still record's bar within the fit's ticker).
_shown: dict[TextIO, object] = {}


def terminal(stream: TextIO | None) -> TextIO | None:
    """``stream`` (stderr when None) if it is a terminal, else None."""
    stream = sys.stderr if stream is None else stream
    return stream if stream.isatty() else None


def clear() -> None:
    """Wipe the progress line, if one is shown, for a message to take its place (the next update redraws it)."""
    for stream in _shown:
        stream.write(_CLEAR_LINE)
        stream.flush()
    _shown.clear()


def _show(stream: TextIO, text: str, owner: object, yields: bool = False) -> None:
    """Write ``owner``'s line; one that ``yields`` (a ticker) waits while another's is shown."""
    if yields and _shown.get(stream, owner) is not owner:
        return
    _shown[stream] = owner
    stream.write(_CLEAR_LINE + text)
    stream.flush()


def _end(stream: TextIO, owner: object) -> None:
    """End ``owner``'s line, if it is the one shown."""
    if _shown.get(stream) is owner:
        del _shown[stream]
        stream.write('\n')
        stream.flush()


class Progress:
    """A progress line for work of ``total`` units (a bar and the time left), or a count when ``total`` is None."""

    def __init__(self, stream: TextIO | None, total: float | None, label: str) -> None:
        self._stream = terminal(stream)
        self._total, self._label = total, label
        self._start = self._last = time.monotonic()

    def update(self, done: float, unit: str = 'samples', note: str = '') -> None:
        """Say that ``done`` units are done (at most every UPDATE_S); ``note`` is added to the line."""
        if self._stream is None or time.monotonic() - self._last < UPDATE_S:
            return
        self._last = time.monotonic()
        elapsed = self._last - self._start
        if self._total:
            share = min(done / self._total, 1.0)
            bar = '#' * int(30 * share)
            eta = elapsed * (1.0 - share) / share if share > 0 else 0.0
            text = f'{self._label} [{bar:<30}] {100 * share:5.1f} % {elapsed:5.0f} s, {eta:4.0f} s left'
        else:
            text = f'{self._label} {done:.0f} {unit}, {elapsed:.0f} s'
        _show(self._stream, text + (f' {note}' if note else ''), self)

    def done(self) -> None:
        """End the line (if one was shown)."""
        if self._stream is not None:
            _end(self._stream, self)


class Ticker:
    """The time spent on work that reports no progress, shown from TICKER_AFTER_S on (a context manager)."""

    def __init__(self, label: str, stream: TextIO | None = None) -> None:
        self._stream = terminal(stream)
        self._label = label
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> Ticker:
        if self._stream is not None:
            self._thread = threading.Thread(target=self._run, args=(self._stream,), daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            assert self._stream is not None
            _end(self._stream, self)

    def _run(self, stream: TextIO) -> None:
        start = time.monotonic()
        if self._stop.wait(TICKER_AFTER_S):
            return
        while True:
            _show(stream, f'{self._label}: working, {time.monotonic() - start:.0f} s', self, yields=True)
            if self._stop.wait(UPDATE_S):
                return
