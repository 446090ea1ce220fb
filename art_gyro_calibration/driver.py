"""The RD2100 serial driver: reads frames on its own thread and stamps them (no ROS).

The reader thread owns the port: it opens it, reads what is available, parses and
stamps frames, and when the port is missing or disappears (unplugged) it closes it,
reports the loss and retries until the port is back. Callbacks run on that thread.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import serial

from art_gyro_calibration.frame import KvhFogConfig, RawSample, make_parser

STANDARD_BAUDS = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)
# A read returns after this long without data: bounds how late stop() and an unplug are seen.
READ_TIMEOUT_S = 0.1
BITS_PER_BYTE = 10   # start + 8 data + stop


@dataclass(frozen=True, slots=True)
class Frame:
    """A sample and its stamp: host time its first byte left the gyro, estimated; never decreasing."""

    sample: RawSample
    stamp_ns: int


@dataclass(frozen=True, slots=True)
class DriverStats:
    """A snapshot of the driver's counters and link state."""

    frames: int
    rejected: int
    rejected_by_reason: dict[str, int]
    bytes_skipped: int
    reopens: int
    connected: bool
    last_error: str
    port: str
    lost_frames: int = 0   # numbered by the gyro but never received whole (kvh_fog sequence gaps)


class WireStamper:
    """Host stamps of frames from the time a read returned, corrected for time on the wire, never decreasing."""

    __slots__ = ('byte_ns', 'frame_ns', 'last_ns')

    def __init__(self, baud: int, frame_bytes: int) -> None:
        self.byte_ns = BITS_PER_BYTE * 1_000_000_000 // baud
        self.frame_ns = frame_bytes * self.byte_ns
        self.last_ns = -1

    def stamp(self, read_ns: int, chunk_bytes: int, end: int) -> int:
        """Stamp of the frame ending at offset ``end`` of a chunk of ``chunk_bytes`` whose read returned at ``read_ns``.

        The read returned when the chunk's last byte arrived; the frame's first byte left
        the gyro the wire time of the frame and of every byte after it in the chunk earlier.
        """
        stamp = read_ns - (chunk_bytes - end) * self.byte_ns - self.frame_ns
        if stamp < self.last_ns:   # a late read must not put a frame before the previous one
            stamp = self.last_ns
        self.last_ns = stamp
        return stamp


class Rd2100Driver:
    """Reads an RD2100 on ``port``, calling ``on_frame`` for every valid frame (on the reader thread)."""

    def __init__(self, port: str, baud: int, protocol: str, on_frame: Callable[[Frame], None], *,
                 clock_ns: Callable[[], int] = time.time_ns, reopen_period_s: float = 0.5,
                 on_link: Callable[[bool, str], None] | None = None, kvh_fog: KvhFogConfig | None = None) -> None:
        if not isinstance(port, str) or not port:
            raise ValueError(f'port must be a device path such as /dev/ttyUSB0, got {port!r}')
        if baud not in STANDARD_BAUDS:
            raise ValueError(f'baud {baud!r} is not a standard rate: one of {", ".join(map(str, STANDARD_BAUDS))}')
        if not (isinstance(reopen_period_s, (int, float)) and math.isfinite(reopen_period_s) and reopen_period_s > 0):
            raise ValueError(f'reopen_period_s must be a positive number of seconds, got {reopen_period_s!r}')
        self._parser = make_parser(protocol, kvh_fog)
        self.port = port
        self.baud = baud
        self.protocol = protocol
        self._on_frame = on_frame
        self._on_link = on_link
        self._clock_ns = clock_ns
        self._reopen_period_s = float(reopen_period_s)
        self._stamper = WireStamper(baud, self._parser.frame_bytes)
        self._serial: serial.Serial | None = None
        self._identity: tuple[int, int] | None = None   # (st_dev, st_ino) of the open device
        self._connected = False
        self._ever_connected = False
        self._reopens = 0
        self._last_error = ''
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def stats(self) -> DriverStats:
        """Counters so far and whether the port is open now."""
        p = self._parser.stats
        return DriverStats(frames=p.frames, rejected=p.rejected, rejected_by_reason=dict(p.rejected_by_reason),
                           bytes_skipped=p.bytes_skipped, reopens=self._reopens, connected=self._connected,
                           last_error=self._last_error, port=self.port, lost_frames=p.lost_frames)

    def start(self) -> None:
        """Start the reader thread; returns at once, even if the port is missing (it retries)."""
        if self._thread is not None:
            raise RuntimeError('Rd2100Driver already started')
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f'rd2100 {self.port}', daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the reader thread and close the port (seen within READ_TIMEOUT_S)."""
        # The reader thread alone touches the port: a cancel_read() from here could race its
        # close() (pyserial then writes to a closed, possibly reused, descriptor).
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise RuntimeError(f'reader thread of {self.port} did not stop within {timeout_s} s')
            self._thread = None

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if self._serial is None and not self._open():
                    self._stop.wait(self._reopen_period_s)
                    continue
                self._read_once()
        except Exception as e:
            # A callback raised: the thread ends, so say why in the stats before the traceback.
            self._last_error = f'reader thread stopped: {type(e).__name__}: {e}'
            raise
        finally:
            self._close()

    def _open(self) -> bool:
        try:
            port = serial.Serial(self.port, self.baud, timeout=READ_TIMEOUT_S, exclusive=True)
            st = os.fstat(port.fileno())
        except (serial.SerialException, OSError, ValueError) as e:
            self._lost(f'cannot open {self.port}: {e}')
            return False
        self._serial, self._identity = port, (st.st_dev, st.st_ino)
        self._parser.reset()
        self._connected = True
        if self._ever_connected:
            self._reopens += 1
        self._ever_connected = True
        if self._on_link is not None:
            self._on_link(True, f'opened {self.port} at {self.baud} baud')
        return True

    def _close(self) -> None:
        port, self._serial, self._identity = self._serial, None, None
        self._connected = False
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass   # the device is already gone

    def _lost(self, reason: str) -> None:
        """Close and report a lost or missing port, once per loss (not on every retry)."""
        was_up = self._connected or not self._ever_connected and not self._last_error
        self._last_error = reason
        self._close()
        if was_up and self._on_link is not None:
            self._on_link(False, reason)

    def _read_once(self) -> None:
        port = self._serial
        assert port is not None
        try:
            data = port.read(1)
            if data:
                waiting = port.in_waiting
                if waiting:
                    data += port.read(waiting)
            now_ns = self._clock_ns()
        except (serial.SerialException, OSError) as e:
            if not self._stop.is_set():
                self._lost(f'read from {self.port} failed: {e}')
            return
        if not data:
            self._check_path()
            return
        frames = self._parser.feed(data)
        size = len(data)
        stamp = self._stamper.stamp
        for sample, end in frames:
            self._on_frame(Frame(sample, stamp(now_ns, size, end)))

    def _check_path(self) -> None:
        """A quiet port may be gone without a read error: its path vanished or now names another device."""
        try:
            st = os.stat(self.port)
        except OSError:
            self._lost(f'{self.port} disappeared')
            return
        if (st.st_dev, st.st_ino) != self._identity:
            self._lost(f'{self.port} now names another device')
