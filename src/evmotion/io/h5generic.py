"""HDF5 event files in other tools' layouts (read-only).

The formats with a layout of their own (evmotion's, DSEC, MVSEC, the published BOS data)
are detected first; this one takes the HDF5 files that hold events in any of the layouts
other tools write:

* one dataset per field at the root or in a group ``events`` / ``CD`` / ``dvs``, named as
  :data:`evmotion.io.base.EVENT_FIELD_NAMES` knows them (``x``, ``y``, ``t`` / ``ts`` /
  ``timestamp``, ``p`` / ``pol`` / ``polarity``; event_utils' ``xs, ys, ts, ps``);
* a compound dataset ``events`` or ``CD/events`` with such fields (Metavision's HDF5,
  when stored without its ECF compression);
* an N×4 dataset ``events`` (v2e's ``t, x, y, p``; the time column is the sorted one).

Times: whole numbers are µs, floating point seconds (as for NumPy inputs), unless the
time field's name states its unit (``t_ns``, ``timestamp_us``). The sensor size
comes from ``width`` / ``height`` (or ``sensor_size`` ``(H, W)``, or Metavision's
``geometry`` ``WxH``) attributes of the file or the events, else from the largest
coordinates, said in a warning.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from evmotion.errors import EvmotionWarning, FormatError
from evmotion.events import EventArray
from evmotion.io.base import EVENT_FIELD_NAMES, FormatSpec, event_fields, split_unit
from evmotion.io.guard import (
    LARGEST_COORDINATE,
    check_h5_storage,
    check_sensor_size,
    open_h5,
    warn_inferred_size,
)
from evmotion.io.h5attrs import read_attrs_many
from evmotion.io.h5filters import HDF5_MAGIC, filter_error
from evmotion.io.npy import chunks_of_read, events_from_columns, split_columns

__all__ = ["FORMAT", "describe", "find_layout", "find_layouts", "read", "size_from_attrs"]

GROUPS = ("", "events", "CD", "cd", "dvs")  # where the field datasets may lie
TABLES = ("events", "CD/events", "cd/events", "event")  # compound or N x 4 datasets


def find_layout(f) -> dict | None:
    """Where an open HDF5 file holds its events: ``{"kind": "fields", "group", "names"}``,
    ``{"kind": "compound", "dataset", "names"}``, ``{"kind": "table", "dataset"}``, or
    None (the first of :func:`find_layouts`)."""
    found = find_layouts(f)
    return found[0] if found else None


def find_layouts(f) -> list[dict]:
    """Every place an open HDF5 file holds events (see :func:`find_layout`), in the
    order they are preferred."""
    import h5py

    found = []
    for g in GROUPS:
        if g and (g not in f or not isinstance(f[g], h5py.Group)):
            continue
        grp = f[g] if g else f
        names = [k for k, v in grp.items() if isinstance(v, h5py.Dataset) and v.ndim == 1]
        named = event_fields(names)
        if named is not None:
            found.append({"kind": "fields", "group": g, "names": named})
    for d in TABLES:
        if d not in f or not isinstance(f[d], h5py.Dataset):
            continue
        ds = f[d]
        if ds.dtype.names:
            named = event_fields(ds.dtype.names)
            if named is not None:
                found.append({"kind": "compound", "dataset": d, "names": named})
        elif ds.ndim == 2 and 4 in ds.shape and ds.dtype.kind in "iuf":
            found.append({"kind": "table", "dataset": d})
    return found


def _where(lay: dict) -> str:
    """Where layout ``lay`` lies, as a path in the file."""
    return lay["dataset"] if "dataset" in lay else (lay["group"] or "/") + " (x, y, t, p)"


def _n_events(f, lay: dict) -> int:
    """The number of events of layout ``lay``, from the datasets' shapes (nothing read)."""
    if lay["kind"] == "fields":
        grp = f[lay["group"]] if lay["group"] else f
        return int(grp[lay["names"]["t"]].shape[0])
    shape = f[lay["dataset"]].shape
    return int(shape[0] if lay["kind"] == "compound" or shape[1] == 4 else shape[1])


