"""Adversarial input through the node's per-frame path, without ROS: what is published from garbage.

``python bench/bench_fuzz.py [--mib 20] [--seed 1]`` feeds the RD2100 binary parser (with the
driver's stream lock, LOCK_FRAMES valid frames in a row; ``--lock 1`` for none) and the node's
:class:`~art_gyro_calibration.compensation.FrameCorrector` (NAVC3545) with:

- random bytes (``--mib`` MiB) with a valid 50 Hz frame every 2,000 bytes;
- a 9600-baud gyro read at 115200 (each bit seen as 12 receiver bits: mostly 0x80/0x00 bytes);
- bursts: 100,000 valid frames, and 1,000 frames of +-32767 (clipped) counts among them.

It prints, per input, the frames the parser accepted, its rejections by reason, and what the
corrector would publish and drop by reason; the published garbage frames are the ones no
check could tell from a gyro (a window whose 8-bit checksum passes by chance, with a plausible
temperature and an unclipped rate).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from art_gyro_calibration.calibration import load_packaged_calibration
from art_gyro_calibration.compensation import FrameCorrector
from art_gyro_calibration.frame import LOCK_FRAMES
from art_gyro_calibration.protocols.rd2100_binary import BinaryFrameParser, encode_binary

GOOD_TEMP = 500   # counts: 25 degC; the valid frames carry this and a rate count of 7, garbage rarely does


def run(name: str, data: bytes, lock_frames: int = LOCK_FRAMES) -> dict[str, object]:
    """Parse ``data`` in 4 KiB reads and correct every frame; the counts."""
    parser = BinaryFrameParser(lock_frames)
    corrector = FrameCorrector(load_packaged_calibration('NAVC3545'))
    published = published_garbage = 0
    start = time.perf_counter()
    for k in range(0, len(data), 4096):
        for sample, _ in parser.feed(data[k:k + 4096]):
            if not corrector.step(sample.raw_rate, sample.raw_temp, 0.0):
                published += 1
                published_garbage += (sample.raw_rate, sample.raw_temp) not in ((7, GOOD_TEMP), (6, GOOD_TEMP))
    return {'input': name, 'bytes': len(data), 'seconds': round(time.perf_counter() - start, 2),
            'frames': parser.stats.frames, 'rejected': dict(parser.stats.rejected_by_reason),
            'published': published, 'published_not_sent_as_frames': published_garbage,
            'dropped': dict(corrector.dropped)}


def misclocked(data: bytes, ratio: float) -> bytes:
    """What a UART at ``ratio`` times the sender's baud decodes from ``data`` (8N1, idle high)."""
    bits = [1] * 20
    for byte in data:
        bits += [0] + [(byte >> i) & 1 for i in range(8)] + [1]
    bits += [1] * 40
    out = bytearray()
    bit_time, t = 1.0 / ratio, 0.0
    while t + 10 * bit_time < len(bits):
        if bits[int(t)]:
            t += bit_time / 16
            continue
        out.append(sum(bits[int(t + (1.5 + i) * bit_time)] << i for i in range(8)))
        t += 9.5 * bit_time
    return bytes(out)


def main() -> None:
    """Run the three inputs and print their counts as JSON lines."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--mib', type=float, default=20.0)
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--lock', type=int, default=LOCK_FRAMES, help='the stream lock\'s frames (1: none)')
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    noise = bytearray(rng.integers(0, 256, int(args.mib * (1 << 20)), dtype=np.uint8).tobytes())
    frame = encode_binary(7, GOOD_TEMP)
    for k in range(0, len(noise) - 8, 2000):
        noise[k:k + 8] = frame
    print(json.dumps(run(f'{args.mib:g} MiB random bytes, a valid frame every 2000 bytes', bytes(noise), args.lock)))
    gyro = b''.join(encode_binary(int(r), GOOD_TEMP) for r in rng.integers(-5, 6, 2000))
    print(json.dumps(run('2000 frames of a 9600-baud gyro read at 115200', misclocked(gyro, 12.0), args.lock)))
    burst = bytearray(b''.join([encode_binary(7, GOOD_TEMP), encode_binary(6, GOOD_TEMP)]) * 50_000)
    for k in rng.choice(100_000, 1000, replace=False):
        burst[8 * k:8 * k + 8] = encode_binary(int(rng.choice([32767, -32767, -32768])), GOOD_TEMP)
    print(json.dumps(run('a burst of 100000 frames, 1000 of them clipped', bytes(burst), args.lock)))


if __name__ == '__main__':
    main()
