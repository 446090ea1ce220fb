"""The node's raw log (``log_path``): every frame received as ``t,raw_rate,raw_temp``, never at publishing's expense.

A write that fails (full disk) or a file deleted meanwhile stops logging with one console
error and an ERROR status; a new file is tried every :data:`LOG_RETRY_S`; the rows meanwhile
are counted, not logged, and so are the rows of the failed write not yet flushed. A ``log_path``
that is a file is continued after its last whole row; one that was a directory is made again
if deleted; a file that cannot take its header (the disk still full) is removed, not left empty.
"""

from __future__ import annotations

import os
import threading
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, NamedTuple

from rclpy.node import Node

from art_gyro_calibration.log import RawLogWriter
from art_gyro_calibration.ros.parameters import ParameterError
from art_gyro_calibration.ros.rclpy_typed import logger

# A raw log that failed (full disk, deleted) is reopened this often; frames meanwhile are not logged.
LOG_RETRY_S = 5.0


class RawLogState(NamedTuple):
    """One consistent look at the raw log, for its diagnostics status."""

    logging: bool
    file: str
    rows_not_logged: int
    last_error: str


class RawLog:
    """The raw log of a node whose ``log_path`` is set; with it empty, :meth:`write` does nothing."""

    def __init__(self, node: Node, log_path: str, serial_number: str, closing: threading.Event) -> None:
        """Open the log (a :class:`ParameterError` if it cannot be) and retry it on a timer of ``node``'s."""
        self._node = node
        self._log_path = log_path
        self._serial_number = serial_number
        self._closing = closing
        self._lock = threading.Lock()
        self._log: RawLogWriter | None = None
        self._stream: Any = None
        self._file = ''
        self._error = ''
        self._rows_lost = 0
        self._directory = bool(log_path) and Path(log_path).is_dir()   # at startup: made again if deleted
        if log_path:
            self._open(at_startup=True)
        node.create_timer(LOG_RETRY_S, self._retry)

    def _target(self) -> Path:
        path = Path(self._log_path)
        if self._directory:
            path.mkdir(parents=True, exist_ok=True)   # deleted while running: a directory again, not a file
            stamp = datetime.now(timezone.utc).strftime('%Y%m%dT%H%M%SZ')
            name = f'{self._serial_number}_{stamp}'
            path = path / f'{name}.csv'
            n = 1
            while path.exists():   # a second file within the same second (a retry)
                path, n = path.with_name(f'{name}_{n}.csv'), n + 1
        return path

    def _open(self, at_startup: bool = False) -> None:
        created = False
        path = Path(self._log_path)
        stream = None
        try:
            path = self._target()
            if not self._directory and not at_startup and path.is_file() and path.stat().st_size:
                _cut_to_last_line(path)   # the same file, after its last whole row
                stream = open(path, 'a', encoding='utf-8')
                writer = RawLogWriter(stream, header=False)
            else:
                stream = open(path, 'x', encoding='utf-8')
                created = True
                writer = RawLogWriter(stream)
            writer.flush()   # the header on disk now: a full disk fails here, not on the first rows
        except OSError as e:
            if stream is not None:   # the header did not fit
                try:
                    stream.close()   # its flush fails again; the file is closed all the same
                except OSError:
                    pass
            if created:   # no empty file every retry while the disk stays full
                try:
                    path.unlink()
                except OSError:
                    pass
            if at_startup:
                raise ParameterError(f'parameter log_path: cannot create {path}: {e.strerror}') from None
            self._error = f'cannot create {path}: {e.strerror or e}'
            return
        with self._lock:
            self._log, self._stream, self._file = writer, stream, str(path)
            self._error = ''
        logger(self._node).info(f'logging raw frames to {path}')

    def write(self, t: float, raw_rate: float, raw_temp: float) -> None:
        """Log one frame (the driver's reader thread, after publishing it)."""
        with self._lock:
            log = self._log
            if log is None:
                if self._log_path:
                    self._rows_lost += 1
                return
            try:
                log.write(t, raw_rate, raw_temp)
            except (OSError, ValueError) as e:
                # This row and those written since the last flush that succeeded: none of them is on disk whole.
                self._rows_lost += max(1, log.unwritten())
                self._stop(log, f'writing {self._file} failed: {e}')

    def _stop(self, log: RawLogWriter, error: str) -> None:
        """Stop logging to ``log`` after a failure (lock held): one console error, an ERROR status, a retry."""
        self._log = None
        self._error = error
        try:
            log.close()
        except (OSError, ValueError):
            pass   # the rows not flushed are lost with the file system that refused them
        logger(self._node).error(
            f'raw log stopped, publishing goes on: {error}; retrying every {LOG_RETRY_S:g} s')

    def check_file(self) -> None:
        """Stop logging to a file deleted (or replaced) while open, which would swallow every row without an error."""
        with self._lock:
            log = self._log
            if log is None:
                return
            try:
                same = os.path.samestat(os.stat(self._file), os.fstat(self._stream.fileno()))
            except OSError:
                same = False
            if not same:
                self._stop(log, f'{self._file} was deleted or replaced while logging')

    def _retry(self) -> None:
        if self._log_path and self._log is None and self._error and not self._closing.is_set():
            self._open()

    def state(self) -> RawLogState:
        """Whether it is logging, to which file, the rows lost and the last error."""
        with self._lock:
            return RawLogState(self._log is not None, self._file, self._rows_lost, self._error)

    def close(self) -> None:
        """Close the file; a row after this is not logged (the driver is stopped first)."""
        with self._lock:
            log, self._log = self._log, None
        if log is not None:
            try:
                log.close()
            except (OSError, ValueError) as e:
                logger(self._node).error(f'closing the raw log {self._file}: {e}')


def _cut_to_last_line(path: Path) -> None:
    """Cut a log after its last line end: a row a full disk left half-written is not continued into a wrong one."""
    with open(path, 'r+b') as f:
        keep = f.seek(0, os.SEEK_END)
        while keep > 0:
            start = max(0, keep - 4096)
            f.seek(start)
            end = f.read(keep - start).rfind(b'\n')
            if end >= 0:
                keep = start + end + 1
                break
            keep = start
        f.truncate(keep)