SIZE_ATTRS = ("height", "width", "sensor_height", "sensor_width", "geometry", "sensor_size",
              "sensor_resolution")


def size_from_attrs(path: Path, *objs) -> tuple[int, int] | None:
    """The sensor size the attributes of ``objs`` (first one stating it) give, or None;
    read by :func:`evmotion.io.h5attrs.read_attrs_many` (a corrupt variable-length
    attribute cannot hang the reader)."""
    for a in read_attrs_many(path, objs, SIZE_ATTRS):
        for hk, wk in (("height", "width"), ("sensor_height", "sensor_width")):
            if hk in a and wk in a:
                return _checked_size(path, a[hk], a[wk], f"attributes '{hk}', '{wk}'")
        if "geometry" in a:  # Metavision: "1280x720"
            wh = str(a["geometry"]).lower().split("x")
            if not (len(wh) == 2 and all(v.strip().isdigit() for v in wh)):
                # ignored, it had let the size come from the coordinates with a warning
                # that the file states none (probe AS)
                raise FormatError(path, f"attribute 'geometry' is {a['geometry']!r}, not a "
                                  "sensor size WxH (e.g. '1280x720'): a corrupt header?",
                                  "give the sensor size (--sensor-size H W)")
            return _checked_size(path, wh[1], wh[0], "attribute 'geometry' (WxH)")
        for key in ("sensor_size", "sensor_resolution"):  # event_utils / E2VID: (H, W)
            if key not in a:
                continue
            v = np.asarray(a[key]).ravel()
            if v.size < 2:
                # ([60] or 'abc' had been passed over for a default size, said to be
                # assumed as the file states none, probe CG)
                shown = v.tolist() if np.ndim(a[key]) else v.tolist()[0]
                raise FormatError(path, f"attribute '{key}' is {shown!r}, not a sensor size "
                                  "(height, width): a corrupt header?",
                                  "give the sensor size (--sensor-size H W)")
            return _checked_size(path, v[0], v[1], f"attribute '{key}' (H, W)")
    return None


def _checked_size(path: Path, h, w, what: str) -> tuple[int, int]:
    # (check_sensor_size refuses fractions: int() had floored 60.9 to 60, probe CG)
    return check_sensor_size(path, (h, w), what)


def read(path: str | os.PathLike, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, columns: str | None = None,
         time_unit: str | None = None, validate: bool = True) -> EventArray:
    """Read events from an HDF5 file in another tool's layout (see the module).

    Examples
    --------
    >>> import h5py
    >>> with h5py.File("v2e_events.h5", "w") as f:  # v2e's N x 4 rows t, x, y, p
    ...     f["events"] = np.array([[100, 7, 4, 1], [200, 3, 6, 0], [300, 5, 2, 1]])
    ...     f.attrs["height"], f.attrs["width"] = 260, 346
    >>> ev = read("v2e_events.h5")
    >>> ev.sensor_size, ev.t.tolist(), ev.x.tolist()
    ((260, 346), [100, 200, 300], [7, 3, 5])
    """
    path = Path(path)
    with open_h5(path) as f:  # registers the Blosc filters other tools compress with
        found = find_layouts(f)
        if not found:
            raise FormatError(path, "no events found: no x, y, t, p datasets (at the root or "
                              "in events/, CD/), no compound or N x 4 'events' dataset")
        lay, others = found[0], found[1:]
        meta = {"source": str(path), "format": "h5generic", "layout": lay["kind"]}
        if others:
            # events/ read, CD/events beside it left unsaid (probe AS)
            warnings.warn(EvmotionWarning(
                f"{path}: read the events of {_where(lay)} ({_n_events(f, lay):,}); the file "
                "also holds " + ", ".join(f"{_where(o)} ({_n_events(f, o):,})"
                                          for o in others) + ", not read"), stacklevel=3)
        if lay["kind"] == "fields":
            grp = f[lay["group"]] if lay["group"] else f
            prefix = f"{lay['group']}/" if lay["group"] else ""
            cols = {k: _load(path, grp[n], prefix + n) for k, n in lay["names"].items()}
            lengths = {prefix + lay["names"][k]: len(v) for k, v in cols.items()}
            if len(set(lengths.values())) > 1:
                raise FormatError(path, "the event fields differ in length: " + ", ".join(
                    f"{n} {m:,}" for n, m in lengths.items()))
            size = sensor_size or size_from_attrs(path, grp, f)
        elif lay["kind"] == "compound":
            data = _load(path, f[lay["dataset"]], lay["dataset"])
            cols = {k: data[n] for k, n in lay["names"].items()}
            size = sensor_size or size_from_attrs(path, f[lay["dataset"]], f)
        else:
            cols, meta["columns"] = split_columns(
                path, _load(path, f[lay["dataset"]], lay["dataset"]), columns)
            size = sensor_size or size_from_attrs(path, f[lay["dataset"]], f)
    if sensor_size is not None:
        size = tuple(sensor_size)
    if size is None:
        meta["sensor_size_from"] = LARGEST_COORDINATE
    p = np.asarray(cols["p"])
    p = p.astype(np.int8) if p.dtype.kind == "b" else p
    ev = events_from_columns(path, cols["x"], cols["y"], cols["t"], p, sensor_size=size,
                             time_unit=time_unit, meta=meta, validate=validate,
                             time_field=lay.get("names", {}).get("t"))
    if size is None:
        warn_inferred_size(path, ev.sensor_size)
    return ev.slice_time(t0, t1) if (t0 is not None or t1 is not None) else ev


