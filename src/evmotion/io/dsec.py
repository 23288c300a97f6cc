"""DSEC event files (Gehrig et al. 2021): ``events.h5`` and ``rectify_map.h5``.

Layout of ``events.h5``::

    /events/x, /events/y   uint16
    /events/t              uint32 µs, relative to t_offset
    /events/p              uint8 0/1
    /ms_to_idx             uint64: first event with t >= 1000·k µs (relative)
    /t_offset              int64 µs: add to every t to get absolute time

Datasets are Blosc/zstd-compressed: :mod:`hdf5plugin` must be importable (a missing
filter gets a :class:`FormatError` that says so). ``t_offset`` is always added: the
returned times are absolute µs (some readers forget this).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from evmotion.catalog import NS_EPOCH_US
from evmotion.errors import FormatError, ParameterError
from evmotion.events import EventArray
from evmotion.io.base import FormatSpec
from evmotion.io.guard import check_h5_dataset, not_hdf5, open_h5, verified_position
from evmotion.io.h5filters import (
    FILTER_HINT,
    HDF5_MAGIC,
    filter_error,
    missing_filters,
    register_filters,
)
from evmotion.io.h5generic import size_from_attrs

__all__ = ["read", "iter_chunks", "write", "describe", "read_rectify_map", "rectify_events",
           "missing_filters",
           "FORMAT", "DSEC_SENSOR_SIZE"]

DSEC_SENSOR_SIZE = (480, 640)
# Largest t_offset accepted: 10^17 us lies past the year 5000 (catalog.NS_EPOCH_US), no
# clock's microseconds; a negative one puts the recording before its clock's zero.
MAX_T_OFFSET_US = NS_EPOCH_US


def _open(path: Path):
    if path.is_dir():
        path = path / "events.h5"
    f = open_h5(path)
    try:
        for name in ("events/x", "events/y", "events/t", "events/p"):
            if name not in f:
                raise FormatError(path, f"missing dataset '{name}' (not a DSEC events.h5)")
        n = check_h5_dataset(path, f, "events/t", ndim=1, kinds="iu").shape[0]
        for name, kinds in (("events/x", "iu"), ("events/y", "iu"), ("events/p", "iub")):
            check_h5_dataset(path, f, name, ndim=1, kinds=kinds, length=n)
        if "ms_to_idx" in f:
            check_h5_dataset(path, f, "ms_to_idx", ndim=1, kinds="iu")
        if "t_offset" in f:
            check_h5_dataset(path, f, "t_offset", ndim=0, kinds="iu")
    except BaseException:
        f.close()
        raise
    return f, path


def _read(path: Path, ds, lo: int, hi: int, field: str) -> np.ndarray:
    try:
        return ds[lo:hi]
    except OSError as exc:
        raise filter_error(path, exc, ds, field) from None


def _t_offset(f) -> int:
    off = int(f["t_offset"][()]) if "t_offset" in f else 0
    if not 0 <= off <= MAX_T_OFFSET_US:
        raise FormatError(f.filename, f"dataset 't_offset' is {off} us, outside [0, 1e17] "
                          "(microseconds since a clock's zero: a corrupt header?)")
    return off


def _range(path: Path, f, t0: int | None, t1: int | None) -> tuple[int, int]:
    n = int(f["events/t"].shape[0])
    # Only the two index entries around each query are read: the index of a long
    # recording is large.
    ms = f["ms_to_idx"] if "ms_to_idx" in f else None

    def entry(k: int) -> int:
        return int(_read(path, ms, k, k + 1, "ms_to_idx")[0])

    off = _t_offset(f)
    t_ds = f["events/t"]

    def locate(tq: int) -> int:
        rel = tq - off
        if rel <= 0:
            return 0
        if ms is None or ms.size == 0:
            return int(np.searchsorted(_read(path, t_ds, 0, n, "events/t"), rel))
        k = rel // 1000
        if k >= ms.size:
            a, b = min(entry(ms.size - 1), n), n
        else:
            a = min(entry(k), n)
            b = min(entry(k + 1), n) if k + 1 < ms.size else n
        i = a + int(np.searchsorted(_read(path, t_ds, a, b, "events/t"), rel))
        return verified_position(path, lambda u, v: _read(path, t_ds, u, v, "events/t"), n,
                                 rel, i, "ms_to_idx")

    lo = 0 if t0 is None else locate(int(t0))
    hi = n if t1 is None else locate(int(t1))
    return lo, max(lo, hi)


def _make(path: Path, f, lo: int, hi: int, size, meta, validate: bool) -> EventArray:
    g = f["events"]
    x = _read(path, g["x"], lo, hi, "events/x")
    y = _read(path, g["y"], lo, hi, "events/y")
    t = _read(path, g["t"], lo, hi, "events/t").astype(np.int64)
    t += _t_offset(f)
    p = _read(path, g["p"], lo, hi, "events/p")
    try:
        return EventArray(x=x, y=y, t=t, p=p, sensor_size=size, validate=validate,
                          meta=dict(meta))
    except Exception as exc:
        assumed = "sensor_size_from" in meta
        raise FormatError(path, str(exc), "the file does not state its sensor, and DSEC's "
                          "640 x 480 was assumed: give the size (--sensor-size H W, or "
                          "sensor_size=)" if assumed else None) from None


def _size(path: Path, f, sensor_size) -> tuple[int, int]:
    """The size asked for, else one the file's attributes state (not part of DSEC's
    layout: evmotion's writer stores ``sensor_size``, other tools ``width`` / ``height``),
    else DSEC's 480 x 640."""
    if sensor_size:
        return tuple(sensor_size)
    return size_from_attrs(path, f) or DSEC_SENSOR_SIZE


