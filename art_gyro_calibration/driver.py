"""The serial gyro driver: reads frames of any protocol on its own thread and stamps them (no ROS).

The reader thread owns the port: it opens it, reads what is available, parses and
stamps frames, and when the port is missing or disappears (unplugged) it closes it,
reports the loss and retries until the port is back. Callbacks run on that thread.

Stamps follow the gyro, not the reads: frame times are kept on the monotonic clock (the
arrival of the chunk less its time on the wire, frames of one chunk spaced by the gyro's own
period, estimated from the stream) and put on the caller's clock (wall or ROS time) by its
offset from the monotonic clock. A step of that clock (set by hand, NTP, a simulation reset)
re-anchors the stamps to it once, with a warning, instead of freezing them or spreading it.
"""

from __future__ import annotations

import math
import os
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import serial

from art_gyro_calibration.frame import LOCK_FRAMES, Frame, RawSample
from art_gyro_calibration.frame_guard import FrameGuard
from art_gyro_calibration.protocols import KVH_BAUDS, KvhFogConfig, make_parser
from art_gyro_calibration.stamper import STAMP_STEP_NS, UnitClock, WireStamper, held_after, wire_byte_ns

STANDARD_BAUDS = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)
# Every rate the driver opens: the standard ones and a KVH unit's (576000, 4147200: pyserial sets them on Linux).
BAUDS = tuple(sorted(set(STANDARD_BAUDS) | set(KVH_BAUDS)))
# A read returns after this long without data: bounds how late stop() and an unplug are seen.
READ_TIMEOUT_S = 0.1
# The most one read takes: all a port's buffer holds (a Linux tty's is 4 KiB), so a backlog comes in one read.
READ_BYTES = 4096
# After the port opens, this long without a valid frame means the wrong baud rate or protocol (or no gyro).
NO_FRAMES_WARNING_S = 2.0
# Once frames came: more than this share of the bytes of a NO_FRAMES_WARNING_S window skipped (garbage, bad or
# unlocked frames) is warned once, until the share is back under half of it: a baud or protocol changed, or a
# link that corrupts bytes. A correct link skips almost none (the lock's first frames after a reopen).
BAD_SHARE_WARNING = 0.5
# A port that stays missing (or unreadable) is reported again this often while the driver retries it.
LINK_DOWN_REPEAT_S = 10.0


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
    measured_rate_hz: float | None = None   # frames per second as the parser measures them (kvh_fog), else None
    garbage_runs: int = 0   # runs of bytes that were no message, where not counted as rejected messages (kvh_fog)
    stamp_source: str = 'arrival'   # where the latest stamps came from: arrival, or unit_clock (kvh_fog Format B)


