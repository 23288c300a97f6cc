"""Windows of recordings too long to hold in memory: cut from a stream of event chunks,
and their events handed out in blocks of bounded size.

:func:`make_windows_streaming` gives the windows :func:`evmotion.events.make_windows` cuts
from the whole recording while holding two numbers a window; :func:`window_blocks` then
reads the stream again and yields consecutive windows' events a block at a time, so that a
per-window command holds one block, not the recording (a 97.5 M-event file took 2.9 GB).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence

import numpy as np

from evmotion.errors import ParameterError
from evmotion.events import EventArray, Window, concatenate
from evmotion.utils import whole_number

__all__ = ["BLOCK_EVENTS", "make_windows_streaming", "window_blocks"]

#: Events a block of :func:`window_blocks` holds at most (a longer window is one block):
#: ~150 MB of events with float coordinates
BLOCK_EVENTS = 1 << 23


def make_windows_streaming(chunks: Iterable[EventArray], *, n_events: int | None = None,
                           duration_us: int | None = None, t0: int | None = None,
                           t1: int | None = None, max_windows: int | None = None,
                           min_events: int = 1) -> list[Window]:
    """The windows :func:`~evmotion.events.make_windows` cuts from the concatenated
    ``chunks``, read once and not kept.

    Parameters
    ----------
    chunks : iterable of EventArray
        Consecutive events sorted by time, all within ``[t0, t1)`` (as
        :func:`evmotion.io.iter_events` gives them with ``t0``/``t1``).
    n_events, duration_us : int
        How windows are cut (exactly one), as in ``make_windows``.
    t0, t1 : int, optional
        The time range in µs, as in ``make_windows``: ``t0`` starts the duration windows'
        grid (default the first event), ``t1`` ends the last window (default just after
        the last event).
    max_windows : int, optional
        Keep at most this many windows (None: all); the stream is read no further.
    min_events : int
        Leave out windows with fewer events.

    Returns
    -------
    list of Window
        ``start``/``stop`` index the concatenated stream.

    Examples
    --------
    >>> ev = EventArray(x=np.zeros(10), y=np.zeros(10), t=np.arange(0, 1000, 100),
    ...                 p=np.ones(10), sensor_size=(4, 4))
    >>> chunks = (ev[i:i + 3] for i in range(0, 10, 3))
    >>> [(w.t0, w.t1, w.count) for w in make_windows_streaming(chunks, n_events=4)]
    [(0, 301, 4), (400, 701, 4), (800, 901, 2)]
    """
    if (n_events is None) == (duration_us is None):
        raise ParameterError("make_windows_streaming needs exactly one of n_events, "
                             f"duration_us; got n_events={n_events}, "
                             f"duration_us={duration_us}")
    if t0 is not None and t1 is not None and t1 <= t0:
        raise ParameterError(f"t1 = {t1} µs must be after t0 = {t0} µs")
    if max_windows is not None:
        max_windows = whole_number("max_windows", max_windows, lo=1)
    need = max(int(min_events), 1)
    if n_events is not None:
        n = whole_number("events per window (n_events)", n_events, lo=1)
        windows = _count_windows(chunks, n, t1, need, max_windows)
    else:
        d = whole_number("window duration (duration_us, µs)", duration_us, lo=1)
        windows = _duration_windows(chunks, d, t0, t1, need, max_windows)
    return windows if max_windows is None else windows[:max_windows]


def _count_windows(chunks, n: int, t1: int | None, need: int,
                   max_windows: int | None) -> list[Window]:
    """Windows of ``n`` events: window ``k`` holds events ``[k n, (k + 1) n)`` and spans
    its first event to just after its last, or to the next window's first where that
    shares its last one's µs (:meth:`EventArray.windows_by_count`)."""
    firsts: list[np.ndarray] = []  # the time of each window's first event
    lasts: list[np.ndarray] = []  # and of its last one (full windows)
    seen = 0
    t_end = None
    for chunk in chunks:
        m = len(chunk)
        if not m:
            continue
        t = chunk.t
        firsts.append(t[(-seen) % n::n])
        lasts.append(t[(n - 1 - seen) % n::n])
        seen += m
        t_end = int(t[-1])
        # (a window is complete once the next one's first event is in: it bounds its end)
        if max_windows is not None and seen > max_windows * n:
            break
    if not seen:
        return []
    first = np.concatenate(firsts).astype(np.int64)
    last = np.concatenate(lasts).astype(np.int64)
    if len(last) < len(first):
        last = np.r_[last, t_end]  # the last window, shorter than n
    end = last + 1
    end[:-1] = np.minimum(end[:-1], first[1:])
    if t1 is not None:
        end[-1] = min(int(end[-1]), int(t1))
    starts = np.arange(len(first), dtype=np.int64) * n
    stops = np.minimum(starts + n, seen)
    return [Window(k, int(a), int(b), int(s), int(e))
            for k, (a, b, s, e) in enumerate(zip(first, end, starts, stops, strict=True))
            if e - s >= need]


