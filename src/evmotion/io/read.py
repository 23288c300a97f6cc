"""Reading events: a whole file or folder (:func:`read_events`), or streamed in bounded
memory as fixed-size chunks or time windows (:func:`iter_events`).

Examples
--------
>>> from evmotion.io.read import iter_events, read_events
>>> from evmotion.io.write import write_events
>>> write_events("boxes_rotation/events.txt", EventArray(  # an ECD folder
...     x=[1, 2, 3, 4, 5], y=[0, 1, 2, 3, 4], t=[0, 5_000, 15_000, 25_000, 60_000],
...     p=[1, 0, 1, 0, 1], sensor_size=(180, 240)))
>>> ev = read_events("boxes_rotation/", t0=0, t1=50_000)
>>> write_events("big.h5", ev)
>>> for chunk in iter_events("big.h5", window_us=10_000):
...     print(chunk.t_start, len(chunk))
0 2
15000 1
25000 1
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from evmotion.errors import ParameterError
from evmotion.events import EventArray, concatenate
from evmotion.io.base import FormatSpec
from evmotion.io.guard import given_sensor_size
from evmotion.io.registry import resolve_format
from evmotion.utils import whole_number

__all__ = ["iter_events", "read_events"]


def _accepts(fn, name: str) -> bool:
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False
    return name in params or any(p.kind == p.VAR_KEYWORD for p in params.values())


def read_events(path: str | os.PathLike, format: str | None = None, t0: int | None = None,
                t1: int | None = None, *, warn_empty: bool = True, **kw) -> EventArray:
    """Read the events of a file or folder.

    Parameters
    ----------
    path : path-like
        File or folder (ECD layout).
    format : str, optional
        Format name (see :func:`all_formats`); default detected by content.
    t0, t1 : int, optional
        Keep events with ``t0 <= t < t1`` (absolute µs).
    warn_empty : bool
        Warn (naming the recording's span) when ``t0``/``t1`` select no event (default);
        False for a caller that refuses the empty span itself.
    **kw
        Reader options, e.g. ``sensor_size=(height, width)`` (every reader accepts it).

    Returns
    -------
    EventArray

    Raises
    ------
    FormatError
        For a corrupt, truncated or unreadable file: one line naming the file (the
        low-level exception, if any, is chained as ``__cause__``).

    Examples
    --------
    >>> import scipy.io
    >>> scipy.io.savemat("shapes_rotation.mat",  # N x 4 rows t [µs], x, y, p
    ...                  {"seq": np.array([[100, 3, 4, 1], [200, 5, 6, 0]], float)})
    >>> ev = read_events("shapes_rotation.mat")
    >>> ev.meta["format"], ev.t.tolist(), ev.x.tolist()
    ('mat', [100, 200], [3, 5])
    """
    _check_path(path)
    _check_span(t0, t1)
    _check_sensor_size(kw)
    spec = resolve_format(path, format)
    _check_time_unit(path, spec, kw)
    events = spec.read(Path(path), t0=t0, t1=t1, **kw)
    if warn_empty and (t0 is not None or t1 is not None) and not len(events):
        _warn_outside(path, format, t0, t1, kw)
    if t0 is None and t1 is None and len(events) > 1:
        gaps = np.diff(np.asarray(events.t, np.int64))
        k = int(np.argmax(gaps))
        warn_time_jump(path, int(gaps[k]), k, int(events.t[-1]) - int(events.t[0]),
                       len(events))
    return events


def _check_path(path) -> None:
    """A str or path-like, else ParameterError (bytes or an int met pathlib's TypeError)."""
    if not isinstance(path, (str, os.PathLike)):
        raise ParameterError(f"path must be a str or a path-like object, got "
                             f"{type(path).__name__} {path!r}")


def _check_time_unit(path, spec, kw: dict) -> None:
    """``time_unit=`` refused in words for a format whose times carry their unit (it was
    "dat read: got an unexpected keyword argument 'time_unit'", probe BL)."""
    import inspect

    if kw.get("time_unit") is not None and \
            "time_unit" not in inspect.signature(spec.read).parameters:
        raise ParameterError(f"time_unit={kw['time_unit']!r}: {path} is '{spec.name}', "
                             "whose times carry their unit; it applies to text, NumPy, "
                             "MATLAB, MVSEC-layout and other tools' HDF5 files")


def _check_sensor_size(kw: dict) -> None:
    """A reader's ``sensor_size=`` in ``kw`` checked once for every format (the text
    reader had taken "big" for a corrupt file), as ints."""
    if kw.get("sensor_size") is not None:
        kw["sensor_size"] = given_sensor_size(kw["sensor_size"])


#: One pause between consecutive events longer than this share of a whole recording's span
#: (and than ``JUMP_MIN_US``) is said: the largest in the project's real recordings is 1 %
#: of theirs; 16 flipped bytes in an EVT3 body moved 55 % of its events 10.6 s on.
JUMP_SHARE = 0.5
JUMP_MIN_US = 1_000_000


def warn_time_jump(path, gap_us: int, index: int, span_us: int, n_events: int) -> str | None:
    """Warn (EvmotionWarning) when a whole recording of ``n_events`` spanning ``span_us``
    pauses ``gap_us`` between events ``index`` and ``index + 1``, more than
    ``JUMP_SHARE`` of its span (and ``JUMP_MIN_US``): a corrupt time field, or a camera
    that stopped; returns the message (else None).

    Examples
    --------
    >>> import warnings
    >>> with warnings.catch_warnings(record=True):
    ...     print(warn_time_jump("a.raw", 5_000_000, 1, 5_000_010, 3)[:40])
    a.raw: no event for 5 s between events 1
    """
    if not (gap_us > JUMP_MIN_US and gap_us > JUMP_SHARE * span_us):
        return None
    import warnings

    from evmotion.errors import EvmotionWarning

    msg = (f"{path}: no event for {gap_us / 1e6:.3g} s between events {index} and "
           f"{index + 1}, {gap_us / span_us:.0%} of the recording's {span_us / 1e6:.3g} s "
           f"({n_events - index - 1:,} events after it): a corrupt time field, or a camera "
           "that stopped? --t0/--t1 cut the part to use")
    warnings.warn(EvmotionWarning(msg), stacklevel=3)
    return msg


def _warn_outside(path, format, t0, t1, kw) -> None:
    """Say where the recording's events are when ``[t0, t1)`` holds none of them (an ECD
    excerpt starting at 13.58 s read from 0 returned nothing, unsaid; probe AI)."""
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.io.summary import describe

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the reader's warnings were given with the read
        info = describe(path, format, **kw)
    first, last = info.get("t_first_us"), info.get("t_last_us")
    where = ("the recording holds no event" if first is None else
             f"the recording spans {first}..{last} us (its own clock, as evmotion info "
             "shows it)")
    warnings.warn(EvmotionWarning(f"{path}: no event in [{t0}, {t1}) us: {where}"),
                  stacklevel=3)


def _check_span(t0, t1) -> None:
    """``t0``, ``t1``: whole µs (or None), ``t1`` after ``t0``; ParameterError otherwise
    (``t0 > t1`` gave no event, silently)."""
    for name, v in (("t0", t0), ("t1", t1)):
        if v is not None:
            whole_number(name, v)
    if t0 is not None and t1 is not None and int(t1) <= int(t0):
        raise ParameterError(f"t1 = {t1} µs must be after t0 = {t0} µs")


def _chunks(spec: FormatSpec, path: Path, chunk_events: int, t0, t1, kw) -> Iterator[EventArray]:
    if spec.iter_chunks is None or not all(_accepts(spec.iter_chunks, k) for k in kw):
        # a format that streams without the option (sensor_size of .npy) reads whole
        ev = spec.read(path, t0=t0, t1=t1, **kw)
        for s in range(0, len(ev), chunk_events):
            yield ev[s:s + chunk_events]
        return
    if _accepts(spec.iter_chunks, "t0"):
        yield from spec.iter_chunks(path, chunk_events, t0=t0, t1=t1, **kw)
        return
    for chunk in spec.iter_chunks(path, chunk_events, **kw):
        if t1 is not None and len(chunk) and chunk.t[0] >= t1:
            return
        if t0 is not None or t1 is not None:
            if len(chunk) and ((t0 is not None and chunk.t[0] < t0)
                               or (t1 is not None and chunk.t[-1] >= t1)):
                chunk = chunk.slice_time(t0, t1)
        if len(chunk):
            yield chunk


def iter_events(path: str | os.PathLike, chunk_events: int = 1_000_000, *,
                window_us: int | None = None, windows=None, format: str | None = None,
                t0: int | None = None, t1: int | None = None, drop_empty: bool = False,
                **kw) -> Iterator[EventArray]:
    """Stream a file in bounded memory: chunks of ``chunk_events`` events, or time windows.

    Parameters
    ----------
    path : path-like
        File or folder.
    chunk_events : int
        Events per chunk (the last may be shorter); also the read granularity for windows.
    window_us : int, optional
        Yield consecutive windows ``[t0 + k·window_us, t0 + (k+1)·window_us)`` (µs) instead
        of fixed-count chunks; ``t0`` defaults to the first event's time. Memory is bounded
        by one window plus one chunk.
    windows : sequence of (int, int), optional
        Explicit windows ``[a, b)`` in µs, sorted by start, possibly overlapping (e.g.
        between ground-truth timestamps); one EventArray per window, in order. Memory is
        bounded by the events spanned by the windows open at once plus one chunk.
    format : str, optional
        Format name; default detected by content.
    t0, t1 : int, optional
        Restrict to ``t0 <= t < t1`` (µs).
    drop_empty : bool
        With ``window_us``, skip windows without events (default: yield them empty, so
        window ``k`` is always the k-th item).

    Yields
    ------
    EventArray
        With ``meta["window"] = (t_start, t_end)`` in µs when ``window_us`` is given.

    Examples
    --------
    >>> from evmotion.io.write import write_events
    >>> write_events("rec.raw", EventArray(x=[1, 2, 3], y=[0, 0, 0], t=[10, 20, 30],
    ...                                    p=[1, 0, 1], sensor_size=(180, 240)))
    >>> [len(c) for c in iter_events("rec.raw", 2)]
    [2, 1]
    """
    # (whole: "3" read as 3, 1.5 as 1 and True as 1 had passed: probe)
    chunk_events = whole_number("chunk_events", chunk_events, lo=1)
    _check_path(path)
    _check_span(t0, t1)
    _check_sensor_size(kw)
    path = Path(path)
    spec = resolve_format(path, format)
    _check_time_unit(path, spec, kw)
    if window_us is not None and windows is not None:
        raise ParameterError("give window_us or windows, not both")
    if windows is not None:
        edges = _window_edges(windows)
        if not edges.size:
            return
        lo = int(edges[0, 0]) if t0 is None else max(int(t0), int(edges[0, 0]))
        hi = int(edges[:, 1].max()) if t1 is None else min(int(t1), int(edges[:, 1].max()))
        def first() -> EventArray | None:
            # the file's first event: the empty windows' template (sensor size, meta) where
            # none of the span's events is read (windows past the recording yielded
            # nothing, probe CB)
            return next(iter(_chunks(spec, path, 1, None, None, kw)), None)

        yield from _explicit_windows(
            _chunks(spec, path, chunk_events, lo, max(hi, lo + 1), kw), edges, first)
        return
    chunks = _chunks(spec, path, chunk_events, t0, t1, kw)
    if window_us is None:
        yield from chunks
        return
    window_us = whole_number("window_us (microseconds)", window_us, lo=1)
    yield from _windows(chunks, window_us, t0, drop_empty)


def _windows(chunks: Iterable[EventArray], window_us: int, t0: int | None,
             drop_empty: bool) -> Iterator[EventArray]:
    pending: list[EventArray] = []
    start = t0
    template: EventArray | None = None

    def emit(parts: list[EventArray], a: int) -> EventArray:
        ev = concatenate(parts) if len(parts) > 1 else (parts[0] if parts else template[:0])
        ev.meta = {**template.meta, "window": (a, a + window_us)}
        return ev

    for chunk in chunks:
        if not len(chunk):
            continue
        template = chunk
        if start is None:
            start = int(chunk.t[0])
        while True:
            end = start + window_us
            if chunk.t[-1] < end:
                pending.append(chunk)
                break
            cut = int(np.searchsorted(chunk.t, end, side="left"))
            head, chunk = chunk[:cut], chunk[cut:]
            if len(head):
                pending.append(head)
            if pending or not drop_empty:
                yield emit(pending, start)
            pending = []
            start = end
    if pending:
        yield emit(pending, start)


def _window_edges(windows) -> np.ndarray:
    """``windows`` as an (n, 2) int64 array of whole µs, sorted by start, end >= start;
    ParameterError otherwise (seconds had become (1, 1), windows without events, and a
    NaN or a 3-tuple numpy's ValueError; probe CB)."""
    try:
        edges = np.asarray(windows, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"windows must be (start, end) pairs of whole µs, got "
                             f"{windows!r:.80}") from None
    if edges.size == 0:
        return np.empty((0, 2), np.int64)
    if edges.ndim != 2 or edges.shape[1] != 2:
        raise ParameterError(f"windows must be (start, end) pairs of whole µs, got an array "
                             f"of shape {edges.shape}")
    if not np.all(np.isfinite(edges)):
        raise ParameterError("windows must be finite (start, end) µs pairs, got "
                             f"{edges[~np.isfinite(edges).all(axis=1)][0].tolist()}")
    if np.any(edges != np.round(edges)):
        bad = edges[(edges != np.round(edges)).any(axis=1)][0].tolist()
        raise ParameterError(f"windows are whole µs, got {bad}: seconds? (multiply by 1e6)")
    edges = edges.astype(np.int64)
    if np.any(np.diff(edges[:, 0]) < 0) or np.any(edges[:, 1] < edges[:, 0]):
        raise ParameterError("windows must be (start, end) µs pairs sorted by start, "
                             "with end >= start")
    return edges


def _explicit_windows(chunks: Iterable[EventArray], edges: np.ndarray, first
                      ) -> Iterator[EventArray]:
    buf: EventArray | None = None
    k = 0
    template: EventArray | None = None

    def emit(i: int) -> EventArray:
        a, b = int(edges[i, 0]), int(edges[i, 1])
        ev = buf.slice_time(a, b) if buf is not None else template[:0]
        ev.meta = {**template.meta, "window": (a, b)}
        return ev

    for chunk in chunks:
        if not len(chunk):
            continue
        template = chunk
        buf = chunk if buf is None else concatenate([buf, chunk])
        t_seen = int(chunk.t[-1])
        # A window is complete once an event at or after its end has been read.
        while k < len(edges) and edges[k, 1] <= t_seen:
            yield emit(k)
            k += 1
        keep_from = int(edges[k, 0]) if k < len(edges) else t_seen + 1
        buf = buf.slice_time(keep_from, None)
    if template is None and k < len(edges):
        template = first()
    while template is not None and k < len(edges):
        yield emit(k)
        k += 1
