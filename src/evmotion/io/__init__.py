"""Reading and writing events, frames, IMU and flow in every common format.

Formats are found by content (:func:`detect_format`), so ``read_events("anything")`` works
for ECD text folders, evmotion/MVSEC/DSEC HDF5, npy/npz, MATLAB excerpts, AEDAT, Prophesee
RAW/DAT and rosbags (whichever modules are installed). Every reader returns an
:class:`~evmotion.events.EventArray` with absolute int64 µs timestamps.

Examples
--------
>>> import evmotion.io as eio
>>> ev = eio.read_events("boxes_rotation/", t0=0, t1=50_000)  # doctest: +SKIP
>>> for chunk in eio.iter_events("big.h5", window_us=10_000):  # doctest: +SKIP
...     print(chunk.t_start, len(chunk))
>>> eio.write_events("out.h5", ev)  # doctest: +SKIP
"""

from __future__ import annotations

import inspect
import json
import os
import warnings
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError, ParameterError
from evmotion.events import EventArray, concatenate
from evmotion.io.aux import FrameSequence, ImuSequence, read_frames, read_imu
from evmotion.io.base import FormatSpec
from evmotion.io.flowfiles import (
    FlowSequence,
    FlowWriter,
    read_dsec_flow_png,
    read_flo,
    read_flow_h5,
    read_gt_flow,
    write_dsec_flow_png,
    write_flo,
)
from evmotion.io.flowout import open_flow_output
from evmotion.io.flowread import read_flow
from evmotion.io.guard import guard_call
from evmotion.io.registry import all_formats, get_format
from evmotion.io.registry import detect_format as _detect

__all__ = [
    "FlowSequence",
    "FlowWriter",
    "FormatSpec",
    "FrameSequence",
    "ImuSequence",
    "all_formats",
    "describe",
    "detect_format",
    "format_for_output",
    "iter_events",
    "open_flow_output",
    "read_calibration",
    "read_dsec_flow_png",
    "read_events",
    "read_flo",
    "read_flow",
    "read_flow_h5",
    "read_frames",
    "read_gt_flow",
    "read_imu",
    "write_dsec_flow_png",
    "write_events",
    "write_flo",
]


def detect_format(path: str | os.PathLike) -> str:
    """Name of the format of ``path`` (file or folder), detected by content.

    Examples
    --------
    >>> detect_format("boxes_rotation/")  # doctest: +SKIP
    'ecd'
    """
    return _detect(path).name


def _spec(path, format: str | None) -> FormatSpec:
    if format is not None:
        return get_format(format)
    return _detect(path)


def _accepts(fn, name: str) -> bool:
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False
    return name in params or any(p.kind == p.VAR_KEYWORD for p in params.values())


def read_events(path: str | os.PathLike, format: str | None = None, t0: int | None = None,
                t1: int | None = None, **kw) -> EventArray:
    """Read the events of a file or folder.

    Parameters
    ----------
    path : path-like
        File or folder (ECD layout).
    format : str, optional
        Format name (see :func:`all_formats`); default detected by content.
    t0, t1 : int, optional
        Keep events with ``t0 <= t < t1`` (absolute µs).
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
    >>> ev = read_events("shapes_rotation.mat")  # doctest: +SKIP
    """
    spec = _spec(path, format)
    return spec.read(Path(path), t0=t0, t1=t1, **kw)


