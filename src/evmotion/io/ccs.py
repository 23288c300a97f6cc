"""The published event-based BOS recordings (co-capture system, ``tub-rip/event_based_bos``).

Layout of a sequence folder::

    <sequence>/prophesee_0/events.hdf5        group raw_events: x, y, t (µs), p (0/1)
    <sequence>/prophesee_0/trigger_events.txt Metavision trigger log (frame times)
    <sequence>/basler_0/frames/*.png          frames (or basler_0/frames.mp4)
    <sequence>/homography.txt                 3x3, frame pixels -> event pixels

The events are those of a Prophesee Gen4 (1280x720) in the event camera's clock, in
which the trigger log also gives the frame times; the frames are read by
:func:`evmotion.io.frames.read_frames`. ``path`` may be the sequence folder or the
``events.hdf5`` file itself.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError, ParameterError
from evmotion.events import EventArray
from evmotion.io.base import FormatSpec
from evmotion.io.guard import open_h5
from evmotion.io.h5filters import HDF5_MAGIC

__all__ = ["FORMAT", "describe", "iter_chunks", "read", "read_frames"]

SENSOR_SIZE = (720, 1280)


def _events_file(path: Path) -> Path:
    return path / "prophesee_0" / "events.hdf5" if path.is_dir() else path


@contextmanager
def _group(path: Path):

    f_path = _events_file(path)
    f = open_h5(f_path)
    with f:
        for k in "xytp":
            if f"raw_events/{k}" not in f:
                raise FormatError(f_path, f"lacks dataset 'raw_events/{k}'")
        g = f["raw_events"]
        n = {int(g[k].shape[0]) for k in "xytp"}
        if len(n) != 1:
            raise FormatError(f_path, f"raw_events columns differ in length: {sorted(n)}")
        yield f_path, g


def _first_at_or_after(t, value: int) -> int:
    """First index with ``t >= value`` by bisection on the dataset (a few reads, not the
    whole column: recordings hold up to 200 M events)."""
    lo, hi = 0, int(t.shape[0])
    while lo < hi:
        mid = (lo + hi) // 2
        if int(t[mid]) < value:
            lo = mid + 1
        else:
            hi = mid
    return lo


def _range(g, t0, t1) -> tuple[int, int]:
    t = g["t"]
    lo = 0 if t0 is None else _first_at_or_after(t, int(t0))
    hi = int(t.shape[0]) if t1 is None else _first_at_or_after(t, int(t1))
    return lo, max(lo, hi)


def _make(f_path, g, lo, hi, size, validate) -> EventArray:
    x = np.asarray(g["x"][lo:hi]).astype(np.int64)
    y = np.asarray(g["y"][lo:hi]).astype(np.int64)
    h, w = size
    if x.size and (x.min() < 0 or y.min() < 0 or x.max() >= w or y.max() >= h):
        raise FormatError(f_path, f"events reach x={x.max()}, y={y.max()} outside the "
                          f"{w}x{h} sensor", "give sensor_size=(height, width)")
    return EventArray(x, y, np.asarray(g["t"][lo:hi]).astype(np.int64),
                      np.asarray(g["p"][lo:hi]).astype(np.uint8), size, validate=validate,
                      meta={"source": str(f_path), "format": "ccs"})


def read(path: str | os.PathLike, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, validate: bool = True) -> EventArray:
    """Events of a published BOS sequence (``t0 <= t < t1``, µs).

    Examples
    --------
    >>> import h5py
    >>> Path("CCS/hot_plate1/prophesee_0").mkdir(parents=True)
    >>> with h5py.File("CCS/hot_plate1/prophesee_0/events.hdf5", "w") as f:
    ...     for k, v in dict(x=[5, 9], y=[3, 4], t=[100, 200], p=[1, 0]).items():
    ...         f[f"raw_events/{k}"] = v
    >>> ev = read("CCS/hot_plate1/")
    >>> len(ev), ev.sensor_size, ev.t.tolist()
    (2, (720, 1280), [100, 200])
    """
    path = Path(path)
    size = tuple(sensor_size) if sensor_size is not None else SENSOR_SIZE
    with _group(path) as (f_path, g):
        lo, hi = _range(g, t0, t1)
        return _make(f_path, g, lo, hi, size, validate)


def iter_chunks(path: str | os.PathLike, chunk_events: int, *,
                sensor_size: tuple[int, int] | None = None, validate: bool = True,
                t0: int | None = None, t1: int | None = None) -> Iterator[EventArray]:
    """Stream the events in chunks of ``chunk_events``."""
    if int(chunk_events) <= 0:
        raise ParameterError(f"chunk_events must be positive, got {chunk_events}")
    path = Path(path)
    size = tuple(sensor_size) if sensor_size is not None else SENSOR_SIZE
    with _group(path) as (f_path, g):
        lo, hi = _range(g, t0, t1)
        for s in range(lo, hi, int(chunk_events)):
            yield _make(f_path, g, s, min(hi, s + int(chunk_events)), size, validate)


def read_frames(path: str | os.PathLike):
    """The sequence's frames on the event sensor (:func:`evmotion.io.frames.read_frames`)."""
    from evmotion.io.frames import read_frames as read_any

    path = Path(path)
    return read_any(path if path.is_dir() else path.parent.parent)


def describe(path: str | os.PathLike) -> dict:
    """Sensor size, event count and time range without reading the events."""
    path = Path(path)
    with _group(path) as (_, g):
        n = int(g["t"].shape[0])
        out: dict = {"format": "ccs", "sensor_size": SENSOR_SIZE, "n_events": n}
        if n:
            out.update(t_first_us=int(g["t"][0]), t_last_us=int(g["t"][n - 1]))
    return out


def _sniff(path: Path, head: bytes) -> bool:
    if path.is_dir():
        return (path / "prophesee_0" / "events.hdf5").is_file()
    if not head.startswith(HDF5_MAGIC):
        return False
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return "raw_events/t" in f and "raw_events/x" in f
    except OSError:
        return False


FORMAT = FormatSpec(name="ccs", extensions=(".hdf5",), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, describe=describe)
