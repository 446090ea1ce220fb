"""The RD2100 frame guards measured: real motion they drop, and corrupt frames they let through.

``python bench/bench_guards.py [--seconds 10] [--seed 1] [--mean] [--no-temperature-test] [--look-ahead]`` drives
:class:`SerialGyroDriver`'s per-chunk path (parser, stream lock, stamper, guard) without a port: each encoded frame
is one read, returned after its wire time and a random latency of up to 30 % of the period (stamp jitter). At 10,
100 and 1000 Hz it reports:

- real motion (no corruption), point-sampled (``--mean``: each frame the mean rate over its interval) with
  0.02 deg/s of noise: vibrations of 10, 23, 37 and 50 Hz at 30 and 50 deg/s, ten bumps (a 10 ms half-sine of
  80 deg/s ringing on at 40 Hz), fast turns (0 -> 90 deg/s in 0.2 s and back): real frames lost, and the heading
  error they cause (each delivered rate held until the next delivered frame, against every sent one);
- corrupt frames: a still and a vibrating gyro (30 Hz, 30 deg/s) whose frames get two random bit flips (binary)
  or one digit replaced (ascii) at a 5 % rate, 100,000 frames a run: corrupt frames passed (delivered with a rate
  or temperature other than the one sent), of those corrupted, those beyond the noise (a rate more than 0.1 deg/s,
  five times the noise, or a temperature 2 counts or more off: what no plausibility test can tell from noise is
  not), and the largest rate error passed.

``--no-temperature-test``: the guard does not refuse temperature jumps (``FrameGuard``'s option, which the RD2100
protocols' descriptions turn on). ``--look-ahead``: the guard also refuses one-frame spikes, at a frame of latency
(the driver's ``guard_look_ahead``).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.driver import SerialGyroDriver
from art_gyro_calibration.frame import Frame
from art_gyro_calibration.frame_guard import FrameGuard
from art_gyro_calibration.protocols import make_encoder

SCALE = 0.00305   # deg/s per count (NAVC3545's)
TEMP_COUNTS = 500   # 25 degC at 0.05 degC per count
NOISE_DPS = 0.02
BAUD = 115200
CORRUPT_SHARE = 0.05
BUMP_OFFSETS = np.random.default_rng(7).uniform(0.0, 0.1, 10)
CORRUPT_FRAMES = 100_000   # of each corrupt-frame run, at every rate
CONTINUOUS_TEMPERATURE = [True]   # False: --no-temperature-test
LOOK_AHEAD = [False]   # --look-ahead


def vibration(freq_hz: float, amp_dps: float) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """A sinusoidal vibration."""
    return lambda t: amp_dps * np.sin(2 * np.pi * freq_hz * t + 0.3)


def bumps(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Ten bumps about a second apart: a 10 ms half-sine of 80 deg/s, then ringing at 40 Hz (40 deg/s, 25 ms decay).

    Each starts at a random time in its second's middle 100 ms (fixed seed): some land on a frame at 10 Hz.
    """
    tau = np.mod(t, 1.0) - 0.5 - BUMP_OFFSETS[np.minimum(t.astype(np.int64), 9)]
    half = np.where((tau >= 0) & (tau < 0.01), 80 * np.sin(np.pi * np.clip(tau, 0, 0.01) / 0.01), 0.0)
    after = np.clip(tau - 0.01, 0, None)
    ring = np.where(tau >= 0.01, -40 * np.sin(2 * np.pi * 40 * after) * np.exp(-after / 0.025), 0.0)
    return np.where(t < 10.0, half + ring, 0.0)


