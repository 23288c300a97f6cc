"""The recording a per-window command works on: its windows, cut as
:func:`evmotion.events.make_windows` cuts them within ``--t0``/``--t1``, and their events a
block at a time (:func:`open_windowed`).

A recording that may hold more than :data:`~evmotion.streamed_windows.BLOCK_EVENTS` events
is not held whole (egomotion held 2.9 GB for a 97.5 M-event file, and past 9.6 GB for
475 M; probe DL): it is read as a stream once to count each pixel's events (the hot-pixel
search) and cut the windows (twice with ``--remove-hot-pixels``, whose pixels must be known
before the windows are cut), then once more, a block of windows at a time. The windows,
their events and the results are those of the recording read whole; only the readers'
own warnings about a whole file (a pause in it) are not given. A smaller recording, and
the first ``--max-windows`` windows of any, are read as
:func:`evmotion.cli.calib.read_for_windows` reads them.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evmotion.errors import CalibrationError

#: Bytes an event takes at the least in a file whose header states no count (EVT3's
#: vectors pack the densest): a smaller file holds no more than a block and is read whole
MIN_EVENT_BYTES = 1


@dataclass
class WindowedRecording:
    """A recording's windows and where their events come from.

    Attributes
    ----------
    windows : list of Window
        In time order; ``start``/``stop`` index the recording's events as undistorted and
        without the hot pixels ``--remove-hot-pixels`` drops.
    camera : Camera or None
    grid : str
        Which pixel grid the events are on (:func:`evmotion.cli.calib.undistort_for`).
    sensor_size : tuple of int
    meta : dict
        The events' ``meta`` (``undistort_dropped``: events undistortion left out).
    events : EventArray or None
        The events, held whole; None where they are streamed.
    """

    windows: list
    camera: Any
    grid: str
    sensor_size: tuple[int, int]
    meta: dict
    events: Any = None
    _stream: Callable[[], Iterator] | None = None

    @property
    def streamed(self) -> bool:
        return self.events is None

    def blocks(self, windows: list[int] | None = None) -> Iterator[tuple[Any, list, list[int]]]:
        """``(events, windows, positions)`` a block at a time
        (:func:`evmotion.streamed_windows.window_blocks`; one block where the events are
        held): the windows at ``positions`` of :attr:`windows` (default all), re-based to
        the block's events."""
        from evmotion.streamed_windows import window_blocks

        keep = range(len(self.windows)) if windows is None else windows
        if self.events is not None:
            yield self.events, [self.windows[k] for k in keep], list(keep)
            return
        with contextlib.closing(self._stream()) as chunks:
            for block, bw, pos in window_blocks(chunks, [self.windows[k] for k in keep]):
                yield block, bw, [keep[k] for k in pos]

    def reader(self):
        """What serves each window's events (``.window(w)`` of a window of :attr:`windows`,
        and ``.sensor_size``): the events where they are held, else an
        :class:`InOrderWindows` reading the recording again, the windows asked for in
        order."""
        return self.events if self.events is not None else InOrderWindows(self)

    def window_events(self, k: int):
        """The events of window ``k`` (streamed: read from the start of the recording)."""
        with contextlib.closing(self.blocks([k])) as blocks:
            block, bw, _ = next(blocks)
        return block.window(bw[0])


class InOrderWindows:
    """The events of a streamed :class:`WindowedRecording`'s windows, read a block at a
    time as they are asked for (in order; the last one again as often as needed)."""

    def __init__(self, rec: WindowedRecording):
        self.sensor_size = rec.sensor_size
        self._windows = rec.windows
        self._blocks = rec.blocks()
        self._block = None
        self._span = (0, 0)  # the stream's events the block holds

    def window(self, w):
        """The events of ``w`` (one of the recording's windows, none before the last one
        asked for)."""
        from evmotion.errors import ParameterError

        if self._block is not None and w.start < self._span[0]:
            raise ParameterError(f"window {w.index} asked for after a later one: a streamed "
                                 "recording's windows are read in order")
        while self._block is None or w.stop > self._span[1]:
            try:
                self._block, _, positions = next(self._blocks)
            except StopIteration:
                raise ParameterError(f"window {w.index} is not one of the recording's "
                                     "windows") from None
            self._span = (self._windows[positions[0]].start,
                          self._windows[positions[-1]].stop)
        return self._block[w.start - self._span[0]:w.stop - self._span[0]]

    def close(self) -> None:
        """Stop reading (the file is closed)."""
        self._blocks.close()


def open_windowed(args, *, n_events: int | None = None, duration_us: int | None = None,
                  min_events: int = 1, check: Callable[..., None] | None = None,
                  stream: bool = True) -> WindowedRecording:
    """The windows of ``args.file`` a per-window command processes (cut by ``n_events`` or
    ``duration_us``, those holding ``min_events`` events or more; checked and refused as
    :func:`evmotion.cli.options.select_windows` does) and their events.
    ``check(camera, grid, meta, sensor_size)`` runs once the camera is known, before the
    windows are cut. ``stream`` False: read as ``read_for_windows`` reads, whatever the
    length (an output that holds one window)."""
    from evmotion.cli.calib import read_for_windows
    from evmotion.cli.options import select_windows

    cut = {"n_events": n_events, "duration_us": duration_us, "min_events": min_events}
    if (stream and getattr(args, "max_windows", None) is None
            and _may_hold_more_than_a_block(args)):
        streamed = _streamed(args, check, **cut)
        if streamed is not None:
            return streamed
    events, cam, grid = read_for_windows(args, **cut)
    if check is not None:
        check(cam, grid, events.meta, events.sensor_size)
    windows = select_windows(args, events, file=args.file, **cut)
    return WindowedRecording(windows, cam, grid, events.sensor_size, events.meta, events)


