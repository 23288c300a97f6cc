"""Edge-crossing bursts: one event per burst, at the mean time of the burst's events.

An edge that sweeps over a pixel fires a burst of events, one per threshold level its
intensity crosses. Which levels a pixel crosses depends on its reference level, so matching
single events of neighbouring pixels pairs different levels of their bursts, and the time
of a step between them is off by up to a level's spacing, with a bias that depends on the
event rate (on the simulated translation, +2 % of the time-surface slope at C = 0.2, -10 %
at C = 0.1). The mean time of a burst's events is the time the middle of the edge's
intensity range crossed the pixel, to within half a level, and that error is symmetric:
on the same scene the triplets of burst means give the time-surface slope with a median of
0.9994-0.9999 of the true one (gaps of 2.5-5 ms; interquartile range 0.97-1.04) against
1.025 for single events (an extension of thesis ch. 5, used by the ``dense="robust"``
output of :mod:`evmotion.methods.triplet`).

A burst is a run of events of one pixel and polarity, each within ``gap_us`` of the
previous one. It ends when the pixel stays silent for longer than ``gap_us``, so its mean is
known only then: :class:`BurstMeans` emits the bursts of a stream in time order, late by at
least ``gap_us``, with memory bounded by the sensor size.

Units: pixels, microseconds.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from evmotion.errors import ParameterError
from evmotion.events import EventArray, check_stream_order, concatenate, sensor_pixels

__all__ = ["BURST_GAP_US", "MAX_GAP_US", "BurstMeans", "burst_means"]

# Default gap: longer than the spacing of one edge's events at the simulated scenes'
# speeds (70-300 px/s), shorter than the time between edges (chosen on seed 0 of
# benchmarks/bench_triplet_accuracy.py among 2.5, 3, 4, 5 and 10 ms).
BURST_GAP_US = 4_000


@njit(cache=True)
def _bursts(x, y, t, p, seq0, gap, first, last, tsum, cnt, seq, ox, oy, op, ofirst, osum,
            ocnt, oseq):
    """Add events to the open bursts (state per polarity and pixel); a burst that an event
    interrupts after a silence over ``gap`` is written to the outputs. Returns how many."""
    m = 0
    for k in range(t.shape[0]):
        c = 1 if p[k] else 0
        yy = y[k]
        xx = x[k]
        tk = t[k]
        if cnt[c, yy, xx] > 0 and tk - last[c, yy, xx] > gap:
            ox[m] = xx
            oy[m] = yy
            op[m] = c
            ofirst[m] = first[c, yy, xx]
            osum[m] = tsum[c, yy, xx]
            ocnt[m] = cnt[c, yy, xx]
            oseq[m] = seq[c, yy, xx]
            m += 1
            cnt[c, yy, xx] = 0
        if cnt[c, yy, xx] == 0:
            first[c, yy, xx] = tk
            tsum[c, yy, xx] = 0
            seq[c, yy, xx] = seq0 + k
        tsum[c, yy, xx] += tk - first[c, yy, xx]
        cnt[c, yy, xx] += 1
        last[c, yy, xx] = tk
    return m


#: Longest gap between bursts (an hour): beyond, int64 time arithmetic nears overflow and
#: no pixel's burst lasts that long
MAX_GAP_US = 3_600_000_000


class BurstMeans:
    """Streaming burst means: ``process(chunk)`` returns the bursts that ended, in time order.

    Each burst becomes one event at its pixel and polarity, at the mean of its events'
    timestamps (rounded half up to the microsecond). Bursts come out sorted by that time,
    ties by the stream position of their first event; a burst is returned once no burst
    still to come can precede it, so any split of a stream into chunks gives the same
    sequence as :func:`burst_means` on the whole stream. Call :meth:`flush` at the end.

    Parameters
    ----------
    sensor_size : (int, int)
        ``(height, width)`` in pixels.
    gap_us : int
        A silence longer than this (µs) at a pixel and polarity ends its burst.

    Examples
    --------
    >>> ev = EventArray(x=[1, 1, 1, 2], y=[0, 0, 0, 0], t=[0, 10, 20, 9_000],
    ...                 p=[1, 1, 1, 1], sensor_size=(2, 4))
    >>> b = BurstMeans((2, 4), gap_us=5_000)
    >>> len(b.process(ev)), b.flush().t.tolist()
    (1, [9000])
    """

    def __init__(self, sensor_size: tuple[int, int], gap_us: int = BURST_GAP_US) -> None:
        h, w = (int(v) for v in sensor_size)
        if h <= 0 or w <= 0:
            raise ParameterError(f"sensor_size must be positive (height, width), got {(h, w)}")
        if not (isinstance(gap_us, (int, float, np.integer, np.floating))
                and not isinstance(gap_us, bool) and np.isfinite(float(gap_us))
                and 1 <= gap_us <= MAX_GAP_US and int(gap_us) == gap_us):
            raise ParameterError(f"gap_us must be an integer from 1 microsecond to "
                                 f"{MAX_GAP_US} (an hour), got {gap_us!r}")
        self.sensor_size = (h, w)
        self.gap_us = int(gap_us)
        shape = (2, h, w)
        self._first = np.zeros(shape, np.int64)
        self._last = np.zeros(shape, np.int64)
        self._sum = np.zeros(shape, np.int64)
        self._cnt = np.zeros(shape, np.int64)
        self._seq = np.zeros(shape, np.int64)
        self._pending = _Ended.alloc(0)
        self._seen = 0
        self._t_last: int | None = None

    def process(self, chunk: EventArray) -> EventArray:
        """Add ``chunk`` (sorted, continuing the stream); return the bursts now final."""
        if tuple(chunk.sensor_size) != self.sensor_size:
            raise ParameterError(f"chunk sensor_size {chunk.sensor_size} differs from "
                                 f"{self.sensor_size}")
        n = len(chunk)
        if n == 0:
            return self._emit(None)
        t = np.ascontiguousarray(chunk.t, np.int64)
        check_stream_order(t, self._t_last)
        x, y = sensor_pixels(chunk)
        out = _Ended.alloc(n)
        m = _bursts(x, y, t, np.ascontiguousarray(chunk.p, np.uint8), np.int64(self._seen),
                    np.int64(self.gap_us), self._first, self._last, self._sum, self._cnt,
                    self._seq, *out.columns())
        self._seen += n
        self._t_last = int(t[-1])
        ended = out.head(m)
        # Bursts silent for longer than the gap can no longer grow.
        quiet = (self._cnt > 0) & (self._t_last - self._last > self.gap_us)
        ended = ended.join(self._take(quiet))
        return self._emit(ended)

    def flush(self) -> EventArray:
        """End every open burst and return all bursts not yet returned."""
        return self._emit(self._take(self._cnt > 0), final=True)

    def _take(self, sel: np.ndarray) -> _Ended:
        c, yy, xx = np.nonzero(sel)
        ended = _Ended(xx.astype(np.int32), yy.astype(np.int32), c.astype(np.uint8),
                       self._first[sel], self._sum[sel], self._cnt[sel], self._seq[sel])
        self._cnt[sel] = 0
        return ended

    def _emit(self, ended: _Ended | None, final: bool = False) -> EventArray:
        pending = self._pending if ended is None else self._pending.join(ended)
        t = pending.mean_t()
        bound = None
        if not final:
            # A burst still open has its mean at or after its first event; one not yet
            # begun, at or after the last time seen.
            open_first = self._first[self._cnt > 0]
            bound = self._t_last if self._t_last is not None else int(np.iinfo(np.int64).min)
            if open_first.size:
                bound = min(bound, int(open_first.min()))
        order = np.lexsort((pending.seq, t))
        ready = order if bound is None else order[t[order] < bound]
        keep = np.ones(len(t), bool)
        keep[ready] = False
        self._pending = pending.select(keep)
        return EventArray(pending.x[ready], pending.y[ready], t[ready], pending.p[ready],
                          self.sensor_size, validate=False)


class _Ended:
    """Ended bursts: pixel, polarity, first timestamp, sum of the timestamps after it, count,
    and the stream position of the first event."""

    def __init__(self, x, y, p, first, tsum, cnt, seq):
        self.x, self.y, self.p = x, y, p
        self.first, self.tsum, self.cnt, self.seq = first, tsum, cnt, seq

    @classmethod
    def alloc(cls, n: int) -> _Ended:
        return cls(np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.uint8),
                   *(np.empty(n, np.int64) for _ in range(4)))

    def columns(self) -> tuple:
        return self.x, self.y, self.p, self.first, self.tsum, self.cnt, self.seq

    def head(self, m: int) -> _Ended:
        return _Ended(*(a[:m] for a in self.columns()))

    def select(self, sel: np.ndarray) -> _Ended:
        return _Ended(*(a[sel] for a in self.columns()))

    def join(self, other: _Ended) -> _Ended:
        return _Ended(*(np.concatenate(ab) for ab in zip(self.columns(), other.columns(),
                                                          strict=True)))

    def mean_t(self) -> np.ndarray:
        """Mean timestamp, rounded half up (integer arithmetic, exact)."""
        return self.first + (2 * self.tsum + self.cnt) // (2 * np.maximum(self.cnt, 1))

    def __len__(self) -> int:
        return int(self.x.shape[0])


def burst_means(events: EventArray, gap_us: int = BURST_GAP_US) -> EventArray:
    """One event per burst of ``events`` (see :class:`BurstMeans`), sorted by time.

    Parameters
    ----------
    events : EventArray
        Sorted events.
    gap_us : int
        A silence longer than this (µs) at a pixel and polarity ends its burst.

    Returns
    -------
    EventArray
        The bursts' pixels and polarities at the mean time of their events.

    Examples
    --------
    >>> ev = EventArray(x=[1, 1, 2], y=[0, 0, 0], t=[0, 30, 100], p=[1, 1, 0],
    ...                 sensor_size=(2, 4))
    >>> burst_means(ev, gap_us=1_000).t.tolist()
    [15, 100]
    """
    b = BurstMeans(events.sensor_size, gap_us)
    return concatenate([b.process(events), b.flush()], validate=False)