def turns(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """0 -> 90 deg/s in 0.2 s, held 0.8 s, back in 0.2 s, 0.8 s still; repeating."""
    tau = np.mod(t, 2.0)
    return 90 * np.clip(np.minimum(tau / 0.2, (1.2 - tau) / 0.2), 0, 1)


MOTIONS: dict[str, Callable[[NDArray[np.float64]], NDArray[np.float64]]] = {
    **{f'vibration {f} Hz {a} deg/s': vibration(f, a) for f in (10, 23, 37, 50) for a in (30, 50)},
    'bumps 80 deg/s ringing 40 Hz': bumps,
    'turns 0-90 deg/s in 0.2 s': turns,
}


def run(protocol: str, rate_hz: float, raw_rates: NDArray[np.int64], raw_temps: NDArray[np.int64],
        wire: list[bytes], rng: np.random.Generator) -> tuple[list[Frame], NDArray[np.int64], SerialGyroDriver]:
    """The frames the driver delivers from ``wire`` (one read each), and the sent index of each."""
    frames: list[Frame] = []
    now = [0]
    driver = SerialGyroDriver('/dev/null', BAUD, protocol, frames.append, clock_ns=lambda: now[0],
                              monotonic_ns=lambda: now[0], rate_scale_dps=SCALE, guard_look_ahead=LOOK_AHEAD[0])
    if not CONTINUOUS_TEMPERATURE[0]:
        driver._guard = FrameGuard(driver._parser.description.corrupt_rate_steps, False, LOOK_AHEAD[0])
    period_ns = 1e9 / rate_hz
    t0 = 1_000_000_000
    latency = rng.uniform(0, 0.3 * period_ns, len(wire))
    for i, chunk in enumerate(wire):
        now[0] = int(t0 + i * period_ns + len(chunk) * 1e10 / BAUD + latency[i])
        driver._on_data(chunk, now[0], now[0], 0)   # the per-chunk path, without a device
    driver._release()   # the last frame, held by the look-ahead
    index = np.array([round((f.steady_ns - t0) / period_ns) for f in frames], dtype=np.int64)
    return frames, index, driver


def samples(motion: Callable[[NDArray[np.float64]], NDArray[np.float64]], rate_hz: float, seconds: float,
            rng: np.random.Generator, mean: bool = False) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Rate and temperature counts of ``motion`` at ``rate_hz``, with noise.

    Point-sampled, or (``mean``) each the mean rate over its interval, as a fiber gyro's angle increment over it
    (taken at 10 kHz).
    """
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    if mean:
        sub = max(1, int(10_000 / rate_hz))
        fine = motion(np.arange(t.size * sub) / (rate_hz * sub)).reshape(t.size, sub).mean(axis=1)
    else:
        fine = motion(t)
    rate = fine + rng.normal(0, NOISE_DPS, t.size)
    raw = np.clip(np.round(rate / SCALE), -32768, 32767).astype(np.int64)
    temps = TEMP_COUNTS + np.round(t / max(seconds, 1e-9) * 4).astype(np.int64)   # a slow warm-up of 0.2 degC
    return raw, temps


def corrupt(protocol: str, frame: bytes, rng: np.random.Generator) -> bytes:
    """Two random bit flips (binary), or one digit replaced by another (ascii)."""
    data = bytearray(frame)
    if protocol == 'binary':
        for bit in rng.choice(len(data) * 8, 2, replace=False):
            data[bit // 8] ^= 1 << (bit % 8)
        return bytes(data)
    digits = [i for i, c in enumerate(data) if chr(c).isdigit()]
    i = digits[rng.integers(len(digits))]
    data[i] = ord(str((int(chr(data[i])) + rng.integers(1, 10)) % 10))
    return bytes(data)


def motion_case(protocol: str, rate_hz: float, name: str, seconds: float, seed: int,
                mean: bool = False) -> dict[str, object]:
    """Real frames lost and the heading error, for one motion."""
    rng = np.random.default_rng(seed)
    raw, temps = samples(MOTIONS[name], rate_hz, seconds, rng, mean)
    encode = make_encoder(protocol)
    frames, index, driver = run(protocol, rate_hz, raw, temps, [encode(int(r), int(c)) for r, c in zip(raw, temps)],
                                rng)
    first = int(index[0]) if len(index) else len(raw)   # after the stream lock
    sent = len(raw) - first
    # Each delivered rate held until the next delivered frame (a consumer integrating what it gets): the error is
    # the lost frames', not the stamps' jitter.
    rates = np.array([f.sample.raw_rate for f in frames], dtype=np.float64) * SCALE
    heading = float(np.sum(rates[:-1] * np.diff(index))) / rate_hz if len(frames) > 1 else 0.0
    true = float(np.sum(raw[first:-1])) * SCALE / rate_hz
    return {'protocol': protocol, 'rate_hz': rate_hz, 'motion': name, 'sent': sent, 'lost': sent - len(frames),
            'heading_error_deg': round(heading - true, 3), 'true_heading_deg': round(true, 3),
            'rejected': {k: v for k, v in driver.stats.rejected_by_reason.items() if v}}


def corrupt_case(protocol: str, rate_hz: float, moving: bool, seed: int, mean: bool = False) -> dict[str, object]:
    """Corrupt frames passed, of those corrupted, on a still or vibrating gyro."""
    rng = np.random.default_rng(seed)
    raw, temps = samples(vibration(30, 30) if moving else (lambda t: 0.0 * t), rate_hz, CORRUPT_FRAMES / rate_hz, rng,
                         mean)
    encode = make_encoder(protocol)
    wire = [encode(int(r), int(c)) for r, c in zip(raw, temps)]
    hit = rng.random(len(wire)) < CORRUPT_SHARE
    hit[:10] = False
    for i in np.flatnonzero(hit):
        wire[i] = corrupt(protocol, wire[i], rng)
    frames, index, driver = run(protocol, rate_hz, raw, temps, wire, rng)
    ok = (index >= 0) & (index < len(raw))
    got_rate = np.array([f.sample.raw_rate for f in frames], dtype=np.int64)
    got_temp = np.array([f.sample.raw_temp for f in frames], dtype=np.int64)
    at = np.clip(index, 0, len(raw) - 1)
    wrong = ok & ((got_rate != raw[at]) | (got_temp != temps[at]))
    errors = np.abs(got_rate[wrong] - raw[index[wrong]]) * SCALE
    temp_errors = np.abs(got_temp[wrong] - temps[index[wrong]])
    real_lost = int(np.sum(~hit)) - int(np.sum(ok & ~wrong))
    return {'protocol': protocol, 'rate_hz': rate_hz, 'gyro': 'vibrating 30 Hz 30 deg/s' if moving else 'still',
            'corrupted': int(np.sum(hit)), 'passed': int(np.sum(wrong)),
            'passed_beyond_noise': int(np.sum((errors > 5 * NOISE_DPS) | (temp_errors >= 2))),
            'passed_over_1dps': int(np.sum(errors > 1.0)),
            'max_rate_error_dps': round(float(errors.max()), 2) if errors.size else 0.0,
            'clean_frames_not_delivered': real_lost,
            'rejected': {k: v for k, v in driver.stats.rejected_by_reason.items() if v}}


def main() -> None:
    """Run every case and print one JSON line each, then the totals per protocol and rate."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=10.0, help='of each run at each rate (default 10)')
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--mean', action='store_true',
                        help='each frame the mean rate over its interval (a fiber gyro\'s), not a point sample')
    parser.add_argument('--no-temperature-test', action='store_true',
                        help='the guard does not refuse temperature jumps')
    parser.add_argument('--look-ahead', action='store_true',
                        help='the guard also refuses one-frame spikes (a frame of latency)')
    args = parser.parse_args()
    CONTINUOUS_TEMPERATURE[0] = not args.no_temperature_test
    LOOK_AHEAD[0] = args.look_ahead
    start = time.perf_counter()
    totals: dict[str, dict[str, float]] = {}
    for protocol in ('binary', 'ascii'):
        for rate_hz in (10.0, 100.0, 1000.0):
            seconds = max(args.seconds, 100.0 if rate_hz == 10.0 else args.seconds)   # enough frames at 10 Hz
            key = f'{protocol} {rate_hz:g} Hz'
            total = totals.setdefault(key, dict.fromkeys(('sent', 'lost', 'worst_heading_error_deg', 'corrupted',
                                                          'passed', 'passed_beyond_noise', 'passed_over_1dps'), 0.0))
            for name in MOTIONS:
                row = motion_case(protocol, rate_hz, name, seconds, args.seed, args.mean)
                print(json.dumps(row))
                total['sent'] += row['sent']   # type: ignore[operator]
                total['lost'] += row['lost']   # type: ignore[operator]
                total['worst_heading_error_deg'] = max(total['worst_heading_error_deg'],
                                                       abs(row['heading_error_deg']))   # type: ignore[arg-type]
            for moving in (False, True):
                row = corrupt_case(protocol, rate_hz, moving, args.seed, args.mean)
                print(json.dumps(row))
                for k in ('corrupted', 'passed', 'passed_beyond_noise', 'passed_over_1dps'):
                    total[k] += row[k]   # type: ignore[operator]
    for key, total in totals.items():
        print(f'{key:18s} real frames lost {total["lost"]:.0f} of {total["sent"]:.0f} (worst heading error '
              f'{total["worst_heading_error_deg"]:.2f} deg); corrupt frames passed {total["passed"]:.0f} of '
              f'{total["corrupted"]:.0f} ({total["passed_beyond_noise"]:.0f} beyond the noise, '
              f'{total["passed_over_1dps"]:.0f} off by more than 1 deg/s)')
    print(f'{time.perf_counter() - start:.1f} s')


if __name__ == '__main__':
    main()
