"""A log's rows chunk by chunk, so that no matrix with a row per log row is ever built whole.

The fit and the screen need only sums over rows (normal equations, bin sums, per-fold
sums); each chunk's design columns and candidate bases are computed, summed and dropped.
A chunk's causal signals continue from the state the chunk before ended in
(:meth:`Signals.end_state`), so they equal the whole log's to rounding.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from art_gyro_calibration.signals import Signals, SignalState
from art_gyro_calibration.static_bias import refinement_span_s

# Rows per chunk of the fit's and the screen's design columns: a matrix of a dozen columns over a chunk is
# 25 MiB. The sums add chunk by chunk: the value sets their rounding (results agree to about 1e-9, not bit for bit).
DESIGN_CHUNK_ROWS = 1 << 18


@dataclass(frozen=True)
class Chunk:
    """Consecutive log rows ``[start, start + len(signals))`` and the selected rows among them."""

    signals: Signals             # the chunk's signals, continuing the log's causal recursions
    start: int                   # log row of the chunk's first row
    rows: NDArray[np.int64]      # the selected rows in the chunk, counted from ``start``
    positions: slice             # where those rows are in the selection


def chunks(signals: Signals, index: NDArray[np.int64], chunk_rows: int | None = None) -> Iterator[Chunk]:
    """The log of ``signals`` in chunks of ``chunk_rows`` rows (default :data:`DESIGN_CHUNK_ROWS`), rows of ``index``.

    ``index`` must be increasing (the steady rows of a log are). Every chunk is yielded,
    selected rows or not: the signals' recursions run through all of them. No chunk crosses
    the start of a run (:attr:`Signals.run_starts`): each run's first chunk starts afresh.
    """
    size = DESIGN_CHUNK_ROWS if chunk_rows is None else max(int(chunk_rows), 1)
    index = np.asarray(index)
    known = signals.chunk_states.get(size)
    ends: list[SignalState] = []
    low = 0
    spans = [(first, run, start, stop) for first, run in signals.runs() for start, stop in _bounds(run, size)]
    state: SignalState | None = None
    for k, (first, run, start, stop) in enumerate(spans):
        if start == 0:   # a run's first chunk
            state = run.previous
        part = Signals(t=run.t[start:stop], rate=run.rate[start:stop], temperature=run.temperature[start:stop],
                       extras={k: v[start:stop] for k, v in run.extras.items()}, filters=run.filters,
                       previous=state, powered_on_at_start=run.powered_on_at_start,
                       angle_correction=run.angle_correction, refined_start=run.refined_start)
        rate = signals.chunk_rates.get((size, k))
        if known is not None and rate is not None:   # the pass that made the states computed the filter's levels
            part.__dict__['temperature_rate'] = rate
        start, stop = first + start, first + stop   # rows of the log
        high = low + int(np.searchsorted(index[low:], stop, side='left'))
        if np.any(np.diff(index[low:high]) <= 0) or (low < index.size and index[low] < start):
            raise ValueError('the rows to select must be increasing')
        yield Chunk(part, start, index[low:high] - start, slice(low, high))
        if rate is None and 'temperature_rate' in part.__dict__:
            signals.chunk_rates[(size, k)] = part.temperature_rate
            part.temperature_rate.flags.writeable = False   # shared by every later pass
        # After the caller's work: the lags it computed continue too. The rest of the state (the
        # filters, the angle) is the same on every pass over the log: computed on the first.
        if known is None:
            state = part.end_state()
            ends.append(state)
        else:
            state = replace(known[k], lag_levels=part.lag_levels())
        low = high
    if known is None and len(ends) == len(spans):
        signals.chunk_states[size] = [replace(end, lag_levels=()) for end in ends]


def _bounds(run: Signals, size: int) -> list[tuple[int, int]]:
    """(start, stop) of a run's chunks of ``size`` rows.

    With :attr:`Signals.refined_start` the first holds the refinement's span: its slope is fitted on all of it.
    """
    first = size
    if run.refined_start and len(run):
        span_s = refinement_span_s(run.filters.refinement_scale_s)
        first = max(size, int(np.searchsorted(run.t, run.t[0] + span_s, side='left')))
    starts = [0, *range(first, len(run), size)] if len(run) else []
    return [(a, min(len(run), b)) for a, b in zip(starts, [*starts[1:], len(run)])]
