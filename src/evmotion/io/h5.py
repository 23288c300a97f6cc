"""evmotion's own HDF5 event format: chunked, compressed, time-indexed, appendable.

Layout::

    /events/x, /events/y   uint16 (float32 when undistorted)
    /events/t              int64 µs, absolute
    /events/p              uint8 0/1
    /events/ms_to_idx      int64: ms_to_idx[k] = first event with t >= t_index0 + step·k
    attrs: format="evmotion-events", version, height, width, t_index0 (µs),
           index_step_us (step: 1000, coarser when the recording spans far more
           milliseconds than it holds events; absent in older files: 1000),
           provenance (JSON), calibration (JSON, optional), plus user attributes
    /frames/images (N,H,W), /frames/t        optional APS frames
    /imu/t, /imu/gyro, /imu/accel             optional
    /ground_truth/...                        optional (e.g. ``flow`` from io.flowfiles,
                                             ``motion/t``, ``motion/params``)

Events are compressed with Blosc-LZ4 (byte shuffle) through hdf5plugin when available,
otherwise gzip level 1. :class:`EventWriter` appends chunk by chunk in bounded memory and
renames ``<name>.part`` onto ``<name>`` at close (atomic).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError, ParameterError
from evmotion.events import EventArray
from evmotion.io.base import FormatSpec, PartFileWriter
from evmotion.io.guard import check_h5_dataset, check_sensor_size, open_h5, verified_position
from evmotion.io.h5attrs import read_attrs, text_attr
from evmotion.io.h5filters import HDF5_MAGIC, filter_error, h5_compression
from evmotion.utils import ensure_file_target, ensure_room

# the time index: its finest step (µs), the entries it may always have, and how many it
# fills at a time
INDEX_STEP_US = 1000
INDEX_MIN_ENTRIES = 1 << 20
INDEX_BLOCK = 1 << 20

__all__ = ["EventWriter", "read", "iter_chunks", "write", "describe", "read_frames",
           "read_imu", "FORMAT", "FORMAT_NAME"]

FORMAT_NAME = "evmotion-events"
VERSION = 1
CHUNK = 1 << 18


def _jsonable(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (tuple, list)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, Path):
        return str(obj)
    return obj


class EventWriter(PartFileWriter):
    """Append events to an evmotion HDF5 file chunk by chunk (bounded memory, atomic).

    Parameters
    ----------
    path : path-like
        Output ``.h5`` file; written as ``<path>.part`` and renamed at :meth:`close`.
    sensor_size : (int, int)
        ``(height, width)``.
    float_coords : bool
        Store x, y as float32 (undistorted events) instead of uint16.
    calibration : dict, optional
        Stored as JSON in the ``calibration`` attribute.
    provenance : dict, optional
        Where the data came from (JSON attribute).
    attrs : dict, optional
        Further root attributes.

    Examples
    --------
    >>> ev = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                 sensor_size=(180, 240))
    >>> with EventWriter("out.h5", (180, 240)) as w:
    ...     for chunk in (ev[:2], ev[2:]):
    ...         w.append(chunk)
    >>> read("out.h5").t.tolist()
    [100, 200, 300]
    """

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int], *,
                 float_coords: bool = False, calibration: dict | None = None,
                 provenance: dict | None = None, attrs: dict | None = None):
        import h5py

        self.path = Path(path)
        ensure_file_target(self.path)
        self.part = self.path.with_name(self.path.name + ".part")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        h, w = (int(v) for v in sensor_size)
        if h <= 0 or w <= 0:
            raise ParameterError(f"sensor_size must be positive (height, width), got {(h, w)}")
        self.sensor_size = (h, w)
        self.f = h5py.File(self.part, "w")
        f = self.f
        f.attrs["format"] = text_attr(FORMAT_NAME)
        f.attrs["version"] = VERSION
        f.attrs["height"] = h
        f.attrs["width"] = w
        f.attrs["provenance"] = text_attr(json.dumps(_jsonable(provenance or {})))
        if calibration is not None:
            f.attrs["calibration"] = text_attr(json.dumps(_jsonable(calibration)))
        for k, v in (attrs or {}).items():
            f.attrs[k] = v if isinstance(v, (int, float, np.ndarray)) else text_attr(
                v if isinstance(v, str) else json.dumps(_jsonable(v)))
        g = f.create_group("events")
        comp = h5_compression("lz4")
        cdt = "<f4" if float_coords else "<u2"
        for name, dt in (("x", cdt), ("y", cdt), ("t", "<i8"), ("p", "u1")):
            g.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dt, chunks=(CHUNK,),
                             **comp)
        g.create_dataset("ms_to_idx", shape=(0,), maxshape=(None,), dtype="<i8",
                         chunks=(4096,))
        self.n = 0
        self.t_last: int | None = None
        self.t_index0: int | None = None
        self.step = INDEX_STEP_US

    def append(self, events: EventArray) -> None:
        """Append a chunk; its timestamps must not precede the previous chunk's."""
        n = len(events)
        if n == 0:
            return
        if tuple(events.sensor_size) != self.sensor_size:
            raise ParameterError(f"chunk sensor_size {events.sensor_size} differs from the "
                                 f"file's {self.sensor_size}")
        ensure_room(self.part, sum(a.nbytes for a in (events.x, events.y, events.t, events.p)))
        t = events.t
        if self.t_last is not None and t[0] < self.t_last:
            raise ParameterError(f"chunk starts at t={t[0]} us, before the previous chunk's "
                                 f"last event at {self.t_last} us (append in time order)")
        g = self.f["events"]
        float_file = g["x"].dtype.kind == "f"
        if events.x.dtype.kind == "f" and not float_file:
            raise ParameterError("float (undistorted) coordinates in a uint16 file: create "
                                 "the writer with float_coords=True")
        for name in ("x", "y", "t", "p"):
            ds = g[name]
            ds.resize(self.n + n, axis=0)
            ds[self.n:] = getattr(events, name)
        if self.t_index0 is None:
            self.t_index0 = int(t[0] // 1000 * 1000)
            self.f.attrs["t_index0"] = self.t_index0
        self._extend_index(t)
        self.n += n
        self.t_last = int(t[-1])

    def _extend_index(self, t: np.ndarray) -> None:
        ms = self.f["events/ms_to_idx"]
        # Entries for every step boundary up to this chunk's last event; later boundaries
        # are added once later events show where they fall.
        k1 = int((t[-1] - self.t_index0) // self.step) + 1
        limit = max(INDEX_MIN_ENTRIES, 2 * (self.n + len(t)))
        if k1 > limit:
            # a recording spanning far more steps than it holds events (a pause of hours):
            # a coarser step, whose entries are every m-th of the finer ones, keeps the
            # index in proportion to the events (was 865 MB for 100 events over 30 h)
            m = -(-k1 // limit)
            kept = ms[::m] if ms.shape[0] else np.zeros(0, np.int64)
            ms.resize(len(kept), axis=0)
            ms[:] = kept
            self.step *= m
            self.f.attrs["index_step_us"] = self.step
            k1 = int((t[-1] - self.t_index0) // self.step) + 1
        k0 = ms.shape[0]
        if k1 <= k0:
            return
        ms.resize(k1, axis=0)
        for a in range(k0, k1, INDEX_BLOCK):  # bounded memory across a long pause
            b = min(a + INDEX_BLOCK, k1)
            bounds = self.t_index0 + self.step * np.arange(a, b, dtype=np.int64)
            ms[a:b] = self.n + np.searchsorted(t, bounds, side="left")

    def close(self) -> None:
        """Finish (close the index with the end marker) and rename onto the final name."""
        if not self.f.id.valid:
            return
        ms = self.f["events/ms_to_idx"]
        ms.resize(ms.shape[0] + 1, axis=0)
        ms[-1] = self.n
        self.f.attrs["n_events"] = self.n
        self.f.close()
        os.replace(self.part, self.path)

    def abort(self) -> None:
        if self.f.id.valid:
            try:
                self.f.close()
            except RuntimeError:  # a flush that fails again (a full device): drop the file
                pass
        if self.part.exists():
            self.part.unlink()


def write(path: str | os.PathLike, events: EventArray | Iterable[EventArray], *,
          sensor_size: tuple[int, int] | None = None, calibration: dict | None = None,
          provenance: dict | None = None, frames: dict | None = None, imu: dict | None = None,
          attrs: dict | None = None) -> None:
    """Write events (one EventArray or an iterable of chunks) to evmotion HDF5, atomically.

    Parameters
    ----------
    frames : dict, optional
        ``{"t": (N,) µs, "images": (N, H, W)}``.
    imu : dict, optional
        ``{"t": (N,) µs, "gyro": (N, 3) rad/s, "accel": (N, 3) m/s²}``.

    Examples
    --------
    >>> ev = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                 sensor_size=(180, 240))
    >>> write("out.h5", ev, provenance={"source": "sim"})
    >>> back = read("out.h5")
    >>> len(back), back.meta["provenance"]
    (3, {'source': 'sim'})
    """
    it = iter([events] if isinstance(events, EventArray) else events)
    first = next(it, None)
    if first is None and sensor_size is None:
        raise ParameterError("no events to write and no sensor_size given")
    size = sensor_size or first.sensor_size
    if calibration is None and first is not None:
        calibration = first.meta.get("calibration")
    floaty = first is not None and first.x.dtype.kind == "f"
    w = EventWriter(path, size, float_coords=floaty, calibration=calibration,
                    provenance=provenance, attrs=attrs)
    try:
        if first is not None:
            w.append(first)
        for chunk in it:
            w.append(chunk)
        if frames is not None:
            g = w.f.create_group("frames")
            g.create_dataset("t", data=np.asarray(frames["t"], np.int64))
            g.create_dataset("images", data=np.asarray(frames["images"]),
                             compression="gzip", compression_opts=1)
        if imu is not None:
            g = w.f.create_group("imu")
            for k, v in imu.items():
                g.create_dataset(k, data=np.asarray(v))
        w.close()  # its flush can fail too (a full device): the .part goes then
    except BaseException:
        w.abort()
        raise


def _open(path: Path):
    f = open_h5(path)  # registers the Blosc filters of the event datasets
    if "events" not in f:
        f.close()
        raise FormatError(path, "no 'events' group (not an evmotion event file)")
    try:
        for name in ("x", "y", "t", "p"):
            if f"events/{name}" not in f:
                raise FormatError(path, f"missing dataset 'events/{name}'")
        n = check_h5_dataset(path, f, "events/t", ndim=1, kinds="iu").shape[0]
        for name, kinds in (("x", "uif"), ("y", "uif"), ("p", "iub")):
            check_h5_dataset(path, f, f"events/{name}", ndim=1, kinds=kinds, length=n)
        if "events/ms_to_idx" in f:
            check_h5_dataset(path, f, "events/ms_to_idx", ndim=1, kinds="iu")
    except BaseException:
        f.close()
        raise
    return f


def _meta(f, path: Path) -> tuple[tuple[int, int], dict]:
    attrs = read_attrs(path, f, ("height", "width", "calibration", "provenance"))
    if "height" not in attrs or "width" not in attrs:
        raise FormatError(path, "missing attribute 'height'/'width' (the sensor size)")
    size = check_sensor_size(path, (attrs["height"], attrs["width"]),
                             "attributes 'height', 'width'")
    meta = {"source": str(path), "format": "h5"}
    for key in ("calibration", "provenance"):
        if key in attrs:
            try:
                meta[key] = json.loads(attrs[key])
            except (TypeError, ValueError):
                raise FormatError(path, f"attribute '{key}' is not valid JSON") from None
    return size, meta


def _index_range(f, base: int, t0: int | None, t1: int | None, step: int = INDEX_STEP_US
                 ) -> tuple[int, int]:
    g = f["events"]
    n = g["t"].shape[0]
    lo, hi = 0, n
    # Only the two index entries around each query are read: the index of a long
    # recording is large.
    ms = g["ms_to_idx"] if "ms_to_idx" in g else None

    def locate(tq: int) -> int:
        if ms is None or ms.size == 0:
            return int(np.searchsorted(g["t"][:], tq, side="left"))
        k = (tq - base) // step
        if k < 0:
            i = 0
        else:
            # ms[k] <= answer <= ms[k+1]: search only the events of that step.
            a = int(ms[k]) if k < ms.size else int(ms[ms.size - 1])
            b = int(ms[k + 1]) if k + 1 < ms.size else n
            a, b = min(max(a, 0), n), min(max(b, 0), n)  # a corrupt index stays in range
            i = a + int(np.searchsorted(g["t"][a:b], tq, side="left"))
        return verified_position(f.filename, lambda u, v: g["t"][u:v], n, tq, i,
                                 "events/ms_to_idx, t_index0")

    if t0 is not None:
        lo = locate(int(t0))
    if t1 is not None:
        hi = locate(int(t1))
    return lo, max(lo, hi)


def _col(path: Path, g, name: str, lo: int, hi: int) -> np.ndarray:
    try:
        return g[name][lo:hi]
    except OSError as exc:
        raise filter_error(path, exc, g[name], f"events/{name}") from None


def _make(path: Path, size, meta, x, y, t, p, validate: bool) -> EventArray:
    try:
        return EventArray(x=x, y=y, t=t, p=p, sensor_size=size, validate=validate,
                          meta=dict(meta))
    except Exception as exc:
        raise FormatError(path, str(exc)) from None


@contextmanager
def _events_range(path: Path, sensor_size: tuple[int, int] | None, t0: int | None,
                  t1: int | None) -> Iterator[tuple]:
    """The open file's ``events`` group, sensor size (``sensor_size`` overrides the
    file's), meta and the index range ``[lo, hi)`` of ``t0 <= t < t1`` (µs)."""
    with _open(path) as f:
        size, meta = _meta(f, path)
        size = tuple(sensor_size) if sensor_size is not None else size
        attrs = read_attrs(path, f, ("t_index0", "index_step_us"))
        base, step = attrs.get("t_index0", 0), attrs.get("index_step_us", INDEX_STEP_US)
        try:
            base, step = int(base), int(step)
        except (TypeError, ValueError):
            raise FormatError(path, "attributes 't_index0', 'index_step_us' are not integers: "
                              f"{base!r}, {step!r}") from None
        if step < 1:
            raise FormatError(path, f"attribute 'index_step_us' is {step}, not positive")
        lo, hi = _index_range(f, base, t0, t1, step)
        yield f["events"], size, meta, lo, hi


def read(path: str | os.PathLike, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, validate: bool = True) -> EventArray:
    """Read events from an evmotion HDF5 file, using the ms index for ``t0``/``t1`` (µs).

    Examples
    --------
    >>> write("sim.h5", EventArray(x=[1, 2, 3, 4], y=[0, 0, 0, 0], p=[1, 0, 1, 0],
    ...                            t=[0, 20_000, 40_000, 60_000], sensor_size=(180, 240)))
    >>> ev = read("sim.h5", t0=0, t1=50_000)
    >>> len(ev), ev.t.tolist()
    (3, [0, 20000, 40000])
    """
    path = Path(path)
    with _events_range(path, sensor_size, t0, t1) as (g, size, meta, lo, hi):
        cols = [_col(path, g, k, lo, hi) for k in ("x", "y", "t", "p")]
    return _make(path, size, meta, *cols, validate)


def iter_chunks(path: str | os.PathLike, chunk_events: int, *,
                sensor_size: tuple[int, int] | None = None, validate: bool = True,
                t0: int | None = None, t1: int | None = None) -> Iterator[EventArray]:
    """Stream events in chunks of ``chunk_events`` (last may be shorter), bounded memory.

    Examples
    --------
    >>> write("sim.h5", EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300],
    ...                            p=[1, 0, 1], sensor_size=(180, 240)))
    >>> for c in iter_chunks("sim.h5", 2):
    ...     print(len(c))
    2
    1
    """
    if int(chunk_events) <= 0:
        raise ParameterError(f"chunk_events must be positive, got {chunk_events}")
    path = Path(path)
    with _events_range(path, sensor_size, t0, t1) as (g, size, meta, lo, hi):
        for s in range(lo, hi, int(chunk_events)):
            e = min(hi, s + int(chunk_events))
            yield _make(path, size, meta, *(_col(path, g, k, s, e) for k in "xytp"), validate)


def read_frames(path: str | os.PathLike) -> dict:
    """APS frames stored in the file: ``{"t": (N,) µs, "images": (N, H, W)}``."""
    path = Path(path)
    with _open(path) as f:
        if "frames" not in f:
            raise FormatError(path, "no 'frames' group")
        return {"t": f["frames/t"][:], "images": f["frames/images"][:]}


def read_imu(path: str | os.PathLike) -> dict:
    """IMU samples stored in the file (``t`` µs, ``gyro`` rad/s, ``accel`` m/s²)."""
    path = Path(path)
    with _open(path) as f:
        if "imu" not in f:
            raise FormatError(path, "no 'imu' group")
        return {k: v[:] for k, v in f["imu"].items()}


def describe(path: str | os.PathLike) -> dict:
    """Sensor size, count, time range and what else the file holds, without reading events."""
    path = Path(path)
    with _open(path) as f:
        size, meta = _meta(f, path)
        g = f["events"]
        n = int(g["t"].shape[0])
        out: dict = {"format": "h5", "sensor_size": size, "n_events": n}
        if n:
            out["t_first_us"] = int(g["t"][0])
            out["t_last_us"] = int(g["t"][n - 1])
        out["frames"] = int(f["frames/t"].shape[0]) if "frames/t" in f else 0
        out["imu"] = int(f["imu/t"].shape[0]) if "imu/t" in f else 0
        if "ground_truth" in f:
            out["ground_truth"] = sorted(f["ground_truth"].keys())
        beside = path.with_name(path.stem + "_gt.h5")
        if beside.exists():
            out["ground_truth_file"] = str(beside)  # the simulator writes its GT beside
        for k in ("calibration", "provenance"):
            if k in meta:
                out[k] = meta[k]
        out["compression"] = _filter_names(g["t"])
    return out


def _filter_names(ds) -> list[str]:
    plist = ds.id.get_create_plist()
    names = []
    for i in range(plist.get_nfilters()):
        name = plist.get_filter(i)[3]
        names.append(name.decode(errors="replace") if isinstance(name, bytes) else str(name))
    return names


def _sniff(path: Path, head: bytes) -> bool:
    if not head.startswith(HDF5_MAGIC):
        return False
    import h5py

    try:
        with h5py.File(path, "r") as f:
            # By structure only: reading the 'format' attribute (a variable-length string)
            # of a corrupt file can crash libhdf5 (a segfault found by fuzzing), and
            # detection must survive any file. Same field names as DSEC, which has a root
            # t_offset / ms_to_idx instead.
            # its own layout states the sensor and its name ('format', whose presence
            # is checked, not its value) and stores integer us; other HDF5 with
            # events/x, events/t (in any unit, sized or not) is io.h5generic's
            return ("events/t" in f and "events/x" in f and "t_offset" not in f
                    and "ms_to_idx" not in f and "height" in f.attrs and "width" in f.attrs
                    and "format" in f.attrs and f["events/t"].dtype.kind in "iu")
    except OSError:
        return False


FORMAT = FormatSpec(name="h5", extensions=(".h5", ".hdf5"), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, write=write, describe=describe)