def _duration_windows(chunks, d: int, t0: int | None, t1: int | None, need: int,
                      max_windows: int | None) -> list[Window]:
    """The occupied cells of the grid ``origin + k d`` (``origin``: ``t0`` or the first
    event), each a window indexed by its cell."""
    cells: list[list[int]] = []  # [cell, first event, count] of each occupied cell
    origin = t0
    seen = 0
    t_end = None
    for chunk in chunks:
        if not len(chunk):
            continue
        if origin is None:
            origin = int(chunk.t[0])
        k = (chunk.t - origin) // d
        first = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
        counts = np.diff(np.r_[first, len(k)])
        for a, c in zip(first.tolist(), counts.tolist(), strict=True):
            cell = int(k[a])
            if cells and cells[-1][0] == cell:
                cells[-1][2] += c  # the cell began in an earlier chunk
            else:
                cells.append([cell, seen + a, c])
        seen += len(k)
        t_end = int(chunk.t[-1])
        if (max_windows is not None
                and sum(c >= need for _, _, c in cells[:-1]) >= max_windows):
            break  # (the last cell may still grow)
    if not cells:
        return []
    end = t_end + 1 if t1 is None else int(t1)
    return [Window(cell, origin + cell * d, min(origin + (cell + 1) * d, end), s, s + c)
            for cell, s, c in cells if c >= need]


def window_blocks(chunks: Iterable[EventArray], windows: Sequence[Window], *,
                  block_events: int | None = None
                  ) -> Iterator[tuple[EventArray, list[Window], list[int]]]:
    """The events of ``windows`` (in order, not overlapping, ``start``/``stop`` indexing
    the concatenated ``chunks``) a block at a time.

    Parameters
    ----------
    chunks : iterable of EventArray
        The stream the windows were cut from (:func:`make_windows_streaming`), read again.
    windows : sequence of Window
    block_events : int, optional
        Events a block spans at most, from its first window's first event to its last
        window's last (a longer window is a block of its own); default
        :data:`BLOCK_EVENTS`.

    Yields
    ------
    block : EventArray
        The events from the block's first window's start to its last window's stop.
    windows : list of Window
        The block's windows, ``start``/``stop`` indexing ``block``.
    positions : list of int
        Their positions in ``windows``.

    Raises
    ------
    ParameterError
        The stream ends before the windows do (it is not the one they were cut from).

    Examples
    --------
    >>> ev = EventArray(x=np.zeros(10), y=np.zeros(10), t=np.arange(0, 1000, 100),
    ...                 p=np.ones(10), sensor_size=(4, 4))
    >>> ws = ev.windows_by_count(3)
    >>> for block, bw, pos in window_blocks((ev[i:i + 4] for i in range(0, 10, 4)), ws,
    ...                                     block_events=6):
    ...     print(len(block), [(w.start, w.stop) for w in bw], pos)
    6 [(0, 3), (3, 6)] [0, 1]
    4 [(0, 3), (3, 4)] [2, 3]
    """
    block_events = whole_number("block_events", BLOCK_EVENTS if block_events is None
                                else block_events, lo=1)
    stream = iter(chunks)
    held: list[EventArray] = []
    held_start = 0  # stream index of the first event held
    held_stop = 0  # and one past the last
    pos = 0
    while pos < len(windows):
        first = windows[pos]
        last = pos + 1
        while (last < len(windows)
               and windows[last].stop - first.start <= block_events):
            last += 1
        stop = windows[last - 1].stop
        while held_stop < stop:
            chunk = next(stream, None)
            if chunk is None:
                raise ParameterError(f"the event stream ends at event {held_stop:,}, "
                                     f"before window {windows[last - 1].index} "
                                     f"(events up to {stop:,}): not the stream the "
                                     "windows were cut from")
            held.append(chunk)
            held_stop += len(chunk)
        joined = held[0] if len(held) == 1 else concatenate(held, validate=False)
        block = joined[first.start - held_start:stop - held_start]
        yield (block,
               [Window(w.index, w.t0, w.t1, w.start - first.start, w.stop - first.start)
                for w in windows[pos:last]],
               list(range(pos, last)))
        # only the events past the block are kept for the next one
        held = [joined[stop - held_start:]]
        held_start = stop
        pos = last