def _may_hold_more_than_a_block(args) -> bool:
    """Whether the recording may hold more events than a block: its header's count, else
    its size at :data:`MIN_EVENT_BYTES` an event (a folder: its largest file)."""
    from evmotion.cli.options import header_event_count
    from evmotion.streamed_windows import BLOCK_EVENTS

    path = Path(args.file)
    try:
        size = (max((f.stat().st_size for f in path.iterdir() if f.is_file()), default=0)
                if path.is_dir() else path.stat().st_size)
    except OSError:
        return False  # the reader says what is wrong with it
    if size <= MIN_EVENT_BYTES * BLOCK_EVENTS:
        return False
    n = header_event_count(args.file, getattr(args, "format", None))
    return n is None or n > BLOCK_EVENTS


def _streamed(args, check, *, n_events, duration_us, min_events) -> WindowedRecording | None:
    """The recording read as a stream (see the module's text); None where its span holds
    no event, or none left, for the whole read to refuse it."""
    from evmotion.cli.calib import (
        CHUNK_EVENTS,
        hot_pixels_to_drop,
        say_undistortion_loss,
        undistorting,
    )
    from evmotion.cli.options import (
        check_time_range,
        checked_windows,
        header_event_count,
        read_kwargs,
        say_a_short_window,
    )
    from evmotion.filters import pixel_counts, remove_hot_pixels
    from evmotion.io import iter_events
    from evmotion.streamed_windows import make_windows_streaming
    from evmotion.utils import progress

    kw = read_kwargs(args)
    t0, t1 = getattr(args, "t0", None), getattr(args, "t1", None)
    remove = bool(getattr(args, "remove_hot_pixels", False))
    total = header_event_count(args.file, getattr(args, "format", None), t0, t1)
    cut = {"n_events": n_events, "duration_us": duration_us, "t0": t0, "t1": t1,
           "min_events": min_events}

    def undistorted(desc: str | None):
        """The span's events, undistorted, with a bar in events read (``desc`` None:
        none); None: no event."""
        raw = iter_events(args.file, CHUNK_EVENTS, t0=t0, t1=t1, **kw)
        bar = progress(None, total=total, desc=desc or "", unit="ev", unit_scale=True,
                       disable=True if desc is None else None)

        def read():
            try:
                for chunk in raw:
                    bar.update(len(chunk))
                    yield chunk
            finally:
                raw.close()
                bar.close()

        return undistorting(args, read(), integer=False)

    counts = None
    seen = {"kept": 0, "dropped": 0, "first": None, "last": None}

    def counted(chunks):
        nonlocal counts
        for chunk in chunks:
            seen["dropped"] += int(chunk.meta.get("undistort_dropped", 0))
            if counts is None:
                counts = np.zeros(chunk.sensor_size, np.int64)
            if len(chunk):
                counts += pixel_counts(chunk)
            yield chunk

    def tracked(chunks):
        for chunk in chunks:
            if len(chunk):
                seen["kept"] += len(chunk)
                seen["first"] = int(chunk.t[0]) if seen["first"] is None else seen["first"]
                seen["last"] = int(chunk.t[-1])
            yield chunk

    def masked(chunks, mask):
        for chunk in chunks:
            yield chunk if mask is None else remove_hot_pixels(chunk, mask)

    first = undistorted("reading")
    if first is None:
        return None
    stream, cam, grid = first
    with contextlib.closing(stream):
        head = next(stream)
        meta, sensor_size = dict(head.meta), head.sensor_size
        if check is not None:
            check(cam, grid, meta, sensor_size)
        chunks = counted(_chained(head, stream))
        if remove:
            for _ in chunks:  # the hot pixels first: the windows are cut without them
                pass
        else:
            windows = make_windows_streaming(tracked(chunks), **cut)
    read = int(counts.sum()) + seen["dropped"]
    if read and not counts.any():
        raise CalibrationError(f"{cam.source}: undistortion moved all {read:,} events "
                               "outside the image: the wrong calibration for this sensor? "
                               "(--no-undistort keeps the sensor's grid)")
    say_undistortion_loss(seen["dropped"], read)
    # (the network finds a window's hot pixels itself: read_for_windows says nothing then)
    mask = (hot_pixels_to_drop(args, counts)
            if remove or getattr(args, "method", None) != "dnn" else None)
    if remove:
        stream = undistorted("cutting windows")[0]
        with contextlib.closing(stream):
            windows = make_windows_streaming(tracked(masked(stream, mask)), **cut)
    if not seen["kept"]:
        return None
    meta["undistort_dropped"] = seen["dropped"]
    span = (seen["first"], seen["last"])
    check_time_range(args, *span, args.file)
    checked_windows(args, windows, file=args.file, span=span, min_events=min_events)

    def again():
        undistorted_again = undistorted(None)
        return masked(iter(()) if undistorted_again is None else undistorted_again[0], mask)

    rec = WindowedRecording(windows, cam, grid, sensor_size, meta, _stream=again)
    if len(windows) == 1:
        w = windows[0]
        say_a_short_window(args, w, file=args.file, held=w.count + seen["dropped"],
                           last_t=int(rec.window_events(0).t[-1]), n_events=n_events,
                           duration_us=duration_us)
    return rec


def _chained(head, rest):
    yield head
    yield from rest


__all__ = ["MIN_EVENT_BYTES", "InOrderWindows", "WindowedRecording", "open_windowed"]
