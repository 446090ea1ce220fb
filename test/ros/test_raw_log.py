"""The node's raw log under a full disk and a deleted directory, with the failures injected (no root tricks)."""

from __future__ import annotations

import errno
import shutil
import threading
import warnings
from pathlib import Path

import pytest

pytest.importorskip('rclpy')

from art_gyro_calibration.log import CutRowWarning, read_log  # noqa: E402
from art_gyro_calibration.ros import raw_log  # noqa: E402
from art_gyro_calibration.ros.raw_log import RawLog  # noqa: E402


class FakeNode:
    """What RawLog uses of a node: a logger and a timer (called by hand here)."""

    def __init__(self) -> None:
        self.errors: list[str] = []
        self.retry = None

    def get_logger(self) -> FakeNode:
        return self

    def info(self, message: str) -> None:
        pass

    def error(self, message: str) -> None:
        self.errors.append(message)

    def create_timer(self, period: float, callback) -> None:
        self.retry = callback


class Disk:
    """Files whose flush writes half of what is pending and fails with ENOSPC while ``full``."""

    def __init__(self) -> None:
        self.full = False

    def open(self, path, mode='r', **kwargs):
        real = open(path, mode, **kwargs)
        return real if 'b' in mode else FullDiskFile(self, real)


class FullDiskFile:
    def __init__(self, disk: Disk, real) -> None:
        self._disk, self._real, self._pending = disk, real, ''

    def write(self, text: str) -> int:
        self._pending += text
        return len(text)

    def flush(self) -> None:
        if self._disk.full:
            cut, self._pending = self._pending[:len(self._pending) // 2 + 3], ''   # whole rows, then a cut one
            self._real.write(cut)
            self._real.flush()
            raise OSError(errno.ENOSPC, 'No space left on device')
        self._real.write(self._pending)
        self._pending = ''
        self._real.flush()

    def close(self) -> None:
        try:
            self.flush()
        finally:
            self._real.close()

    def fileno(self) -> int:
        return self._real.fileno()


def _log(tmp_path: Path, log_path: Path, monkeypatch) -> tuple[RawLog, FakeNode, Disk]:
    disk = Disk()
    monkeypatch.setattr(raw_log, 'open', disk.open, raising=False)
    node = FakeNode()
    return RawLog(node, str(log_path), 'NAVC3545', threading.Event()), node, disk


def _read(path: Path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        log = read_log(path, 0.00305, 0.05)
    return log, [w for w in caught if issubclass(w.category, CutRowWarning)]


@pytest.mark.parametrize('as_directory', [True, False], ids=['directory', 'file'])
def test_a_full_disk_loses_counted_rows_only_and_logging_resumes(tmp_path, monkeypatch, as_directory):
    """Disk full: a file ending mid-row, an empty file every 5 s, lost rows uncounted, a file path never resumed."""
    path = tmp_path / 'logs' if as_directory else tmp_path / 'raw.csv'
    if as_directory:
        path.mkdir()
    log, node, disk = _log(tmp_path, path, monkeypatch)
    t = iter(range(1, 100_000))
    for _ in range(150):
        log.write(float(next(t)), 10, 500)
    disk.full = True
    for _ in range(50):   # the 200th row's flush fails half-way: rows 101..150 land, 151 is cut, 152..200 lost
        log.write(float(next(t)), 10, 500)
    assert not log.state().logging and log.state().rows_not_logged == 50
    for _ in range(30):
        log.write(float(next(t)), 10, 500)
    for _ in range(3):
        node.retry()
    assert log.state().rows_not_logged == 80 and len(node.errors) == 1
    files = sorted(path.iterdir()) if as_directory else [path]
    assert len(files) == 1   # no empty file per retry
    disk.full = False
    node.retry()
    assert log.state().logging
    for _ in range(10):
        log.write(float(next(t)), 10, 500)
    log.close()
    if as_directory:
        first, second = sorted(path.iterdir())
        rows, cut = _read(first)
        assert len(rows) == 150 and len(cut) == 1   # the row cut mid-way: dropped, said
        rows, cut = _read(second)
        assert len(rows) == 10 and not cut
    else:
        rows, cut = _read(path)   # continued after its last whole row: one readable log
        assert len(rows) == 160 and not cut
        assert rows.t[:150].tolist() == [float(i) for i in range(1, 151)] and rows.t[150] == 231.0


def test_a_deleted_log_directory_is_made_again_as_a_directory(tmp_path, monkeypatch):
    """The directory removed mid-run: the node created a regular file at its path, and the next start exited 1."""
    path = tmp_path / 'logs'
    path.mkdir()
    log, node, _ = _log(tmp_path, path, monkeypatch)
    log.write(1.0, 10, 500)
    shutil.rmtree(path)
    log.check_file()
    assert not log.state().logging
    node.retry()
    log.write(2.0, 10, 500)
    log.close()
    assert path.is_dir() and len(list(path.glob('NAVC3545_*.csv'))) == 1
