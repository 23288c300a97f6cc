"""Summary of a recording (:func:`describe`): what ``evmotion info`` prints. Events are
counted by streaming; flow files and folders of frames are summarised too.

Examples
--------
>>> from evmotion import EventArray
>>> from evmotion.io import write_events
>>> from evmotion.io.summary import describe
>>> write_events("boxes_rotation/events.txt", EventArray(
...     x=[1, 2, 3], y=[0, 1, 2], t=[0, 10_000, 20_000], p=[1, 0, 1], sensor_size=(180, 240)))
>>> describe("boxes_rotation/")["n_events"]
3
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError
from evmotion.io.guard import guard_call
from evmotion.io.h5attrs import read_attrs
from evmotion.io.h5filters import is_hdf5
from evmotion.io.read import iter_events, warn_time_jump
from evmotion.io.registry import own_output_folder, resolve_format

__all__ = ["describe"]


def describe(path: str | os.PathLike, format: str | None = None, *,
             chunk_events: int = 1_000_000, stream: bool = True, progress: bool = False,
             **kw) -> dict:
    """Summary of a recording, computed by streaming (bounded memory); ``progress``: a
    progress bar over the events read (rate, and ETA where the header states their count
    or the reader the share of the file read).

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
    >>> from evmotion import EventArray
    >>> from evmotion.io import write_events
    >>> write_events("boxes_rotation/events.txt", EventArray(
    ...     x=[1, 2, 3], y=[0, 1, 2], t=[0, 10_000, 20_000], p=[1, 0, 1], sensor_size=(180, 240)))
    >>> d = describe("boxes_rotation/")
    >>> d["format"], d["n_events"], d["t_last_us"], d["sensor_size"]
    ('ecd', 3, 20000, (180, 240))
    """
    from evmotion.io.frames import VIDEO_SUFFIXES, describe_frames

    path = Path(path)
    try:
        spec = resolve_format(path, format)
    except FormatError:
        flow = guard_call(_describe_flow, "flow", "describe")(path) if format is None else None
        if flow is None:
            if own_output_folder(path) is not None:
                raise  # its PNG panels are no frames
            frames = describe_frames(path) if format is None and (
                path.is_dir() or path.suffix.lower() in VIDEO_SUFFIXES) else None
            if frames is None:
                raise
            return {"path": str(path), "format": "frames", "frames_info": frames}
        return flow
    out: dict = {"path": str(path), "format": spec.name}
    if spec.describe is not None:
        try:
            extra = spec.describe(path)
        except FormatError:
            if kw.get("sensor_size") is None:
                raise
            extra = {}  # a header that cannot size the sensor: the size given does
        out.update({k: v for k, v in extra.items() if k != "format"})
    # the same keys for every format: one that cannot hold frames or IMU samples has none
    out.setdefault("frames", 0)
    out.setdefault("imu", 0)
    try:
        # (an EVT2 file named .aedat4 was described as AEDAT4 frames, "bad magic", by its
        # extension: probe BL)
        frames = (describe_frames(path) if path.is_dir() or spec.name == "aedat4"
                  or path.suffix.lower() != ".aedat4" else None)
    except FormatError as exc:
        frames = {"error": str(exc)}
    if frames is not None:
        out["frames_info"] = frames
    if not stream:
        if kw.get("sensor_size") is not None:
            # the size given, as the readers take it over the header's (--header-only
            # said "unknown" beside it, or the header's other size, probe CA)
            out["sensor_size"] = tuple(int(v) for v in kw["sensor_size"])
        return out
    n = 0
    n_pos = 0
    t_first = t_last = None
    xmin = ymin = np.inf
    xmax = ymax = -np.inf
    size = None
    gap = (0, 0)  # the longest pause between consecutive events and the index before it
    from evmotion.utils import progress as progress_bar
    from evmotion.utils import refine_total

    total = out.get("n_events") if isinstance(out.get("n_events"), int) else None
    bar = progress_bar(None, total=total or None, desc="info", unit="ev", unit_scale=True,
                       disable=None if progress else True)
    for chunk in iter_events(path, chunk_events, format=spec.name, **kw):
        if not len(chunk):
            continue
        bar.update(len(chunk))
        if not total:
            refine_total(bar, n + len(chunk), chunk.meta)
        t = np.asarray(chunk.t, np.int64)
        d = np.diff(t, prepend=t[0] if t_last is None else t_last)
        k = int(np.argmax(d))
        if d[k] > gap[0]:
            gap = (int(d[k]), n + k - 1)
        if size is None and chunk.meta.get("sensor_size_from"):
            # the reader's word: the header alone may have guessed another size
            out["sensor_size_from"] = chunk.meta["sensor_size_from"]
        if size is None and chunk.meta.get("time_unit"):  # how the events were read
            out["time_unit"] = chunk.meta["time_unit"]
        size = chunk.sensor_size
        n += len(chunk)
        n_pos += int(np.count_nonzero(chunk.p))
        if t_first is None:
            t_first = int(chunk.t[0])
        t_last = int(chunk.t[-1])
        xmin, xmax = min(xmin, float(chunk.x.min())), max(xmax, float(chunk.x.max()))
        ymin, ymax = min(ymin, float(chunk.y.min())), max(ymax, float(chunk.y.max()))
    bar.close()
    if size is not None:
        out["sensor_size"] = tuple(size)
    elif kw.get("sensor_size") is not None:
        # no event to carry it (an empty raw file): the size given, as the readers take
        # it over the header's
        out["sensor_size"] = tuple(int(v) for v in kw["sensor_size"])
    out["n_events"] = n
    if n:
        dur = (t_last - t_first) * 1e-6
        warn_time_jump(path, gap[0], gap[1], t_last - t_first, n)
        out.update(t_first_us=t_first, t_last_us=t_last, duration_s=dur,
                   rate_ev_per_s=(n / dur) if dur > 0 else None,
                   positive_fraction=n_pos / n, x_range=[xmin, xmax], y_range=[ymin, ymax])
    return out


def _describe_flow(path: Path) -> dict | None:
    """Summary of an optical-flow HDF5 file (not events), or None if it is not one."""
    from evmotion.io.flowfiles import FLOW_FORMAT, SIM_GT_FORMAT

    if not path.is_file():
        return None
    if not is_hdf5(path):
        return None
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError:
        return None
    with f:
        fmt = read_attrs(path, f, ("format",)).get("format")
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
