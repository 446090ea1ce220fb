"""A simulated gyro (an RD2100 or a KVH FOG) on a real pseudo-terminal, with the errors of a calibrated gyro.

The physics (what the gyro reads for a true rate and temperature) is in
:class:`GyroSimulator`, pure and vectorised; :class:`FakeGyro` puts its samples on a
pty at a steady rate, can be unplugged and replugged, and can inject garbage.

A reading is ``measured_from_true(polynomial, true_rate, T) + turn_on_bias + earth_rate
+ white noise`` in deg/s, quantised to counts with the calibration's rate scale factor;
the temperature is ``round(T / temp_scale_factor)`` counts (the physics of
:mod:`art_gyro_calibration.gyro_physics`, shared with ``calibrate simulate``). Like the gyro, readings
saturate at the signed 16-bit count range (about +-100 deg/s at 0.00305 deg/s per count).
With ``protocol='kvh_fog'`` the fake is a KVH DSP-1760/1775 instead: the reading and the
temperature go unquantised into its float message, set as a :class:`KvhFogConfig` says, at the
fake's own output rate, numbered 0..127 in turn.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import signal
import sys
import threading
import time
import tty
from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from art_gyro_calibration.calibration import Calibration, load_packaged_calibration
from art_gyro_calibration.frame import INT16_MAX, INT16_MIN
from art_gyro_calibration.gyro_physics import (ANN_ARBOR_LATITUDE_DEG, earth_rate_dps, measured_from_true, to_counts,
                                               white_noise_dps)
from art_gyro_calibration.protocols import KVH_FOG, PROTOCOLS, make_encoder
from art_gyro_calibration.protocols.kvh_fog import (KVH_ANGLE_UNITS, KVH_FORMATS, KVH_ROTATIONS, KVH_TEMPERATURE_UNITS,
                                                    KvhFogConfig)

# White noise of an RD2100: 0.005 deg/s per sample at its 10 Hz output, as an angle random walk.
DEFAULT_ARW_DEG_RTHR = 0.005 * 60.0 / math.sqrt(10.0)
DEFAULT_TURN_ON_BIAS_SIGMA_DPS = 0.02
# Bytes a slow or absent reader may leave unsent before the fake drops them, as a
# real gyro's UART would: about a second of binary frames at 1 kHz.
MAX_PENDING_BYTES = 8192
# Its console scripts: the second is its name from before it simulated KVH units too.
CONSOLE_SCRIPTS = ('fake_gyro', 'fake_rd2100')


def default_noise_dps(rate_hz: float) -> float:
    """Per-sample noise at ``rate_hz`` of an RD2100: white noise of fixed density, so it grows as sqrt(rate)."""
    return white_noise_dps(DEFAULT_ARW_DEG_RTHR, rate_hz)


@dataclass(frozen=True)
class RateProfile:
    """True rate over time: piecewise-constant segments ``(duration_s, rate_dps)``, repeating."""

    segments: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        if not self.segments:
            raise ValueError('a rate profile needs at least one segment')
        for duration, rate in self.segments:
            if not (math.isfinite(duration) and duration > 0 and math.isfinite(rate)):
                raise ValueError(f'rate profile segment {duration}:{rate} needs a positive duration '
                                 'and a finite rate')

    @classmethod
    def parse(cls, text: str) -> RateProfile:
        """``'rate_dps'`` (constant) or ``'duration_s:rate_dps,...'`` (repeating)."""
        segments = []
        try:
            if ':' not in text:
                return cls(((1.0, float(text)),))
            for part in text.split(','):
                duration, rate = part.split(':')
                segments.append((float(duration), float(rate)))
        except ValueError:
            raise ValueError(f'rate profile {text!r}: expected a rate in deg/s or '
                             '"duration_s:rate_dps,..." segments') from None
        return cls(tuple(segments))

    def rate_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """True rate in deg/s at times ``t`` (seconds since start)."""
        durations = np.array([d for d, _ in self.segments])
        rates = np.array([r for _, r in self.segments])
        ends = np.cumsum(durations)
        phase = np.mod(np.asarray(t, dtype=float), ends[-1])
        return cast(NDArray[np.float64], rates[np.minimum(np.searchsorted(ends, phase, side='right'), len(rates) - 1)])


@dataclass(frozen=True)
class TemperatureProfile:
    """Temperature over time: ``start_c`` ramping linearly to ``end_c`` over ``ramp_s``, then held."""

    start_c: float
    end_c: float | None = None
    ramp_s: float = 0.0

    def __post_init__(self) -> None:
        if self.end_c is not None and not (math.isfinite(self.ramp_s) and self.ramp_s > 0):
            raise ValueError(f'a temperature ramp needs a positive duration, got {self.ramp_s}')

    @classmethod
    def parse_ramp(cls, text: str) -> TemperatureProfile:
        """``'start_c:end_c:ramp_s'``."""
        try:
            start, end, ramp = (float(v) for v in text.split(':'))
        except ValueError:
            raise ValueError(f'temperature ramp {text!r}: expected "start_c:end_c:ramp_s"') from None
        return cls(start, end, ramp)

    def temperature_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """Temperature in degC at times ``t``."""
        t = np.asarray(t, dtype=float)
        if self.end_c is None:
            return np.full(t.shape, self.start_c)
        return self.start_c + (self.end_c - self.start_c) * np.clip(t / self.ramp_s, 0.0, 1.0)


class GyroSimulator:
    """The readings of one calibrated gyro, in counts, for a rate and temperature profile."""

    def __init__(self, calibration: Calibration, profile: RateProfile, temperature: TemperatureProfile,
                 noise_dps: float, seed: int | None = None, turn_on_bias_dps: float | None = None,
                 latitude_deg: float = ANN_ARBOR_LATITUDE_DEG) -> None:
        if not (math.isfinite(noise_dps) and noise_dps >= 0):
            raise ValueError(f'noise must be a non-negative number of deg/s, got {noise_dps}')
        self.calibration = calibration
        self.profile = profile
        self.temperature = temperature
        self.noise_dps = noise_dps
        self._rng = np.random.default_rng(seed)
        self.turn_on_bias_dps = (float(self._rng.normal(0.0, DEFAULT_TURN_ON_BIAS_SIGMA_DPS))
                                 if turn_on_bias_dps is None else turn_on_bias_dps)
        self.earth_rate_dps = earth_rate_dps(latitude_deg)

    def reading_dps(self, true_rate_dps: ArrayLike, temp_c: ArrayLike) -> NDArray[np.float64]:
        """What the gyro reads, noise-free, in deg/s."""
        return (measured_from_true(self.calibration.polynomial, true_rate_dps, temp_c)
                + self.turn_on_bias_dps + self.earth_rate_dps)

    def readings(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """What the gyro reads (deg/s, with fresh noise) and its temperature (degC) at times ``t``."""
        t = np.asarray(t, dtype=float)
        temp = self.temperature.temperature_at(t)
        reading = self.reading_dps(self.profile.rate_at(t), temp)
        if self.noise_dps > 0:
            reading = reading + self._rng.normal(0.0, self.noise_dps, t.shape)
        return reading, temp

    def counts(self, t: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Raw (rate, temperature) counts at times ``t``, with fresh noise."""
        reading, temp = self.readings(t)
        # Like the gyro, saturated at the signed 16-bit count range.
        raw_rate = np.clip(to_counts(reading, self.calibration.rate_scale_factor), INT16_MIN, INT16_MAX)
        raw_temp = np.clip(to_counts(temp, self.calibration.temp_scale_factor), INT16_MIN, INT16_MAX)
        return raw_rate.astype(np.int64), raw_temp.astype(np.int64)