def _load(path: Path, ds, name: str) -> np.ndarray:
    """The whole dataset ``ds``, its storage checked first (:func:`check_h5_storage`); a
    compression filter this process lacks is named."""
    check_h5_storage(path, ds, name)
    try:
        return ds[()]
    except OSError as exc:
        raise filter_error(path, exc, ds, name) from None


def iter_chunks(path: str | os.PathLike, chunk_events: int, **kw) -> Iterator[EventArray]:
    """Chunks of ``chunk_events`` (the file is read whole)."""
    yield from chunks_of_read(read, path, chunk_events, **kw)


def partial_fields(f) -> tuple[list[str], list[str]]:
    """``(datasets, missing)``: where an open HDF5 file's 1-D datasets (at the root,
    ``events/``, ``CD/``...) name two or three of the event fields ``t, x, y, p``, those
    datasets and the fields none of them names -- what a file missing ``p``, say, lacks.
    Two empty lists otherwise."""
    import h5py

    for g in GROUPS:
        if g and (g not in f or not isinstance(f[g], h5py.Group)):
            continue
        grp = f[g] if g else f
        names = sorted(k for k, v in grp.items() if isinstance(v, h5py.Dataset) and v.ndim == 1)
        missing = [k for k, aliases in EVENT_FIELD_NAMES.items()
                   if not any(split_unit(n)[0] in aliases for n in names)]
        if 1 <= len(missing) <= 2:
            return [f"{g}/{n}" if g else n for n in names], missing
    return [], []


def _sniff(path: Path, head: bytes) -> bool:
    if not head.startswith(HDF5_MAGIC):
        return False
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return find_layout(f) is not None
    except (OSError, KeyError, ValueError):
        return False


def describe(path: str | os.PathLike) -> dict:
    """What the file's header states: the sensor size (its attributes) and the number of
    events (the datasets' shapes), without reading the events."""
    path = Path(path)
    with open_h5(path) as f:
        lay = find_layout(f)
        if lay is None:
            raise FormatError(path, "no events found")
        obj = (f[lay["group"]] if lay["group"] else f) if lay["kind"] == "fields" \
            else f[lay["dataset"]]
        out: dict = {"format": "h5generic", "layout": _where(lay),
                     "n_events": _n_events(f, lay)}
        size = size_from_attrs(path, obj, f)
        if size is not None:
            out["sensor_size"] = size
    return out


FORMAT = FormatSpec(name="h5generic", extensions=(".h5", ".hdf5"), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, describe=describe)