def _meta(path: Path, f, sensor_size) -> dict:
    meta = {"source": str(path), "format": "dsec", "t_offset_us": _t_offset(f)}
    # (the attributes only where no size is given: a corrupt one, refused, is what the
    # size given replaces)
    if not sensor_size and size_from_attrs(path, f) is None:
        meta["sensor_size_from"] = "DSEC's 640 x 480 (the file states no size)"
    return meta


def read(path: str | os.PathLike, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, validate: bool = True) -> EventArray:
    """Read a DSEC ``events.h5`` (or a folder holding one).

    Parameters
    ----------
    t0, t1 : int, optional
        Keep ``t0 <= t < t1``, **absolute** µs (``t_offset`` included); ``ms_to_idx``
        locates them without reading the whole file.
    sensor_size : (int, int), optional
        ``(height, width)``, default 480×640.

    Returns
    -------
    EventArray
        Absolute timestamps; ``meta["t_offset_us"]`` is the offset that was added.

    Examples
    --------
    >>> write("zurich_city_05_a/events/left/events.h5", EventArray(
    ...     x=[10, 20], y=[5, 6], t=[1_000_100, 1_000_200], p=[1, 0], sensor_size=(480, 640)))
    >>> ev = read("zurich_city_05_a/events/left/events.h5")
    >>> ev.t.tolist(), ev.meta["t_offset_us"]
    ([1000100, 1000200], 1000000)
    """
    path = Path(path)
    f, path = _open(path)
    with f:
        lo, hi = _range(path, f, t0, t1)
        return _make(path, f, lo, hi, _size(path, f, sensor_size),
                     _meta(path, f, sensor_size), validate)


def iter_chunks(path: str | os.PathLike, chunk_events: int, *,
                sensor_size: tuple[int, int] | None = None, validate: bool = True,
                t0: int | None = None, t1: int | None = None) -> Iterator[EventArray]:
    """Stream a DSEC file in chunks of ``chunk_events`` (absolute µs timestamps)."""
    if int(chunk_events) <= 0:
        raise ParameterError(f"chunk_events must be positive, got {chunk_events}")
    f, path = _open(Path(path))
    with f:
        lo, hi = _range(path, f, t0, t1)
        size = _size(path, f, sensor_size)
        meta = _meta(path, f, sensor_size)
        for s in range(lo, hi, int(chunk_events)):
            yield _make(path, f, s, min(hi, s + int(chunk_events)), size, meta, validate)


