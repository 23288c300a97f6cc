"""Per-event flow files: each event with its flow, for those who want the events rather than
dense fields (e.g. the triplet matcher's output).

Both containers hold the same columns, one value per event, in stream order:

=============  =========  =====  ==================================================
name           dtype      unit   meaning
=============  =========  =====  ==================================================
``t``          int64      µs     timestamp
``x``, ``y``   float32    px     column, row (integers unless undistorted)
``p``          uint8             polarity 0/1
``vx``, ``vy`` float32    px/s   flow (u right, v down); 0 where not ``valid``
``nx``, ``ny`` float32    px/s   normal flow (the component along the local gradient)
``valid``      bool              the estimator found a flow for the event
``n_triplets`` int32             matches that voted (triplet matching)
=============  =========  =====  ==================================================

``.h5``: one resizable dataset per column (Blosc-LZ4 with bit shuffle by default),
attributes ``format="evmotion-event-flow"``, ``version``, ``height``, ``width``,
``units="px/s"``, ``time_units="us"``, ``columns`` and the caller's own (method,
parameters). ``.npz``: the same columns as ``.npy`` members plus ``height``, ``width`` and
``meta`` (the attributes as a JSON string; no pickle needed). Both are written in bounded
memory and renamed onto their final name only when complete.
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError, ParameterError
from evmotion.io.base import PartFileWriter
from evmotion.io.h5attrs import read_attrs
from evmotion.io.h5filters import h5_compression
from evmotion.utils import atomic_path, ensure_room, remove_stale_temps, temp_prefix

__all__ = ["EVENT_FLOW_COLUMNS", "EVENT_FLOW_FORMAT", "EventFlow", "EventFlowWriter",
           "describe_event_flow",
           "read_event_flow"]

EVENT_FLOW_FORMAT = "evmotion-event-flow"
EVENT_FLOW_VERSION = 1
EVENT_FLOW_COLUMNS: tuple[tuple[str, str], ...] = (
    ("t", "<i8"), ("x", "<f4"), ("y", "<f4"), ("p", "u1"), ("vx", "<f4"), ("vy", "<f4"),
    ("nx", "<f4"), ("ny", "<f4"), ("valid", "?"), ("n_triplets", "<i4"))
_H5_CHUNK = 1 << 16  # events per HDF5 chunk (512 KiB of t: smaller and faster than 1 << 18)


@dataclass(frozen=True)
class EventFlow:
    """A per-event flow file read back: ``columns[name]`` (N,) arrays (see the module
    table), the sensor ``(height, width)`` and the attributes."""

    columns: dict[str, np.ndarray]
    sensor_size: tuple[int, int]
    attrs: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.columns["t"].shape[0])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]


class EventFlowWriter(PartFileWriter):
    """Append chunks of per-event flow to a ``.h5`` or ``.npz`` file, in bounded memory.

    Parameters
    ----------
    path : path-like
        ``.h5``/``.hdf5`` or ``.npz``; written under a temporary name and renamed onto
        ``path`` by :meth:`close` (:meth:`abort` leaves nothing).
    sensor_size : (int, int)
        ``(height, width)`` in pixels.
    attrs : dict, optional
        Metadata (strings, numbers): the method, its parameters, the source recording.
    compression : str or None
        ``.h5`` filter (:func:`~evmotion.io.flowfiles.h5_compression`, default ``"lz4"``;
        Blosc codecs shuffle bits);
        ``.npz`` members are stored uncompressed (the zip's deflate is several times slower
        than the estimators).

    Examples
    --------
    >>> t, x, y, p = np.array([100, 200]), np.array([3, 4]), np.array([5, 5]), np.array([1, 0])
    >>> vx, vy = np.array([50.0, 0.0]), np.zeros(2)
    >>> nx, ny, ok, nt = vx, vy, np.array([True, False]), np.array([3, 0])
    >>> with EventFlowWriter("flow.h5", (720, 1280)) as w:
    ...     w.append(t=t, x=x, y=y, p=p, vx=vx, vy=vy, nx=nx, ny=ny, valid=ok,
    ...              n_triplets=nt)
    >>> len(read_event_flow("flow.h5"))
    2
    """

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int], *,
                 attrs: dict | None = None, compression: str | None = "lz4") -> None:
        self.path = Path(path)
        self.kind = self.path.suffix.lower()
        if self.kind not in (".h5", ".hdf5", ".npz"):
            raise ParameterError(f"{self.path}: a per-event flow file ends in .h5 or .npz")
        h, w = (int(v) for v in sensor_size)
        if h <= 0 or w <= 0:
            raise ParameterError(f"sensor_size must be positive (height, width), got {(h, w)}")
        self.sensor_size = (h, w)
        self.n = 0
        self.attrs = {"format": EVENT_FLOW_FORMAT, "version": EVENT_FLOW_VERSION,
                      "height": h, "width": w, "units": "px/s", "time_units": "us",
                      "columns": ",".join(k for k, _ in EVENT_FLOW_COLUMNS), **(attrs or {})}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._ctx = atomic_path(self.path)
        self._tmp = self._ctx.__enter__()
        if self.kind == ".npz":
            remove_stale_temps(self.path, ".columns.part")
            self._dir = tempfile.TemporaryDirectory(prefix=temp_prefix(self.path),
                                                    suffix=".columns.part",
                                                    dir=self.path.parent)
            self._files = {k: open(Path(self._dir.name) / k, "wb")
                           for k, _ in EVENT_FLOW_COLUMNS}
            return
        import h5py

        kw = _h5_filter(compression)
        self._f = h5py.File(self._tmp, "w")
        for k, v in self.attrs.items():
            self._f.attrs[k] = v
        for k, dt in EVENT_FLOW_COLUMNS:
            self._f.create_dataset(k, shape=(0,), maxshape=(None,), dtype=dt,
                                   chunks=(_H5_CHUNK,), **kw)

    def append(self, **columns: np.ndarray) -> None:
        """Add the next events: every column of :data:`EVENT_FLOW_COLUMNS`, of one length."""
        missing = [k for k, _ in EVENT_FLOW_COLUMNS if k not in columns]
        extra = sorted(set(columns) - {k for k, _ in EVENT_FLOW_COLUMNS})
        if missing or extra:
            raise ParameterError(f"per-event flow columns: missing {missing}, unknown {extra}")
        n = {int(np.shape(v)[0]) for v in columns.values()}
        if len(n) != 1:
            raise ParameterError(f"per-event flow columns of different lengths {sorted(n)}")
        m = n.pop()
        if m == 0:
            return
        # (the .npz's columns are zipped into one file at the end: counted as one)
        row = sum(np.dtype(dt).itemsize for _, dt in EVENT_FLOW_COLUMNS)
        ensure_room(self._tmp, m * row, size_now=self.n * row)
        for k, dt in EVENT_FLOW_COLUMNS:
            a = np.ascontiguousarray(columns[k], dtype=dt)
            if self.kind == ".npz":
                self._files[k].write(a.tobytes())
            else:
                ds = self._f[k]
                ds.resize(self.n + m, axis=0)
                ds[self.n:] = a
        self.n += m

    def close(self) -> None:
        """Finish the file and rename it onto its final name."""
        if self.kind == ".npz":
            self._close_npz()
        else:
            self._f.close()
        self._ctx.__exit__(None, None, None)

    def _close_npz(self) -> None:
        for fh in self._files.values():
            fh.close()
        meta = {"meta": np.array(json.dumps(self.attrs, default=_plain)),
                "height": np.array(self.sensor_size[0]), "width": np.array(self.sensor_size[1])}
        with zipfile.ZipFile(self._tmp, "w", allowZip64=True) as zf:
            for k, dt in EVENT_FLOW_COLUMNS:
                with zf.open(f"{k}.npy", "w", force_zip64=True) as dst, \
                        open(Path(self._dir.name) / k, "rb") as src:
                    np.lib.format.write_array_header_1_0(
                        dst, {"descr": np.lib.format.dtype_to_descr(np.dtype(dt)),
                              "fortran_order": False, "shape": (self.n,)})
                    while block := src.read(1 << 22):
                        dst.write(block)
            for k, a in meta.items():
                with zf.open(f"{k}.npy", "w") as dst:
                    np.lib.format.write_array(dst, a, allow_pickle=False)
        self._dir.cleanup()

    def abort(self) -> None:
        """Close and remove everything written."""
        if self.kind == ".npz":
            for fh in self._files.values():
                fh.close()
            self._dir.cleanup()
        else:
            self._f.close()
        self._ctx.__exit__(RuntimeError, RuntimeError("aborted"), None)


def _h5_filter(compression: str | None) -> dict:
    """h5py keywords of the columns' filter: :func:`h5_compression`, except that Blosc
    shuffles bits rather than bytes (the columns are small integers and float32 flows with
    many equal high bits: on a 1.2 M-event recording 5 % smaller and a third faster to
    write than byte shuffle)."""
    return h5_compression(compression, bitshuffle=True)


def _plain(obj):
    return obj.item() if hasattr(obj, "item") else str(obj)


def read_event_flow(path: str | os.PathLike) -> EventFlow:
    """Read a per-event flow file written by :class:`EventFlowWriter` (``.h5`` or ``.npz``).

    Examples
    --------
    >>> cols = {k: np.zeros(3, dt) for k, dt in EVENT_FLOW_COLUMNS}  # t, x, y, p, vx...
    >>> cols["t"][:], cols["vx"][:] = [100, 200, 300], [50, -25, 0]
    >>> with EventFlowWriter("flow.npz", (4, 5)) as w:
    ...     w.append(**cols)
    >>> ef = read_event_flow("flow.npz")
    >>> ef["vx"][:3].tolist(), ef.attrs["units"], ef.sensor_size
    ([50.0, -25.0, 0.0], 'px/s', (4, 5))
    """
    path = Path(path)
    if path.suffix.lower() == ".npz":
        from evmotion.io.guard import open_npz

        with open_npz(path) as z:
            if "meta" not in z.files:
                raise FormatError(path, "not an evmotion per-event flow file (no 'meta' member)")
            attrs = json.loads(str(z["meta"]))
            cols = _columns(path, {k: z[k] for k in z.files})
    else:
        from evmotion.io.guard import open_h5  # registers the Blosc filters

        with open_h5(path) as f:
            attrs = read_attrs(path, f)
            if attrs.get("format") != EVENT_FLOW_FORMAT:
                raise FormatError(path, f"not an evmotion per-event flow file (attribute "
                                  f"format={attrs.get('format')!r})")
            cols = _columns(path, {k: f[k][()] for k in f if k in dict(EVENT_FLOW_COLUMNS)})
    if attrs.get("format") != EVENT_FLOW_FORMAT:
        raise FormatError(path, f"not an evmotion per-event flow file (format="
                          f"{attrs.get('format')!r})")
    return EventFlow(cols, (int(attrs["height"]), int(attrs["width"])), attrs)


def describe_event_flow(path: str | os.PathLike) -> dict:
    """What a per-event flow file holds (``evmotion info``) without reading its flow.

    Returns
    -------
    dict
        ``format``, ``container``, ``sensor_size`` (H, W), ``events``, ``t_first_us``,
        ``t_last_us``, ``duration_s``, ``units``, ``fields``, ``valid_fraction`` (events
        with a flow), ``method`` and ``grid`` when stored.

    Examples
    --------
    >>> cols = {k: np.zeros(4, dt) for k, dt in EVENT_FLOW_COLUMNS}  # t, x, y, p, vx...
    >>> cols["t"][:], cols["valid"][:] = [0, 10, 20, 30], [True, True, True, False]
    >>> with EventFlowWriter("triplet.h5", (4, 5), attrs={"method": "triplet"}) as w:
    ...     w.append(**cols)
    >>> d = describe_event_flow("triplet.h5")
    >>> d["events"], d["valid_fraction"], d["method"]
    (4, 0.75, 'triplet')
    """
    path = Path(path)
    if path.suffix.lower() == ".npz":
        ef = read_event_flow(path)
        attrs, t, valid = ef.attrs, ef["t"], ef["valid"]
    else:
        from evmotion.io.guard import open_h5  # registers the Blosc filters

        with open_h5(path) as f:
            attrs = read_attrs(path, f)
            if attrs.get("format") != EVENT_FLOW_FORMAT or "t" not in f or "valid" not in f:
                raise FormatError(path, "not an evmotion per-event flow file")
            n = int(f["t"].shape[0])
            t = np.asarray(f["t"][[0, n - 1]] if n else f["t"][:0])
            valid = np.asarray(f["valid"][()])
    out = {"path": str(path), "format": EVENT_FLOW_FORMAT,
           "container": "npz" if path.suffix.lower() == ".npz" else "h5",
           "sensor_size": [int(attrs["height"]), int(attrs["width"])],
           "events": int(valid.shape[0]), "units": str(attrs.get("units", "px/s")),
           "fields": [k for k, _ in EVENT_FLOW_COLUMNS]}
    if valid.shape[0]:
        out.update(t_first_us=int(t[0]), t_last_us=int(t[-1]),
                   duration_s=(int(t[-1]) - int(t[0])) * 1e-6,
                   valid_fraction=float(np.count_nonzero(valid) / valid.shape[0]))
    for key in ("method", "grid", "source"):
        if key in attrs:
            out[key] = attrs[key]
    return out


def _columns(path: Path, found: dict) -> dict[str, np.ndarray]:
    missing = [k for k, _ in EVENT_FLOW_COLUMNS if k not in found]
    if missing:
        raise FormatError(path, f"per-event flow file lacks column(s) {', '.join(missing)}")
    n = {k: found[k].shape for k, _ in EVENT_FLOW_COLUMNS}
    if len(set(n.values())) != 1:
        raise FormatError(path, f"per-event flow columns of different shapes {n}")
    return {k: np.asarray(found[k]) for k, _ in EVENT_FLOW_COLUMNS}