class SerialGyroDriver:
    """Reads a gyro of any protocol on ``port``, calling ``on_frame`` for every valid frame (on the reader thread)."""

    def __init__(self, port: str, baud: int, protocol: str, on_frame: Callable[[Frame], None], *,
                 clock_ns: Callable[[], int] = time.time_ns, reopen_period_s: float = 0.5,
                 on_link: Callable[[bool, str], None] | None = None, kvh_fog: KvhFogConfig | None = None,
                 on_warning: Callable[[str], None] | None = None,
                 monotonic_ns: Callable[[], int] = time.monotonic_ns, rate_scale_dps: float | None = None,
                 guard_look_ahead: bool = False) -> None:
        """``clock_ns`` is the stamps' clock; ``on_warning`` hears of clock steps and of no frames after an open.

        ``rate_scale_dps`` (deg/s per count, the calibration's rate_scale_factor) turns on the frame guard
        (:class:`~art_gyro_calibration.frame_guard.FrameGuard`) of the protocols whose description asks for it (the
        RD2100's; kvh_fog is left to its CRC-32); None: no guard. ``guard_look_ahead``: the guard also refuses
        one-frame spikes, each frame delivered when the next one comes (a frame of latency; at a read that times
        out, or a close, the frame held is delivered).
        """
        if not isinstance(port, str) or not port:
            raise ValueError(f'port must be a device path such as /dev/ttyUSB0, got {port!r}')
        if baud not in BAUDS:
            raise ValueError(f'baud {baud!r} is not a standard rate nor a KVH unit\'s: '
                             f'one of {", ".join(map(str, BAUDS))}')
        if not (isinstance(reopen_period_s, (int, float)) and math.isfinite(reopen_period_s) and reopen_period_s > 0):
            raise ValueError(f'reopen_period_s must be a positive number of seconds, got {reopen_period_s!r}')
        # A frame is trusted once the stream is locked.
        self._parser = make_parser(protocol, kvh_fog, LOCK_FRAMES, wire_byte_ns(baud))
        if rate_scale_dps is not None and not (isinstance(rate_scale_dps, (int, float))
                                               and math.isfinite(rate_scale_dps) and rate_scale_dps > 0):
            raise ValueError(f'rate_scale_dps must be a positive number of deg/s per count, got {rate_scale_dps!r}')
        self._stamper = WireStamper(baud, self._parser.frame_bytes)
        description = self._parser.description
        self._guard = (FrameGuard(description.corrupt_rate_steps, description.continuous_temperature, guard_look_ahead)
                       if rate_scale_dps is not None and description.checks_rate_jumps else None)
        self._look_ahead = guard_look_ahead and self._guard is not None
        self._held: Frame | None = None   # with look-ahead: the last frame passed, until the next one says
        self.port = port
        self.baud = baud
        self.protocol = protocol
        self._on_frame = on_frame
        self._on_link = on_link
        self._on_warning = on_warning
        self._clock_ns = clock_ns
        self._monotonic_ns = monotonic_ns
        self._opened_ns = 0            # monotonic time of the last open
        self._frames_at_open = 0
        self._quiet_warned = False
        self._share_warned = False
        self._window_ns = 0            # the byte-share window: when it started, bytes read, skipped before it
        self._window_bytes = 0
        self._window_skipped = 0
        self._window_startup = 0       # start-up rejections before the window
        self._down_since_ns = 0        # monotonic time the link went down, and of its last report
        self._down_said_ns = 0
        self._reopen_period_s = float(reopen_period_s)
        self._too_fast_said = False
        # Samples stamped by the unit's clock (kvh_fog Format B's) mapped onto the monotonic clock.
        self._unit_clock = UnitClock() if description.stamps_by_unit_clock else None
        self._clock_faults = 0
        self._stamp_source = 'arrival'
        self._last_stamp = 0
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
        """Counters so far and whether the port is open now: ``frames`` those delivered."""
        p = self._parser.stats
        reasons = self._rejected_by_reason()
        return DriverStats(frames=self._delivered(), rejected=sum(reasons.values()), rejected_by_reason=reasons,
                           bytes_skipped=p.bytes_skipped, reopens=self._reopens, connected=self._connected,
                           last_error=self._last_error, port=self.port, lost_frames=p.lost_frames,
                           measured_rate_hz=self._parser.measured_rate_hz, garbage_runs=p.garbage_runs,
                           stamp_source=self._stamp_source)

    def _delivered(self) -> int:
        """Frames handed to ``on_frame`` (or being handed): the parser's, less those the frame guard refused."""
        return self._parser.stats.frames - (self._guard.rejected if self._guard is not None else 0)

    def _rejected_by_reason(self) -> dict[str, int]:
        """The parser's rejections by reason, and the frame guard's if it checks."""
        reasons = dict(self._parser.stats.rejected_by_reason)
        if self._guard is not None:
            reasons.update(self._guard.rejected_by_reason)
        return reasons

    def start(self) -> None:
        """Start the reader thread; returns at once, even if the port is missing (it retries)."""
        if self._thread is not None:
            raise RuntimeError('SerialGyroDriver already started')
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f'gyro {self.port}', daemon=True)
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
        self._stamper.restart()
        if self._guard is not None:
            self._guard.reset()
        if self._unit_clock is not None:
            self._unit_clock.reset()   # the unit's clock is read anew from 0: the mapping too
            self._stamp_source = 'arrival'
        self._opened_ns = self._monotonic_ns()
        self._frames_at_open = self._delivered()
        self._quiet_warned = False
        self._window_ns, self._window_bytes = self._opened_ns, 0
        self._window_skipped = self._parser.stats.bytes_skipped
        self._window_startup = self._startup_rejections()
        self._connected = True
        if self._ever_connected:
            self._reopens += 1
        self._ever_connected = True
        if self._on_link is not None:
            self._on_link(True, f'opened {self.port} at {self.baud} baud')
        return True

    def _close(self) -> None:
        self._release()
        port, self._serial, self._identity = self._serial, None, None
        self._connected = False
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass   # the device is already gone

    def _lost(self, reason: str) -> None:
        """Close and report a lost or missing port: at the loss, then every LINK_DOWN_REPEAT_S while it stays down."""
        was_up = self._connected or not self._ever_connected and not self._last_error
        self._last_error = reason
        self._close()
        now = self._monotonic_ns()
        if was_up:
            self._down_since_ns = now
        elif now - self._down_said_ns < LINK_DOWN_REPEAT_S * 1e9:
            return
        self._down_said_ns = now
        if self._on_link is not None:
            self._on_link(False, reason if was_up else f'{reason} (down {(now - self._down_since_ns) * 1e-9:.0f} s; '
                                                       f'retried every {self._reopen_period_s:g} s)')

    def _read_once(self) -> None:
        port = self._serial
        assert port is not None
        try:
            # One wait and one read of all that is there (the port is non-blocking): pyserial's read(1), in_waiting
            # and read(n) did the same in three calls and two waits (doc/benchmark.md: what it bought).
            fd = port.fileno()
            data = os.read(fd, READ_BYTES) if select.select([fd], [], [], READ_TIMEOUT_S)[0] else None
            if data == b'':   # readable with nothing to read: pyserial's sign of a device gone
                raise serial.SerialException('device reports readiness to read but returned no data '
                                             '(device disconnected or multiple access on port?)')
            before_ns = self._monotonic_ns()   # the offset of the two clocks is read between two monotonic reads
            now_ns = self._clock_ns()
            monotonic_ns = self._monotonic_ns()
        except BlockingIOError:   # woken with nothing to read after all
            return
        except (serial.SerialException, OSError) as e:
            if not self._stop.is_set():
                self._lost(f'read from {self.port} failed: {e}')
            return
        if not data:
            self._release()
            self._check_path()
            self._check_quiet(monotonic_ns)
            return
        self._on_data(data, now_ns, monotonic_ns, monotonic_ns - before_ns)

    def _release(self) -> None:
        """Deliver the frame the look-ahead holds, if any, without its next one."""
        held, self._held = self._held, None
        if held is not None:
            assert self._guard is not None
            self._guard.release()
            self._on_frame(held)

    def _on_data(self, data: bytes, now_ns: int, monotonic_ns: int, clock_read_ns: int) -> None:
        """One read's bytes, read at ``now_ns`` (stamps' clock, read in ``clock_read_ns`` before) and ``monotonic_ns``.

        Parsed, stamped, guarded.
        """
        frames = self._parser.feed(data, monotonic_ns)
        self._window_bytes += len(data)
        if monotonic_ns - self._window_ns >= NO_FRAMES_WARNING_S * 1e9:
            self._check_share(monotonic_ns)
        stamps = self._stamper.stamp(now_ns, monotonic_ns, len(data), [end for _, end in frames], clock_read_ns,
                                     self._parser.frames_missed)
        if self._stamper.too_fast and not self._too_fast_said:
            self._too_fast_said = True
            self._warn(self._stamper.too_fast)
        if self._stamper.step_ns:
            self._warn(f'the clock stepped by {self._stamper.step_ns * 1e-9:+.3f} s against the monotonic clock: '
                       'stamps re-anchored to it')
        if self._unit_clock is not None and frames:
            stamps = self._unit_clock_stamps(frames, stamps, monotonic_ns, len(data))
        guard, period_ns, on_frame = self._guard, self._stamper.period_ns, self._on_frame
        for (sample, _), (stamp, steady), missed in zip(frames, stamps, self._parser.frames_missed, strict=True):
            if guard is None:
                on_frame(Frame(sample, stamp, steady))
                continue
            held = self._held
            if held is not None:
                self._held = None
                if guard.confirm(sample.raw_rate, steady, period_ns, missed):
                    on_frame(held)
            if guard.passes(sample.raw_rate, sample.raw_temp, steady, period_ns, missed):
                if self._look_ahead:
                    self._held = Frame(sample, stamp, steady)
                else:
                    on_frame(Frame(sample, stamp, steady))
        if not frames:
            self._check_quiet(monotonic_ns)

    def _unit_clock_stamps(self, frames: list[tuple[RawSample, int]], stamps: list[tuple[int, int]],
                           monotonic_ns: int, chunk_bytes: int) -> list[tuple[int, int]]:
        """Stamps by Format B's clock once it is mapped (never after the arrival's, never back), else by arrival."""
        clock, faults = self._unit_clock, self._parser.stats.clock_faults
        assert clock is not None
        if faults != self._clock_faults:
            self._clock_faults = faults
            clock.reset()
            if self._stamp_source == 'unit_clock':
                self._warn('kvh_fog: the unit\'s clock went back or leapt: stamps by arrival until it is mapped again')
        sample, end = frames[-1]
        if sample.unit_time_us is not None:
            # As the stamper: the message's first byte left the unit its wire time before its last byte arrived.
            stamper = self._stamper
            clock.add(sample.unit_time_us, monotonic_ns - (chunk_bytes - end) * stamper.byte_ns - stamper.frame_ns)
        if not clock.ready:
            self._stamp_source = 'arrival'
            self._last_stamp = stamps[-1][0]
            return stamps
        self._stamp_source = 'unit_clock'
        offset, steps = self._stamper.offset_ns, self._stamper.steps_ns
        out = []
        for i, ((sample, _), (arrival, _steady)) in enumerate(zip(frames, stamps)):
            stamp = arrival
            if sample.unit_time_us is not None:
                stamp = clock.map(sample.unit_time_us) + offset
            if stamp < self._last_stamp + STAMP_STEP_NS and not self._stamper.step_ns:   # never back, but a clock step
                stamp = held_after(self._last_stamp, monotonic_ns + offset, len(frames) - i)
            self._last_stamp = stamp
            out.append((stamp, stamp - steps))
        return out

    def _warn(self, message: str) -> None:
        if self._on_warning is not None:
            self._on_warning(message)

    def _check_quiet(self, monotonic_ns: int) -> None:
        """Warn once per open when no frame came for NO_FRAMES_WARNING_S: say what did come and the likely cause."""
        stats = self._parser.stats
        if (self._quiet_warned or self._delivered() != self._frames_at_open
                or monotonic_ns - self._opened_ns < NO_FRAMES_WARNING_S * 1e9):
            return
        self._quiet_warned = True
        if startup := self._startup_rejections():   # messages that are right: the baud and protocol are
            self._warn(f'no frame from {self.port} yet, {NO_FRAMES_WARNING_S:g} s after opening it: {startup} '
                       f'valid messages came, held as a connection\'s first ({self._rejections()}), as a unit set '
                       'to a slow output rate does')
        elif stats.bytes_skipped:
            self._warn(f'no valid frame from {self.port} in {NO_FRAMES_WARNING_S:g} s after opening it; '
                       f'{stats.bytes_skipped} bytes skipped so far ({self._rejections()}): check the baud rate '
                       f'({self.baud}) and the protocol ({self.protocol}) against the gyro\'s settings')
        else:
            self._warn(f'nothing received from {self.port} in {NO_FRAMES_WARNING_S:g} s after opening it: '
                       'is the gyro powered and wired to this port?')

    def _check_share(self, monotonic_ns: int) -> None:
        """Warn once when, after frames came, most bytes of a window were no valid frame (re-armed on recovery)."""
        stats = self._parser.stats
        startup = self._startup_rejections()
        skipped = (stats.bytes_skipped - self._window_skipped
                   - (startup - self._window_startup) * self._parser.frame_bytes)
        share = min(1.0, max(skipped, 0) / self._window_bytes) if self._window_bytes else 0.0
        seconds = (monotonic_ns - self._window_ns) * 1e-9
        total = self._window_bytes
        self._window_ns, self._window_bytes, self._window_skipped = monotonic_ns, 0, stats.bytes_skipped
        self._window_startup = startup
        if self._delivered() == self._frames_at_open:
            return   # no frame since the open: _check_quiet says so
        if share > BAD_SHARE_WARNING and not self._share_warned:
            self._share_warned = True
            self._warn(f'{100 * share:.0f} % of the {total} bytes from {self.port} in the last {seconds:.1f} s were '
                       f'no valid frame ({self._rejections()}): check the baud rate ({self.baud}) and the '
                       f'protocol ({self.protocol}) against the gyro\'s settings, and the cable')
        elif share < BAD_SHARE_WARNING / 2:
            self._share_warned = False

    def _rejections(self) -> str:
        """The frames rejected so far by reason, for a warning; or that the bytes held no frame at all."""
        counts = [f'{count} {reason}' for reason, count in self._rejected_by_reason().items() if count]
        return f'rejected so far: {", ".join(counts)}' if counts else 'no frame found in them'

    def _startup_rejections(self) -> int:
        """Rejections so far of the kinds every connection makes at its start (the protocol's ``startup_rejections``).

        They are part of a correct link (a kvh_fog delta angle before its interval is measured), not of the bad share.
        """
        reasons = self._parser.stats.rejected_by_reason
        return sum(reasons.get(reason, 0) for reason in self._parser.description.startup_rejections)

    def _check_path(self) -> None:
        """A quiet port may be gone without a read error: its path vanished or now names another device."""
        try:
            st = os.stat(self.port)
        except OSError:
            self._lost(f'{self.port} disappeared')
            return
        if (st.st_dev, st.st_ino) != self._identity:
            self._lost(f'{self.port} now names another device')