class FakeGyro:
    """A simulated gyro writing frames to a pseudo-terminal (an RD2100 by default); use as a context manager.

    With ``protocol='kvh_fog'`` it sends KVH messages set as ``kvh_fog`` says, except for the
    output rate, which is the fake's ``rate_hz``; ``last_sample`` is then (deg/s, degC).
    """

    def __init__(self, serial_number: str, protocol: str = 'binary', rate_hz: float = 10.0,
                 link: str | None = None, profile: RateProfile | str = '0',
                 temperature: TemperatureProfile | float = 25.0, noise_dps: float | None = None,
                 seed: int | None = None, turn_on_bias_dps: float | None = None,
                 kvh_fog: KvhFogConfig | None = None) -> None:
        if not (math.isfinite(rate_hz) and 0 < rate_hz <= 10000):
            raise ValueError(f'rate_hz must be in (0, 10000], got {rate_hz}')
        if link is not None and os.path.lexists(link) and not os.path.islink(link):
            raise ValueError(f'link {link} exists and is not a symlink: refusing to replace it')
        self.kvh_fog = (dataclasses.replace(kvh_fog or KvhFogConfig(), output_rate_hz=rate_hz)
                        if protocol == KVH_FOG else None)
        # Public, so that a test can corrupt what follows (a kvh_fog encoder's status byte, say).
        self.encoder = make_encoder(protocol, self.kvh_fog)
        self.protocol = protocol
        self.rate_hz = rate_hz
        self.link = link
        self.simulator = GyroSimulator(
            load_packaged_calibration(serial_number),
            profile if isinstance(profile, RateProfile) else RateProfile.parse(profile),
            temperature if isinstance(temperature, TemperatureProfile) else TemperatureProfile(float(temperature)),
            default_noise_dps(rate_hz) if noise_dps is None else noise_dps, seed, turn_on_bias_dps)
        self.sent = 0        # frames written
        self.dropped = 0     # bytes dropped because nobody read them
        self.lost = 0        # frames made but not sent (drop())
        self._to_lose = 0
        self.last_sample: tuple[float, float] | None = None
        self._lock = threading.Lock()    # master fd and pending bytes: frames and injections never interleave
        self._master: int | None = None
        self._slave: int | None = None
        self._slave_name = ''
        self._pending = b''
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._open_pty()

    @property
    def path(self) -> str:
        """The port to open: the link if there is one, else the current pty slave."""
        return self.link if self.link is not None else self._slave_name

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        try:
            tty.setraw(slave)           # no byte translated (no CR/LF mapping, no echo, no signals)
            os.set_blocking(master, False)
            name = os.ttyname(slave)
            if self.link is not None:
                # Re-point atomically so a reader never sees the link missing while plugged.
                temporary = f'{self.link}.{os.getpid()}.tmp'
                if os.path.lexists(temporary):
                    os.unlink(temporary)
                os.symlink(name, temporary)
                os.replace(temporary, self.link)
        except BaseException:
            # No link (its folder gone, say): stay unplugged rather than hold a pty nobody can find.
            os.close(master)
            os.close(slave)
            raise
        self._master, self._slave, self._slave_name = master, slave, name

    def _close_pty(self) -> None:
        if self._master is None or self._slave is None:
            return
        # Only a link to this pty: another fake may have re-pointed it since (a renamed device).
        if self.link is not None and os.path.islink(self.link) and os.readlink(self.link) == self._slave_name:
            os.unlink(self.link)
        os.close(self._master)
        os.close(self._slave)
        self._master = self._slave = None
        self._pending = b''

    def start(self) -> None:
        """Start sending frames at ``rate_hz``."""
        if self._thread is not None:
            raise RuntimeError('FakeGyro already started')
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name='fake_gyro', daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop sending and remove the pty and link."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        with self._lock:
            self._close_pty()

    def unplug(self) -> None:
        """Take the device away: close the pty (readers get an I/O error) and remove the link."""
        with self._lock:
            self._close_pty()

    def replug(self) -> None:
        """Plug the device in again on a new pty; the link points to it."""
        with self._lock:
            if self._master is None:
                self._open_pty()

    def inject(self, data: bytes) -> None:
        """Write raw bytes (garbage) between two frames."""
        with self._lock:
            self._write(data)

    def drop(self, frames: int) -> None:
        """Lose the next ``frames`` frames on the wire: made (and numbered, in kvh_fog) but not sent."""
        with self._lock:
            self._to_lose += frames

    def _write(self, data: bytes) -> None:
        """Write under the lock; what a slow reader leaves is kept, then dropped past a bound."""
        if self._master is None:
            return
        out = self._pending + data
        try:
            written = os.write(self._master, out)
        except BlockingIOError:   # the pty is full: no reader, or a slow one (the fake holds the slave open)
            written = 0
        self._pending = out[written:]
        if len(self._pending) > MAX_PENDING_BYTES:
            self.dropped += len(self._pending)
            self._pending = b''

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        block = max(1, int(self.rate_hz * 0.1))   # simulate 0.1 s at a time: numpy, not per sample
        start = time.monotonic()
        index = 0
        kvh = self.protocol == KVH_FOG
        while not self._stop.is_set():
            times = (index + np.arange(block)) * period
            # A KVH unit sends floats: its samples are the readings themselves, not counts.
            raw_rates, raw_temps = self.simulator.readings(times) if kvh else self.simulator.counts(times)
            for raw_rate, raw_temp in zip(raw_rates.tolist(), raw_temps.tolist()):
                # Absolute deadlines: sleep jitter does not accumulate into a rate error.
                delay = start + index * period - time.monotonic()
                if delay < -1.0:   # stalled for over a second: resume now rather than burst
                    start -= delay
                elif delay > 0 and self._stop.wait(delay):
                    return
                with self._lock:
                    frame = self.encoder(raw_rate, raw_temp)
                    self.last_sample = (raw_rate, raw_temp)
                    if self._to_lose:
                        self._to_lose -= 1
                        self.lost += 1
                    else:
                        self._write(frame)
                        self.sent += 1
                index += 1

    def __enter__(self) -> FakeGyro:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _parser() -> argparse.ArgumentParser:
    invoked = os.path.basename(sys.argv[0])
    p = argparse.ArgumentParser(prog=invoked if invoked in CONSOLE_SCRIPTS else CONSOLE_SCRIPTS[0],
                                description=__doc__.splitlines()[0])
    p.add_argument('--serial', required=True, help='serial number of a packaged calibration, e.g. NAVC3545')
    p.add_argument('--link', help='symlink to the current pty, e.g. /tmp/rd2100 (survives replugging)')
    p.add_argument('--protocol', choices=PROTOCOLS, default='binary')
    p.add_argument('--rate-hz', type=float, default=10.0, help='output rate (default 10)')
    p.add_argument('--profile', default='0',
                   help='true rate: deg/s, or repeating segments "duration_s:rate_dps,..." (default 0)')
    temp = p.add_mutually_exclusive_group()
    temp.add_argument('--temperature', type=float, default=25.0, help='constant degC (default 25)')
    temp.add_argument('--temperature-ramp', help='"start_c:end_c:ramp_s", then held at end_c')
    p.add_argument('--noise-dps', type=float, help='per-sample white noise (default 0.005 at 10 Hz, x sqrt(rate/10))')
    p.add_argument('--turn-on-bias-dps', type=float, help='turn-on bias (default: drawn with the seed)')
    p.add_argument('--seed', type=int, help='random seed')
    kvh = p.add_argument_group('protocol kvh_fog', 'how the simulated KVH unit is set (the node\'s kvh_fog.* '
                                                   'parameters must say the same; its output rate is --rate-hz)')
    defaults = KvhFogConfig()
    kvh.add_argument('--kvh-message-format', choices=tuple(KVH_FORMATS), default=defaults.message_format)
    kvh.add_argument('--kvh-yaw-axis', default=defaults.yaw_axis, help='x, y or z, - if it points down '
                                                                       '(default %(default)s)')
    kvh.add_argument('--kvh-rotation', choices=KVH_ROTATIONS, default=defaults.rotation)
    kvh.add_argument('--kvh-angle-units', choices=KVH_ANGLE_UNITS, default=defaults.angle_units)
    kvh.add_argument('--kvh-temperature-units', choices=KVH_TEMPERATURE_UNITS, default=defaults.temperature_units)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry: run a fake gyro until SIGINT or SIGTERM; prints the port path."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        temperature = (TemperatureProfile.parse_ramp(args.temperature_ramp) if args.temperature_ramp
                       else TemperatureProfile(args.temperature))
        # Its output rate is the fake's --rate-hz.
        kvh_fog = KvhFogConfig(message_format=args.kvh_message_format, yaw_axis=args.kvh_yaw_axis,
                               rotation=args.kvh_rotation, angle_units=args.kvh_angle_units,
                               temperature_units=args.kvh_temperature_units)
        fake = FakeGyro(args.serial, args.protocol, args.rate_hz, args.link, RateProfile.parse(args.profile),
                        temperature, args.noise_dps, args.seed, args.turn_on_bias_dps, kvh_fog)
    except (ValueError, OSError) as e:
        parser.exit(2, f'{parser.prog}: {e}\n')
    done = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: done.set())
    with fake:
        print(fake.path, flush=True)
        while not done.wait(0.5):
            pass
    return 0


if __name__ == '__main__':
    sys.exit(main())
