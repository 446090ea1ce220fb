"""``calibrate apply`` on a log of any length: read, compensate and write chunk by chunk.

Memory holds one chunk (and the static bias's first rows) whatever the log's length, and
the output equals :func:`~art_gyro_calibration.compensation.apply_calibration` over the
whole log: each chunk goes through that same function, continuing the previous one.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from art_gyro_calibration.calibration import Calibration
from art_gyro_calibration.compensation import RunStart, apply_calibration, plausible
from art_gyro_calibration.log import READ_CHUNK_ROWS, concatenate
from art_gyro_calibration.analysis.csv_writer import CsvWriter
from art_gyro_calibration.analysis.bags import BagTopics, read_any_chunks
from art_gyro_calibration.static_bias import DEFAULT_MAX_MEAN_DPS, DEFAULT_MAX_STD_DPS, StaticBias

OUTPUT_COLUMNS = ('t', 'rate_dps', 'temp_c', 'comp_dps', 'corrected_dps')


@dataclass(frozen=True)
class Streamed:
    """What :func:`apply_to_csv` did."""

    rows: int       # rows of the log
    dropped: int    # rows dropped as the node drops their frames (implausible temperature)
    bias: StaticBias
    outside_range: int    # kept rows outside the calibration's expected temperature range
    flagged: Mapping[str, tuple[int, int]]   # per signal from outside the gyro: rows held, rows beyond its limits
    beyond_unit_range: int = 0   # rows whose corrected rate was beyond the unit's range: written uncorrected


def apply_to_csv(log_path: str | Path, calibration: Calibration, bias_samples: int, out: IO[bytes],
                 max_mean_dps: float = DEFAULT_MAX_MEAN_DPS, max_std_dps: float = DEFAULT_MAX_STD_DPS,
                 chunk_rows: int = READ_CHUNK_ROWS, start: RunStart = RunStart(),
                 topics: BagTopics = BagTopics()) -> Streamed:
    """Static bias over the first ``bias_samples`` kept rows of the log, then every kept row written to ``out``.

    A rosbag2 log (:mod:`.bags`, its ``topics``) is read whole, then compensated as a CSV's chunks are.
    """
    chunks = read_any_chunks(log_path, calibration.rate_scale_factor, calibration.temp_scale_factor, topics,
                             chunk_rows)
    # The static bias needs its rows in one piece: gather chunks until they hold enough kept rows.
    head, kept = [], 0
    for chunk in chunks:
        head.append(chunk)
        kept += int(np.count_nonzero(plausible(chunk.temp_c)))
        if kept >= bias_samples:
            break
    writer = CsvWriter(out, OUTPUT_COLUMNS)
    rows = dropped = 0
    applied = None   # an empty log is refused by the reader: the loop runs at least once
    for chunk in itertools.chain([concatenate(head)], chunks):
        applied = apply_calibration(chunk, calibration, bias_samples, max_mean_dps, max_std_dps, after=applied,
                                    start=start)
        kept_log = chunk if applied.kept.all() else chunk.slice(applied.kept)
        writer.write({'t': kept_log.t, 'rate_dps': kept_log.rate_dps, 'temp_c': kept_log.temp_c,
                      'comp_dps': applied.comp_dps, 'corrected_dps': applied.corrected_dps})
        rows += len(chunk)
        dropped += len(chunk) - len(kept_log)
    assert applied is not None   # the loop ran: an empty log is refused by the reader
    return Streamed(rows, dropped, applied.bias, applied.outside_range, applied.flagged, applied.beyond_unit_range)