def write(path: str | os.PathLike, events: EventArray, *, t_offset: int | None = None,
          compression: str = "zstd") -> None:
    """Write events in the DSEC layout (atomically), for tests and interchange.

    ``t`` is stored as uint32 relative to ``t_offset`` (default: the first event's time,
    rounded down to the ms); ``compression`` is ``"zstd"`` (Blosc, as DSEC) or ``"none"``.
    """
    import h5py

    from evmotion.utils import atomic_path

    t = events.t
    if t_offset is None:
        t_offset = int(t[0] // 1000 * 1000) if len(events) else 0
    rel = t - int(t_offset)
    if not 0 <= int(t_offset) <= 10**17:
        # (written, it was then refused as "a corrupt header" by the reader, probe BL)
        raise ParameterError(f"cannot write {path}: DSEC's t_offset must lie in [0, 1e17] "
                             f"us, these events start at t={int(t[0]) if len(t) else 0} us")
    if len(events) and (rel.min() < 0 or rel.max() >= 2**32):
        raise ParameterError(f"cannot write {path}: times relative to t_offset={t_offset} us "
                             f"must fit in uint32 (got {rel.min()}..{rel.max()})")
    if events.x.dtype.kind == "f":
        raise ParameterError(f"cannot write {path}: DSEC stores integer pixels; these events "
                             "are undistorted")
    kw: dict = {}
    if compression == "zstd":
        if not register_filters():
            raise FormatError(path, "cannot write Blosc/zstd", FILTER_HINT)
        import hdf5plugin

        kw = dict(hdf5plugin.Blosc(cname="zstd", clevel=1, shuffle=hdf5plugin.Blosc.SHUFFLE))
    elif compression != "none":
        raise ParameterError(f"compression must be 'zstd' or 'none', got {compression!r}")
    n_ms = int(rel[-1] // 1000) + 2 if len(events) else 1
    ms_to_idx = np.searchsorted(rel, 1000 * np.arange(n_ms, dtype=np.int64)).astype(np.uint64)
    chunks = (min(len(events), 1 << 18),) if len(events) else None
    if not len(events):
        kw = {}  # HDF5 filters need chunks, which an empty dataset cannot have
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as f:
            # not in DSEC's layout (its sensor is 640 x 480): what a reader of another
            # size needs, ignored by DSEC's own tools
            f.attrs["sensor_size"] = np.asarray(events.sensor_size, np.int64)
            g = f.create_group("events")
            g.create_dataset("x", data=events.x.astype(np.uint16), chunks=chunks, **kw)
            g.create_dataset("y", data=events.y.astype(np.uint16), chunks=chunks, **kw)
            g.create_dataset("t", data=rel.astype(np.uint32), chunks=chunks, **kw)
            g.create_dataset("p", data=events.p.astype(np.uint8), chunks=chunks, **kw)
            f.create_dataset("ms_to_idx", data=ms_to_idx)
            f.create_dataset("t_offset", data=np.int64(t_offset))


def read_rectify_map(path: str | os.PathLike) -> np.ndarray:
    """DSEC ``rectify_map.h5``: (H, W, 2) float32, the rectified (x, y) of every raw pixel."""
    import h5py

    path = Path(path)
    try:
        with h5py.File(path, "r") as f:
            if "rectify_map" not in f:
                raise FormatError(path, "missing dataset 'rectify_map'")
            m = f["rectify_map"][()]
    except OSError as exc:
        raise not_hdf5(path, exc) from None
    if m.ndim != 3 or m.shape[2] != 2:
        raise FormatError(path, f"'rectify_map' has shape {m.shape}, expected (H, W, 2)")
    return m.astype(np.float32)


def rectify_events(events: EventArray, rectify_map: np.ndarray, *,
                   drop_outside: bool = True) -> EventArray:
    """Map raw DSEC pixels through ``rectify_map`` (H, W, 2): float32 rectified x, y.

    Events landing outside the sensor are dropped (``meta["dropped_outside"]`` counts
    them) unless ``drop_outside=False``, which keeps them unvalidated.

    Examples
    --------
    >>> import h5py
    >>> ev = EventArray(x=[1, 2], y=[0, 3], t=[10, 20], p=[1, 0], sensor_size=(4, 5))
    >>> yy, xx = np.mgrid[0:4, 0:5]
    >>> with h5py.File("rectify_map.h5", "w") as f:  # a shift by (+0.5, +0.25) px
    ...     f["rectify_map"] = np.stack([xx + 0.5, yy + 0.25], axis=-1)
    >>> ev_r = rectify_events(ev, read_rectify_map("rectify_map.h5"))
    >>> ev_r.x.tolist(), ev_r.y.tolist(), ev_r.meta["dropped_outside"]
    ([1.5], [0.25], 1)
    """
    m = np.asarray(rectify_map, dtype=np.float32)
    if m.shape[:2] != events.sensor_size or m.ndim != 3 or m.shape[2] != 2:
        raise ParameterError(f"rectify_map has shape {m.shape}, expected "
                             f"{(*events.sensor_size, 2)} for these events")
    xi = events.x.astype(np.intp)
    yi = events.y.astype(np.intp)
    xr, yr = m[yi, xi, 0], m[yi, xi, 1]
    h, w = events.sensor_size
    meta = dict(events.meta, rectified=True)
    keep = (xr >= 0) & (yr >= 0) & (xr <= w - 1) & (yr <= h - 1)
    if drop_outside:
        meta["dropped_outside"] = int((~keep).sum())
        return EventArray(x=xr[keep], y=yr[keep], t=events.t[keep], p=events.p[keep],
                          sensor_size=events.sensor_size, validate=False, meta=meta)
    return EventArray(x=xr, y=yr, t=events.t, p=events.p, sensor_size=events.sensor_size,
                      validate=False, meta=meta)


def describe(path: str | os.PathLike) -> dict:
    path = Path(path)
    f, path = _open(path)
    with f:
        n = int(f["events/t"].shape[0])
        off = _t_offset(f)
        out: dict = {"format": "dsec", "sensor_size": _size(path, f, None), "n_events": n,
                     "t_offset_us": off}
        # a default, which --sensor-size does not replace as stated (probe CR)
        default = _meta(path, f, None).get("sensor_size_from")
        if default is not None:
            out["sensor_size_from"] = default
        if n:
            out["t_first_us"] = int(_read(path, f["events/t"], 0, 1, "events/t")[0]) + off
            out["t_last_us"] = int(_read(path, f["events/t"], n - 1, n, "events/t")[0]) + off
    folder = path.parent
    if (folder / "rectify_map.h5").exists():
        out["rectify_map"] = str(folder / "rectify_map.h5")
    out["frames"] = 0
    out["imu"] = 0
    return out


def _sniff(path: Path, head: bytes) -> bool:
    if path.is_dir():
        path = path / "events.h5"
        if not path.is_file():
            return False
        with open(path, "rb") as fh:
            head = fh.read(8)
    if not head.startswith(HDF5_MAGIC):
        return False
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return "events" in f and ("t_offset" in f or "ms_to_idx" in f)
    except OSError:
        return False


FORMAT = FormatSpec(name="dsec", extensions=(".h5",), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, write=write, describe=describe)