def _chunks(spec: FormatSpec, path: Path, chunk_events: int, t0, t1, kw) -> Iterator[EventArray]:
    if spec.iter_chunks is None:
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
    >>> n = sum(len(c) for c in iter_events("rec.raw", 500_000))  # doctest: +SKIP
    """
    chunk_events = int(chunk_events)
    if chunk_events <= 0:
        raise ParameterError(f"chunk_events must be positive, got {chunk_events}")
    path = Path(path)
    spec = _spec(path, format)
    if window_us is not None and windows is not None:
        raise ParameterError("give window_us or windows, not both")
    if windows is not None:
        edges = np.asarray(windows, dtype=np.int64).reshape(-1, 2)
        if edges.size and (np.any(np.diff(edges[:, 0]) < 0) or np.any(edges[:, 1] < edges[:, 0])):
            raise ParameterError("windows must be (start, end) µs pairs sorted by start, "
                                 "with end >= start")
        if not edges.size:
            return
        lo = int(edges[0, 0]) if t0 is None else max(int(t0), int(edges[0, 0]))
        hi = int(edges[:, 1].max()) if t1 is None else min(int(t1), int(edges[:, 1].max()))
        yield from _explicit_windows(_chunks(spec, path, chunk_events, lo, hi, kw), edges)
        return
    chunks = _chunks(spec, path, chunk_events, t0, t1, kw)
    if window_us is None:
        yield from chunks
        return
    window_us = int(window_us)
    if window_us <= 0:
        raise ParameterError(f"window_us must be positive, got {window_us}")
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


def _explicit_windows(chunks: Iterable[EventArray], edges: np.ndarray
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
    while template is not None and k < len(edges):
        yield emit(k)
        k += 1


# Extensions shared by several formats (jAER also used .dat) get their usual meaning.
_EXT_WRITERS = {".h5": "h5", ".hdf5": "h5", ".txt": "ecd", ".npy": "npy", ".npz": "npy",
                ".dat": "dat", ".raw": "evt3", ".aedat4": "aedat4", ".aedat": "aedat2"}


def format_for_output(path: str | os.PathLike) -> str:
    """Format name chosen for writing ``path`` from its extension.

    Examples
    --------
    >>> format_for_output("out.h5")
    'h5'
    """
    path = Path(path)
    suffix = path.suffix.lower()
    formats = all_formats()
    known = {f.name for f in formats if f.write is not None}
    if _EXT_WRITERS.get(suffix) in known:
        return _EXT_WRITERS[suffix]
    for spec in formats:
        if spec.write is not None and suffix in spec.extensions:
            return spec.name
    writable = sorted({s for f in all_formats() if f.write for s in f.extensions})
    raise FormatError(path, f"cannot tell the output format from the extension '{suffix}'",
                      f"use one of {', '.join(writable)} or give format=")


_STREAMING_WRITERS = ("h5", "ecd")


def write_events(path: str | os.PathLike, events: EventArray | Iterable[EventArray],
                 format: str | None = None, **meta) -> None:
    """Write events atomically (nothing appears at ``path`` until the file is complete).

    Parameters
    ----------
    path : path-like
        Output file; the format follows the extension (``.h5`` evmotion HDF5, ``.txt``
        ECD text, ``.npz``/``.npy``, ``.raw``, ``.dat``, ``.aedat4``...).
    events : EventArray or iterable of EventArray
        Chunks in time order are streamed in bounded memory by the ``h5`` and ``ecd``
        writers (others concatenate them first).
    format : str, optional
        Format name, overriding the extension.
    **meta
        Writer options (e.g. ``calibration={...}`` for ``h5``); any other keyword is
        metadata, stored in the ``h5`` provenance attribute (other formats cannot store
        it and warn).

    Examples
    --------
    >>> write_events("out.h5", ev, provenance={"tool": "evmotion convert"})  # doctest: +SKIP
    """
    name = format or format_for_output(path)
    spec = get_format(name)
    if spec.write is None:
        raise FormatError(path, f"format '{name}' is read-only",
                          "write .h5, .txt, .npz or another writable format")
    if not isinstance(events, EventArray) and name not in _STREAMING_WRITERS:
        events = concatenate(list(events))
    opts, extra = {}, {}
    for k, v in meta.items():
        (opts if _accepts_named(spec.write, k) else extra)[k] = v
    if extra:
        if _accepts_named(spec.write, "provenance"):
            opts["provenance"] = {**(opts.get("provenance") or {}), **extra}
        else:
            warnings.warn(f"format '{name}' cannot store metadata {sorted(extra)}; "
                          "write .h5 to keep it", stacklevel=2)
    spec.write(Path(path), events, **opts)


def _accepts_named(fn, name: str) -> bool:
    try:
        return name in inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False


def read_calibration(path: str | os.PathLike) -> dict:
    """Camera calibration stored with a recording.

    Accepts an ECD ``calib.txt`` or a folder holding one, or an evmotion HDF5 file with a
    ``calibration`` attribute.

    Returns
    -------
    dict
        ``K`` (3x3 nested list, px), ``dist`` (``[k1, k2, p1, p2, k3]`` radial-tangential),
        ``fx, fy, cx, cy``, ``model``, ``source`` and ``sensor_size`` when known.

    Examples
    --------
    >>> read_calibration("boxes_rotation/")["dist"][:2]  # doctest: +SKIP
    [-0.368436311798, 0.150947243557]
    """
    from evmotion.io import ecd

    path = Path(path)
    if not path.exists():
        raise FormatError(path, "no such file or folder")
    if path.is_dir() or path.suffix.lower() == ".txt":
        return ecd.read_calibration(path)
    with open(path, "rb") as fh:
        head = fh.read(8)
    if head.startswith(b"\x89HDF\r\n\x1a\n"):
        return guard_call(_h5_calibration, "HDF5", "read the calibration")(path)
    raise FormatError(path, "no calibration found",
                      "give an ECD calib.txt or an evmotion .h5 with calibration; YAML "
                      "calibrations are read by evmotion.camera.Camera.from_file")


def _h5_calibration(path: Path) -> dict:
    import h5py

    with h5py.File(path, "r") as f:
        if "calibration" in f.attrs:
            cal = json.loads(f.attrs["calibration"])
            if not isinstance(cal, dict):
                raise FormatError(path, "attribute 'calibration' is not a JSON object")
            cal.setdefault("sensor_size", [int(f.attrs["height"]), int(f.attrs["width"])]
                           if "height" in f.attrs else None)
            return cal
    raise FormatError(path, "no 'calibration' attribute in this HDF5 file")


def describe(path: str | os.PathLike, format: str | None = None, *,
             chunk_events: int = 1_000_000, stream: bool = True, **kw) -> dict:
    """Summary of a recording, computed by streaming (bounded memory).

    Returns
    -------
    dict
        ``format``, ``sensor_size`` (height, width), ``n_events``, ``t_first_us``,
        ``t_last_us``, ``duration_s``, ``rate_ev_per_s``, ``positive_fraction``
        (polarity balance), ``x_range``, ``y_range`` and what else the file holds
        (``frames``, ``imu``, ``ground_truth``, ``calibration``...) from the format's
        own ``describe``, and ``frames_info`` (count, size, bit depth, time span, fps) for
        co-captured frames (:func:`evmotion.io.frames.describe_frames`); a folder of frames
        without events gives format ``frames``. With ``stream=False`` only the format's
        header summary.

    Examples
    --------
    >>> describe("boxes_rotation/")["n_events"]  # doctest: +SKIP
    30000
    """
    from evmotion.io.frames import VIDEO_SUFFIXES, describe_frames

    path = Path(path)
    try:
        spec = _spec(path, format)
    except FormatError:
        flow = guard_call(_describe_flow, "flow", "describe")(path) if format is None else None
        if flow is None:
            frames = describe_frames(path) if format is None and (
                path.is_dir() or path.suffix.lower() in VIDEO_SUFFIXES) else None
            if frames is None:
                raise
            return {"path": str(path), "format": "frames", "frames_info": frames}
        return flow
    out: dict = {"path": str(path), "format": spec.name}
    if spec.describe is not None:
        extra = spec.describe(path)
        out.update({k: v for k, v in extra.items() if k != "format"})
    try:
        frames = describe_frames(path)
    except FormatError as exc:
        frames = {"error": str(exc)}
    if frames is not None:
        out["frames_info"] = frames
    if not stream:
        return out
    n = 0
    n_pos = 0
    t_first = t_last = None
    xmin = ymin = np.inf
    xmax = ymax = -np.inf
    size = None
    for chunk in iter_events(path, chunk_events, format=spec.name, **kw):
        if not len(chunk):
            continue
        size = chunk.sensor_size
        n += len(chunk)
        n_pos += int(np.count_nonzero(chunk.p))
        if t_first is None:
            t_first = int(chunk.t[0])
        t_last = int(chunk.t[-1])
        xmin, xmax = min(xmin, float(chunk.x.min())), max(xmax, float(chunk.x.max()))
        ymin, ymax = min(ymin, float(chunk.y.min())), max(ymax, float(chunk.y.max()))
    if size is not None:
        out["sensor_size"] = tuple(size)
    out["n_events"] = n
    if n:
        dur = (t_last - t_first) * 1e-6
        out.update(t_first_us=t_first, t_last_us=t_last, duration_s=dur,
                   rate_ev_per_s=(n / dur) if dur > 0 else None,
                   positive_fraction=n_pos / n, x_range=[xmin, xmax], y_range=[ymin, ymax])
    return out


def _describe_flow(path: Path) -> dict | None:
    """Summary of an optical-flow HDF5 file (not events), or None if it is not one."""
    from evmotion.io.flowfiles import FLOW_FORMAT, SIM_GT_FORMAT

    if not path.is_file():
        return None
    with open(path, "rb") as fh:
        if not fh.read(8).startswith(b"\x89HDF\r\n\x1a\n"):
            return None
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError:
        return None
    with f:
        fmt = f.attrs.get("format")
        if fmt == FLOW_FORMAT and "t1" in f:
            t0, t1 = f["t0"][: f["t1"].shape[0]], f["t1"][:]
        elif fmt == SIM_GT_FORMAT and "frame_times_us" in f:
            ft = f["frame_times_us"][:]
            t0, t1 = ft[:-1], ft[1:]
        else:
            return None
        out = {"path": str(path), "format": str(fmt), "sensor_size": tuple(
            int(v) for v in f["flow"].shape[1:3]), "windows": int(len(t1)),
            "units": "px/s", "valid_masks": "valid" in f or "event_masks" in f}
        if len(t1):
            out.update(t_first_us=int(t0[0]), t_last_us=int(t1[-1]),
                       duration_s=(int(t1[-1]) - int(t0[0])) * 1e-6)
        return out
